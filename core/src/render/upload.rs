//! Preparing an asset's maps for the marcher at upload: depth codes with sub-texel silhouettes,
//! footprint texels, the visible box, and the direction lookup texture.

use std::sync::Arc;
use std::sync::atomic::Ordering;

use glam::DVec3;

use crate::asset::{AssetError, AssetFile, AssetHeader, Channel, Encoding, ImageKey};
use crate::geometry;
use crate::gpu::{Gpu, GpuError, array_view, texture_array};
use crate::light::LightStates;

use super::options::{RenderError, UploadOptions};
use super::{GpuLightField, Renderer};

/// Texture bytes [`Renderer::upload`] allocates on the device for an asset: one colour
/// (RGBA8, 4 bytes) and one depth-footprint (RGBA16, 8 bytes) texel per map texel, for every
/// camera (padded as [`Gpu::padded_layers`] does) and every layer of the base state, plus one
/// RGBA8 texel per map texel and camera for each light-state map (the ambient part, the normals
/// and every proxy direction, [`crate::light`]). The upload stages one layer's worth again on the host
/// while it runs. Saturates instead of overflowing. A two-plane asset takes
/// [`crate::two_plane_render::field_bytes_with`] of its planes (BC1 colour counted compressed).
pub fn field_bytes(header: &AssetHeader) -> u64 {
    if let Some(planes) = header.two_plane() {
        // BC1 colour stays compressed on every device that samples BC (all desktop GPUs and
        // lavapipe); BC7 may be decoded on the host (`Gpu::keeps_compressed`): counted whole.
        return crate::two_plane_render::field_bytes_with(
            planes,
            header
                .compression(Channel::Color)
                .filter(|&c| c == crate::asset::BlockCodec::Bc1),
        );
    }
    let side = u64::from(header.image_size()[0]);
    let layers = u64::from(Gpu::padded_layers(header.camera_count()));
    // Deformation states: a whole copy of the base state's maps each.
    let deformations = (0..header.states.len())
        .filter(|&s| crate::deform::is_geometry_state(header, s))
        .count() as u64;
    let base = base_field_bytes(header).saturating_mul(1 + deformations);
    // Light states: one RGBA8 map per camera for the ambient part and each proxy direction.
    let light_maps = LightStates::of(header).ok().flatten().map_or(0, |s| {
        u64::from(s.count) + 1 + u64::from(s.normal.is_some())
    });
    let lights = [light_maps, layers, side, side, 4]
        .into_iter()
        .fold(1, u64::saturating_mul);
    base.saturating_add(lights)
}

/// [`field_bytes`] of the base state alone: what an upload that leaves the other states out
/// allocates.
fn base_field_bytes(header: &AssetHeader) -> u64 {
    let side = u64::from(header.image_size()[0]);
    let layers = u64::from(Gpu::padded_layers(header.camera_count()));
    [
        layers,
        header.layers.len() as u64,
        side,
        side,
        FIELD_TEXEL_BYTES,
    ]
    .into_iter()
    .fold(1, u64::saturating_mul)
}

/// Bytes per map texel on the device: RGBA8 colour plus RGBA16 depth footprint.
const FIELD_TEXEL_BYTES: u64 = 4 + 8;

impl Renderer {
    /// Uploads an asset's base state, every layer and camera, as texture arrays (one pair per
    /// layer).
    ///
    /// # Errors
    /// [`RenderError::Asset`] for unreadable images, [`RenderError::Gpu`] for device limits.
    pub fn upload(&self, asset: &AssetFile) -> Result<GpuLightField, RenderError> {
        self.upload_with(asset, &UploadOptions::default())
    }

    /// [`Renderer::upload`] with options: `depth_bits: Some(8)` requantizes a 16-bit asset's
    /// depth to the 8-bit codes an 8-bit bake stores (the depth-precision knob of the
    /// trade-off sweep, without a second bake).
    ///
    /// # Errors
    /// As [`Renderer::upload`]; [`RenderError::Option`] for depth bits other than 8 or 16, or
    /// 16 bits asked of an 8-bit asset (precision cannot be added back).
    pub fn upload_with(
        &self,
        asset: &AssetFile,
        options: &UploadOptions,
    ) -> Result<GpuLightField, RenderError> {
        let header = asset.header();
        let geometry = header.spherical("the spherical renderer")?;
        let n = geometry.resolution_px;
        let cameras = geometry.camera_count;
        let max_level = u32::from(geometry.camera_level);
        let depth_encoding = header
            .encoding(Channel::Depth)
            .ok_or_else(|| AssetError::Header("no depth channel".to_owned()))?;
        let requantize_8 = match (options.depth_bits, depth_encoding) {
            (None, _) | (Some(8), Encoding::R8) => false,
            (Some(8), _) => true,
            (Some(16), Encoding::R8) => {
                return Err(RenderError::Option(
                    "depth bits 16 asked of an asset that stores 8-bit depth".to_owned(),
                ));
            }
            (Some(16), _) => false,
            (Some(b), _) => {
                return Err(RenderError::Option(format!("depth bits {b}: use 8 or 16")));
            }
        };
        let limit = self.gpu.device.limits().max_texture_dimension_2d;
        if n > limit {
            return Err(GpuError::Limit {
                what: "map resolution",
                needed: n.into(),
                limit: limit.into(),
            }
            .into());
        }
        self.gpu.check_layers(Gpu::padded_layers(cameras))?;
        let translucent = (header.encoding(Channel::Color) == Some(Encoding::Rgba8Premultiplied))
            .then(|| translucent_depth_threshold(header));
        let (maps, mut union) =
            self.upload_state(asset, 0, depth_encoding, requantize_8, translucent)?;
        let mut deformations = Vec::new();
        let mut shared_states = Vec::new();
        if !options.base_state_only {
            // Which states store any page, from one pass over the index.
            let mut stores = vec![false; header.states.len()];
            for entry in asset.index() {
                if let Some(flag) = stores.get_mut(usize::from(entry.key.state)) {
                    *flag = true;
                }
            }
            for (state, &stored) in stores.iter().enumerate().skip(1) {
                if !crate::deform::is_geometry_state(header, state) {
                    continue;
                }
                let state_index = state as u16;
                // A state that stores no page reads as the base state: it shares its maps.
                if !stored {
                    shared_states.push(state_index);
                    continue;
                }
                let (maps, boxed) = self.upload_state(
                    asset,
                    state_index,
                    depth_encoding,
                    requantize_8,
                    translucent,
                )?;
                // The field's box holds every state's surface (scenes cull by it).
                for axis in 0..3 {
                    union[0][axis] = union[0][axis].min(boxed[0][axis]);
                    union[1][axis] = union[1][axis].max(boxed[1][axis]);
                }
                deformations.push(super::StateMaps {
                    state: state_index,
                    maps,
                });
            }
        }
        let lights = if options.base_state_only {
            None
        } else {
            self.upload_lights(asset)?
        };
        let gpu_bytes = if options.base_state_only {
            base_field_bytes(header)
        } else {
            // The states without maps of their own (no stored page) cost nothing.
            field_bytes(header)
                .saturating_sub(base_field_bytes(header).saturating_mul(shared_states.len() as u64))
        };
        let frame = &header.frame;
        // Decremented by the field's drop.
        self.resident.fields.fetch_add(1, Ordering::AcqRel);
        self.resident.bytes.fetch_add(gpu_bytes, Ordering::AcqRel);
        Ok(GpuLightField {
            scale: frame.world_from_lf_scale(),
            center: DVec3::from(frame.center),
            radius: frame.radius,
            max_level,
            resolution: n,
            gpu_bytes,
            visible_box: union,
            layers: header.layers.clone(),
            layer_order: header.layer_order,
            translucent,
            maps,
            deformations,
            shared_states,
            lights,
            gpu: Arc::clone(&self.gpu),
            resident: Arc::clone(&self.resident),
        })
    }
}

impl Renderer {
    /// One state's maps (every layer; pages the state leaves out read from state 0), with the
    /// union of the layers' visible boxes.
    fn upload_state(
        &self,
        asset: &AssetFile,
        state: u16,
        depth_encoding: Encoding,
        requantize_8: bool,
        translucent: Option<f32>,
    ) -> Result<(Vec<super::LayerMaps>, [[f32; 3]; 2]), RenderError> {
        let header = asset.header();
        let layer_count = u16::try_from(header.layers.len())
            .map_err(|_| AssetError::Header("too many layers".to_owned()))?;
        let n = header.image_size()[0];
        let cameras = header.camera_count();
        let mut maps = Vec::with_capacity(header.layers.len());
        let mut union = VisibleBox::default();
        for layer in 0..layer_count {
            let mut colors = Vec::with_capacity(cameras as usize);
            let mut depths = Vec::with_capacity(cameras as usize);
            let mut visible = VisibleBox::default();
            let positions = &geometry::camera_set().positions;
            for k in 0..cameras {
                colors.push(asset.read_image(ImageKey::new(layer, state, k, Channel::Color))?);
                let raw = asset.read_image(ImageKey::new(layer, state, k, Channel::Depth))?;
                let codes: Vec<u16> = match depth_encoding {
                    Encoding::R16 => raw
                        .chunks_exact(2)
                        .map(|c| u16::from_le_bytes([c[0], c[1]]))
                        .collect(),
                    Encoding::R8 => raw
                        .iter()
                        .map(|&v| {
                            geometry::encode_depth_u16(if v == geometry::NO_HIT_U8 {
                                1.0
                            } else {
                                geometry::decode_depth_u8(v)
                            })
                        })
                        .collect(),
                    _ => raw
                        .chunks_exact(4)
                        .map(|c| {
                            geometry::encode_depth_u16(
                                f32::from_le_bytes([c[0], c[1], c[2], c[3]]).max(0.0),
                            )
                        })
                        .collect(),
                };
                let codes = if requantize_8 {
                    codes.into_iter().map(requantize_u16_to_u8).collect()
                } else {
                    codes
                };
                visible.add_map(&codes, n as usize, positions[k as usize]);
                // Premultiplied maps have no edge texels (docs/format.md §8.5).
                let codes = if translucent.is_some() {
                    codes
                } else {
                    edge_codes(&codes, &mut colors[k as usize], n as usize)
                };
                depths.push(footprint_texels(&codes, n as usize));
            }
            let color_refs: Vec<&[u8]> = colors.iter().map(Vec::as_slice).collect();
            let depth_refs: Vec<&[u8]> = depths.iter().map(Vec::as_slice).collect();
            let color_tex = texture_array(
                &self.gpu,
                "light-field colour",
                wgpu::TextureFormat::Rgba8Unorm,
                n,
                n,
                &color_refs,
            );
            let depth_tex = texture_array(
                &self.gpu,
                "light-field depth footprints",
                wgpu::TextureFormat::Rgba16Uint,
                n,
                n,
                &depth_refs,
            );
            // Submitting flushes the texture writes, which wgpu otherwise holds (with a staging copy
            // of every byte) until the next frame is submitted; waiting frees that copy and turns an
            // allocation failure into an error here rather than in some later frame.
            self.gpu.queue.submit(std::iter::empty());
            drop((colors, depths));
            self.gpu.wait()?;
            let color_view = array_view(&color_tex);
            let depth_view = array_view(&depth_tex);
            let group = self.field_group(&color_view, &depth_view, [&color_view; 5]);
            let visible_box = visible.finish(n, requantize_8 || depth_encoding == Encoding::R8);
            let (lo, hi) = (
                glam::Vec3::from(visible_box[0]),
                glam::Vec3::from(visible_box[1]),
            );
            if lo.cmple(hi).all() {
                union.lo = union.lo.min(lo);
                union.hi = union.hi.max(hi);
            }
            maps.push(super::LayerMaps {
                visible_box,
                group,
                textures: [color_tex, depth_tex],
                views: [color_view, depth_view],
            });
        }
        let union = if union.lo.cmple(union.hi).all() {
            [union.lo.to_array(), union.hi.to_array()]
        } else {
            maps[0].visible_box
        };
        Ok((maps, union))
    }
}

impl Renderer {
    /// The asset's light states' colour maps ([`crate::light`]), or `None` without them.
    fn upload_lights(&self, asset: &AssetFile) -> Result<Option<super::LightMaps>, RenderError> {
        let header = asset.header();
        let Some(states) = LightStates::of(header)? else {
            return Ok(None);
        };
        let n = header.image_size()[0];
        let cameras = header.camera_count();
        let upload = |state: u16| -> Result<(wgpu::Texture, wgpu::TextureView), RenderError> {
            let mut colors = Vec::with_capacity(cameras as usize);
            for k in 0..cameras {
                colors.push(asset.read_image(ImageKey::new(0, state, k, Channel::Color))?);
            }
            let refs: Vec<&[u8]> = colors.iter().map(Vec::as_slice).collect();
            let texture = texture_array(
                &self.gpu,
                "light-state colour",
                wgpu::TextureFormat::Rgba8Unorm,
                n,
                n,
                &refs,
            );
            self.gpu.queue.submit(std::iter::empty());
            drop(colors);
            self.gpu.wait()?;
            let view = array_view(&texture);
            Ok((texture, view))
        };
        let ambient = upload(states.ambient)?;
        let normal = states.normal.map(upload).transpose()?;
        let direct = states
            .direct
            .iter()
            .map(|&s| upload(s))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Some(super::LightMaps {
            count: states.count,
            ambient,
            normal,
            direct,
            shadows: crate::bake::BakeOptions::of(header).shading.shadows,
        }))
    }
}

/// Running bounds of the surface points the depth maps hold (light-field units).
pub(super) struct VisibleBox {
    pub(super) lo: glam::Vec3,
    pub(super) hi: glam::Vec3,
}

impl Default for VisibleBox {
    fn default() -> Self {
        VisibleBox {
            lo: glam::Vec3::splat(f32::INFINITY),
            hi: glam::Vec3::splat(f32::NEG_INFINITY),
        }
    }
}

impl VisibleBox {
    /// Adds every hit texel of one camera's `n×n` map: the point `p + d·chord·w` of the
    /// texel centre's direction `w` (the parabolic inverse in the camera frame).
    pub(super) fn add_map(&mut self, codes: &[u16], n: usize, camera: glam::Vec3) {
        let [fx, fy, fz] = geometry::camera_frame(camera);
        let scale = 2.0 / n as f32;
        for (row, line) in codes.chunks_exact(n).enumerate() {
            let v = (row as f32 + 0.5) * scale - 1.0;
            for (col, &code) in line.iter().enumerate() {
                if code == geometry::NO_HIT_U16 {
                    continue;
                }
                let u = (col as f32 + 0.5) * scale - 1.0;
                let s = u * u + v * v;
                let inv = 1.0 / (1.0 + s);
                let (rx, ry, rz) = (2.0 * u * inv, 2.0 * v * inv, (1.0 - s) * inv);
                if rz <= 0.0 {
                    continue;
                }
                let w = fx * rx + fy * ry + fz * rz;
                // Chord of a unit-sphere camera along w: −2 p·w = 2 r_z.
                let x = camera + w * (geometry::decode_depth_u16(code) * 2.0 * rz);
                self.lo = self.lo.min(x);
                self.hi = self.hi.max(x);
            }
        }
    }

    /// The box grown by a margin covering what a lookup can return beyond the texel centres:
    /// one texel of angle (≤ 2/n rad per texel at the rim) at chord ≤ 2, doubled, plus the
    /// depth quantization (8-bit: 1/255 of a chord ≤ 2), plus 0.01 for f32 rounding. An empty
    /// map gives an empty box (lo > hi), which no ray enters.
    pub(super) fn finish(&self, n: u32, eight_bit: bool) -> [[f32; 3]; 2] {
        if self.lo.cmpgt(self.hi).any() {
            return [[1.0; 3], [-1.0; 3]];
        }
        let quantization = if eight_bit {
            2.0 / 255.0
        } else {
            2.0 / 65535.0
        };
        let margin = 8.0 / n.max(1) as f32 + quantization + 0.01;
        [(self.lo - margin).to_array(), (self.hi + margin).to_array()]
    }
}

/// The 16-bit code of the depth an 8-bit bake would store for a 16-bit code (no hit stays no
/// hit). The extra rounding of the 16-bit code moves the 8-bit decision only for depths within
/// 1/131070 of an 8-bit rounding boundary.
pub(super) fn requantize_u16_to_u8(code: u16) -> u16 {
    if code == geometry::NO_HIT_U16 {
        return code;
    }
    let d8 = geometry::encode_depth_u8(geometry::decode_depth_u16(code));
    geometry::encode_depth_u16(geometry::decode_depth_u8(d8))
}

/// First footprint code of a no-hit texel beside the silhouette ([`edge_codes`]); hit codes are
/// capped below it (every hit of a valid asset has depth < 0.854, code ≤ 55 962).
pub(super) const EDGE_BASE: u16 = u16::MAX - EDGE_CODES;
/// Edge codes: `EDGE_BASE + (e level << 9 | depth level)`, up to 65 534 (no-hit is 65 535).
pub(super) const EDGE_CODES: u16 = EDGE_E_LEVELS * EDGE_DEPTH_LEVELS;
/// Levels of the silhouette position e in an edge code: e = (level + 0.5) / 16 texel.
pub(super) const EDGE_E_LEVELS: u16 = 16;
/// Levels of the extrapolated depth in an edge code: depth = level / 511 (a power of two: the
/// shader splits a code with a shift).
pub(super) const EDGE_DEPTH_LEVELS: u16 = 512;
const _: () = assert!(EDGE_DEPTH_LEVELS.is_power_of_two());

/// The depth of one level of an edge code's extrapolated depth, in f32 as the shader takes it.
pub(super) fn edge_depth_step() -> f32 {
    (1.0 / f64::from(EDGE_DEPTH_LEVELS - 1)) as f32
}

/// Folds the sub-texel silhouettes of a camera's `n×n` colour map into its depth codes, where
/// `probe` (shaders/render/probe.wgsl) reads them in the same load as the depths. A no-hit texel with alpha
/// A > 0 lies beside the silhouette, which passes e = A / 255 texel spacings from the centres of
/// its hit 4-neighbours at depth code R | G << 8 (docs/format.md §8.5). It gets code
/// `EDGE_BASE + e level · 512 + depth level`, where the depth is the line from its neighbours'
/// mean depth through the silhouette's depth (at e) extended to its own centre: bilinear weights
/// over the footprint then reproduce the surface receding to the silhouette instead of a flat
/// skirt in front of it. Its colour becomes 0, as the format has no-hit colour; a texel without a
/// hit neighbour (no silhouette to place) stays plain no hit.
pub(super) fn edge_codes(codes: &[u16], color: &mut [u8], n: usize) -> Vec<u16> {
    let mut out: Vec<u16> = codes
        .iter()
        .map(|&c| {
            if c == geometry::NO_HIT_U16 {
                c
            } else {
                c.min(EDGE_BASE - 1)
            }
        })
        .collect();
    for (i, texel) in color.chunks_exact_mut(4).enumerate().take(codes.len()) {
        if codes[i] != geometry::NO_HIT_U16 || texel[3] == 0 {
            continue;
        }
        let (a, silhouette) = (texel[3], u16::from_le_bytes([texel[0], texel[1]]));
        texel.copy_from_slice(&[0; 4]);
        let (sum, count) = geometry::texel_neighbours(i, n)
            .into_iter()
            .flatten()
            .filter_map(|j| codes.get(j).copied())
            .filter(|&c| c != geometry::NO_HIT_U16)
            .fold((0.0_f64, 0_u32), |(sum, count), c| {
                (sum + f64::from(c) / 65535.0, count + 1)
            });
        if count == 0 {
            continue;
        }
        let near = sum / f64::from(count);
        let e_level = (f64::from(a) / 255.0 * f64::from(EDGE_E_LEVELS)).floor() as u16;
        let e_level = e_level.min(EDGE_E_LEVELS - 1);
        // The position the shader decodes, so that its bilinear depth meets the silhouette's
        // exactly there.
        let e = (f64::from(e_level) + 0.5) / f64::from(EDGE_E_LEVELS);
        let silhouette = f64::from(silhouette.min(geometry::NO_HIT_U16 - 1)) / 65535.0;
        let extrapolated = (near + (silhouette - near) / e).clamp(0.0, 1.0);
        let depth_level = (extrapolated * f64::from(EDGE_DEPTH_LEVELS - 1)).round() as u16;
        out[i] = EDGE_BASE + e_level * EDGE_DEPTH_LEVELS + depth_level;
    }
    out
}

/// Packs a camera's `n×n` depth codes into footprint texels: texel `(x, y)` holds the codes of
/// `(x, y)`, `(x+1, y)`, `(x, y+1)`, `(x+1, y+1)` (clamped at the border), as `Rgba16Uint` bytes.
pub(super) fn footprint_texels(codes: &[u16], n: usize) -> Vec<u8> {
    let at = |x: usize, y: usize| {
        codes
            .get(y.min(n - 1) * n + x.min(n - 1))
            .copied()
            .unwrap_or(geometry::NO_HIT_U16)
    };
    let mut out = Vec::with_capacity(n * n * 8);
    for y in 0..n {
        for x in 0..n {
            for code in [at(x, y), at(x + 1, y), at(x, y + 1), at(x + 1, y + 1)] {
                out.extend_from_slice(&code.to_le_bytes());
            }
        }
    }
    out
}

/// The marcher's direction lookup ([`geometry::CameraSet::direction_lookup`] at
/// [`geometry::DIRECTION_LOOKUP_SIZE`]), built once per process.
pub(super) fn direction_lookup() -> &'static [u16] {
    static LOOKUP: std::sync::OnceLock<Vec<u16>> = std::sync::OnceLock::new();
    LOOKUP.get_or_init(|| geometry::camera_set().direction_lookup(geometry::DIRECTION_LOOKUP_SIZE))
}

/// [`direction_lookup`] as a texture.
pub(super) fn direction_lookup_texture(gpu: &Gpu) -> wgpu::TextureView {
    use wgpu::util::DeviceExt;
    let n = geometry::DIRECTION_LOOKUP_SIZE;
    gpu.device
        .create_texture_with_data(
            &gpu.queue,
            &wgpu::TextureDescriptor {
                label: Some("icosphere direction lookup"),
                size: wgpu::Extent3d {
                    width: n,
                    height: n,
                    depth_or_array_layers: 1,
                },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format: wgpu::TextureFormat::R16Uint,
                usage: wgpu::TextureUsages::TEXTURE_BINDING,
                view_formats: &[],
            },
            wgpu::util::TextureDataOrder::LayerMajor,
            bytemuck::cast_slice(direction_lookup()),
        )
        .create_view(&wgpu::TextureViewDescriptor::default())
}

/// The depth threshold `τ_d` a translucent asset was baked with (its provenance), else DESIGN
/// §9's default 0.5.
pub(crate) fn translucent_depth_threshold(header: &crate::asset::AssetHeader) -> f32 {
    header
        .provenance
        .bake_options
        .get("depth_threshold")
        .and_then(serde_json::Value::as_f64)
        .filter(|t| *t > 0.0 && *t <= 1.0)
        .map_or(0.5, |t| t as f32)
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use glam::Vec3;

    /// The shader's `locate`, replayed on the CPU in f32 with the same lookup: the triangle
    /// and the weights of its cameras.
    fn locate_like_shader(p: Vec3, level: u32) -> (usize, [u32; 3], [f32; 3]) {
        let set = geometry::camera_set();
        let n = geometry::DIRECTION_LOOKUP_SIZE;
        let lookup = direction_lookup();
        let (i, j) = geometry::octahedral_texel(p, n);
        let finest = u32::from(lookup[(j * n + i) as usize]);
        let l = level.min(geometry::MAX_LEVEL);
        let local = finest >> (2 * (geometry::MAX_LEVEL - l));
        let level_start = 20 * ((1u32 << (2 * l)) - 1) / 3;
        let t = (level_start + local) as usize;
        let v = set.triangles[t].v;
        (t, v, weights_like_shader(p, v))
    }

    /// The shader's `triangle_weights` in f32: direction `p`'s central-projection barycentric
    /// weights in the triangle of cameras `v`, clamped to it.
    fn weights_like_shader(p: Vec3, v: [u32; 3]) -> [f32; 3] {
        let [v0, v1, v2] = v.map(|k| geometry::camera_set().positions[k as usize]);
        let w = Vec3::new(
            p.dot(v1.cross(v2)),
            v0.dot(p.cross(v2)),
            v0.dot(v1.cross(p)),
        )
        .max(Vec3::ZERO);
        let sum = w.x + w.y + w.z;
        (if sum > 0.0 { w / sum } else { Vec3::X }).to_array()
    }

    /// Uniform pseudo-random numbers in [−1, 1) from `seed`.
    pub(in crate::render) fn signed_uniform(seed: u64) -> impl FnMut() -> f32 {
        let mut raw = crate::xorshift(seed);
        move || (raw() >> 11) as f32 / (1u64 << 53) as f32 * 2.0 - 1.0
    }

    /// `count` random unit directions drawn from `next` (uniform in [−1, 1] per axis).
    pub(in crate::render) fn random_directions(
        next: &mut impl FnMut() -> f32,
        count: usize,
    ) -> Vec<Vec3> {
        (0..count)
            .map(|_| Vec3::new(next(), next(), next()).normalize())
            .collect()
    }

    /// Every icosphere triangle's cameras and edge midpoints (all levels), triangle by
    /// triangle: where a lookup or a triangle's weights can go wrong.
    pub(in crate::render) fn vertices_and_edge_midpoints() -> Vec<Vec3> {
        let set = geometry::camera_set();
        set.triangles
            .iter()
            .flat_map(|t| {
                let [a, b, c] = t.v.map(|k| set.positions[k as usize]);
                [
                    a,
                    (a + b).normalize(),
                    (b + c).normalize(),
                    (c + a).normalize(),
                ]
            })
            .collect()
    }

    /// The smallest height of a `level` triangle over any of its edges, as the sine of the
    /// angle from that edge's great circle to the opposite camera.
    pub(in crate::render) fn smallest_height(level: u32) -> f32 {
        let set = geometry::camera_set();
        set.triangles[set.level_range(level)]
            .iter()
            .flat_map(|t| {
                let [a, b, c] = t.v.map(|k| set.positions[k as usize]);
                [(a, b, c), (b, c, a), (c, a, b)]
                    .map(|(x, y, z)| x.cross(y).normalize().dot(z).abs())
            })
            .fold(f32::INFINITY, f32::min)
    }

    /// `probe`'s decoding of an edge code (shaders/render/probe.wgsl): (e, extrapolated depth), in f32 as there.
    fn decode_edge_like_shader(code: u16) -> (f32, f32) {
        let rel = u32::from(code.wrapping_sub(EDGE_BASE));
        assert!(rel < u32::from(EDGE_CODES));
        let e =
            ((rel >> EDGE_DEPTH_LEVELS.trailing_zeros()) as f32 + 0.5) / f32::from(EDGE_E_LEVELS);
        let depth = (rel & u32::from(EDGE_DEPTH_LEVELS - 1)) as f32 * edge_depth_step();
        (e, depth)
    }

    #[test]
    fn edge_codes_place_the_silhouette_and_extend_the_depth() {
        // A 4×2 map: row 0 = hit (depth 0.4), edge texel (e = 100/255, silhouette depth 0.5),
        // plain no hit, an edge texel with no hit neighbour; row 1 = a hit whose code lies in
        // the edge range (capped), then no hits with alpha 0.
        let n = 4;
        let code = |d: f64| (d * 65535.0).round() as u16;
        let no = geometry::NO_HIT_U16;
        let codes = vec![code(0.4), no, no, no, 60_000, no, no, no];
        let mut color = vec![0u8; 32];
        color[..4].copy_from_slice(&[10, 20, 30, 255]);
        let sil = code(0.5).to_le_bytes();
        color[4..8].copy_from_slice(&[sil[0], sil[1], 0, 100]);
        color[12..16].copy_from_slice(&[sil[0], sil[1], 0, 77]);
        color[16..20].copy_from_slice(&[1, 2, 3, 255]);
        let out = edge_codes(&codes, &mut color, n);
        // Hits keep their codes and colours, capped below the edge range.
        assert_eq!(out[0], codes[0]);
        assert_eq!(out[4], EDGE_BASE - 1);
        assert_eq!(&color[..4], &[10, 20, 30, 255]);
        // Plain no-hit texels stay; an edge texel without a hit 4-neighbour (texel 3: its
        // neighbours are texels 2 and 7) becomes plain no hit; edge colours are cleared.
        assert_eq!((out[2], out[3], out[5]), (no, no, no));
        assert_eq!(&color[4..8], &[0; 4]);
        assert_eq!(&color[12..16], &[0; 4]);
        // Texel 1: its neighbours are texel 0 (hit, 0.4), texel 2 and texel 5 (no hit).
        assert!((EDGE_BASE..no).contains(&out[1]));
        let (e, depth) = decode_edge_like_shader(out[1]);
        // e: 100/255 = 0.392 lies in level 6 of 16 (0.375–0.4375), decoded at its middle.
        assert_eq!(e, 6.5 / 16.0);
        // The line from 0.4 (at the hit centre) through 0.5 (at e) reaches 0.4 + 0.1 / e at this
        // texel's centre; within half a depth level (0.5 / 511) plus f32 rounding.
        let want = 0.4 + 0.1 / f64::from(e);
        assert!(
            (f64::from(depth) - want).abs() <= 0.5 / 511.0 + 1e-5,
            "{depth} vs {want}"
        );
        // Every code round-trips: all e levels and depth levels decode to themselves.
        for e_level in 0..EDGE_E_LEVELS {
            for depth_level in [0, 1, 295, EDGE_DEPTH_LEVELS - 1] {
                let c = EDGE_BASE + e_level * EDGE_DEPTH_LEVELS + depth_level;
                assert!(c < no);
                let (e, d) = decode_edge_like_shader(c);
                assert_eq!(e, (f32::from(e_level) + 0.5) / 16.0);
                let want = f32::from(depth_level) / f32::from(EDGE_DEPTH_LEVELS - 1);
                assert!((d - want).abs() < 1e-6, "{c}: {d} vs {want}");
            }
        }
        // Extrapolation is clamped to [0, 1]: a silhouette far behind a near hit at e ≈ 0.
        let mut color = vec![0u8; 16];
        let far = code(0.85).to_le_bytes();
        color[4..8].copy_from_slice(&[far[0], far[1], 0, 1]);
        let out = edge_codes(&[code(0.1), no, no, no], &mut color, 2);
        assert_eq!(decode_edge_like_shader(out[1]).1, 1.0);
    }

    #[test]
    fn requantized_depth_equals_an_8_bit_bake() {
        // Exact: for every 16-bit hit code, the requantized code decodes to the 8-bit code an
        // 8-bit bake of the same depth stores, except within 1/131070 of a rounding boundary.
        let mut off_boundary = 0;
        for code in 0..geometry::NO_HIT_U16 {
            let d = geometry::decode_depth_u16(code);
            let want =
                geometry::encode_depth_u16(geometry::decode_depth_u8(geometry::encode_depth_u8(d)));
            let got = requantize_u16_to_u8(code);
            let frac = (f64::from(d) * 255.0).fract();
            if (frac - 0.5).abs() > 1.0 / 256.0 {
                off_boundary += 1;
                assert_eq!(got, want, "code {code}");
            }
            // Within 0.5/255 (+ f32 rounding) of the 16-bit depth below 254.5/255, as the
            // format promises; above, the last hit code 254 is up to 1/255 away.
            let err = (geometry::decode_depth_u16(got) - d).abs();
            let bound = if d < 254.5 / 255.0 { 0.5 } else { 1.0 } / 255.0 + 1e-6;
            assert!(err <= bound, "code {code}: {err}");
        }
        assert!(off_boundary > 60_000);
        assert_eq!(
            requantize_u16_to_u8(geometry::NO_HIT_U16),
            geometry::NO_HIT_U16
        );
    }

    /// The largest difference, over the cameras of both, between the weights the shader's
    /// lookup gives direction `p` at `level` and the exact ones of [`geometry::CameraSet::locate`],
    /// and how far (sine of the angle) `p` lies outside the triangle the lookup found.
    fn lookup_error(p: Vec3, level: u32) -> (f32, f32) {
        lookup_error_at(p, p, level)
    }

    /// [`lookup_error`] for a direction `p` weighed in the triangle the shader finds for
    /// another, `c` (an interior block's centre, shaders/render/shade.wgsl `shade_interior_block`).
    pub(in crate::render) fn lookup_error_at(c: Vec3, p: Vec3, level: u32) -> (f32, f32) {
        let set = geometry::camera_set();
        let (t, cams, _) = locate_like_shader(c, level);
        assert!(
            set.level_range(level).contains(&t),
            "level {level}: triangle {t}"
        );
        let w = weights_like_shader(p, cams);
        let exact = set.locate(p, level);
        let weight_of = |cams: &[u32; 3], w: &[f32; 3], k: u32| {
            cams.iter()
                .zip(w)
                .filter(|(c, _)| **c == k)
                .map(|(_, w)| *w)
                .sum::<f32>()
        };
        let worst = cams
            .iter()
            .chain(&exact.cameras)
            .map(|&k| {
                (weight_of(&cams, &w, k) - weight_of(&exact.cameras, &exact.weights, k)).abs()
            })
            .fold(0.0f32, f32::max);
        let [a, b, c] = cams.map(|k| set.positions[k as usize]);
        let outside = [(a, b), (b, c), (c, a)]
            .iter()
            .map(|(x, y)| -x.cross(*y).normalize().dot(p))
            .fold(f32::NEG_INFINITY, f32::max);
        (worst, outside)
    }

    #[test]
    fn shader_lookup_finds_the_triangle_within_its_reach() {
        // Random directions, and the places a lookup can go wrong: the cameras (vertices), the
        // midpoints of every level's edges, points just beside both, the octahedral map's fold
        // (z = 0), its axes and its corners (the poles).
        let mut next = signed_uniform(0x2545_f491_4f6c_dd1d);
        let mut points = random_directions(&mut next, 20_000);
        for q in vertices_and_edge_midpoints() {
            points.push(q);
            for _ in 0..4 {
                let jitter = Vec3::new(next(), next(), next()) * 3e-3;
                points.push((q + jitter).normalize());
            }
        }
        for k in 0..2000 {
            let a = k as f32 / 2000.0 * std::f32::consts::TAU;
            points.push(Vec3::new(a.cos(), a.sin(), 0.0));
            points.push(Vec3::new(a.cos(), a.sin(), 1e-7).normalize());
            points.push(Vec3::new(a.cos(), a.sin(), -1e-7).normalize());
        }
        points.extend([Vec3::X, -Vec3::X, Vec3::Y, -Vec3::Y, Vec3::Z, -Vec3::Z]);
        // A direction lies within DIRECTION_LOOKUP_REACH of its texel's centre, which its
        // triangle holds, so it lies at most that far outside it (sine, plus f32 rounding).
        let reach = geometry::DIRECTION_LOOKUP_REACH.sin() as f32 + 1e-5;
        // Weights: a point δ outside its triangle, across an edge, gets the weights of the
        // nearest point of that edge, where the exact triangle gives its opposite camera
        // about δ / h of weight (h: the height over that edge, as a sine); the weights of the
        // edge's cameras move by as much. Bound: 2 · reach / the smallest height of the
        // level's triangles.
        for level in 0..=3u32 {
            let height = smallest_height(level);
            let bound = 2.0 * reach / height;
            let (mut worst_w, mut worst_out) = (0.0f32, f32::NEG_INFINITY);
            for &p in &points {
                let (w, out) = lookup_error(p, level);
                worst_w = worst_w.max(w);
                worst_out = worst_out.max(out);
            }
            eprintln!(
                "level {level}: weights off by up to {worst_w} (bound {bound}, smallest height \
                 {height}), outside by up to {worst_out}"
            );
            assert!(
                worst_out <= reach,
                "level {level}: {worst_out} outside (reach {reach})"
            );
            assert!(
                worst_w <= bound,
                "level {level}: weights off by {worst_w} (bound {bound})"
            );
        }
    }

    /// The shader's `camera`, replayed on the CPU in f32: the frame of a camera at `p` built
    /// from the world axis of index `axis`.
    fn camera_like_shader(p: Vec3, axis: f32) -> [Vec3; 3] {
        let z = -p.normalize();
        let a = Vec3::select(
            Vec3::splat(axis).cmpeq(Vec3::new(0.0, 1.0, 2.0)),
            Vec3::ONE,
            Vec3::ZERO,
        );
        let x = a.cross(z).normalize();
        [x, z.cross(x), z]
    }

    #[test]
    fn shader_derives_the_camera_frames_of_the_bake() {
        // Every camera of the set (642, all levels): the frame the marcher derives from the
        // position and the axis index the renderer uploads equals the CPU's f64 frame, which
        // the bake rendered with, to f32 rounding (bound 1e-6 per component of the unit
        // vectors: a 256-texel map's texel spans about 0.008 rad, so a ten-thousandth of one).
        let set = geometry::camera_set();
        let mut worst = 0.0f32;
        for &p in &set.positions {
            let axis = geometry::camera_frame_axis(p) as f32;
            let derived = camera_like_shader(p, axis);
            let exact = geometry::camera_frame(p);
            for (d, e) in derived.iter().zip(&exact) {
                worst = worst.max((*d - *e).abs().max_element());
            }
        }
        eprintln!("derived frames off by up to {worst}");
        assert!(worst <= 1e-6, "{worst}");
        // The axis index is the one the frame was built from: x is perpendicular to it.
        for &p in &set.positions {
            let axis = geometry::camera_frame_axis(p);
            let [x, _, _] = geometry::camera_frame(p);
            assert!(x[axis].abs() <= 1e-6, "{p}: axis {axis}, x {x}");
        }
    }
}
