//! Import and export of two-plane light fields as image grids (docs/two_plane.md, "Import and
//! export"): a folder of PNGs on a rectangular camera grid (`grid`: the last two whole numbers
//! of each file name are its row and column; the Stanford light-field archive's
//! `out_RR_CC_….png` names read the same way with the first two), with an optional
//! `planes.json` (DESIGN §9) and per-camera depth (`.npy` beside each PNG); and back, as one
//! PNG (+ depth) per camera or as the seed's plenoptic mosaic (every camera's image tiled by
//! (u, v)).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use crate::asset::{
    AssetError, AssetFile, AssetHeader, AssetWriter, Channel, ImageKey, Provenance,
};
use crate::image_io::{self, ImageIoError};
use crate::two_plane::{
    MAX_CAMERAS, MAX_ST_RESOLUTION, StPlane, TwoPlaneError, TwoPlanes, UvPlane,
};

/// How the images of a folder name their camera.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum GridLayout {
    /// `…ROW…COL.png`: the last two whole numbers of the file stem are the row (b, from the
    /// top) and the column (a, from the left), e.g. `003_012.png` or `cam_3_12.png`.
    Grid,
    /// The Stanford light-field archive: `out_ROW_COL_….png`, the first two whole numbers.
    Stanford,
}

impl std::str::FromStr for GridLayout {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "grid" => Ok(GridLayout::Grid),
            "stanford" => Ok(GridLayout::Stanford),
            "lenslet" => Err(
                "layout lenslet is a raw plenoptic image with its calibration, not a grid of \
                 images: import it with lumigraph::lenslet::import_lenslet"
                    .to_owned(),
            ),
            other => Err(format!(
                "layout {other:?}: choose grid, stanford or lenslet"
            )),
        }
    }
}

/// Why an import or export failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum TwoPlaneIoError {
    /// The folder cannot be listed.
    #[error("cannot list {}", path.display())]
    List {
        /// The folder.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// An image or depth file cannot be read or written.
    #[error("{}: {source}", path.display())]
    Image {
        /// The file.
        path: PathBuf,
        /// Why.
        source: ImageIoError,
    },
    /// The files do not form a complete rectangular grid of equal images.
    #[error("{0}")]
    Grid(String),
    /// `planes.json` or the planes given are invalid or do not match the images.
    #[error("planes: {0}")]
    Planes(String),
    /// Writing or reading the asset failed.
    #[error(transparent)]
    Asset(#[from] AssetError),
}

impl From<TwoPlaneError> for TwoPlaneIoError {
    fn from(e: TwoPlaneError) -> Self {
        TwoPlaneIoError::Planes(e.to_string())
    }
}

/// The whole numbers in a file stem, in order (also what orders a z-stack's slice files).
pub(crate) fn numbers(stem: &str) -> Vec<u64> {
    let mut out = Vec::new();
    let mut current: Option<u64> = None;
    for c in stem.chars() {
        if let Some(d) = c.to_digit(10) {
            current = Some(
                current
                    .unwrap_or(0)
                    .saturating_mul(10)
                    .saturating_add(u64::from(d)),
            );
        } else if let Some(n) = current.take() {
            out.push(n);
        }
    }
    out.extend(current);
    out
}

/// The (row, column) a file name gives under `layout`, `None` when it has too few numbers.
fn cell_of(stem: &str, layout: GridLayout) -> Option<(u64, u64)> {
    let n = numbers(stem);
    match layout {
        GridLayout::Grid if n.len() >= 2 => Some((n[n.len() - 2], n[n.len() - 1])),
        GridLayout::Stanford if n.len() >= 2 => Some((n[0], n[1])),
        _ => None,
    }
}

/// The default planes of an imported grid with no `planes.json`: cameras a unit apart on the
/// plane z = 1 facing −z, images of the st rectangle on z = 0 with square texels the width of
/// the camera grid across (so an st texel spans `nu / ns` camera spacings).
pub fn default_planes(grid: [u32; 2], resolution: [u32; 2]) -> TwoPlanes {
    let [nu, nv] = grid.map(f64::from);
    let [ns, nt] = resolution.map(f64::from);
    TwoPlanes {
        right: [1.0, 0.0, 0.0],
        up: [0.0, 1.0, 0.0],
        uv: UvPlane {
            center: [0.0, 0.0, 1.0],
            size: [nu, nv],
            grid,
        },
        st: StPlane {
            center: [0.0, 0.0, 0.0],
            size: [nu, nu * nt / ns],
            resolution,
        },
    }
}

/// What [`import_grid`] made.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ImportReport {
    /// Cameras per row and rows.
    pub grid: [u32; 2],
    /// Image size.
    pub resolution: [u32; 2],
    /// Whether depth images were found (else every texel stores depth 1: the st plane).
    pub depth: bool,
    /// Whether `planes.json` placed the planes (else [`default_planes`]).
    pub planes_from_file: bool,
}

/// The provenance of an import from `source` (its file name): `import` is recorded as the
/// bake options' `import` object (its `depth: false` tells [`crate::two_plane::has_captured_depth`]
/// that no depth came with the images).
pub(crate) fn import_provenance(source: &Path, import: serde_json::Value) -> Provenance {
    Provenance {
        source_name: source.file_name().map_or_else(
            || source.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        ),
        lumigraph_version: env!("CARGO_PKG_VERSION").to_owned(),
        bake_options: serde_json::Value::Object(serde_json::Map::from_iter([(
            "import".to_owned(),
            import,
        )])),
        created_unix: std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_secs()),
        ..Provenance::default()
    }
}

/// The depth image of `texels` texels that all store depth 1 (on the st plane): the depth of an
/// import without depth images.
pub(crate) fn unit_depth(texels: usize) -> Vec<u8> {
    (0..texels).flat_map(|_| 1.0f32.to_le_bytes()).collect()
}

/// Imports the PNGs of `dir` as a two-plane light field into `output` (atomically). Rows and
/// columns must be consecutive from their smallest number and every cell present once; every
/// image the same size (≤ 8192 a side); at most 2048 cameras. A `.npy` (f32 z, the stored depth
/// of DESIGN §9, `+inf` for no hit) beside a PNG of the same stem gives its depth: all or none.
/// `planes` (or `dir/planes.json`) places the planes; its grid and st resolution must match
/// the images. Colour is stored as read (alpha included), so export then import round-trips
/// bit for bit.
///
/// # Errors
/// [`TwoPlaneIoError`] naming the file or the rule.
pub fn import_grid(
    dir: &Path,
    layout: GridLayout,
    planes: Option<TwoPlanes>,
    output: &Path,
    progress: &mut dyn FnMut(u32, u32),
) -> Result<ImportReport, TwoPlaneIoError> {
    let entries = std::fs::read_dir(dir).map_err(|source| TwoPlaneIoError::List {
        path: dir.to_path_buf(),
        source,
    })?;
    let mut cells: BTreeMap<(u64, u64), PathBuf> = BTreeMap::new();
    for entry in entries {
        let path = entry
            .map_err(|source| TwoPlaneIoError::List {
                path: dir.to_path_buf(),
                source,
            })?
            .path();
        let is_png = path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("png"));
        if !is_png {
            continue;
        }
        let stem = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        let cell = cell_of(&stem, layout).ok_or_else(|| {
            TwoPlaneIoError::Grid(format!(
                "{}: the name holds no row and column (two whole numbers)",
                path.display()
            ))
        })?;
        if let Some(other) = cells.insert(cell, path.clone()) {
            return Err(TwoPlaneIoError::Grid(format!(
                "{} and {} both name row {} column {}",
                other.display(),
                path.display(),
                cell.0,
                cell.1
            )));
        }
    }
    if cells.is_empty() {
        return Err(TwoPlaneIoError::Grid(format!(
            "{} holds no PNG images",
            dir.display()
        )));
    }
    // Rows and columns run from their smallest to their largest number; every cell between
    // must be there.
    let rows: std::collections::BTreeSet<u64> = cells.keys().map(|c| c.0).collect();
    let cols: std::collections::BTreeSet<u64> = cells.keys().map(|c| c.1).collect();
    let span = |set: &std::collections::BTreeSet<u64>| {
        let (lo, hi) = (
            set.first().copied().unwrap_or(0),
            set.last().copied().unwrap_or(0),
        );
        (lo, hi - lo + 1)
    };
    let ((r0, nv), (c0, nu)) = (span(&rows), span(&cols));
    if nu.saturating_mul(nv) > u64::from(MAX_CAMERAS) {
        return Err(TwoPlaneIoError::Grid(format!(
            "{nu} x {nv} cameras: at most {MAX_CAMERAS}"
        )));
    }
    for r in r0..r0 + nv {
        for c in c0..c0 + nu {
            if !cells.contains_key(&(r, c)) {
                return Err(TwoPlaneIoError::Grid(format!(
                    "the grid is {nu} x {nv} but row {r} column {c} has no image"
                )));
            }
        }
    }
    let grid = [nu as u32, nv as u32];
    let read_png = |path: &Path| {
        image_io::read_png_rgba8(path).map_err(|source| TwoPlaneIoError::Image {
            path: path.to_path_buf(),
            source,
        })
    };
    let first = cells.values().next().map_or(dir, PathBuf::as_path);
    let (width, height, _) = read_png(first)?;
    if width > MAX_ST_RESOLUTION || height > MAX_ST_RESOLUTION {
        return Err(TwoPlaneIoError::Grid(format!(
            "{}: {width} x {height} px, at most {MAX_ST_RESOLUTION} a side",
            first.display()
        )));
    }
    let resolution = [width, height];
    let planes_file = dir.join("planes.json");
    let (planes, planes_from_file) = match planes {
        Some(p) => (p, false),
        None if planes_file.is_file() => {
            let text = std::fs::read_to_string(&planes_file)
                .map_err(|e| TwoPlaneIoError::Planes(format!("{}: {e}", planes_file.display())))?;
            (TwoPlanes::from_json(&text)?, true)
        }
        None => (default_planes(grid, resolution), false),
    };
    planes.validate()?;
    if planes.uv.grid != grid || planes.st.resolution != resolution {
        return Err(TwoPlaneIoError::Planes(format!(
            "the planes say {:?} cameras of {:?} px; the images are {grid:?} of {resolution:?}",
            planes.uv.grid, planes.st.resolution
        )));
    }
    let depth_of = |png: &Path| png.with_extension("npy");
    let with_depth = cells.values().filter(|p| depth_of(p).is_file()).count();
    if with_depth != 0 && with_depth != cells.len() {
        return Err(TwoPlaneIoError::Grid(format!(
            "{with_depth} of {} images have a depth .npy beside them: give all or none",
            cells.len()
        )));
    }
    let depth = with_depth != 0;
    let provenance = import_provenance(
        dir,
        serde_json::json!({"layout": format!("{layout:?}").to_lowercase(), "depth": depth}),
    );
    let header = AssetHeader::new_two_plane(planes, crate::asset::DEFAULT_PAGE_SIZE, provenance)?;
    let mut writer = AssetWriter::create(output, header)?;
    let total = nu as u32 * nv as u32;
    let unit_depth = unit_depth(width as usize * height as usize);
    for ((r, c), path) in &cells {
        let (w, h, rgba) = read_png(path)?;
        if [w, h] != resolution {
            return Err(TwoPlaneIoError::Grid(format!(
                "{} is {w} x {h} px; {} is {width} x {height}",
                path.display(),
                first.display()
            )));
        }
        let camera = (r - r0) as u32 * nu as u32 + (c - c0) as u32;
        writer.add_image(ImageKey::new(0, 0, camera, Channel::Color), &rgba)?;
        if depth {
            let depth_path = depth_of(path);
            let (dw, dh, values) =
                image_io::read_depth_npy(&depth_path).map_err(|source| TwoPlaneIoError::Image {
                    path: depth_path.clone(),
                    source,
                })?;
            if [dw, dh] != resolution {
                return Err(TwoPlaneIoError::Grid(format!(
                    "{} is {dw} x {dh}; its image is {width} x {height}",
                    depth_path.display()
                )));
            }
            if let Some(bad) = values
                .iter()
                .find(|d| !(d.is_finite() && **d > 0.0) && **d != f32::INFINITY)
            {
                return Err(TwoPlaneIoError::Grid(format!(
                    "{} holds depth {bad}: stored depths are positive, or +inf for no hit",
                    depth_path.display()
                )));
            }
            let bytes: Vec<u8> = values.iter().flat_map(|d| d.to_le_bytes()).collect();
            writer.add_image(ImageKey::new(0, 0, camera, Channel::Depth), &bytes)?;
        } else {
            writer.add_image(ImageKey::new(0, 0, camera, Channel::Depth), &unit_depth)?;
        }
        progress(camera + 1, total);
    }
    writer.finish()?;
    Ok(ImportReport {
        grid,
        resolution,
        depth,
        planes_from_file,
    })
}

fn planes_of(asset: &AssetFile) -> Result<TwoPlanes, TwoPlaneIoError> {
    asset.header().two_plane().copied().ok_or_else(|| {
        TwoPlaneIoError::Asset(AssetError::Kind {
            what: "export",
            kind: asset.header().kind,
        })
    })
}

/// Writes every camera of a two-plane asset into `dir` (created if needed) as
/// `ROW_COL.png` (colour as stored) and `ROW_COL.npy` (stored depth), rows and columns three
/// digits from 000, plus `planes.json`: what [`import_grid`] reads back bit for bit.
///
/// # Errors
/// [`TwoPlaneIoError`].
pub fn export_images(asset: &AssetFile, dir: &Path) -> Result<u32, TwoPlaneIoError> {
    let planes = planes_of(asset)?;
    std::fs::create_dir_all(dir).map_err(|source| TwoPlaneIoError::List {
        path: dir.to_path_buf(),
        source,
    })?;
    let [nu, nv] = planes.uv.grid;
    let [ns, nt] = planes.st.resolution;
    for b in 0..nv {
        for a in 0..nu {
            let camera = b * nu + a;
            let png = dir.join(format!("{b:03}_{a:03}.png"));
            let color = asset.read_image(ImageKey::new(0, 0, camera, Channel::Color))?;
            image_io::write_png_rgba8(&png, ns, nt, &color)
                .map_err(|source| TwoPlaneIoError::Image { path: png, source })?;
            let npy = dir.join(format!("{b:03}_{a:03}.npy"));
            let bytes = asset.read_image(ImageKey::new(0, 0, camera, Channel::Depth))?;
            let depth: Vec<f32> = bytes
                .chunks_exact(4)
                .map(|x| f32::from_le_bytes([x[0], x[1], x[2], x[3]]))
                .collect();
            image_io::write_depth_npy(&npy, ns, nt, &depth)
                .map_err(|source| TwoPlaneIoError::Image { path: npy, source })?;
        }
    }
    let json =
        serde_json::to_vec_pretty(&planes).map_err(|e| TwoPlaneIoError::Planes(e.to_string()))?;
    let path = dir.join("planes.json");
    crate::atomic_write(&path, |w| std::io::Write::write_all(w, &json)).map_err(|source| {
        TwoPlaneIoError::Image {
            path: path.clone(),
            source: ImageIoError::Io {
                path: path.clone(),
                source,
            },
        }
    })?;
    Ok(nu * nv)
}

/// The seed's plenoptic texture: every camera's colour image tiled by (u, v), camera (a, b) at
/// column a, row b of tiles: `nu·ns × nv·nt` RGBA8 pixels.
///
/// # Errors
/// [`TwoPlaneIoError::Grid`] when the mosaic would exceed 65535 px a side (PNG's practical
/// limit here) or 2³² bytes; asset errors.
pub fn mosaic(asset: &AssetFile) -> Result<(u32, u32, Vec<u8>), TwoPlaneIoError> {
    let planes = planes_of(asset)?;
    let [nu, nv] = planes.uv.grid;
    let [ns, nt] = planes.st.resolution;
    let (width, height) = (u64::from(nu) * u64::from(ns), u64::from(nv) * u64::from(nt));
    if width > 65535 || height > 65535 || width * height * 4 > u64::from(u32::MAX) {
        return Err(TwoPlaneIoError::Grid(format!(
            "the mosaic would be {width} x {height} px; export --images instead"
        )));
    }
    let (width, height) = (width as usize, height as usize);
    let mut out = vec![0u8; width * height * 4];
    for b in 0..nv {
        for a in 0..nu {
            let color = asset.read_image(ImageKey::new(0, 0, b * nu + a, Channel::Color))?;
            let row_bytes = ns as usize * 4;
            for i in 0..nt as usize {
                let dst = ((b as usize * nt as usize + i) * width + a as usize * ns as usize) * 4;
                out[dst..dst + row_bytes]
                    .copy_from_slice(&color[i * row_bytes..(i + 1) * row_bytes]);
            }
        }
    }
    Ok((width as u32, height as u32, out))
}
