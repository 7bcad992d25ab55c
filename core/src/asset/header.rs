//! The JSON header of an `.lfa` file: what the asset holds and how it was made, with the
//! validation every reader and writer applies to it.

use std::collections::HashSet;
use std::fmt;

use serde::{Deserialize, Serialize};

use super::block::{BLOCK, BlockCodec};
use super::{AssetError, FORMAT_VERSION, MIN_FORMAT_VERSION, Result};

/// Highest icosahedron subdivision level of a spherical camera set (642 cameras).
pub const MAX_CAMERA_LEVEL: u8 = 3;
/// Largest accepted image side in pixels (one RGBA8 image is then 256 MiB).
pub const MAX_RESOLUTION_PX: u32 = 8192;
/// Smallest accepted page side in pixels.
pub const MIN_PAGE_SIZE: u32 = 16;
/// Largest accepted page side in pixels.
pub const MAX_PAGE_SIZE: u32 = 4096;
/// Page side used by [`AssetHeader::new_spherical`].
pub const DEFAULT_PAGE_SIZE: u32 = 128;
/// Most layers an asset may declare.
pub const MAX_LAYERS: usize = 256;
/// Most states an asset may declare.
pub const MAX_STATES: usize = 256;

/// Number of cameras of the icosahedron subdivided `level` times: `10·4^level + 2`
/// (12, 42, 162, 642), or `None` above [`MAX_CAMERA_LEVEL`].
pub fn camera_count_for_level(level: u8) -> Option<u32> {
    (level <= MAX_CAMERA_LEVEL).then(|| 10 * 4u32.pow(u32::from(level)) + 2)
}

/// What kind of light field the asset holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[non_exhaustive]
pub enum AssetKind {
    /// Cameras on a sphere around the object, each recording the opposite hemisphere (DESIGN §4).
    Spherical,
    /// A uv grid of cameras imaging an st rectangle (DESIGN §9; format version 5).
    TwoPlane,
}

impl AssetKind {
    /// The kind as the header spells it (`spherical`, `two_plane`).
    pub fn name(self) -> &'static str {
        match self {
            AssetKind::Spherical => "spherical",
            AssetKind::TwoPlane => "two_plane",
        }
    }
}

/// The first format version with the kind `two_plane`.
pub const TWO_PLANE_SINCE: u32 = 5;

/// How a camera's hemisphere is mapped to its square image.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[non_exhaustive]
pub enum MapProjection {
    /// `(u, v) = (r_x, r_y) / (1 + r_z)` with the hemisphere's pole on +z.
    Parabolic,
}

/// Camera set and image size of a spherical light field.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SphericalGeometry {
    /// Icosahedron subdivision level, 0..=3.
    pub camera_level: u8,
    /// `10·4^camera_level + 2`; stored so a reader can check it.
    pub camera_count: u32,
    /// Side of every (square) camera image in pixels.
    pub resolution_px: u32,
    /// Hemisphere-to-image mapping.
    pub map: MapProjection,
}

/// The planes of a two-plane light field (DESIGN §9's JSON under `planes`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TwoPlaneGeometry {
    /// The uv and st rectangles, the camera grid and the st resolution.
    pub planes: crate::two_plane::TwoPlanes,
}

/// What the images of an asset are: a spherical camera set, or a uv grid of cameras over an st
/// rectangle. Which one must match [`AssetHeader::kind`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum Geometry {
    /// Kind `spherical`.
    Spherical(SphericalGeometry),
    /// Kind `two_plane`.
    TwoPlane(TwoPlaneGeometry),
}

impl Geometry {
    /// The kind this geometry belongs to.
    pub fn kind(&self) -> AssetKind {
        match self {
            Geometry::Spherical(_) => AssetKind::Spherical,
            Geometry::TwoPlane(_) => AssetKind::TwoPlane,
        }
    }
}

/// The light-field frame: the object's bounding sphere in world units.
///
/// `world_from_lf = translate(center) · scale(radius·√2)`, so the bounding sphere has radius
/// `1/√2` in the light-field frame and the cameras sit on the unit sphere.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LfFrame {
    /// Centre of the bounding sphere in world units.
    pub center: [f64; 3],
    /// Radius of the bounding sphere in world units, > 0.
    pub radius: f64,
}

impl LfFrame {
    /// World units per light-field unit: `radius·√2`.
    pub fn world_from_lf_scale(&self) -> f64 {
        self.radius * std::f64::consts::SQRT_2
    }

    /// `translate(center) · scale(radius·√2)` as a column-major 4×4 matrix (`m[column][row]`).
    pub fn world_from_lf(&self) -> [[f64; 4]; 4] {
        let s = self.world_from_lf_scale();
        let [cx, cy, cz] = self.center;
        [
            [s, 0.0, 0.0, 0.0],
            [0.0, s, 0.0, 0.0],
            [0.0, 0.0, s, 0.0],
            [cx, cy, cz, 1.0],
        ]
    }

    /// The inverse of [`Self::world_from_lf`], column-major.
    pub fn lf_from_world(&self) -> [[f64; 4]; 4] {
        let inv = 1.0 / self.world_from_lf_scale();
        let [cx, cy, cz] = self.center;
        [
            [inv, 0.0, 0.0, 0.0],
            [0.0, inv, 0.0, 0.0],
            [0.0, 0.0, inv, 0.0],
            [-cx * inv, -cy * inv, -cz * inv, 1.0],
        ]
    }
}

/// What an image's texels mean.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[non_exhaustive]
pub enum Channel {
    /// Display colour, RGBA8 in v1.
    Color,
    /// Normalized depth along the camera ray (1 = no hit).
    Depth,
}

impl Channel {
    /// Every channel, in index order.
    pub const ALL: [Channel; 2] = [Channel::Color, Channel::Depth];

    /// The channel's code in the binary index.
    pub fn code(self) -> u8 {
        match self {
            Channel::Color => 0,
            Channel::Depth => 1,
        }
    }

    /// The channel for an index code, `None` for unknown codes.
    pub fn from_code(code: u8) -> Option<Self> {
        match code {
            0 => Some(Channel::Color),
            1 => Some(Channel::Depth),
            _ => None,
        }
    }
}

impl fmt::Display for Channel {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Channel::Color => "color",
            Channel::Depth => "depth",
        })
    }
}

/// How one texel is stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
#[non_exhaustive]
pub enum Encoding {
    /// 4 bytes R, G, B, A (colour): opaque where depth says hit (A = 255), edge texels
    /// beside silhouettes (docs/format.md §8.5).
    Rgba8,
    /// 4 bytes of premultiplied colour and opacity (`round(255·C)`, `round(255·A)`) of a
    /// semi-transparent light field such as a ray-cast volume; no edge texels (format version
    /// 2, docs/format.md §8.5).
    #[serde(rename = "rgba8_premultiplied")]
    Rgba8Premultiplied,
    /// u16 little endian: `round(d·65535)`, hits clamped to ≤ 65534, 65535 = no hit (depth).
    R16,
    /// u8: `round(d·255)`, hits clamped to ≤ 254, 255 = no hit (depth).
    R8,
    /// f32 little endian: `d` itself, 1.0 = no hit (depth).
    R32F,
}

impl Encoding {
    /// Bytes per texel: 4, 2, 1, 4.
    pub fn bytes_per_texel(self) -> u32 {
        match self {
            Encoding::Rgba8 | Encoding::Rgba8Premultiplied | Encoding::R32F => 4,
            Encoding::R16 => 2,
            Encoding::R8 => 1,
        }
    }

    /// Whether a channel may use this encoding (in some format version: see
    /// [`Encoding::since_version`]).
    pub fn allowed_for(self, channel: Channel) -> bool {
        match channel {
            Channel::Color => matches!(self, Encoding::Rgba8 | Encoding::Rgba8Premultiplied),
            Channel::Depth => matches!(self, Encoding::R16 | Encoding::R8 | Encoding::R32F),
        }
    }

    /// The first format version that has this encoding.
    pub fn since_version(self) -> u32 {
        match self {
            Encoding::Rgba8Premultiplied => 2,
            Encoding::Rgba8 | Encoding::R16 | Encoding::R8 | Encoding::R32F => 1,
        }
    }
}

/// The first format version with the header field `layer_order`.
pub const LAYER_ORDER_SINCE: u32 = 3;

/// One channel of every image and its encoding.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ChannelDesc {
    /// Which channel.
    pub name: Channel,
    /// How its texels are stored.
    pub encoding: Encoding,
    /// Block compression of its pages (format version 6): the pages store 4 × 4 blocks that
    /// decode to texels in `encoding` (docs/format.md §7.1). Absent: the texels themselves.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub compression: Option<BlockCodec>,
}

/// The first format version with block-compressed channels.
pub const BLOCK_COMPRESSION_SINCE: u32 = 6;

/// A named layer (e.g. one volume transfer function), composited at runtime.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LayerDesc {
    /// Unique, non-empty name.
    pub name: String,
    /// Opacity in [0, 1] a viewer starts with.
    pub default_opacity: f32,
}

/// How a multi light field's layers composite per pixel (format version 3 adds [`Self::Ray`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LayerOrder {
    /// Sorted by each fragment's depth (layers per structure or TF: seed 002 §6).
    #[default]
    Depth,
    /// In the header's layer order, front to back: depth layers, consecutive segments of every
    /// ray (seed 002 §7), whose order along the ray is fixed by the split.
    Ray,
}

impl LayerOrder {
    /// The default, [`Self::Depth`] (left out of the header).
    pub fn is_depth(&self) -> bool {
        *self == LayerOrder::Depth
    }
}

/// A named state (light direction, animation frame, deformation) with its parameter values.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StateDesc {
    /// Unique, non-empty name.
    pub name: String,
    /// Free-form parameters, e.g. `{"light_dir": [0, 1, 0]}`.
    pub params: serde_json::Map<String, serde_json::Value>,
}

/// How the asset was made.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Provenance {
    /// File name (or description) of the source.
    pub source_name: String,
    /// Hex SHA-256 of the source bytes (empty if unknown).
    pub source_sha256: String,
    /// Version of lumigraph that baked the asset.
    pub lumigraph_version: String,
    /// The bake options as given, for reproduction.
    pub bake_options: serde_json::Value,
    /// Triangles of the source mesh (0 for non-mesh sources).
    pub triangles: u64,
    /// Vertices of the source mesh (0 for non-mesh sources).
    pub vertices: u64,
    /// Wall-clock bake time in milliseconds, finite and ≥ 0.
    pub bake_ms: f64,
    /// Creation time, seconds since the Unix epoch.
    pub created_unix: u64,
}

/// The JSON header of an `.lfa` file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AssetHeader {
    /// Must equal the preamble's format version (1).
    pub format_version: u32,
    /// Light-field kind; decides the geometry.
    pub kind: AssetKind,
    /// Camera set and image size.
    pub geometry: Geometry,
    /// The object's bounding sphere in world units.
    pub frame: LfFrame,
    /// Side of a page in pixels: a power of two in 16..=4096.
    pub page_size: u32,
    /// Exactly one colour and one depth channel in v1, in any order.
    pub channels: Vec<ChannelDesc>,
    /// 1..=256 layers.
    pub layers: Vec<LayerDesc>,
    /// How the layers composite; absent (depth order) before version 3.
    #[serde(default, skip_serializing_if = "LayerOrder::is_depth")]
    pub layer_order: LayerOrder,
    /// 1..=256 states; state 0 is the base state.
    pub states: Vec<StateDesc>,
    /// How the asset was made.
    pub provenance: Provenance,
    /// Quality report of the bake (free-form), if measured.
    pub quality: Option<serde_json::Value>,
}

impl AssetHeader {
    /// A spherical asset's header with the defaults: page size 128, RGBA8 colour, one layer
    /// `default` at opacity 1, one state `base`, no quality report.
    pub fn new_spherical(
        camera_level: u8,
        resolution_px: u32,
        frame: LfFrame,
        depth_encoding: Encoding,
        provenance: Provenance,
    ) -> Result<Self> {
        let camera_count = camera_count_for_level(camera_level).ok_or_else(|| {
            AssetError::Header(format!(
                "camera level {camera_level} is above the maximum {MAX_CAMERA_LEVEL}"
            ))
        })?;
        Self::with_defaults(
            Geometry::Spherical(SphericalGeometry {
                camera_level,
                camera_count,
                resolution_px,
                map: MapProjection::Parabolic,
            }),
            frame,
            DEFAULT_PAGE_SIZE,
            depth_encoding,
            provenance,
        )
    }

    /// A validated header of `geometry` with the defaults every new asset starts from: the
    /// lowest format version of its kind, RGBA8 colour and `depth_encoding`, one layer
    /// `default` at opacity 1 in depth order, one state `base`, no quality report.
    fn with_defaults(
        geometry: Geometry,
        frame: LfFrame,
        page_size: u32,
        depth_encoding: Encoding,
        provenance: Provenance,
    ) -> Result<Self> {
        let kind = geometry.kind();
        let mut header = Self {
            format_version: MIN_FORMAT_VERSION,
            kind,
            geometry,
            frame,
            page_size,
            channels: vec![
                ChannelDesc {
                    name: Channel::Color,
                    encoding: Encoding::Rgba8,
                    compression: None,
                },
                ChannelDesc {
                    name: Channel::Depth,
                    encoding: depth_encoding,
                    compression: None,
                },
            ],
            layers: vec![LayerDesc {
                name: "default".to_owned(),
                default_opacity: 1.0,
            }],
            layer_order: LayerOrder::Depth,
            states: vec![StateDesc {
                name: "base".to_owned(),
                params: serde_json::Map::new(),
            }],
            provenance,
            quality: None,
        };
        header.format_version = header.required_version();
        header.validate()?;
        Ok(header)
    }

    /// The block compression of `channel`'s pages, if any.
    pub fn compression(&self, channel: Channel) -> Option<BlockCodec> {
        self.channels
            .iter()
            .find(|c| c.name == channel)
            .and_then(|c| c.compression)
    }

    /// Sets `channel`'s block compression and the format version to the lowest that has it.
    ///
    /// # Errors
    /// [`AssetError::Header`] where the codec does not fit the channel's encoding or the images
    /// are not whole 4 × 4 blocks; the header is then unchanged.
    pub fn set_compression(&mut self, channel: Channel, codec: Option<BlockCodec>) -> Result<()> {
        let mut changed = self.clone();
        for c in &mut changed.channels {
            if c.name == channel {
                c.compression = codec;
            }
        }
        changed.format_version = changed.required_version();
        changed.validate()?;
        *self = changed;
        Ok(())
    }

    /// The encoding of `channel`, if the header declares it.
    pub fn encoding(&self, channel: Channel) -> Option<Encoding> {
        self.channels
            .iter()
            .find(|c| c.name == channel)
            .map(|c| c.encoding)
    }

    /// A two-plane asset's header (format version 5): RGBA8 colour, `r32f` depth (the stored
    /// depth `|hit − C| / |S − C|` of DESIGN §9, `+inf` where nothing is hit), one layer, one
    /// state. `frame` is the bounding sphere of the two rectangles' corners.
    pub fn new_two_plane(
        planes: crate::two_plane::TwoPlanes,
        page_size: u32,
        provenance: Provenance,
    ) -> Result<Self> {
        planes
            .validate()
            .map_err(|e| AssetError::Header(e.to_string()))?;
        let frame = two_plane_frame(&planes);
        Self::with_defaults(
            Geometry::TwoPlane(TwoPlaneGeometry { planes }),
            frame,
            page_size,
            Encoding::R32F,
            provenance,
        )
    }

    /// The spherical geometry, or [`AssetError::Kind`] naming what needed it.
    ///
    /// # Errors
    /// [`AssetError::Kind`] for any other kind.
    pub fn spherical(&self, what: &'static str) -> Result<&SphericalGeometry> {
        match &self.geometry {
            Geometry::Spherical(g) => Ok(g),
            other @ Geometry::TwoPlane(_) => Err(AssetError::Kind {
                what,
                kind: other.kind(),
            }),
        }
    }

    /// The icosahedron level of a spherical asset's camera set, `None` for other kinds.
    pub fn camera_level(&self) -> Option<u8> {
        match &self.geometry {
            Geometry::Spherical(g) => Some(g.camera_level),
            Geometry::TwoPlane(_) => None,
        }
    }

    /// The planes of a two-plane asset, `None` for other kinds.
    pub fn two_plane(&self) -> Option<&crate::two_plane::TwoPlanes> {
        match &self.geometry {
            Geometry::TwoPlane(g) => Some(&g.planes),
            Geometry::Spherical(_) => None,
        }
    }

    /// Number of cameras (as declared; [`Self::validate`] checks it against the level).
    pub fn camera_count(&self) -> u32 {
        match &self.geometry {
            Geometry::Spherical(g) => g.camera_count,
            Geometry::TwoPlane(g) => g.planes.camera_count(),
        }
    }

    /// Width and height of every image in texels: `resolution_px` squared for a spherical
    /// asset, the st resolution `[ns, nt]` for a two-plane one.
    pub fn image_size(&self) -> [u32; 2] {
        match &self.geometry {
            Geometry::Spherical(g) => [g.resolution_px; 2],
            Geometry::TwoPlane(g) => g.planes.st.resolution,
        }
    }

    /// How each image is cut into pages.
    pub fn page_grid(&self) -> Result<PageGrid> {
        let [width, height] = self.image_size();
        PageGrid::rect(width, height, self.page_size).ok_or_else(|| {
            AssetError::Header(format!(
                "images of {width}x{height} px with page size {} px give no valid page grid",
                self.page_size
            ))
        })
    }

    /// Bytes of one whole image of `channel`, or `None` if the channel is not declared.
    pub fn image_bytes(&self, channel: Channel) -> Option<u64> {
        let [w, h] = self.image_size().map(u64::from);
        let bpp = u64::from(self.encoding(channel)?.bytes_per_texel());
        w.checked_mul(h)?.checked_mul(bpp)
    }

    /// Bytes of every image the header declares once decoded: cameras × `resolution_px`² ×
    /// (bytes per texel of every channel) × layers × states. States may omit images (they fall
    /// back to state 0), so this is an upper bound of what reading the whole file decodes; it
    /// is what a reader must be ready for before it trusts the file. Saturates at `u64::MAX`
    /// instead of overflowing, so a forged header cannot wrap it to a small number.
    pub fn decoded_bytes(&self) -> u64 {
        let [width, height] = self.image_size().map(u64::from);
        let texel_bytes: u64 = self
            .channels
            .iter()
            .map(|c| u64::from(c.encoding.bytes_per_texel()))
            .fold(0, u64::saturating_add);
        [
            u64::from(self.camera_count()),
            width,
            height,
            texel_bytes,
            self.layers.len() as u64,
            self.states.len() as u64,
        ]
        .into_iter()
        .fold(1, u64::saturating_mul)
    }

    /// The lowest format version that can express this header: 5 for a two-plane light field,
    /// 3 with layers in ray order, 2 with a version-2 encoding, else 1.
    pub fn required_version(&self) -> u32 {
        let order = if self.layer_order.is_depth() {
            MIN_FORMAT_VERSION
        } else {
            LAYER_ORDER_SINCE
        };
        let order = if self.kind == AssetKind::TwoPlane {
            order.max(TWO_PLANE_SINCE)
        } else {
            order
        };
        self.channels
            .iter()
            .map(|c| {
                let block = if c.compression.is_some() {
                    BLOCK_COMPRESSION_SINCE
                } else {
                    MIN_FORMAT_VERSION
                };
                c.encoding.since_version().max(block)
            })
            .fold(order, u32::max)
    }

    /// Sets how the layers composite and the format version to the lowest that can say it.
    pub fn set_layer_order(&mut self, order: LayerOrder) {
        self.layer_order = order;
        self.format_version = self.required_version();
    }

    /// Sets the colour channel's encoding and the format version to the lowest that has it.
    pub fn set_color_encoding(&mut self, encoding: Encoding) {
        for c in &mut self.channels {
            if c.name == Channel::Color {
                c.encoding = encoding;
            }
        }
        self.format_version = self.required_version();
    }

    /// Checks every rule of the header's format version (see `docs/format.md`, "Validation").
    pub fn validate(&self) -> Result<()> {
        let bad = |msg: String| Err(AssetError::Header(msg));
        if !(MIN_FORMAT_VERSION..=FORMAT_VERSION).contains(&self.format_version) {
            return bad(format!(
                "header says format version {}; this build reads versions \
                 {MIN_FORMAT_VERSION}..={FORMAT_VERSION}",
                self.format_version
            ));
        }
        if let Some(c) = self
            .channels
            .iter()
            .find(|c| c.encoding.since_version() > self.format_version)
        {
            return bad(format!(
                "{} encoding {:?} needs format version {} (the header says {})",
                c.name,
                c.encoding,
                c.encoding.since_version(),
                self.format_version
            ));
        }
        if !self.layer_order.is_depth() && self.format_version < LAYER_ORDER_SINCE {
            return bad(format!(
                "layer_order {:?} needs format version {LAYER_ORDER_SINCE} (the header says {})",
                self.layer_order, self.format_version
            ));
        }
        if self.geometry.kind() != self.kind {
            return bad(format!(
                "kind {:?} does not match its geometry (which describes a {:?} light field)",
                self.kind,
                self.geometry.kind()
            ));
        }
        match &self.geometry {
            Geometry::Spherical(g) => Self::validate_spherical(g)?,
            Geometry::TwoPlane(g) => self.validate_two_plane(g)?,
        }
        if !self.page_size.is_power_of_two()
            || !(MIN_PAGE_SIZE..=MAX_PAGE_SIZE).contains(&self.page_size)
        {
            return bad(format!(
                "page size {} px is not a power of two in {MIN_PAGE_SIZE}..={MAX_PAGE_SIZE}",
                self.page_size
            ));
        }
        self.validate_frame()?;
        self.validate_channels()?;
        validate_names(
            "layer",
            MAX_LAYERS,
            self.layers.iter().map(|l| l.name.as_str()),
        )?;
        for layer in &self.layers {
            if !(layer.default_opacity.is_finite() && (0.0..=1.0).contains(&layer.default_opacity))
            {
                return bad(format!(
                    "layer {:?} has default opacity {}, outside [0, 1]",
                    layer.name, layer.default_opacity
                ));
            }
        }
        validate_names(
            "state",
            MAX_STATES,
            self.states.iter().map(|s| s.name.as_str()),
        )?;
        let bake_ms = self.provenance.bake_ms;
        if !(bake_ms.is_finite() && bake_ms >= 0.0) {
            return bad(format!(
                "provenance bake_ms {bake_ms} is not a finite, non-negative number"
            ));
        }
        Ok(())
    }

    fn validate_spherical(g: &SphericalGeometry) -> Result<()> {
        let bad = |msg: String| Err(AssetError::Header(msg));
        match camera_count_for_level(g.camera_level) {
            None => {
                return bad(format!(
                    "camera level {} is above the maximum {MAX_CAMERA_LEVEL}",
                    g.camera_level
                ));
            }
            Some(count) if count != g.camera_count => {
                return bad(format!(
                    "camera_count {} does not match camera level {} (which has {count} cameras)",
                    g.camera_count, g.camera_level
                ));
            }
            Some(_) => {}
        }
        if !(1..=MAX_RESOLUTION_PX).contains(&g.resolution_px) {
            return bad(format!(
                "resolution {} px is outside 1..={MAX_RESOLUTION_PX}",
                g.resolution_px
            ));
        }
        Ok(())
    }

    fn validate_two_plane(&self, g: &TwoPlaneGeometry) -> Result<()> {
        let bad = |msg: String| Err(AssetError::Header(msg));
        if self.format_version < TWO_PLANE_SINCE {
            return bad(format!(
                "kind two_plane needs format version {TWO_PLANE_SINCE} (the header says {})",
                self.format_version
            ));
        }
        if let Err(e) = g.planes.validate() {
            return bad(format!("two-plane geometry: {e}"));
        }
        if self.encoding(Channel::Depth) != Some(Encoding::R32F)
            || self.encoding(Channel::Color) != Some(Encoding::Rgba8)
        {
            return bad(
                "a two-plane light field stores rgba8 colour and r32f depth (its depth is not \
                 bounded by 1)"
                    .to_owned(),
            );
        }
        Ok(())
    }

    fn validate_frame(&self) -> Result<()> {
        let LfFrame { center, radius } = &self.frame;
        if !center.iter().all(|c| c.is_finite()) {
            return Err(AssetError::Header(format!(
                "frame centre {center:?} is not finite"
            )));
        }
        // The scale and its inverse must be finite too, or the frame matrices overflow.
        let scale = self.frame.world_from_lf_scale();
        if !(radius.is_finite() && *radius > 0.0 && scale.is_finite() && scale.recip().is_finite())
        {
            return Err(AssetError::Header(format!(
                "frame radius {radius} is not a finite number > 0 with a finite inverse"
            )));
        }
        Ok(())
    }

    fn validate_channels(&self) -> Result<()> {
        if self.channels.len() != Channel::ALL.len() {
            return Err(AssetError::Header(format!(
                "{} channels declared; version 1 needs exactly one color and one depth channel",
                self.channels.len()
            )));
        }
        for channel in Channel::ALL {
            let mut found = self.channels.iter().filter(|c| c.name == channel);
            match (found.next(), found.next()) {
                (Some(desc), None) if desc.encoding.allowed_for(channel) => {
                    let Some(codec) = desc.compression else {
                        continue;
                    };
                    if self.format_version < BLOCK_COMPRESSION_SINCE {
                        return Err(AssetError::Header(format!(
                            "{channel} compression {codec} needs format version \
                             {BLOCK_COMPRESSION_SINCE} (the header says {})",
                            self.format_version
                        )));
                    }
                    if !codec.allowed_for(channel, desc.encoding) {
                        return Err(AssetError::Header(format!(
                            "the {channel} channel in {:?} cannot use compression {codec} \
                             (bc1: rgba8 colour; bc7: rgba8 or rgba8_premultiplied colour; bc4: \
                             r8 depth)",
                            desc.encoding
                        )));
                    }
                    let [w, h] = self.image_size();
                    if !w.is_multiple_of(BLOCK) || !h.is_multiple_of(BLOCK) {
                        return Err(AssetError::Header(format!(
                            "{channel} compression {codec} needs images of whole {BLOCK}x{BLOCK} \
                             blocks; they are {w}x{h} px"
                        )));
                    }
                }
                (Some(desc), None) => {
                    return Err(AssetError::Header(format!(
                        "the {channel} channel cannot use encoding {:?} (color: rgba8; depth: \
                         r16, r8 or r32f)",
                        desc.encoding
                    )));
                }
                _ => {
                    return Err(AssetError::Header(format!(
                        "version 1 needs exactly one {channel} channel"
                    )));
                }
            }
        }
        Ok(())
    }
}

fn validate_names<'a>(
    what: &str,
    max: usize,
    names: impl ExactSizeIterator<Item = &'a str>,
) -> Result<()> {
    let count = names.len();
    if !(1..=max).contains(&count) {
        return Err(AssetError::Header(format!(
            "{count} {what}s declared; an asset needs 1..={max}"
        )));
    }
    let mut seen = HashSet::with_capacity(count);
    for name in names {
        if name.is_empty() {
            return Err(AssetError::Header(format!("a {what} has an empty name")));
        }
        if !seen.insert(name) {
            return Err(AssetError::Header(format!(
                "{what} name {name:?} is used twice"
            )));
        }
    }
    Ok(())
}

/// The frame recorded for a two-plane light field: the bounding sphere (about the mean) of the
/// eight corners of its two rectangles.
pub fn two_plane_frame(planes: &crate::two_plane::TwoPlanes) -> LfFrame {
    let (right, up) = planes.axes();
    let mut corners = Vec::with_capacity(8);
    for (center, [w, h]) in [
        (planes.uv.center, planes.uv.size),
        (planes.st.center, planes.st.size),
    ] {
        let c = glam::DVec3::from(center);
        for (sx, sy) in [(-0.5, -0.5), (0.5, -0.5), (-0.5, 0.5), (0.5, 0.5)] {
            corners.push(c + sx * w * right + sy * h * up);
        }
    }
    let center = corners.iter().copied().sum::<glam::DVec3>() / 8.0;
    let radius = corners
        .iter()
        .map(|p| (*p - center).length())
        .fold(0.0, f64::max);
    LfFrame {
        center: center.to_array(),
        radius,
    }
}

/// How an image is cut into square pages, row-major, pages on the right and bottom edges
/// smaller.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct PageGrid {
    width: u32,
    height: u32,
    page_size: u32,
    pages_per_row: u32,
    pages_per_column: u32,
}

/// A page's pixel rectangle within its image.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct PageRect {
    /// First column.
    pub x: u32,
    /// First row (from the top).
    pub y: u32,
    /// Columns: `page_size` or less at the right edge.
    pub width: u32,
    /// Rows: `page_size` or less at the bottom edge.
    pub height: u32,
}

impl PageRect {
    /// Texels in the page.
    pub fn texels(&self) -> u64 {
        u64::from(self.width) * u64::from(self.height)
    }
}

impl PageGrid {
    /// A grid for `resolution_px`² images and `page_size`² pages; `None` if either is zero or
    /// the page count does not fit a `u32`.
    pub fn new(resolution_px: u32, page_size: u32) -> Option<Self> {
        Self::rect(resolution_px, resolution_px, page_size)
    }

    /// A grid for `width × height` images and `page_size`² pages; `None` if any is zero or the
    /// page count does not fit a `u32`.
    pub fn rect(width: u32, height: u32, page_size: u32) -> Option<Self> {
        if width == 0 || height == 0 || page_size == 0 {
            return None;
        }
        let pages_per_row = width.div_ceil(page_size);
        let pages_per_column = height.div_ceil(page_size);
        pages_per_row.checked_mul(pages_per_column)?;
        Some(Self {
            width,
            height,
            page_size,
            pages_per_row,
            pages_per_column,
        })
    }

    /// Image width in pixels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Image height in pixels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Page side in pixels.
    pub fn page_size(&self) -> u32 {
        self.page_size
    }

    /// Pages per row: `ceil(width / page_size)`.
    pub fn pages_per_row(&self) -> u32 {
        self.pages_per_row
    }

    /// Pages per image.
    pub fn page_count(&self) -> u32 {
        self.pages_per_row * self.pages_per_column
    }

    /// The rectangle of page `page = page_row · pages_per_row + page_col`, `None` past the end.
    pub fn page_rect(&self, page: u32) -> Option<PageRect> {
        if page >= self.page_count() {
            return None;
        }
        let x = (page % self.pages_per_row) * self.page_size;
        let y = (page / self.pages_per_row) * self.page_size;
        Some(PageRect {
            x,
            y,
            width: self.page_size.min(self.width - x),
            height: self.page_size.min(self.height - y),
        })
    }
}
