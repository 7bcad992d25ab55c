//! Deformation states (seed 000 §3.3): other meshes of the same object (a dent, a pose, a moved
//! part; any topology) baked in the base mesh's frame, each storing only the pages whose colour
//! or depth differ from the base state. Format: `docs/format.md` §8.6.
//!
//! The bake is deterministic (the same mesh gives the same bytes, and a triangle away from a
//! change is traced and shaded by the same arithmetic whatever the rest of the mesh is), so
//! [`DEFAULT_TOLERANCE`] is 0: a page is kept when any texel differs. What changes is found
//! where it shows, not where the geometry moved: a camera that sees a change only as a moved
//! shadow, or as a part now hidden behind another, keeps the pages where that shows.

use serde::{Deserialize, Serialize};

use crate::asset::{AssetError, AssetFile, AssetHeader, Channel, ImageKey, LfFrame, PageGrid};
use crate::mesh::Mesh;

/// The key of a deformation state's params (`{"deformation": {...}}`).
pub const PARAM_KEY: &str = "deformation";

/// Largest texel difference a page may have and still be left to the base state.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Tolerance {
    /// In colour codes (any of R, G, B, A).
    pub color: u8,
    /// In depth codes of the asset's encoding (16 or 8 bits).
    pub depth: u16,
}

/// Exact: the bake is deterministic (measured in BENCHMARKS.md, "Deformation states": a second
/// bake of an unchanged mesh stores no page).
pub const DEFAULT_TOLERANCE: Tolerance = Tolerance { color: 0, depth: 0 };

/// Page side of an asset with deformation states: small enough that a local change stores a
/// small part of a camera's image (a 256² map has 64 pages), large enough that the index stays
/// small (36 bytes a page) and pages compress (BENCHMARKS.md, "Deformation states").
pub const DEFAULT_STATE_PAGE: u32 = 32;

/// Errors of deformation states.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DeformError {
    /// A state name is empty, repeated or the base state's.
    #[error("state name {0:?}: {1}")]
    BadName(String, &'static str),
    /// A state mesh reaches outside the base mesh's bounding sphere, which the maps cover.
    #[error(
        "state {name:?} reaches {distance:.4} from the base's centre, outside its bounding sphere \
         (radius {radius:.4}): a deformation state must stay inside the base mesh's bounding \
         sphere; bake the larger shape as the base"
    )]
    Outside {
        /// The state.
        name: String,
        /// Farthest vertex distance from the centre, world units.
        distance: f64,
        /// The base's bounding radius.
        radius: f64,
    },
    /// Too many states for the format.
    #[error("{0} states: an asset holds at most 255 besides the base")]
    TooMany(usize),
}

/// A deformation state (or animation frame) to bake: its name and mesh, and where the mesh came
/// from.
#[derive(Clone, Copy, Debug)]
pub struct StateMesh<'a> {
    /// State name (unique, not `base`).
    pub name: &'a str,
    /// The deformed mesh, in the base mesh's world units.
    pub mesh: &'a Mesh,
    /// File name or description of its source.
    pub source_name: &'a str,
    /// Hex SHA-256 of its source bytes (empty if unknown).
    pub source_sha256: &'a str,
    /// The state's params instead of `{"deformation": {...}}`: an animation frame's
    /// `{"animation": {...}}` ([`animation_params`]).
    pub params: Option<&'a serde_json::Map<String, serde_json::Value>>,
}

/// The frame (bounding sphere) around every frame of an animation, in which all its frames
/// are baked.
pub fn frame_around(frames: &[Mesh]) -> crate::asset::LfFrame {
    let mut all = Mesh::default();
    for f in frames {
        let base = all.positions.len() as u32;
        all.positions.extend_from_slice(&f.positions);
        all.triangles
            .extend(f.triangles.iter().map(|t| t.map(|v| v + base)));
    }
    let sphere = all.bounding_sphere();
    crate::asset::LfFrame {
        center: sphere.center.to_array(),
        radius: sphere.radius,
    }
}

/// The animation of an asset baked with `--animation`: its frames' state indices (frame 0 is
/// the base state), frame rate and duration; `None` for an asset without one.
#[derive(Clone, Debug, PartialEq)]
pub struct AnimationInfo {
    /// The animation's name.
    pub name: String,
    /// Frames per second.
    pub fps: f64,
    /// Time of the animation's last key, seconds.
    pub duration: f64,
    /// State index of each frame, in frame order.
    pub states: Vec<u16>,
}

impl AnimationInfo {
    /// The animation an asset holds, if any (from its states' `animation` params).
    pub fn of(header: &AssetHeader) -> Option<AnimationInfo> {
        let base = header.states.first()?.params.get(ANIMATION_KEY)?;
        let mut frames: Vec<(u64, u16)> = header
            .states
            .iter()
            .enumerate()
            .filter_map(|(s, d)| {
                let frame = d.params.get(ANIMATION_KEY)?.get("frame")?.as_u64()?;
                Some((frame, s as u16))
            })
            .collect();
        frames.sort_unstable();
        Some(AnimationInfo {
            name: base.get("name")?.as_str()?.to_owned(),
            fps: base
                .get("fps")?
                .as_f64()
                .filter(|f| f.is_finite() && *f > 0.0)?,
            duration: base
                .get("duration")?
                .as_f64()
                .filter(|d| d.is_finite() && *d >= 0.0)?,
            states: frames.into_iter().map(|(_, s)| s).collect(),
        })
    }

    /// The state showing frame `frame`.
    ///
    /// # Errors
    /// A frame past the last, naming the count.
    pub fn state_of_frame(&self, frame: u32) -> Result<u16, String> {
        self.states.get(frame as usize).copied().ok_or_else(|| {
            format!(
                "frame {frame}: the animation {:?} has {} frames (0 to {})",
                self.name,
                self.states.len(),
                self.states.len().saturating_sub(1)
            )
        })
    }

    /// The frame shown at `time` seconds: the last frame at or before it.
    ///
    /// # Errors
    /// A time outside `[0, duration]` or not finite.
    pub fn frame_at(&self, time: f64) -> Result<u32, String> {
        if !(time.is_finite() && time >= 0.0 && time <= self.duration + 1e-9) {
            return Err(format!(
                "time {time} s is outside the animation {:?} (0 to {} s)",
                self.name, self.duration
            ));
        }
        let frame = (time * self.fps + 1e-6).floor() as u64;
        Ok(frame.min(self.states.len().saturating_sub(1) as u64) as u32)
    }
}

/// How an animation's frames are baked as states: frame 0 the base state, frame `i` the state
/// `frame_<iii>`, each with its `animation` params, all in the frame around every frame.
#[derive(Clone, Debug)]
pub struct AnimationLayout {
    /// The bounding sphere around every frame.
    pub frame: crate::asset::LfFrame,
    /// State names, frame by frame (frame 0's is unused: the base state keeps `base`).
    pub names: Vec<String>,
    /// State params, frame by frame.
    pub params: Vec<serde_json::Map<String, serde_json::Value>>,
}

impl AnimationLayout {
    /// The layout of a sampled animation.
    pub fn new(animation: &crate::mesh::AnimationFrames) -> Self {
        let count = animation.frames.len();
        Self {
            frame: frame_around(&animation.frames),
            names: (0..count).map(|i| format!("frame_{i:03}")).collect(),
            params: (0..count)
                .map(|i| animation_params(&animation.name, i, animation.fps, animation.duration))
                .collect(),
        }
    }

    /// The state meshes of frames 1.. (frame 0 is the base mesh), named after their source.
    pub fn state_meshes<'a>(
        &'a self,
        frames: &'a [Mesh],
        source_name: &'a str,
        source_sha256: &'a str,
    ) -> Vec<StateMesh<'a>> {
        frames
            .iter()
            .zip(self.names.iter().zip(&self.params))
            .skip(1)
            .map(|(mesh, (name, params))| StateMesh {
                name,
                mesh,
                source_name,
                source_sha256,
                params: Some(params),
            })
            .collect()
    }

    /// The state bake of `meshes` (from [`Self::state_meshes`]).
    pub fn state_bake<'a>(&'a self, meshes: &'a [StateMesh<'a>]) -> crate::bake::StateBake<'a> {
        crate::bake::StateBake {
            meshes,
            frame: Some(self.frame.clone()),
            base_params: self.params.first(),
            ..crate::bake::StateBake::default()
        }
    }
}

/// An animation frame's state params.
pub fn animation_params(
    name: &str,
    frame: usize,
    fps: f64,
    duration: f64,
) -> serde_json::Map<String, serde_json::Value> {
    let mut params = serde_json::Map::new();
    params.insert(
        ANIMATION_KEY.to_owned(),
        serde_json::json!({
            "name": name,
            "frame": frame,
            "time": frame as f64 / fps,
            "fps": fps,
            "duration": duration,
        }),
    );
    params
}

/// Checks names and that every state mesh lies inside the base frame's bounding sphere (a
/// relative 1e-6 of slack for rounding).
///
/// # Errors
/// [`DeformError`].
pub fn check_states(frame: &LfFrame, states: &[StateMesh<'_>]) -> Result<(), DeformError> {
    if states.len() > 255 {
        return Err(DeformError::TooMany(states.len()));
    }
    let center = glam::DVec3::from(frame.center);
    for (i, s) in states.iter().enumerate() {
        if s.name.is_empty() {
            return Err(DeformError::BadName(s.name.to_owned(), "empty"));
        }
        if s.name == "base" {
            return Err(DeformError::BadName(
                s.name.to_owned(),
                "`base` is the base state's",
            ));
        }
        if states[..i].iter().any(|o| o.name == s.name) {
            return Err(DeformError::BadName(s.name.to_owned(), "given twice"));
        }
        let distance = s
            .mesh
            .triangles
            .iter()
            .flatten()
            .filter_map(|&v| s.mesh.positions.get(v as usize))
            .map(|p| center.distance(glam::DVec3::from(p.map(f64::from))))
            .fold(0.0_f64, f64::max);
        if distance > frame.radius * (1.0 + 1e-6) {
            return Err(DeformError::Outside {
                name: s.name.to_owned(),
                distance,
                radius: frame.radius,
            });
        }
    }
    Ok(())
}

/// The state descriptions of `states`, in order, as [`crate::asset::StateDesc`]s.
pub fn state_descs(states: &[StateMesh<'_>]) -> Vec<crate::asset::StateDesc> {
    states
        .iter()
        .map(|s| {
            if let Some(params) = s.params {
                return crate::asset::StateDesc {
                    name: s.name.to_owned(),
                    params: params.clone(),
                };
            }
            let mut params = serde_json::Map::new();
            params.insert(
                PARAM_KEY.to_owned(),
                serde_json::json!({
                    "source_name": s.source_name,
                    "source_sha256": s.source_sha256,
                    "triangles": s.mesh.triangles.len(),
                }),
            );
            crate::asset::StateDesc {
                name: s.name.to_owned(),
                params,
            }
        })
        .collect()
}

/// Pages of an `n×n` image (`bytes_per_texel` 4 for RGBA8 colour, 2 for r16 depth, 1 for r8)
/// where `state` differs from `base` by more than `tolerance` codes in any texel component.
pub fn changed_pages(
    grid: &PageGrid,
    base: &[u8],
    state: &[u8],
    bytes_per_texel: usize,
    tolerance: u16,
) -> Vec<u32> {
    let side = grid.width() as usize;
    let differs = |at: usize| -> bool {
        let (a, b) = (
            &base[at..at + bytes_per_texel],
            &state[at..at + bytes_per_texel],
        );
        if bytes_per_texel == 2 {
            u16::from_le_bytes([a[0], a[1]]).abs_diff(u16::from_le_bytes([b[0], b[1]])) > tolerance
        } else {
            a.iter()
                .zip(b)
                .any(|(x, y)| u16::from(x.abs_diff(*y)) > tolerance)
        }
    };
    (0..grid.page_count())
        .filter(|&page| {
            grid.page_rect(page).is_some_and(|r| {
                (r.y..r.y + r.height).any(|y| {
                    (r.x..r.x + r.width)
                        .any(|x| differs((y as usize * side + x as usize) * bytes_per_texel))
                })
            })
        })
        .collect()
}

/// A dent: every vertex within `radius` of `at` (world units) moves by `depth · (1 − (d /
/// radius)²)²` against its normal, `d` its distance from `at` (a smooth bump to 0 at the rim).
/// Normals are recomputed where a triangle moved and kept elsewhere, so the rest of the mesh
/// bakes to the same bytes. For benchmarks and tests of deformation states.
///
/// # Errors
/// [`crate::mesh::MeshError`] when the dented mesh fails validation (a non-finite input).
pub fn dent(
    mesh: &Mesh,
    at: [f32; 3],
    radius: f32,
    depth: f32,
) -> Result<Mesh, crate::mesh::MeshError> {
    let at = glam::Vec3::from(at);
    let mut moved = vec![false; mesh.positions.len()];
    let mut positions = mesh.positions.clone();
    for (i, p) in positions.iter_mut().enumerate() {
        let d = glam::Vec3::from(*p).distance(at);
        if d < radius {
            let falloff = (1.0 - (d / radius).powi(2)).powi(2);
            let n = glam::Vec3::from(mesh.normals.get(i).copied().unwrap_or([0.0, 1.0, 0.0]));
            *p = (glam::Vec3::from(*p) - n * depth * falloff).to_array();
            moved[i] = falloff > 0.0;
        }
    }
    // Vertices of a triangle with a moved corner get new normals.
    let mut touched = vec![false; mesh.positions.len()];
    for t in &mesh.triangles {
        if t.iter().any(|&v| moved[v as usize]) {
            for &v in t {
                touched[v as usize] = true;
            }
        }
    }
    let mut out = Mesh {
        positions,
        normals: Vec::new(),
        ..mesh.clone()
    }
    .finish()?;
    for (i, normal) in out.normals.iter_mut().enumerate() {
        if !touched.get(i).copied().unwrap_or(true)
            && let Some(old) = mesh.normals.get(i)
        {
            *normal = *old;
        }
    }
    Ok(out)
}

/// What a deformation state of an asset stores.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct StateStorage {
    /// State index.
    pub index: u16,
    /// State name.
    pub name: String,
    /// Pages stored (colour and depth, every camera and layer).
    pub stored_pages: u64,
    /// Pages of a whole state.
    pub total_pages: u64,
    /// `stored_pages / total_pages`.
    pub fraction: f64,
    /// Cameras with at least one stored page.
    pub cameras: u32,
    /// Bytes of the stored pages, as stored (compressed).
    pub stored_bytes: u64,
}

/// The key of an animation frame's params (`{"animation": {"name", "frame", "time", "fps"}}`).
pub const ANIMATION_KEY: &str = "animation";

/// Whether state `s` of `header` is a geometry state, rendered from maps of its own: a
/// deformation state or an animation frame (other than state 0, the base).
pub fn is_geometry_state(header: &AssetHeader, s: usize) -> bool {
    s > 0
        && header.states.get(s).is_some_and(|d| {
            d.params.contains_key(PARAM_KEY) || d.params.contains_key(ANIMATION_KEY)
        })
}

/// What each deformation state of `asset` stores, from its index.
///
/// # Errors
/// A header without a page grid (unreachable for an opened asset).
pub fn storage(asset: &AssetFile) -> Result<Vec<StateStorage>, AssetError> {
    let header = asset.header();
    let grid = header.page_grid()?;
    let cameras = header.camera_count();
    let layers = header.layers.len() as u64;
    let total_pages = layers * u64::from(cameras) * 2 * u64::from(grid.page_count());
    let mut out = Vec::new();
    for (s, desc) in header.states.iter().enumerate() {
        if !is_geometry_state(header, s) {
            continue;
        }
        let index = s as u16;
        let stored_bytes = asset
            .index()
            .iter()
            .filter(|e| e.key.state == index)
            .map(|e| u64::from(e.length))
            .sum();
        let (mut stored, mut touched) = (0u64, 0u32);
        for camera in 0..cameras {
            let mut any = false;
            for layer in 0..layers as u16 {
                for channel in Channel::ALL {
                    let pages = asset.stored_pages(ImageKey::new(layer, index, camera, channel));
                    stored += u64::from(pages);
                    any |= pages > 0;
                }
            }
            touched += u32::from(any);
        }
        out.push(StateStorage {
            index,
            name: desc.name.clone(),
            stored_pages: stored,
            total_pages,
            fraction: stored as f64 / total_pages.max(1) as f64,
            cameras: touched,
            stored_bytes,
        });
    }
    Ok(out)
}

/// The index of the state called `name` of `header`: `None` for the base state (`None` or
/// `"base"`), an error naming the asset's states for an unknown name.
///
/// # Errors
/// The message lists the states the asset has.
pub fn state_index(header: &AssetHeader, name: Option<&str>) -> Result<Option<u16>, String> {
    let Some(name) = name else {
        return Ok(None);
    };
    match header.states.iter().position(|s| s.name == name) {
        Some(0) => Ok(None),
        Some(s) if is_geometry_state(header, s) => Ok(Some(s as u16)),
        Some(_) => Err(format!(
            "state {name:?} is a light state: relight with `light` instead"
        )),
        None => {
            let known: Vec<&str> = header
                .states
                .iter()
                .enumerate()
                .filter(|&(s, _)| s == 0 || is_geometry_state(header, s))
                .map(|(_, d)| d.name.as_str())
                .collect();
            Err(format!(
                "unknown state {name:?}: this asset has {}",
                known.join(", ")
            ))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn changed_pages_finds_the_page_of_one_texel_and_respects_the_tolerance() {
        let grid = PageGrid::new(40, 16).expect("grid");
        let base = vec![7u8; 40 * 40 * 4];
        let mut state = base.clone();
        // Texel (33, 20): page row 1, column 2 → page 5.
        state[(20 * 40 + 33) * 4 + 2] = 9;
        assert_eq!(changed_pages(&grid, &base, &state, 4, 0), vec![5]);
        assert_eq!(changed_pages(&grid, &base, &state, 4, 1), vec![5]);
        assert!(changed_pages(&grid, &base, &state, 4, 2).is_empty());
        // 16-bit depth compares codes, not bytes: 0x00ff → 0x0100 is one code.
        let mut d0 = vec![0u8; 40 * 40 * 2];
        d0[0..2].copy_from_slice(&0x00ffu16.to_le_bytes());
        let mut d1 = d0.clone();
        d1[0..2].copy_from_slice(&0x0100u16.to_le_bytes());
        assert!(changed_pages(&grid, &d0, &d1, 2, 1).is_empty());
        assert_eq!(changed_pages(&grid, &d0, &d1, 2, 0), vec![0]);
    }
}
