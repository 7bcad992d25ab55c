//! Microscope z-stacks as two-plane light fields (seed 003: a z-stack shown by a light-field
//! renderer instead of a volume renderer). docs/zstack.md is the user's account.
//!
//! - **Input**: a multi-page TIFF or a folder of single-slice images (TIFF or PNG, ordered by
//!   the whole numbers in their names), 8- or 16-bit grey, every slice the same size; spacing
//!   from `--spacing`, else from ImageJ's metadata, else 1 µm.
//! - **Geometry** ([`zstack_planes`]): the st plane is the stack's middle slice (its pixel
//!   (i, j) is st texel (i, j): row 0 on top, DESIGN §9), the uv plane is parallel above the
//!   last slice at height `H = max(lateral extent, 2 × axial extent)`, and its cameras span a
//!   cone of half-angle `angle` seen from the st centre. Slice k lies at height
//!   `(k − (nz − 1)/2) · sz`: the last slice is nearest the cameras.
//! - **Synthesis** ([`synthesize_camera`]): each camera pixel's ray (DESIGN §9: from the camera
//!   through its st point) crosses every slice at a point where the slice is sampled
//!   bilinearly (0 outside the stack); the samples are combined front to back from the camera,
//!   by maximum intensity (`mip`) or by emission–absorption (`over`: each slice has opacity
//!   `opacity × v` and emits `v`, `v` the sample mapped through the window to [0, 1]). Grey
//!   colour, opaque over black.
//! - **Depth**: where the ray's maximum reaches the depth threshold (`mip`) or its accumulated
//!   opacity reaches ½ (`over`), the stored depth places the hit on that slice (`1 − z/H`
//!   for a slice at height z: DESIGN §9's `|hit − C| / |S − C|`); elsewhere the st plane
//!   (depth 1), so empty background neither ghosts nor moves.
//!
//! The result is an ordinary two-plane asset: every renderer, the paged cache, refocus (focus
//! on a slice: `focus = z`) and export work on it unchanged.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::asset::{AssetHeader, AssetWriter, Channel, ImageKey};
use crate::two_plane::{MAX_CAMERAS, MAX_ST_RESOLUTION, StPlane, TwoPlanes, UvPlane};

/// Most slices a stack may have.
pub const MAX_SLICES: u32 = 4096;
/// Most voxels a stack may have (held as 16-bit values: 16 GiB).
pub const MAX_VOXELS: u64 = 8 << 30;
/// Default camera grid.
pub const DEFAULT_GRID: [u32; 2] = [9, 9];
/// Default half-angle of the cameras' cone, degrees.
pub const DEFAULT_ANGLE_DEG: f64 = 15.0;
/// Largest half-angle, degrees.
pub const MAX_ANGLE_DEG: f64 = 60.0;
/// Default opacity per slice of `over` at full intensity.
pub const DEFAULT_OPACITY: f64 = 0.1;
/// Default depth threshold of `mip`, a fraction of the window.
pub const DEFAULT_DEPTH_THRESHOLD: f64 = 0.25;
/// Percentiles of the automatic window.
pub const AUTO_WINDOW_PERCENTILES: [f64; 2] = [0.1, 99.9];

/// Why a stack cannot be read or imported.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ZStackError {
    /// A file or folder that cannot be read or decoded.
    #[error("{}: {message}", path.display())]
    Read {
        /// The file or folder.
        path: PathBuf,
        /// Why.
        message: String,
    },
    /// A stack whose slices or sizes break a rule.
    #[error("{0}")]
    Stack(String),
    /// An option out of its range.
    #[error("{0}")]
    Option(String),
    /// The asset cannot be written.
    #[error(transparent)]
    Asset(#[from] crate::asset::AssetError),
}

type Result<T> = std::result::Result<T, ZStackError>;

/// A z-stack in memory: `nx × ny × nz` grey values (8-bit stacks widened to 16 bits), slice by
/// slice, rows from the top.
#[derive(Clone, Debug, PartialEq)]
pub struct ZStack {
    /// Columns, rows and slices.
    pub size: [u32; 3],
    /// Bits per voxel in the source (8 or 16).
    pub bits: u8,
    /// Voxel spacing x, y, z (µm or any unit; the light field's world unit).
    pub spacing: [f64; 3],
    voxels: Vec<u16>,
}

impl ZStack {
    /// A stack of `size` from `voxels` (slice-major, rows from the top).
    ///
    /// # Errors
    /// [`ZStackError::Stack`] for sizes out of range or a voxel count that does not match.
    pub fn new(size: [u32; 3], bits: u8, spacing: [f64; 3], voxels: Vec<u16>) -> Result<ZStack> {
        Self::check_size(size)?;
        check_spacing(spacing)?;
        if bits != 8 && bits != 16 {
            return Err(ZStackError::Stack(format!(
                "{bits}-bit voxels: a z-stack is 8- or 16-bit grey"
            )));
        }
        let n = size.iter().map(|&n| n as usize).product::<usize>();
        if voxels.len() != n {
            return Err(ZStackError::Stack(format!(
                "{} voxels for a {}x{}x{} stack",
                voxels.len(),
                size[0],
                size[1],
                size[2]
            )));
        }
        Ok(ZStack {
            size,
            bits,
            spacing,
            voxels,
        })
    }

    /// The voxels, slice-major.
    pub fn voxels(&self) -> &[u16] {
        &self.voxels
    }

    /// The grey values at the [`AUTO_WINDOW_PERCENTILES`] (from a histogram of every voxel);
    /// widened to `[lo, lo + 1]` where the stack is flat.
    pub fn auto_window(&self) -> [f64; 2] {
        let mut histogram = vec![0u64; 65536];
        for &v in &self.voxels {
            histogram[usize::from(v)] += 1;
        }
        let total = self.voxels.len() as f64;
        let at = |percent: f64| {
            let target = (percent / 100.0 * total).floor() as u64;
            let mut seen = 0u64;
            for (value, &count) in histogram.iter().enumerate() {
                seen += count;
                if seen > target {
                    return value as f64;
                }
            }
            65535.0
        };
        let [lo, hi] = AUTO_WINDOW_PERCENTILES.map(at);
        if hi > lo { [lo, hi] } else { [lo, lo + 1.0] }
    }

    /// Bilinear sample of slice `z` at (column x, row y), texel centres at whole numbers; 0
    /// beyond the half texel around the slice.
    #[inline]
    fn sample(&self, z: usize, x: f64, y: f64) -> f64 {
        let [nx, ny, _] = self.size.map(i64::from);
        if x < -0.5 || y < -0.5 || x > nx as f64 - 0.5 || y > ny as f64 - 0.5 {
            return 0.0;
        }
        let (fx, fy) = (x.floor(), y.floor());
        let (tx, ty) = (x - fx, y - fy);
        let (x0, y0) = (fx as i64, fy as i64);
        let slice = &self.voxels[z * (nx * ny) as usize..(z + 1) * (nx * ny) as usize];
        let at = |x: i64, y: i64| {
            let (x, y) = (x.clamp(0, nx - 1), y.clamp(0, ny - 1));
            f64::from(slice[(y * nx + x) as usize])
        };
        let top = at(x0, y0) * (1.0 - tx) + at(x0 + 1, y0) * tx;
        let bottom = at(x0, y0 + 1) * (1.0 - tx) + at(x0 + 1, y0 + 1) * tx;
        top * (1.0 - ty) + bottom * ty
    }
}

impl ZStack {
    /// Checks a stack's size (columns, rows, slices) against the limits before anything is
    /// allocated.
    ///
    /// # Errors
    /// [`ZStackError::Stack`] naming the limit.
    pub fn check_size(size: [u32; 3]) -> Result<()> {
        let [nx, ny, nz] = size;
        if nx == 0 || ny == 0 || nz == 0 {
            return Err(ZStackError::Stack(format!(
                "an empty stack ({nx}x{ny}x{nz})"
            )));
        }
        if nx > MAX_ST_RESOLUTION || ny > MAX_ST_RESOLUTION {
            return Err(ZStackError::Stack(format!(
                "slices of {nx}x{ny} pixels: at most {MAX_ST_RESOLUTION} a side (a light field's \
                 images are textures); bin or crop the stack first"
            )));
        }
        if nz > MAX_SLICES {
            return Err(ZStackError::Stack(format!(
                "{nz} slices: at most {MAX_SLICES}"
            )));
        }
        let voxels = u64::from(nx) * u64::from(ny) * u64::from(nz);
        if voxels > MAX_VOXELS {
            return Err(ZStackError::Stack(format!(
                "{voxels} voxels: at most {MAX_VOXELS}"
            )));
        }
        Ok(())
    }
}

fn check_spacing(spacing: [f64; 3]) -> Result<()> {
    if spacing
        .iter()
        .any(|s| !s.is_finite() || *s <= 0.0 || *s > 1e9)
    {
        return Err(ZStackError::Option(format!(
            "spacing {spacing:?}: three finite, positive numbers"
        )));
    }
    Ok(())
}

/// One decoded slice: size, bits and values.
struct Slice {
    size: [u32; 2],
    bits: u8,
    values: Vec<u16>,
}

fn read_error(path: &Path, message: impl std::fmt::Display) -> ZStackError {
    ZStackError::Read {
        path: path.to_path_buf(),
        message: message.to_string(),
    }
}

/// The TIFF decoder's limits: one slice of at most [`MAX_ST_RESOLUTION`]² 16-bit values.
fn tiff_limits() -> tiff::decoder::Limits {
    let mut limits = tiff::decoder::Limits::default();
    let slice = MAX_ST_RESOLUTION as usize * MAX_ST_RESOLUTION as usize * 2;
    limits.decoding_buffer_size = slice;
    limits.intermediate_buffer_size = slice;
    limits
}

/// Decodes the current image of `decoder` (`what` names it in errors).
fn decode_tiff_slice<R: std::io::Read + std::io::Seek>(
    decoder: &mut tiff::decoder::Decoder<R>,
    path: &Path,
    what: &str,
) -> Result<Slice> {
    let (w, h) = decoder
        .dimensions()
        .map_err(|e| read_error(path, format!("{what}: {e}")))?;
    if w == 0 || h == 0 || w > MAX_ST_RESOLUTION || h > MAX_ST_RESOLUTION {
        return Err(read_error(
            path,
            format!("{what} is {w}x{h}: 1 to {MAX_ST_RESOLUTION} pixels a side"),
        ));
    }
    let colour = decoder
        .colortype()
        .map_err(|e| read_error(path, format!("{what}: {e}")))?;
    let bits = match colour {
        tiff::ColorType::Gray(8) => 8,
        tiff::ColorType::Gray(16) => 16,
        other => {
            return Err(read_error(
                path,
                format!("{what} is {other:?}: a z-stack slice is 8- or 16-bit grey"),
            ));
        }
    };
    let values = match decoder
        .read_image()
        .map_err(|e| read_error(path, format!("{what}: {e}")))?
    {
        tiff::decoder::DecodingResult::U8(v) => v.into_iter().map(u16::from).collect(),
        tiff::decoder::DecodingResult::U16(v) => v,
        _ => {
            return Err(read_error(
                path,
                format!("{what}: not 8- or 16-bit integers"),
            ));
        }
    };
    if values.len() != w as usize * h as usize {
        return Err(read_error(
            path,
            format!("{what}: {} values for {w}x{h} pixels", values.len()),
        ));
    }
    Ok(Slice {
        size: [w, h],
        bits,
        values,
    })
}

/// ImageJ's spacing in a TIFF's first image: x and y from the resolution tags (pixels per
/// unit) and z from `spacing=` in the description, where the description is ImageJ's.
fn imagej_spacing<R: std::io::Read + std::io::Seek>(
    decoder: &mut tiff::decoder::Decoder<R>,
) -> Option<[f64; 3]> {
    let description = decoder
        .get_tag_ascii_string(tiff::tags::Tag::ImageDescription)
        .ok()?;
    if !description.starts_with("ImageJ=") {
        return None;
    }
    let z = description
        .lines()
        .find_map(|l| l.strip_prefix("spacing="))
        .and_then(|v| v.trim().parse::<f64>().ok())
        .unwrap_or(1.0);
    // Resolution is a rational (pixels per unit).
    let mut per_unit = |tag| {
        let per_unit = match decoder.find_tag(tag).ok().flatten() {
            Some(tiff::decoder::ifd::Value::Rational(n, d)) if d > 0 => f64::from(n) / f64::from(d),
            Some(value) => value.into_f64().unwrap_or(0.0),
            None => 0.0,
        };
        if per_unit.is_finite() && per_unit > 0.0 {
            1.0 / per_unit
        } else {
            1.0
        }
    };
    let x = per_unit(tiff::tags::Tag::XResolution);
    let y = per_unit(tiff::tags::Tag::YResolution);
    let spacing = [x, y, z];
    check_spacing(spacing).ok().map(|()| spacing)
}

/// Every image of a (multi-page) TIFF, with ImageJ's spacing when it has it.
fn read_tiff_pages(path: &Path) -> Result<(Vec<Slice>, Option<[f64; 3]>)> {
    let file = std::fs::File::open(path).map_err(|e| read_error(path, e))?;
    let mut decoder = tiff::decoder::Decoder::new(std::io::BufReader::new(file))
        .map_err(|e| read_error(path, e))?
        .with_limits(tiff_limits());
    let spacing = imagej_spacing(&mut decoder);
    let mut slices = Vec::new();
    loop {
        let what = format!("page {}", slices.len());
        slices.push(decode_tiff_slice(&mut decoder, path, &what)?);
        if slices.len() > MAX_SLICES as usize {
            return Err(read_error(path, format!("more than {MAX_SLICES} pages")));
        }
        if !decoder.more_images() {
            break;
        }
        decoder
            .next_image()
            .map_err(|e| read_error(path, format!("page {}: {e}", slices.len())))?;
    }
    Ok((slices, spacing))
}

/// A single-slice PNG (8- or 16-bit grey).
fn read_png_slice(path: &Path) -> Result<Slice> {
    let reader = image::ImageReader::open(path)
        .map_err(|e| read_error(path, e))?
        .with_guessed_format()
        .map_err(|e| read_error(path, e))?;
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(MAX_ST_RESOLUTION);
    limits.max_image_height = Some(MAX_ST_RESOLUTION);
    let mut reader = reader;
    reader.limits(limits);
    let image = reader.decode().map_err(|e| read_error(path, e))?;
    let size = [image.width(), image.height()];
    let (bits, values) = match image {
        image::DynamicImage::ImageLuma8(g) => {
            (8, g.into_raw().into_iter().map(u16::from).collect())
        }
        image::DynamicImage::ImageLuma16(g) => (16, g.into_raw()),
        other => {
            return Err(read_error(
                path,
                format!(
                    "{:?} pixels: a z-stack slice is 8- or 16-bit grey",
                    other.color()
                ),
            ));
        }
    };
    Ok(Slice { size, bits, values })
}

/// Reads a stack: `path` is a (multi-page) TIFF, or a folder whose `.tif`/`.tiff`/`.png` files
/// are its slices, ordered by the whole numbers in their names (then by name), one image each.
/// `spacing` overrides the file's (ImageJ metadata) and the default 1, 1, 1.
///
/// # Errors
/// [`ZStackError`] naming the file: unreadable, not 8/16-bit grey, slices of different sizes
/// or bits, more than [`MAX_SLICES`] slices, slices over [`MAX_ST_RESOLUTION`] a side.
pub fn read_stack(path: &Path, spacing: Option<[f64; 3]>) -> Result<ZStack> {
    let (slices, file_spacing) = if path.is_dir() {
        let entries = std::fs::read_dir(path).map_err(|e| read_error(path, e))?;
        let mut files = Vec::new();
        for entry in entries {
            let entry = entry.map_err(|e| read_error(path, e))?;
            let p = entry.path();
            let ext = p
                .extension()
                .map(|e| e.to_string_lossy().to_ascii_lowercase())
                .unwrap_or_default();
            if matches!(ext.as_str(), "tif" | "tiff" | "png") && p.is_file() {
                let name = p
                    .file_name()
                    .map(|n| n.to_string_lossy().into_owned())
                    .unwrap_or_default();
                files.push((crate::two_plane_io::numbers(&name), name, p));
            }
        }
        if files.is_empty() {
            return Err(read_error(
                path,
                "no .tif, .tiff or .png slices in the folder",
            ));
        }
        if files.len() > MAX_SLICES as usize {
            return Err(read_error(
                path,
                format!("{} slices: at most {MAX_SLICES}", files.len()),
            ));
        }
        files.sort();
        let mut slices = Vec::with_capacity(files.len());
        let mut first_spacing = None;
        for (k, (_, _, file)) in files.iter().enumerate() {
            let is_png = file
                .extension()
                .is_some_and(|e| e.eq_ignore_ascii_case("png"));
            if is_png {
                slices.push(read_png_slice(file)?);
            } else {
                let (mut pages, s) = read_tiff_pages(file)?;
                if pages.len() != 1 {
                    return Err(read_error(
                        file,
                        format!(
                            "{} pages: a slice of a folder is one image (give a multi-page \
                             TIFF as the stack itself)",
                            pages.len()
                        ),
                    ));
                }
                if k == 0 {
                    first_spacing = s;
                }
                slices.append(&mut pages);
            }
        }
        (slices, first_spacing)
    } else {
        read_tiff_pages(path)?
    };
    let first = &slices[0];
    let (size, bits) = (first.size, first.bits);
    for (k, s) in slices.iter().enumerate() {
        if s.size != size || s.bits != bits {
            return Err(ZStackError::Stack(format!(
                "slice {k} is {}x{} at {} bits, slice 0 {}x{} at {} bits: every slice the same",
                s.size[0], s.size[1], s.bits, size[0], size[1], bits
            )));
        }
    }
    let stack_size = [size[0], size[1], slices.len() as u32];
    ZStack::check_size(stack_size)?;
    let voxels: Vec<u16> = slices.into_iter().flat_map(|s| s.values).collect();
    ZStack::new(
        stack_size,
        bits,
        spacing.or(file_spacing).unwrap_or([1.0; 3]),
        voxels,
    )
}

/// How a ray's samples combine.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Composite {
    /// Maximum intensity along the ray (fluorescence).
    #[default]
    Mip,
    /// Emission–absorption front to back.
    Over,
}

impl std::str::FromStr for Composite {
    type Err = String;

    fn from_str(s: &str) -> std::result::Result<Self, Self::Err> {
        match s {
            "mip" => Ok(Composite::Mip),
            "over" => Ok(Composite::Over),
            other => Err(format!("composite {other:?}: choose mip or over")),
        }
    }
}

/// How [`import_zstack`] makes the light field.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ZStackOptions {
    /// Cameras per row and rows.
    pub grid: [u32; 2],
    /// Half-angle of the cameras' cone seen from the st centre, degrees.
    pub angle_deg: f64,
    /// How samples combine.
    pub composite: Composite,
    /// Grey values mapped to 0 and 1 (`None`: [`ZStack::auto_window`]).
    pub window: Option<[f64; 2]>,
    /// `over`: opacity per slice at full intensity.
    pub opacity: f64,
    /// `mip`: the fraction of the window a ray's maximum must reach to store its depth.
    pub depth_threshold: f64,
}

impl Default for ZStackOptions {
    fn default() -> Self {
        ZStackOptions {
            grid: DEFAULT_GRID,
            angle_deg: DEFAULT_ANGLE_DEG,
            composite: Composite::Mip,
            window: None,
            opacity: DEFAULT_OPACITY,
            depth_threshold: DEFAULT_DEPTH_THRESHOLD,
        }
    }
}

impl ZStackOptions {
    /// Checks every option's range.
    ///
    /// # Errors
    /// [`ZStackError::Option`] naming the option.
    pub fn validate(&self) -> Result<()> {
        let [nu, nv] = self.grid;
        if nu == 0 || nv == 0 || u64::from(nu) * u64::from(nv) > u64::from(MAX_CAMERAS) {
            return Err(ZStackError::Option(format!(
                "grid {nu}x{nv}: 1 to {MAX_CAMERAS} cameras"
            )));
        }
        if !(self.angle_deg > 0.0 && self.angle_deg <= MAX_ANGLE_DEG) {
            return Err(ZStackError::Option(format!(
                "angle {}: above 0 and at most {MAX_ANGLE_DEG} degrees",
                self.angle_deg
            )));
        }
        if let Some([lo, hi]) = self.window
            && !(lo.is_finite() && hi.is_finite() && hi > lo)
        {
            return Err(ZStackError::Option(format!(
                "window {lo},{hi}: two finite grey values, low below high"
            )));
        }
        if !(self.opacity > 0.0 && self.opacity <= 1.0) {
            return Err(ZStackError::Option(format!(
                "opacity {}: above 0 and at most 1",
                self.opacity
            )));
        }
        if !(0.0..=1.0).contains(&self.depth_threshold) {
            return Err(ZStackError::Option(format!(
                "depth threshold {}: 0 to 1",
                self.depth_threshold
            )));
        }
        Ok(())
    }
}

/// Height of slice `k` above the st plane.
fn slice_height(stack: &ZStack, k: u32) -> f64 {
    (f64::from(k) - f64::from(stack.size[2] - 1) / 2.0) * stack.spacing[2]
}

/// The planes of `stack`'s light field ([module docs](self)).
pub fn zstack_planes(stack: &ZStack, options: &ZStackOptions) -> TwoPlanes {
    let [nx, ny, nz] = stack.size.map(f64::from);
    let [sx, sy, sz] = stack.spacing;
    let lateral = (nx * sx).max(ny * sy);
    let height = lateral.max(2.0 * nz * sz);
    let uv = 2.0 * height * options.angle_deg.to_radians().tan();
    TwoPlanes {
        right: [1.0, 0.0, 0.0],
        up: [0.0, 1.0, 0.0],
        uv: UvPlane {
            center: [0.0, 0.0, height],
            size: [uv, uv],
            grid: options.grid,
        },
        st: StPlane {
            center: [0.0; 3],
            size: [nx * sx, ny * sy],
            resolution: [stack.size[0], stack.size[1]],
        },
    }
}

/// What one ray shows: a grey value in [0, 1] and the ray parameter of its hit (`None`: none).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RaySample {
    /// Windowed grey value, 0 to 1 (`over`: premultiplied over black).
    pub value: f64,
    /// Ray parameter `t` (point `origin + t · dir`) of the hit: the maximum's slice (`mip`,
    /// where it reaches the depth threshold) or where the accumulated opacity reaches ½
    /// (`over`).
    pub hit: Option<f64>,
}

/// Maps raw grey values through a window `[lo, hi]` to [0, 1].
#[derive(Clone, Copy, Debug)]
struct Windowing {
    lo: f64,
    scale: f64,
}

impl Windowing {
    fn new(window: [f64; 2]) -> Self {
        Self {
            lo: window[0],
            scale: 1.0 / (window[1] - window[0]),
        }
    }

    #[inline]
    fn map(self, v: f64) -> f64 {
        ((v - self.lo) * self.scale).clamp(0.0, 1.0)
    }
}

/// One ray's composite, fed its raw samples front to back ([`Composite`]).
#[derive(Clone, Copy, Debug)]
struct Accumulator {
    /// `mip`: the largest sample so far and its ray parameter.
    best: f64,
    best_t: f64,
    /// `over`: premultiplied grey and opacity so far, and where the opacity reached ½.
    emitted: f64,
    opacity: f64,
    over_t: Option<f64>,
}

impl Accumulator {
    const EMPTY: Accumulator = Accumulator {
        best: f64::NEG_INFINITY,
        best_t: 0.0,
        emitted: 0.0,
        opacity: 0.0,
        over_t: None,
    };

    /// Whether later samples can no longer change the result (`over` at full opacity).
    #[inline]
    fn done(&self) -> bool {
        self.opacity > 0.999
    }

    /// Adds the raw sample `v` at ray parameter `t` (after every sample in front of it).
    #[inline]
    fn add(&mut self, options: &ZStackOptions, windowing: Windowing, v: f64, t: f64) {
        match options.composite {
            Composite::Mip => self.add_mip(v, t),
            Composite::Over => self.add_over(options.opacity, windowing, v, t),
        }
    }

    /// [`Self::add`] for `mip`.
    #[inline]
    fn add_mip(&mut self, v: f64, t: f64) {
        if v > self.best {
            self.best = v;
            self.best_t = t;
        }
    }

    /// [`Self::add`] for `over` with `opacity` per slice at full intensity.
    #[inline]
    fn add_over(&mut self, opacity: f64, windowing: Windowing, v: f64, t: f64) {
        if self.done() {
            return;
        }
        let v = windowing.map(v);
        let alpha = (opacity * v).min(1.0);
        self.emitted += (1.0 - self.opacity) * alpha * v;
        let before = self.opacity;
        self.opacity += (1.0 - self.opacity) * alpha;
        if before < 0.5 && self.opacity >= 0.5 {
            self.over_t = Some(t);
        }
    }

    /// The ray's value and hit.
    fn finish(&self, options: &ZStackOptions, windowing: Windowing) -> RaySample {
        match options.composite {
            Composite::Mip if self.best.is_finite() => {
                let value = windowing.map(self.best);
                RaySample {
                    value,
                    hit: (value > 0.0 && value >= options.depth_threshold).then_some(self.best_t),
                }
            }
            Composite::Mip => RaySample {
                value: 0.0,
                hit: None,
            },
            Composite::Over => RaySample {
                value: self.emitted,
                hit: self.over_t,
            },
        }
    }
}

impl ZStack {
    /// Composites the ray `origin + t · dir` (t > 0) through the slices front to back
    /// ([module docs](self)); slice k is the plane at height `(k − (nz − 1)/2) · sz`, sampled
    /// bilinearly.
    pub fn march(
        &self,
        options: &ZStackOptions,
        window: [f64; 2],
        origin: glam::DVec3,
        dir: glam::DVec3,
    ) -> RaySample {
        let [nx, ny, nz] = self.size;
        let [sx, sy, _] = self.spacing;
        let windowing = Windowing::new(window);
        let mut ray = Accumulator::EMPTY;
        if dir.z == 0.0 || !dir.is_finite() || !origin.is_finite() {
            return ray.finish(options, windowing);
        }
        let (hx, hy) = (f64::from(nx) / 2.0 - 0.5, f64::from(ny) / 2.0 - 0.5);
        // Front to back: down the slices when the ray goes down.
        for n in 0..nz {
            let k = if dir.z < 0.0 { nz - 1 - n } else { n };
            let t = (slice_height(self, k) - origin.z) / dir.z;
            if t <= 0.0 {
                continue;
            }
            if ray.done() {
                break;
            }
            let x = (origin.x + t * dir.x) / sx + hx;
            let y = hy - (origin.y + t * dir.y) / sy;
            ray.add(options, windowing, self.sample(k as usize, x, y), t);
        }
        ray.finish(options, windowing)
    }
}

/// The 8-bit code of a value in [0, 1].
fn code(value: f64) -> u8 {
    (255.0 * value).round().clamp(0.0, 255.0) as u8
}

/// Runs `row(i, first_row, second_row)` for every row `i` of two row-major images of `rows`
/// rows (`first` and `second` split into equal rows) on the machine's cores, a band of rows
/// each.
fn rows_in_parallel<T: Send, F: Fn(u32, &mut [u8], &mut [T]) + Sync>(
    rows: usize,
    first: &mut [u8],
    second: &mut [T],
    row: &F,
) {
    if rows == 0 {
        return;
    }
    let (a, b) = (first.len() / rows, second.len() / rows);
    let workers = std::thread::available_parallelism()
        .map_or(1, std::num::NonZeroUsize::get)
        .min(rows);
    let chunk = rows.div_ceil(workers);
    std::thread::scope(|scope| {
        for (part, (f, s)) in first
            .chunks_mut(chunk * a)
            .zip(second.chunks_mut(chunk * b))
            .enumerate()
        {
            scope.spawn(move || {
                for (r, (frow, srow)) in
                    f.chunks_exact_mut(a).zip(s.chunks_exact_mut(b)).enumerate()
                {
                    row((part * chunk + r) as u32, frow, srow);
                }
            });
        }
    });
}

/// Runs `pixel(row, column)` over `width × height` pixels on the machine's cores: each
/// pixel's RGBA8 colour and f32 value, rows from the top.
fn per_pixel(
    width: u32,
    height: u32,
    pixel: &(dyn Fn(u32, u32) -> ([u8; 4], f32) + Sync),
) -> (Vec<u8>, Vec<f32>) {
    let (w, rows) = (width as usize, height as usize);
    let mut color = vec![0u8; rows * w * 4];
    let mut value = vec![0f32; rows * w];
    rows_in_parallel(rows, &mut color, &mut value, &|i, crow, drow| {
        for j in 0..width {
            let (rgba, z) = pixel(i, j);
            crow[j as usize * 4..j as usize * 4 + 4].copy_from_slice(&rgba);
            drow[j as usize] = z;
        }
    });
    (color, value)
}

/// Camera `(a, b)`'s image of `stack` under `planes` ([`zstack_planes`]): RGBA8 colour (grey,
/// opaque) and the stored depth (f32, little-endian; DESIGN §9: the ray from the camera `C`
/// through st point `S` is `C + t (S − C)`, so the stored depth is the hit's `t`, 1 where there
/// is none), rows from the top; `window` maps grey values to [0, 1]. The same composite as
/// [`ZStack::march`] of each pixel's ray, computed a row at a time slice by slice (the ray
/// through st texel (i, j) crosses slice k at column `t·j + x0` and row `t·i + y0`, `t` the
/// slice's ray parameter), so that the slices are read in order.
pub fn synthesize_camera(
    stack: &ZStack,
    planes: &TwoPlanes,
    options: &ZStackOptions,
    window: [f64; 2],
    a: u32,
    b: u32,
) -> (Vec<u8>, Vec<u8>) {
    let camera = planes.camera(a, b);
    let [nx, ny, nz] = stack.size;
    let [sx, sy, _] = stack.spacing;
    let (hx, hy) = (f64::from(nx) / 2.0 - 0.5, f64::from(ny) / 2.0 - 0.5);
    let h = camera.z;
    let windowing = Windowing::new(window);
    let plane = nx as usize * ny as usize;
    let w = nx as usize;
    // Front to back: the cameras are above every slice.
    let slices: Vec<(usize, f64)> = (0..nz)
        .rev()
        .map(|k| (k as usize, (h - slice_height(stack, k)) / h))
        .filter(|&(_, t)| t > 0.0)
        .collect();
    let row = |i: u32, color: &mut [u8], depth: &mut [u8]| {
        let mut rays = vec![Accumulator::EMPTY; w];
        let mut values = vec![0.0f64; w];
        for &(k, t) in &slices {
            let y = t * f64::from(i) + (hy - camera.y / sy) * (1.0 - t);
            let x0 = (hx + camera.x / sx) * (1.0 - t);
            values.fill(0.0);
            if y >= -0.5 && y <= f64::from(ny) - 0.5 {
                let fy = y.floor();
                let ty = y - fy;
                let r0 = (fy as i64).clamp(0, i64::from(ny) - 1) as usize;
                let r1 = (fy as i64 + 1).clamp(0, i64::from(ny) - 1) as usize;
                let slice = &stack.voxels[k * plane..(k + 1) * plane];
                let (top, bottom) = (&slice[r0 * w..(r0 + 1) * w], &slice[r1 * w..(r1 + 1) * w]);
                for (j, value) in values.iter_mut().enumerate() {
                    let x = x0 + t * j as f64;
                    if x < -0.5 || x > f64::from(nx) - 0.5 {
                        continue;
                    }
                    let fx = x.floor();
                    let tx = x - fx;
                    let c0 = (fx as i64).clamp(0, i64::from(nx) - 1) as usize;
                    let c1 = (fx as i64 + 1).clamp(0, i64::from(nx) - 1) as usize;
                    let upper = f64::from(top[c0]) * (1.0 - tx) + f64::from(top[c1]) * tx;
                    let lower = f64::from(bottom[c0]) * (1.0 - tx) + f64::from(bottom[c1]) * tx;
                    *value = upper * (1.0 - ty) + lower * ty;
                }
            }
            // The composite chosen once per slice, not per pixel.
            match options.composite {
                Composite::Mip => {
                    for (&v, ray) in values.iter().zip(&mut rays) {
                        ray.add_mip(v, t);
                    }
                }
                Composite::Over => {
                    for (&v, ray) in values.iter().zip(&mut rays) {
                        ray.add_over(options.opacity, windowing, v, t);
                    }
                }
            }
        }
        for ((rgba, z), ray) in color
            .chunks_exact_mut(4)
            .zip(depth.chunks_exact_mut(4))
            .zip(&rays)
        {
            let ray = ray.finish(options, windowing);
            let c = code(ray.value);
            rgba.copy_from_slice(&[c, c, c, 255]);
            z.copy_from_slice(&(ray.hit.map_or(1.0, |t| t as f32)).to_le_bytes());
        }
    };
    let rows = ny as usize;
    let mut color = vec![0u8; rows * w * 4];
    let mut depth = vec![0u8; rows * w * 4];
    rows_in_parallel(rows, &mut color, &mut depth, &row);
    (color, depth)
}

/// The direct rendering of `stack` placed as in [`zstack_planes`] for `view` (the ground truth
/// a light field of it approximates; a CPU ray caster): grey colour and z-depth along the
/// view's forward axis (`+inf` without a hit); pixels whose ray crosses no slice inside the
/// stack stay black, opaque.
///
/// # Errors
/// [`ZStackError::Option`] for a bad view or options.
pub fn reference_view(
    stack: &ZStack,
    options: &ZStackOptions,
    window: [f64; 2],
    view: &crate::view::View,
) -> Result<crate::frame::Frame> {
    options.validate()?;
    let basis = view
        .basis(crate::view::DEFAULT_MAX_VIEW_PX)
        .map_err(|e| ZStackError::Option(format!("view: {e}")))?;
    let eye = basis.eye;
    let pixel = |i: u32, j: u32| {
        let dir = basis.pixel_dir(i, j);
        let ray = stack.march(options, window, eye, dir);
        let c = code(ray.value);
        let z = ray
            .hit
            .map_or(f32::INFINITY, |t| (t * dir.dot(basis.forward)) as f32);
        ([c, c, c, 255], z)
    };
    let (color, depth) = per_pixel(view.width, view.height, &pixel);
    Ok(crate::frame::Frame {
        width: view.width,
        height: view.height,
        color,
        depth,
        ..crate::frame::Frame::default()
    })
}

/// What [`import_zstack`] made.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ZStackReport {
    /// Columns, rows, slices.
    pub size: [u32; 3],
    /// Bits per voxel.
    pub bits: u8,
    /// Spacing used.
    pub spacing: [f64; 3],
    /// Grey values mapped to 0 and 1.
    pub window: [f64; 2],
    /// The planes.
    pub planes: TwoPlanes,
    /// Cameras.
    pub cameras: u32,
    /// Milliseconds to synthesise and write.
    pub ms: f64,
}

/// Synthesises `stack`'s light field ([module docs](self)) into `output` (atomically);
/// `source` names it in the provenance; `progress(done, total)` after each camera.
///
/// # Errors
/// [`ZStackError::Option`] for bad options; [`ZStackError::Asset`] when writing fails.
pub fn import_zstack(
    stack: &ZStack,
    source: &Path,
    options: &ZStackOptions,
    output: &Path,
    progress: &mut dyn FnMut(u32, u32),
) -> Result<ZStackReport> {
    options.validate()?;
    let start = std::time::Instant::now();
    let window = options.window.unwrap_or_else(|| stack.auto_window());
    let planes = zstack_planes(stack, options);
    planes
        .validate()
        .map_err(|e| ZStackError::Stack(format!("the stack's planes: {e}")))?;
    let provenance = crate::two_plane_io::import_provenance(
        source,
        serde_json::json!({
            "layout": "zstack",
            "depth": true,
            "size": stack.size,
            "bits": stack.bits,
            "spacing": stack.spacing,
            "window": window,
            "options": options,
        }),
    );
    let header = AssetHeader::new_two_plane(planes, crate::asset::DEFAULT_PAGE_SIZE, provenance)?;
    let mut writer = AssetWriter::create(output, header)?;
    let [nu, nv] = options.grid;
    let total = nu * nv;
    for b in 0..nv {
        for a in 0..nu {
            let (color, depth) = synthesize_camera(stack, &planes, options, window, a, b);
            let camera = b * nu + a;
            writer.add_image(ImageKey::new(0, 0, camera, Channel::Color), &color)?;
            writer.add_image(ImageKey::new(0, 0, camera, Channel::Depth), &depth)?;
            progress(camera + 1, total);
        }
    }
    writer.finish()?;
    Ok(ZStackReport {
        size: stack.size,
        bits: stack.bits,
        spacing: stack.spacing,
        window,
        planes,
        cameras: total,
        ms: start.elapsed().as_secs_f64() * 1e3,
    })
}

/// A synthetic fluorescence specimen of `size` voxels (16-bit, spacing 0.2 × 0.2 × 1 µm): a few
/// hundred curved filaments and a thousand beads, blurred by a small point spread, over a dim
/// noisy background; the same voxels for the same size. `import-zstack --demo` and the
/// benchmarks use it where no microscope stack is at hand.
///
/// # Errors
/// [`ZStackError::Stack`] for a size out of range.
pub fn demo_stack(size: [u32; 3]) -> Result<ZStack> {
    use rand::{RngExt, SeedableRng};
    ZStack::check_size(size)?;
    let [nx, ny, nz] = size.map(|n| n as usize);
    let mut rng = rand_pcg::Pcg64::seed_from_u64(0x5eed_2a57);
    let mut acc = vec![0f32; nx * ny * nz];
    // Splats a blurred point (σ 1 px laterally, half a slice axially) of brightness `b`.
    let mut splat = |x: f64, y: f64, z: f64, b: f32| {
        let (cx, cy, cz) = (x.round() as i64, y.round() as i64, z.round() as i64);
        for dz in -1..=1i64 {
            for dy in -2..=2i64 {
                for dx in -2..=2i64 {
                    let (px, py, pz) = (cx + dx, cy + dy, cz + dz);
                    if px < 0
                        || py < 0
                        || pz < 0
                        || px >= nx as i64
                        || py >= ny as i64
                        || pz >= nz as i64
                    {
                        continue;
                    }
                    let r2 = (px as f64 - x).powi(2) + (py as f64 - y).powi(2);
                    let w = (-0.5 * r2 - 2.0 * (pz as f64 - z).powi(2)).exp() as f32;
                    acc[(pz as usize * ny + py as usize) * nx + px as usize] += b * w;
                }
            }
        }
    };
    let lateral = nx.max(ny) as f64;
    let filaments = (lateral / 8.0).clamp(8.0, 400.0) as usize;
    for _ in 0..filaments {
        let (mut x, mut y, mut z) = (
            rng.random::<f64>() * nx as f64,
            rng.random::<f64>() * ny as f64,
            rng.random::<f64>() * (nz as f64 - 1.0),
        );
        let mut heading = rng.random::<f64>() * std::f64::consts::TAU;
        let climb = (rng.random::<f64>() - 0.5) * 0.04;
        let bend = (rng.random::<f64>() - 0.5) * 0.02;
        let brightness = 0.4 + 0.6 * rng.random::<f32>();
        for _ in 0..(lateral * 0.6) as usize {
            splat(x, y, z, brightness);
            heading += bend + (rng.random::<f64>() - 0.5) * 0.05;
            x += 0.7 * heading.cos();
            y += 0.7 * heading.sin();
            z = (z + climb).clamp(0.0, nz as f64 - 1.0);
        }
    }
    for _ in 0..(lateral as usize).clamp(64, 4000) {
        let (x, y, z) = (
            rng.random::<f64>() * nx as f64,
            rng.random::<f64>() * ny as f64,
            rng.random::<f64>() * (nz as f64 - 1.0),
        );
        splat(x, y, z, 1.5 + rng.random::<f32>());
    }
    let voxels: Vec<u16> = acc
        .iter()
        .enumerate()
        .map(|(i, &v)| {
            // Dim background with hashed noise (no second generator pass over the voxels).
            let h = (i as u64)
                .wrapping_mul(0x9e37_79b9_7f4a_7c15)
                .rotate_left(29)
                >> 52;
            let noise = h as f32 / 4096.0;
            (2000.0 + 600.0 * noise + 24000.0 * v.min(2.5)).min(65535.0) as u16
        })
        .collect();
    ZStack::new(size, 16, [0.2, 0.2, 1.0], voxels)
}
