//! Raw lenslet (plenoptic) images into two-plane light fields (docs/two_plane.md, "Lenslet
//! import").
//!
//! A plenoptic camera puts a lenslet array in the image plane: every lenslet images the
//! objective's pupil onto a small disc of sensor pixels, so the lenslet's position is the
//! spatial sample (s, t) and the pixel within its disc the direction (u, v). The import:
//!
//! 1. reads the raw image, the dark frame and the radiometry frame (a uniformly lit sample
//!    through the same optics) as grey values;
//! 2. finds the lenslet lattice in the radiometry frame: its two fundamental spatial
//!    frequencies, searched near the nominal pitch (`pitch_um / pixel_size_um`) on a coarse grid
//!    and refined to 1/(256·W) cycles per pixel, give both lattice vectors (pitch and rotation);
//!    their phases give the lenslet centres;
//! 3. subtracts the dark frame from both and devignettes: a sample is the raw value over the
//!    radiometry value there, and is empty (alpha 0) where the radiometry is below
//!    [`MIN_RADIOMETRY`] of its 99th percentile (outside the pupil's disc);
//! 4. resamples every lenslet on an N × N grid of integer (u, v) positions spread evenly over
//!    its cell (N = the pitch rounded down), bilinearly, into camera (u, v)'s image;
//! 5. places the planes in object space, in micrometres: st is the lenslet grid at the
//!    specimen (pitch / magnification per texel), and the uv cameras sit 100 st widths away,
//!    spread so that camera u's direction to the st centre has the tangent of the angle the
//!    pupil position of u sees, taken as sinθ = NA / n linearly across the disc (the paraxial
//!    model; at high NA the outer views' angles are compressed). `focus` is then a height above
//!    the native focal plane in micrometres (paraxial).
//!
//! Grey values are stored in RGB8, scaled so that the 99.5th percentile of the devignetted
//! samples is 255; depth is not known (depth 1: the st plane).

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::asset::{AssetHeader, AssetWriter, Channel, ImageKey};
use crate::two_plane::{StPlane, TwoPlanes, UvPlane};

/// Largest side of an image the import reads, pixels.
pub const MAX_SIDE: u32 = 16384;
/// Radiometry below this fraction of its 99th percentile is outside the pupil: empty.
pub const MIN_RADIOMETRY: f32 = 0.1;
/// A lattice frequency whose amplitude is below this fraction of the frame's mean is not a
/// lenslet grid.
pub const MIN_CONTRAST: f64 = 0.05;
/// Most views per axis (2048 cameras at most in a two-plane light field).
pub const MAX_VIEWS: u32 = 45;
/// Distance of the uv plane from st, in st widths: far enough that every camera's rays are
/// parallel to within 1 % across st (the sub-aperture views of a microscope are telecentric).
pub const UV_DISTANCE_ST_WIDTHS: f64 = 100.0;

/// Why a lenslet import failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum LensletError {
    /// No calibration beside the image.
    #[error("a lenslet import needs its calibration: {0}")]
    NoCalibration(String),
    /// A calibration that cannot be read or holds bad values.
    #[error("calibration {}: {message}", path.display())]
    Calibration {
        /// The calibration file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// An image that cannot be read.
    #[error("cannot read {}: {message}", path.display())]
    Image {
        /// The image.
        path: PathBuf,
        /// Why.
        message: String,
    },
    /// No lenslet grid found, or one the image cannot hold.
    #[error("{0}")]
    Grid(String),
    /// The asset cannot be written.
    #[error(transparent)]
    Asset(#[from] crate::asset::AssetError),
}

type Result<T> = std::result::Result<T, LensletError>;

/// The optics of a lenslet light field: `lenslet.json` beside the image (this struct's JSON),
/// or napari-LF's `metadata.txt`, whose `calibrate` and `rectify` sections give the same.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LensletCalibration {
    /// The raw lenslet image (relative to the calibration's folder).
    pub image: PathBuf,
    /// A uniformly lit frame through the same optics (finds the lattice and devignettes).
    pub radiometry: PathBuf,
    /// A frame with no light (subtracted from both), if recorded.
    #[serde(default)]
    pub dark: Option<PathBuf>,
    /// Lenslet pitch in micrometres (at the sensor, after any relay).
    pub pitch_um: f64,
    /// Sensor pixel size in micrometres.
    pub pixel_size_um: f64,
    /// Objective magnification.
    pub magnification: f64,
    /// Objective numerical aperture.
    pub na: f64,
    /// Refractive index of the immersion medium.
    pub medium_index: f64,
}

impl LensletCalibration {
    /// The nominal pitch in sensor pixels.
    pub fn pitch_px(&self) -> f64 {
        self.pitch_um / self.pixel_size_um
    }

    fn validate(&self, path: &Path) -> Result<()> {
        let bad = |message: String| {
            Err(LensletError::Calibration {
                path: path.to_path_buf(),
                message,
            })
        };
        for (name, v) in [
            ("pitch_um", self.pitch_um),
            ("pixel_size_um", self.pixel_size_um),
            ("magnification", self.magnification),
            ("na", self.na),
            ("medium_index", self.medium_index),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return bad(format!("{name} {v} must be finite and positive"));
            }
        }
        if self.na >= self.medium_index {
            return bad(format!(
                "na {} must be below the medium index {}",
                self.na, self.medium_index
            ));
        }
        let pitch = self.pitch_px();
        if !(3.0..=256.0).contains(&pitch) {
            return bad(format!(
                "the lenslet pitch is {pitch:.2} px (pitch_um / pixel_size_um): a lenslet must \
                 span 3 to 256 pixels"
            ));
        }
        Ok(())
    }
}

/// napari-LF's `metadata.txt`: the sections the import reads.
#[derive(Deserialize)]
struct NapariMetadata {
    calibrate: NapariCalibrate,
    rectify: NapariRectify,
}

#[derive(Deserialize)]
struct NapariCalibrate {
    radiometry_frame_file: PathBuf,
    #[serde(default)]
    dark_frame_file: Option<PathBuf>,
    ulens_pitch: f64,
    pixel_size: f64,
    objective_magnification: f64,
    objective_na: f64,
    medium_index: f64,
}

#[derive(Deserialize)]
struct NapariRectify {
    input_file: PathBuf,
}

/// The calibration of `source` (a folder, or the raw image inside one) with its paths made
/// absolute: `lenslet.json` in the folder, else napari-LF's `metadata.txt`.
///
/// # Errors
/// [`LensletError::NoCalibration`] when neither file is there; [`LensletError::Calibration`]
/// for a file that does not parse or holds bad values.
pub fn read_calibration(source: &Path) -> Result<LensletCalibration> {
    let (dir, image) = if source.is_dir() {
        (source.to_path_buf(), None)
    } else {
        let dir = source
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new("."));
        (dir.to_path_buf(), Some(source.to_path_buf()))
    };
    let own = dir.join("lenslet.json");
    let napari = dir.join("metadata.txt");
    let read = |path: &Path| {
        std::fs::read_to_string(path).map_err(|e| LensletError::Calibration {
            path: path.to_path_buf(),
            message: e.to_string(),
        })
    };
    let parse_error = |path: &Path, e: serde_json::Error| LensletError::Calibration {
        path: path.to_path_buf(),
        message: e.to_string(),
    };
    let (mut calibration, path) = if own.is_file() {
        let c: LensletCalibration =
            serde_json::from_str(&read(&own)?).map_err(|e| parse_error(&own, e))?;
        (c, own)
    } else if napari.is_file() {
        let m: NapariMetadata =
            serde_json::from_str(&read(&napari)?).map_err(|e| parse_error(&napari, e))?;
        let c = LensletCalibration {
            image: m.rectify.input_file,
            radiometry: m.calibrate.radiometry_frame_file,
            dark: m
                .calibrate
                .dark_frame_file
                .filter(|p| !p.as_os_str().is_empty()),
            pitch_um: m.calibrate.ulens_pitch,
            pixel_size_um: m.calibrate.pixel_size,
            magnification: m.calibrate.objective_magnification,
            na: m.calibrate.objective_na,
            medium_index: m.calibrate.medium_index,
        };
        (c, napari)
    } else {
        return Err(LensletError::NoCalibration(format!(
            "{} holds neither lenslet.json nor napari-LF's metadata.txt; write a lenslet.json \
             with image, radiometry, dark, pitch_um, pixel_size_um, magnification, na and \
             medium_index (docs/two_plane.md, \"Lenslet import\")",
            dir.display()
        )));
    };
    calibration.validate(&path)?;
    calibration.image = image.unwrap_or_else(|| dir.join(&calibration.image));
    calibration.radiometry = dir.join(&calibration.radiometry);
    calibration.dark = calibration.dark.map(|d| dir.join(d));
    Ok(calibration)
}

/// A grey image, values as decoded scaled to [0, 1].
#[derive(Clone, Debug)]
pub struct Grey {
    /// Width.
    pub width: u32,
    /// Height.
    pub height: u32,
    /// Row-major values.
    pub values: Vec<f32>,
}

impl Grey {
    /// Bilinear value at continuous pixel coordinates (pixel centres at whole numbers),
    /// clamped to the image.
    fn at(&self, x: f64, y: f64) -> f32 {
        let (w, h) = (self.width as usize, self.height as usize);
        let x = x.clamp(0.0, (w - 1) as f64);
        let y = y.clamp(0.0, (h - 1) as f64);
        let (x0, y0) = (x.floor() as usize, y.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
        let (fx, fy) = ((x - x0 as f64) as f32, (y - y0 as f64) as f32);
        let v = |x: usize, y: usize| self.values[y * w + x];
        let top = v(x0, y0) * (1.0 - fx) + v(x1, y0) * fx;
        let bottom = v(x0, y1) * (1.0 - fx) + v(x1, y1) * fx;
        top * (1.0 - fy) + bottom * fy
    }
}

/// Reads a grey image (8 or 16 bit, or float; TIFF, PNG): colour is averaged to grey.
///
/// # Errors
/// [`LensletError::Image`] for an unreadable file, a side above [`MAX_SIDE`] (checked before
/// decoding) or a non-finite value.
pub fn read_grey(path: &Path) -> Result<Grey> {
    let fail = |message: String| LensletError::Image {
        path: path.to_path_buf(),
        message,
    };
    let open = || {
        image::ImageReader::open(path)
            .map_err(|e| fail(e.to_string()))?
            .with_guessed_format()
            .map_err(|e| fail(e.to_string()))
    };
    let (width, height) = open()?.into_dimensions().map_err(|e| fail(e.to_string()))?;
    if width == 0 || height == 0 || width > MAX_SIDE || height > MAX_SIDE {
        return Err(fail(format!(
            "{width} x {height} px: a lenslet image is 1 to {MAX_SIDE} px a side"
        )));
    }
    let decoded = open()?.decode().map_err(|e| fail(e.to_string()))?;
    let values = decoded.to_luma32f().into_raw();
    if values.iter().any(|v| !v.is_finite()) {
        return Err(fail("the image holds NaN or infinite values".to_owned()));
    }
    Ok(Grey {
        width,
        height,
        values,
    })
}

/// The lenslet lattice found in a frame: centre `origin + n1·a1 + n2·a2` for whole n1, n2.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct LensletGrid {
    /// First lattice vector (along the sensor's x), pixels.
    pub a1: [f64; 2],
    /// Second lattice vector (along the sensor's y), pixels.
    pub a2: [f64; 2],
    /// One lenslet centre, pixels (pixel centres at whole numbers).
    pub origin: [f64; 2],
    /// Amplitude of each fundamental frequency over the frame's mean (1 for a pure cosine of
    /// full modulation; below [`MIN_CONTRAST`] no grid is accepted).
    pub contrast: [f64; 2],
}

impl LensletGrid {
    /// Pitch along each lattice vector, pixels.
    pub fn pitch(&self) -> [f64; 2] {
        [self.a1[0].hypot(self.a1[1]), self.a2[0].hypot(self.a2[1])]
    }

    /// Rotation of the lattice from the sensor's axes, degrees (of the first vector).
    pub fn rotation_deg(&self) -> f64 {
        self.a1[1].atan2(self.a1[0]).to_degrees()
    }

    /// Centre of lenslet (n1, n2).
    pub fn center(&self, n1: f64, n2: f64) -> [f64; 2] {
        [
            self.origin[0] + n1 * self.a1[0] + n2 * self.a2[0],
            self.origin[1] + n1 * self.a1[1] + n2 * self.a2[1],
        ]
    }
}

/// Σ v(x, y)·e^{−2πi(kx·x + ky·y)} for each ky of `kys`, at one kx (row sums shared).
fn dft_row(g: &Grey, kx: f64, kys: &[f64]) -> Vec<(f64, f64)> {
    let (w, h) = (g.width as usize, g.height as usize);
    let (cx, sx): (Vec<f64>, Vec<f64>) = (0..w)
        .map(|x| {
            let a = -2.0 * std::f64::consts::PI * kx * x as f64;
            (a.cos(), a.sin())
        })
        .unzip();
    let rows: Vec<(f64, f64)> = (0..h)
        .map(|y| {
            let row = &g.values[y * w..(y + 1) * w];
            row.iter()
                .enumerate()
                .fold((0.0, 0.0), |(re, im), (x, &v)| {
                    (re + f64::from(v) * cx[x], im + f64::from(v) * sx[x])
                })
        })
        .collect();
    kys.iter()
        .map(|&ky| {
            rows.iter()
                .enumerate()
                .fold((0.0, 0.0), |(re, im), (y, &(rr, ri))| {
                    let a = -2.0 * std::f64::consts::PI * ky * y as f64;
                    let (c, s) = (a.cos(), a.sin());
                    (re + rr * c - ri * s, im + rr * s + ri * c)
                })
        })
        .collect()
}

/// The frequency vector near `k0` (cycles per pixel; `along_x` says which component is the
/// large one) with the largest DFT magnitude, searched within ±5 % in length and ±3° in
/// direction, then refined; with its complex DFT value.
fn peak(g: &Grey, k0: f64, along_x: bool) -> ([f64; 2], (f64, f64)) {
    let n = f64::from(g.width.max(g.height));
    let to_k = |major: f64, minor: f64| {
        if along_x {
            [major, minor]
        } else {
            [minor, major]
        }
    };
    // Evaluate a grid of (major, minor) values, sharing row sums per kx.
    let eval = |majors: &[f64], minors: &[f64]| -> Vec<([f64; 2], (f64, f64))> {
        let mut out = Vec::new();
        if along_x {
            for &kx in majors {
                for (ky, f) in minors.iter().zip(dft_row(g, kx, minors)) {
                    out.push(([kx, *ky], f));
                }
            }
        } else {
            for &kx in minors {
                for (ky, f) in majors.iter().zip(dft_row(g, kx, majors)) {
                    out.push(([kx, *ky], f));
                }
            }
        }
        out
    };
    let span = |c: f64, half: f64, step: f64| -> Vec<f64> {
        let k = (half / step).ceil() as i64;
        (-k..=k).map(|i| c + i as f64 * step).collect()
    };
    let mut step = 1.0 / (4.0 * n);
    let majors = span(k0, 0.05 * k0, step);
    let minors = span(0.0, (3.0f64).to_radians().tan() * k0, step);
    let magnitude = |f: (f64, f64)| f.0.hypot(f.1);
    let mut best = eval(&majors, &minors)
        .into_iter()
        .max_by(|a, b| magnitude(a.1).total_cmp(&magnitude(b.1)))
        .unwrap_or((to_k(k0, 0.0), (0.0, 0.0)));
    for _ in 0..3 {
        let (major, minor) = if along_x {
            (best.0[0], best.0[1])
        } else {
            (best.0[1], best.0[0])
        };
        let fine = step / 4.0;
        let candidates = eval(&span(major, step, fine), &span(minor, step, fine));
        if let Some(b) = candidates
            .into_iter()
            .max_by(|a, b| magnitude(a.1).total_cmp(&magnitude(b.1)))
            && magnitude(b.1) >= magnitude(best.1)
        {
            best = b;
        }
        step = fine;
    }
    best
}

/// Finds the lenslet lattice of `frame` (dark frame already subtracted) near the nominal
/// pitch `pitch_px` (see the module doc).
///
/// # Errors
/// [`LensletError::Grid`] when either fundamental is weaker than [`MIN_CONTRAST`].
pub fn find_grid(frame: &Grey, pitch_px: f64) -> Result<LensletGrid> {
    let (w, h) = (frame.width as usize, frame.height as usize);
    let total: f64 = frame.values.iter().map(|&v| f64::from(v)).sum::<f64>();
    if !(total > 0.0) {
        return Err(LensletError::Grid(
            "the radiometry frame is dark (nothing above the dark frame): no lenslet grid"
                .to_owned(),
        ));
    }
    // The mean removed and a Hann window applied: no leakage of the mean or of the frame's
    // edges into the lattice's frequencies (which would bias the pitch and fake a grid).
    let mean = (total / (w * h) as f64) as f32;
    let hann = |i: usize, n: usize| {
        let x = (i as f64 + 0.5) / n as f64;
        (0.5 - 0.5 * (std::f64::consts::TAU * x).cos()) as f32
    };
    let wx: Vec<f32> = (0..w).map(|x| hann(x, w)).collect();
    let wy: Vec<f32> = (0..h).map(|y| hann(y, h)).collect();
    let mut windowed = frame.clone();
    let mut weight = 0.0f64;
    for (i, v) in windowed.values.iter_mut().enumerate() {
        let win = wx[i % w] * wy[i / w];
        weight += f64::from(win * *v);
        *v = (*v - mean) * win;
    }
    let k0 = 1.0 / pitch_px;
    let (k1, f1) = peak(&windowed, k0, true);
    let (k2, f2) = peak(&windowed, k0, false);
    // The DFT of A·cos(2πk·x − φ)·window is ≈ A/2·Σwindow·e^{−iφ}: amplitude over the mean.
    let contrast = [f1, f2].map(|f| 2.0 * f.0.hypot(f.1) / weight.max(f64::MIN_POSITIVE));
    // A true lattice peaks inside the searched band; leakage from elsewhere rises to its edge.
    let pitch_of = |k: [f64; 2]| 1.0 / k[0].hypot(k[1]);
    let inside = |k: [f64; 2]| (pitch_of(k) / pitch_px - 1.0).abs() < 0.045;
    if contrast.iter().any(|&c| c < MIN_CONTRAST) || !inside(k1) || !inside(k2) {
        return Err(LensletError::Grid(format!(
            "no lenslet grid near a pitch of {pitch_px:.2} px in the radiometry frame (lattice \
             contrast {:.4} and {:.4} at pitches {:.2} and {:.2} px; a grid has contrast above \
             {MIN_CONTRAST} within 4.5 % of the nominal pitch): check pitch_um and pixel_size_um",
            contrast[0],
            contrast[1],
            pitch_of(k1),
            pitch_of(k2)
        )));
    }
    // Real-space vectors: the inverse of the frequency matrix [k1; k2].
    let det = k1[0] * k2[1] - k1[1] * k2[0];
    if det.abs() < 1e-12 {
        return Err(LensletError::Grid(
            "the lattice's two frequencies are parallel".to_owned(),
        ));
    }
    let a1 = [k2[1] / det, -k2[0] / det];
    let a2 = [-k1[1] / det, k1[0] / det];
    // Maxima where k·x = φ / 2π (mod 1), φ = −arg F.
    let p1 = -f1.1.atan2(f1.0) / std::f64::consts::TAU;
    let p2 = -f2.1.atan2(f2.0) / std::f64::consts::TAU;
    let origin = [p1 * a1[0] + p2 * a2[0], p1 * a1[1] + p2 * a2[1]];
    Ok(LensletGrid {
        a1,
        a2,
        origin,
        contrast,
    })
}

/// What [`import_lenslet`] made.
#[derive(Clone, Debug, Serialize)]
pub struct LensletReport {
    /// The lattice found.
    pub grid: LensletGrid,
    /// Lenslets imported per row and rows: the st resolution.
    pub lenslets: [u32; 2],
    /// Centre of the lenslet of st texel (0, 0) (the top left), sensor pixels.
    pub first_lenslet: [f64; 2],
    /// Views per axis: the uv grid is views × views.
    pub views: u32,
    /// The planes written.
    pub planes: TwoPlanes,
    /// Devignetted value stored as 255.
    pub scale: f32,
    /// Fraction of samples inside the pupil (the others are empty).
    pub valid_fraction: f64,
}

/// Imports the lenslet image of `source` (a folder with a calibration, or the raw image inside
/// one; [`read_calibration`]) as a two-plane light field into `output`, atomically.
///
/// # Errors
/// [`LensletError`] naming the file, the calibration value or the grid problem.
pub fn import_lenslet(
    source: &Path,
    output: &Path,
    progress: &mut dyn FnMut(u32, u32),
) -> Result<LensletReport> {
    let calibration = read_calibration(source)?;
    let mut raw = read_grey(&calibration.image)?;
    let mut radiometry = read_grey(&calibration.radiometry)?;
    let size = [raw.width, raw.height];
    let same_size = |g: &Grey, path: &Path| -> Result<()> {
        if [g.width, g.height] == size {
            Ok(())
        } else {
            Err(LensletError::Image {
                path: path.to_path_buf(),
                message: format!(
                    "{} x {} px; the lenslet image {} is {} x {}",
                    g.width,
                    g.height,
                    calibration.image.display(),
                    size[0],
                    size[1]
                ),
            })
        }
    };
    same_size(&radiometry, &calibration.radiometry)?;
    if let Some(dark_path) = &calibration.dark {
        let dark = read_grey(dark_path)?;
        same_size(&dark, dark_path)?;
        for (v, d) in raw.values.iter_mut().zip(&dark.values) {
            *v = (*v - d).max(0.0);
        }
        for (v, d) in radiometry.values.iter_mut().zip(&dark.values) {
            *v = (*v - d).max(0.0);
        }
    }
    let pitch_px = calibration.pitch_px();
    let grid = find_grid(&radiometry, pitch_px)?;

    // Lenslets whose whole cell lies on the sensor: the lattice coordinates of the sensor's
    // corners, moved in by half a cell, bound a rectangle of whole (n1, n2).
    let [p1, p2] = grid.pitch();
    // Whole pixels per cell (a pitch found 0.05 px short of a whole number counts as it).
    let views = ((p1.min(p2) + 0.05).floor() as u32).clamp(1, MAX_VIEWS);
    let margin = 0.5 * (p1 + p2) * std::f64::consts::SQRT_2 / 2.0 + 1.0;
    let (w, h) = (f64::from(raw.width) - 1.0, f64::from(raw.height) - 1.0);
    let det = grid.a1[0] * grid.a2[1] - grid.a1[1] * grid.a2[0];
    let lattice = |x: f64, y: f64| {
        let (dx, dy) = (x - grid.origin[0], y - grid.origin[1]);
        [
            (dx * grid.a2[1] - dy * grid.a2[0]) / det,
            (grid.a1[0] * dy - grid.a1[1] * dx) / det,
        ]
    };
    let corners = [
        lattice(margin, margin),
        lattice(w - margin, margin),
        lattice(margin, h - margin),
        lattice(w - margin, h - margin),
    ];
    let n1_lo = corners[0][0].max(corners[2][0]).ceil() as i64;
    let n1_hi = corners[1][0].min(corners[3][0]).floor() as i64;
    let n2_lo = corners[0][1].max(corners[1][1]).ceil() as i64;
    let n2_hi = corners[2][1].min(corners[3][1]).floor() as i64;
    if n1_hi < n1_lo || n2_hi < n2_lo {
        return Err(LensletError::Grid(format!(
            "the {} x {} px image holds no whole lenslet of pitch {p1:.2} x {p2:.2} px",
            raw.width, raw.height
        )));
    }
    let ns = u32::try_from(n1_hi - n1_lo + 1).unwrap_or(u32::MAX);
    let nt = u32::try_from(n2_hi - n2_lo + 1).unwrap_or(u32::MAX);
    if ns > crate::two_plane::MAX_ST_RESOLUTION || nt > crate::two_plane::MAX_ST_RESOLUTION {
        return Err(LensletError::Grid(format!(
            "{ns} x {nt} lenslets: at most {} a side",
            crate::two_plane::MAX_ST_RESOLUTION
        )));
    }

    // Devignetted samples of every view, then one scale for all.
    let mut reference = radiometry.values.clone();
    reference.sort_unstable_by(f32::total_cmp);
    let r99 = reference[(reference.len() - 1) * 99 / 100];
    drop(reference);
    let threshold = MIN_RADIOMETRY * r99;
    let n = views as usize;
    let texels = ns as usize * nt as usize;
    let mut samples = vec![f32::NAN; n * n * texels];
    for b in 0..n {
        for a in 0..n {
            let du = (a as f64 + 0.5) / n as f64 - 0.5;
            let dv = (b as f64 + 0.5) / n as f64 - 0.5;
            let view = &mut samples[(b * n + a) * texels..(b * n + a + 1) * texels];
            for (t, row) in view.chunks_exact_mut(ns as usize).enumerate() {
                for (s, out) in row.iter_mut().enumerate() {
                    let [x, y] = grid.center(
                        (n1_lo + s as i64) as f64 + du,
                        (n2_lo + t as i64) as f64 + dv,
                    );
                    let r = radiometry.at(x, y);
                    if r >= threshold && r > 0.0 {
                        *out = raw.at(x, y) / r;
                    }
                }
            }
        }
    }
    let mut valid: Vec<f32> = samples.iter().copied().filter(|v| v.is_finite()).collect();
    if valid.is_empty() {
        return Err(LensletError::Grid(
            "no sample lies inside the pupil (the radiometry frame is dark everywhere)".to_owned(),
        ));
    }
    let valid_fraction = valid.len() as f64 / samples.len() as f64;
    valid.sort_unstable_by(f32::total_cmp);
    let scale = valid[(valid.len() - 1) * 995 / 1000].max(f32::MIN_POSITIVE);
    drop(valid);

    // Object space, micrometres (module doc).
    let texel = calibration.pitch_um / calibration.magnification;
    let st_size = [f64::from(ns) * texel, f64::from(nt) * texel];
    let distance = UV_DISTANCE_ST_WIDTHS * st_size[0].max(st_size[1]);
    let uv_width = 2.0 * distance * calibration.na / calibration.medium_index;
    let planes = TwoPlanes {
        right: [1.0, 0.0, 0.0],
        up: [0.0, 1.0, 0.0],
        uv: UvPlane {
            center: [0.0, 0.0, distance],
            size: [uv_width, uv_width],
            grid: [views, views],
        },
        st: StPlane {
            center: [0.0; 3],
            size: st_size,
            resolution: [ns, nt],
        },
    };
    let provenance = crate::two_plane_io::import_provenance(
        &calibration.image,
        serde_json::json!({
            "layout": "lenslet",
            "depth": false,
            "grid": grid,
            "scale": scale,
            "calibration": calibration,
        }),
    );
    let header = AssetHeader::new_two_plane(planes, crate::asset::DEFAULT_PAGE_SIZE, provenance)?;
    let mut writer = AssetWriter::create(output, header)?;
    let unit_depth = crate::two_plane_io::unit_depth(texels);
    let total = views * views;
    for camera in 0..n * n {
        let view = &samples[camera * texels..(camera + 1) * texels];
        let rgba: Vec<u8> = view
            .iter()
            .flat_map(|&v| {
                if v.is_finite() {
                    let code = (255.0 * (v / scale).clamp(0.0, 1.0)).round() as u8;
                    [code, code, code, 255]
                } else {
                    [0; 4]
                }
            })
            .collect();
        let id = camera as u32;
        writer.add_image(ImageKey::new(0, 0, id, Channel::Color), &rgba)?;
        writer.add_image(ImageKey::new(0, 0, id, Channel::Depth), &unit_depth)?;
        progress(id + 1, total);
    }
    writer.finish()?;
    Ok(LensletReport {
        grid,
        lenslets: [ns, nt],
        first_lenslet: grid.center(n1_lo as f64, n2_lo as f64),
        views,
        planes,
        scale,
        valid_fraction,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A synthetic radiometry frame: a lattice of bright discs (radius 0.42 pitch) with a soft
    /// edge, on a dim floor.
    fn discs(w: u32, h: u32, grid: &LensletGrid) -> Grey {
        let det = grid.a1[0] * grid.a2[1] - grid.a1[1] * grid.a2[0];
        let pitch = grid.pitch()[0];
        let mut values = Vec::with_capacity((w * h) as usize);
        for y in 0..h {
            for x in 0..w {
                let (dx, dy) = (f64::from(x) - grid.origin[0], f64::from(y) - grid.origin[1]);
                let n1 = (dx * grid.a2[1] - dy * grid.a2[0]) / det;
                let n2 = (grid.a1[0] * dy - grid.a1[1] * dx) / det;
                let [cx, cy] = grid.center(n1.round(), n2.round());
                let r = (f64::from(x) - cx).hypot(f64::from(y) - cy) / pitch;
                values.push((0.05 + 0.9 * (1.0 - ((r - 0.42) / 0.04).clamp(0.0, 1.0))) as f32);
            }
        }
        Grey {
            width: w,
            height: h,
            values,
        }
    }

    /// The lattice of a synthetic frame is found to 0.005 px in pitch and 0.05 px in the
    /// centres across the frame (pitch 11.3 px rotated 0.7°, an off-grid origin): a lenslet
    /// centre 20 pitches from the origin lands within 0.2 px.
    #[test]
    fn the_lattice_of_a_synthetic_frame_is_found() {
        let angle = 0.7f64.to_radians();
        let p = 11.3;
        let truth = LensletGrid {
            a1: [p * angle.cos(), p * angle.sin()],
            a2: [-p * angle.sin(), p * angle.cos()],
            origin: [5.3, 7.9],
            contrast: [0.0; 2],
        };
        let frame = discs(256, 240, &truth);
        let found = find_grid(&frame, 11.0).expect("grid");
        for (got, want) in found.pitch().iter().zip(truth.pitch()) {
            assert!((got - want).abs() < 0.005, "pitch {got} against {want}");
        }
        assert!(
            (found.rotation_deg() - 0.7).abs() < 0.02,
            "{}",
            found.rotation_deg()
        );
        // The found origin is some lenslet centre: compare the nearest true centre.
        for (n1, n2) in [(0.0, 0.0), (20.0, 0.0), (0.0, 20.0), (20.0, 20.0)] {
            let [x, y] = found.center(n1, n2);
            let det = truth.a1[0] * truth.a2[1] - truth.a1[1] * truth.a2[0];
            let (dx, dy) = (x - truth.origin[0], y - truth.origin[1]);
            let m1 = ((dx * truth.a2[1] - dy * truth.a2[0]) / det).round();
            let m2 = ((truth.a1[0] * dy - truth.a1[1] * dx) / det).round();
            let [tx, ty] = truth.center(m1, m2);
            let off = (x - tx).hypot(y - ty);
            assert!(off < 0.2, "lenslet ({n1}, {n2}) off by {off} px");
        }
        assert!(
            found.contrast.iter().all(|&c| c > 0.2),
            "{:?}",
            found.contrast
        );
    }

    #[test]
    fn a_flat_or_dark_frame_has_no_grid() {
        let flat = Grey {
            width: 64,
            height: 64,
            values: vec![0.5; 64 * 64],
        };
        let err = find_grid(&flat, 8.0).expect_err("flat");
        assert!(err.to_string().contains("no lenslet grid"), "{err}");
        let dark = Grey {
            values: vec![0.0; 64 * 64],
            ..flat
        };
        assert!(
            find_grid(&dark, 8.0)
                .expect_err("dark")
                .to_string()
                .contains("dark")
        );
    }
}
