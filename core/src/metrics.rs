//! Image and depth quality metrics (DESIGN §3): the one implementation behind the CLI, the service
//! and the Python bindings.
//!
//! Colour metrics take RGBA8 buffers (row-major, top row first, as in [`Frame`]) and compare only
//! R, G and B; alpha is ignored. They reproduce scikit-image 0.26 exactly:
//! - [`psnr`] = `skimage.metrics.peak_signal_noise_ratio(a_rgb, b_rgb, data_range=255)`, optionally
//!   restricted to a pixel mask (`a_rgb[mask]`, `b_rgb[mask]`);
//! - [`ssim`] = `skimage.metrics.structural_similarity(a_rgb, b_rgb, channel_axis=-1,
//!   data_range=255)` with every other argument at its default;
//! - [`mae`] = `np.mean(np.abs(a_rgb.astype(float) - b_rgb))`.
//!
//! [`compare`] bundles them for a test frame against a reference frame, together with the coverage
//! masks (union, intersection, mismatch count), [`depth_errors`] over the intersection of the
//! masks and [`wrong_surface_px`], the pixels whose depth puts them on another surface. [`mean_comparison`] averages per-view comparisons into per-scene numbers.
//!
//! Non-finite numbers (a PSNR of `+inf`, depth statistics of `NaN` when nothing overlaps) are part
//! of the results. JSON has no literal for them, so the serde representation writes them as the
//! strings `"Infinity"`, `"-Infinity"` and `"NaN"` (which both Python's `float()` and JavaScript's
//! `Number()` parse) and reads those strings, numbers or `null` (as `NaN`) back.

use serde::{Deserialize, Serialize};

use crate::frame::Frame;

/// Side of scikit-image's default (uniform) SSIM window; images must be at least this large.
pub const SSIM_WIN_SIZE: usize = 7;

/// Cap applied to each per-view PSNR before [`mean_comparison`] averages it, so that a view
/// reproduced exactly (`+inf`) still gives a finite mean. 100 dB is an MSE of 6.5e-6, far below
/// one 8-bit step on any frame size we render; nothing of interest is lost by the cap.
pub const PSNR_CAP_DB: f64 = 100.0;

/// A pixel covered in both frames is on a wrong surface when its z-depth differs from the
/// reference's by more than this fraction of the reference z-depth ([`wrong_surface_px`]).
pub const WRONG_SURFACE_FRACTION: f64 = 0.01;

/// Peak value of 8-bit colour, scikit-image's `data_range`.
const DATA_RANGE: f64 = 255.0;
/// scikit-image's SSIM constants (Wang et al. 2004).
const SSIM_K1: f64 = 0.01;
const SSIM_K2: f64 = 0.03;

/// Why a metric could not be computed.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum MetricsError {
    /// The two frames have different dimensions.
    #[error(
        "frame sizes differ: test is {test_width}x{test_height}, \
         reference is {reference_width}x{reference_height}"
    )]
    SizeMismatch {
        /// Width of the test frame.
        test_width: u32,
        /// Height of the test frame.
        test_height: u32,
        /// Width of the reference frame.
        reference_width: u32,
        /// Height of the reference frame.
        reference_height: u32,
    },
    /// A buffer's length does not match the image size times its values per pixel.
    #[error("{buffer} holds {actual} values, expected {expected}")]
    BufferLength {
        /// Which buffer (e.g. "test colour", "mask").
        buffer: &'static str,
        /// Values expected from width, height and values per pixel.
        expected: usize,
        /// Values present.
        actual: usize,
    },
    /// SSIM needs at least a 7×7 image; scikit-image raises `ValueError` here too.
    #[error("{width}x{height} is smaller than the 7x7 SSIM window")]
    TooSmallForSsim {
        /// Image width.
        width: u32,
        /// Image height.
        height: u32,
    },
}

/// Statistics of the absolute depth error (world units) over the pixels both frames cover.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DepthErrorStats {
    /// Pixels where both depths are finite.
    pub count: u64,
    /// Median (`np.median`: mean of the two middle values for an even count); NaN when empty.
    #[serde(with = "nonfinite_f64")]
    pub median: f64,
    /// Mean; NaN when empty.
    #[serde(with = "nonfinite_f64")]
    pub mean: f64,
    /// Maximum; NaN when empty.
    #[serde(with = "nonfinite_f64")]
    pub max: f64,
    /// 95th percentile (`np.percentile(e, 95)`, linear interpolation); NaN when empty.
    #[serde(with = "nonfinite_f64")]
    pub p95: f64,
}

/// A test frame measured against a reference frame of the same view (DESIGN §3).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Comparison {
    /// PSNR (dB) over the full frame; `+inf` when the colours are identical.
    #[serde(with = "nonfinite_f64")]
    pub psnr: f64,
    /// PSNR (dB) over the union of both coverage masks: the harsher number, used for all targets.
    #[serde(with = "nonfinite_f64")]
    pub masked_psnr: f64,
    /// PSNR (dB) over the intersection of both coverage masks (interior quality).
    #[serde(with = "nonfinite_f64")]
    pub intersection_psnr: f64,
    /// Mean SSIM over the full frame, as scikit-image computes it.
    pub ssim: f64,
    /// Mean absolute difference per RGB component over the full frame, in 8-bit steps.
    pub mae: f64,
    /// Pixels covered in exactly one of the two frames.
    pub mask_mismatch_px: u64,
    /// Pixels covered in at least one frame.
    pub union_px: u64,
    /// Pixels covered in both frames.
    pub intersection_px: u64,
    /// Depth error over the intersection of the coverage masks.
    pub depth: DepthErrorStats,
    /// Pixels covered in both frames whose z-depth is off by more than
    /// [`WRONG_SURFACE_FRACTION`] of the reference's: another surface than the true one.
    #[serde(default)]
    pub wrong_surface_px: u64,
}

/// Per-scene numbers: the average of per-view [`Comparison`]s (see [`mean_comparison`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MeanComparison {
    /// Number of views averaged.
    pub views: u64,
    /// Mean full-frame PSNR (dB), each view capped at [`PSNR_CAP_DB`].
    #[serde(with = "nonfinite_f64")]
    pub psnr: f64,
    /// Mean masked PSNR (dB), capped, over views with a non-empty union; NaN if there is none.
    #[serde(with = "nonfinite_f64")]
    pub masked_psnr: f64,
    /// Mean intersection PSNR (dB), capped, over views with a non-empty intersection; NaN if
    /// there is none.
    #[serde(with = "nonfinite_f64")]
    pub intersection_psnr: f64,
    /// Mean SSIM.
    #[serde(with = "nonfinite_f64")]
    pub ssim: f64,
    /// Mean MAE.
    #[serde(with = "nonfinite_f64")]
    pub mae: f64,
    /// Mean count of pixels covered in exactly one frame.
    #[serde(with = "nonfinite_f64")]
    pub mask_mismatch_px: f64,
    /// Mean count of pixels in the union of the masks.
    #[serde(with = "nonfinite_f64")]
    pub union_px: f64,
    /// Mean count of pixels in the intersection of the masks.
    #[serde(with = "nonfinite_f64")]
    pub intersection_px: f64,
    /// Mean depth-error statistics.
    pub depth: MeanDepthErrors,
    /// Mean count of wrong-surface pixels.
    #[serde(default, with = "nonfinite_f64")]
    pub wrong_surface_px: f64,
}

/// Depth-error statistics averaged over views.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MeanDepthErrors {
    /// Views whose masks intersect (the others have no depth error to average).
    pub views: u64,
    /// Mean pixel count over all views.
    #[serde(with = "nonfinite_f64")]
    pub count: f64,
    /// Mean of the per-view medians over views that have any; NaN if none.
    #[serde(with = "nonfinite_f64")]
    pub median: f64,
    /// Mean of the per-view means over views that have any; NaN if none.
    #[serde(with = "nonfinite_f64")]
    pub mean: f64,
    /// Mean of the per-view maxima over views that have any; NaN if none.
    #[serde(with = "nonfinite_f64")]
    pub max: f64,
    /// Mean of the per-view 95th percentiles over views that have any; NaN if none.
    #[serde(with = "nonfinite_f64")]
    pub p95: f64,
}

/// Checks that `buffer` holds `width * height * per_pixel` values.
fn check_len(
    buffer: &'static str,
    actual: usize,
    width: u32,
    height: u32,
    per_pixel: usize,
) -> Result<usize, MetricsError> {
    let pixels = (width as usize).checked_mul(height as usize);
    let expected = pixels.and_then(|p| p.checked_mul(per_pixel));
    match expected {
        Some(expected) if expected == actual => Ok(pixels.unwrap_or(0)),
        _ => Err(MetricsError::BufferLength {
            buffer,
            expected: expected.unwrap_or(usize::MAX),
            actual,
        }),
    }
}

/// Checks both RGBA8 buffers against the image size; returns the pixel count.
fn check_rgba_pair(a: &[u8], b: &[u8], width: u32, height: u32) -> Result<usize, MetricsError> {
    check_len("first image", a.len(), width, height, 4)?;
    check_len("second image", b.len(), width, height, 4)
}

/// Sum of squared RGB differences of one pixel; exact in integers.
fn pixel_sse(a: &[u8], b: &[u8]) -> u64 {
    a[..3]
        .iter()
        .zip(&b[..3])
        .map(|(&x, &y)| {
            let d = u64::from(x.abs_diff(y));
            d * d
        })
        .sum()
}

/// PSNR from an exact sum of squared errors over `components` values. Bit-identical to
/// scikit-image, whose float64 sum of squared integer differences is exact as well.
fn psnr_from_sse(sse: u64, components: u64) -> f64 {
    if sse == 0 {
        // Identical (or nothing to compare): scikit-image divides by zero and returns +inf.
        return f64::INFINITY;
    }
    let mse = sse as f64 / components as f64;
    10.0 * ((DATA_RANGE * DATA_RANGE) / mse).log10()
}

/// Peak signal-to-noise ratio (dB) of two RGBA8 images on R, G, B with data range 255, over the
/// pixels where `mask` is true (all pixels when `None`).
///
/// `+inf` when the images agree on every compared component, as scikit-image returns; an empty
/// mask also gives `+inf` (nothing differs), where scikit-image would give NaN with a warning.
pub fn psnr(
    a: &[u8],
    b: &[u8],
    width: u32,
    height: u32,
    mask: Option<&[bool]>,
) -> Result<f64, MetricsError> {
    check_rgba_pair(a, b, width, height)?;
    let pixels = a.chunks_exact(4).zip(b.chunks_exact(4));
    let (sse, count) = match mask {
        None => (pixels.map(|(pa, pb)| pixel_sse(pa, pb)).sum(), a.len() / 4),
        Some(mask) => {
            check_len("mask", mask.len(), width, height, 1)?;
            pixels
                .zip(mask)
                .filter(|&(_, &m)| m)
                .fold((0_u64, 0_usize), |(sse, n), ((pa, pb), _)| {
                    (sse + pixel_sse(pa, pb), n + 1)
                })
        }
    };
    Ok(psnr_from_sse(sse, 3 * count as u64))
}

/// Mean absolute difference per RGB component over the full frame, in 8-bit steps (NaN for an
/// image without pixels).
pub fn mae(a: &[u8], b: &[u8], width: u32, height: u32) -> Result<f64, MetricsError> {
    let pixels = check_rgba_pair(a, b, width, height)?;
    if pixels == 0 {
        return Ok(f64::NAN);
    }
    let sum: u64 = a
        .chunks_exact(4)
        .zip(b.chunks_exact(4))
        .map(|(pa, pb)| {
            pa[..3]
                .iter()
                .zip(&pb[..3])
                .map(|(&x, &y)| u64::from(x.abs_diff(y)))
                .sum::<u64>()
        })
        .sum();
    Ok(sum as f64 / (3 * pixels) as f64)
}

/// Mean structural similarity of two RGBA8 images on R, G, B: exactly scikit-image's
/// `structural_similarity(a_rgb, b_rgb, channel_axis=-1, data_range=255)`.
///
/// That is, per channel: 7×7 uniform windows, sample covariances (normalised by 48, not 49),
/// `K1 = 0.01`, `K2 = 0.03`, the SSIM map averaged over the pixels at least 3 px from every border
/// (scikit-image crops the border that its reflecting filter invents, so only windows that lie
/// wholly inside the image count); then the mean of the three channels. Window statistics are
/// exact integer running sums, so the only rounding is in the per-window quotient and the mean:
/// the result agrees with scikit-image (which rounds inside its float filters) to ~1e-13.
/// A 512×512 frame takes about 4 ms on one core.
pub fn ssim(a: &[u8], b: &[u8], width: u32, height: u32) -> Result<f64, MetricsError> {
    check_rgba_pair(a, b, width, height)?;
    if (width as usize) < SSIM_WIN_SIZE || (height as usize) < SSIM_WIN_SIZE {
        return Err(MetricsError::TooSmallForSsim { width, height });
    }
    let w = width as usize;
    let h = height as usize;
    let channels = [0, 1, 2].map(|c| ssim_channel(a, b, w, h, c));
    Ok((channels[0] + channels[1] + channels[2]) / 3.0)
}

/// Per-column sums of one channel over the current 7 rows: x, y, x², y², x·y. They stay below
/// 7 · 255² (window sums below 49 · 255² < 2^22), so u32 never overflows, and only a row that
/// was added before is removed, so it never underflows.
struct ColumnSums {
    x: Vec<u32>,
    y: Vec<u32>,
    xx: Vec<u32>,
    yy: Vec<u32>,
    xy: Vec<u32>,
}

impl ColumnSums {
    fn new(w: usize) -> Self {
        Self {
            x: vec![0; w],
            y: vec![0; w],
            xx: vec![0; w],
            yy: vec![0; w],
            xy: vec![0; w],
        }
    }

    /// Adds one image row (RGBA8 pixels of `a` and `b`, channel `c`) and, if given, removes
    /// the row that leaves the window.
    fn slide(&mut self, c: usize, add: (&[u8], &[u8]), remove: Option<(&[u8], &[u8])>) {
        let value = |row: &[u8], j: usize| u32::from(row[4 * j + c]);
        for j in 0..self.x.len() {
            let (x, y) = (value(add.0, j), value(add.1, j));
            self.x[j] += x;
            self.y[j] += y;
            self.xx[j] += x * x;
            self.yy[j] += y * y;
            self.xy[j] += x * y;
            if let Some((ra, rb)) = remove {
                let (x, y) = (value(ra, j), value(rb, j));
                self.x[j] -= x;
                self.y[j] -= y;
                self.xx[j] -= x * x;
                self.yy[j] -= y * y;
                self.xy[j] -= x * y;
            }
        }
    }

    /// Column `j`'s sums, widened for the window arithmetic.
    fn at(&self, j: usize) -> [i64; 5] {
        [self.x[j], self.y[j], self.xx[j], self.yy[j], self.xy[j]].map(i64::from)
    }
}

/// Mean SSIM of channel `c` over the windows that lie wholly inside the image (`w, h >= 7`).
fn ssim_channel(a: &[u8], b: &[u8], w: usize, h: usize, c: usize) -> f64 {
    const WIN: usize = SSIM_WIN_SIZE;
    // scikit-image's per-window formula in terms of window means u = s/NP and sample
    // (co)variances v = NP/(NP-1) · (E[xy] - E[x]E[y]),
    //   S = (2 ux uy + C1)(2 vxy + C2) / ((ux² + uy² + C1)(vx + vy + C2)),
    // is evaluated with both factors scaled to integer sums: multiplying the luminance terms by
    // NP² and the contrast terms by NP·(NP-1) leaves S unchanged and turns the window statistics
    // into exact integers (all below 2^53), so one division per window remains.
    let np = (WIN * WIN) as i64;
    let c1 = (SSIM_K1 * DATA_RANGE) * (SSIM_K1 * DATA_RANGE) * (np * np) as f64;
    let c2 = (SSIM_K2 * DATA_RANGE) * (SSIM_K2 * DATA_RANGE) * (np * (np - 1)) as f64;
    let row_len = 4 * w;

    // Vertical sums per column, slid down the image; horizontal window sums slid along a row.
    let mut columns = ColumnSums::new(w);
    let mut total = 0.0_f64;
    for i in 0..h {
        let row = |k: usize| (&a[row_len * k..][..row_len], &b[row_len * k..][..row_len]);
        columns.slide(c, row(i), (i >= WIN).then(|| row(i - WIN)));
        if i + 1 < WIN {
            continue;
        }
        let mut window = [0_i64; 5];
        for j in 0..WIN - 1 {
            let col = columns.at(j);
            for k in 0..5 {
                window[k] += col[k];
            }
        }
        let mut row_total = 0.0_f64;
        for j in 0..w - (WIN - 1) {
            let entering = columns.at(j + WIN - 1);
            for k in 0..5 {
                window[k] += entering[k];
            }
            let [sx, sy, sxx, syy, sxy] = window;
            // NP² ux uy, NP² (ux² + uy²), NP(NP-1) vx etc., all exact.
            let luminance_xy = (sx * sy) as f64;
            let luminance_sq = (sx * sx + sy * sy) as f64;
            let cov_x = (np * sxx - sx * sx) as f64;
            let cov_y = (np * syy - sy * sy) as f64;
            let cov_xy = (np * sxy - sx * sy) as f64;
            let numerator = (2.0 * luminance_xy + c1) * (2.0 * cov_xy + c2);
            let denominator = (luminance_sq + c1) * (cov_x + cov_y + c2);
            row_total += numerator / denominator;
            let leaving = columns.at(j);
            for k in 0..5 {
                window[k] -= leaving[k];
            }
        }
        total += row_total;
    }
    let windows = (w - (WIN - 1)) * (h - (WIN - 1));
    total / windows as f64
}

/// Absolute depth error over the pixels where both depths are finite (the intersection of the
/// coverage masks), computed in f64 from the f32 depths.
pub fn depth_errors(test: &[f32], reference: &[f32]) -> Result<DepthErrorStats, MetricsError> {
    if test.len() != reference.len() {
        return Err(MetricsError::BufferLength {
            buffer: "reference depth",
            expected: test.len(),
            actual: reference.len(),
        });
    }
    let mut errors: Vec<f64> = test
        .iter()
        .zip(reference)
        .filter(|(t, r)| t.is_finite() && r.is_finite())
        .map(|(&t, &r)| (f64::from(t) - f64::from(r)).abs())
        .collect();
    Ok(error_stats(&mut errors))
}

/// Pixels where both depths are finite and the test depth differs from the reference depth by
/// more than [`WRONG_SURFACE_FRACTION`] of the reference depth (computed in f64).
pub fn wrong_surface_px(test: &[f32], reference: &[f32]) -> Result<u64, MetricsError> {
    if test.len() != reference.len() {
        return Err(MetricsError::BufferLength {
            buffer: "reference depth",
            expected: test.len(),
            actual: reference.len(),
        });
    }
    let wrong = test
        .iter()
        .zip(reference)
        .filter(|(t, r)| t.is_finite() && r.is_finite())
        .filter(|&(&t, &r)| {
            (f64::from(t) - f64::from(r)).abs() > WRONG_SURFACE_FRACTION * f64::from(r).abs()
        })
        .count();
    Ok(wrong as u64)
}

/// The z-depths of a frame's sub-pixel samples: `factor`² per pixel on a regular grid, stored
/// as one image of `factor`·`width` × `factor`·`height` pixels, row-major (`+inf` a miss). The
/// supersampled reference keeps it ([`crate::reference::ReferenceRenderer::render_supersampled_footprint`])
/// so that a depth can be checked against every surface a pixel covers.
#[derive(Clone, Debug, PartialEq)]
pub struct DepthFootprint {
    /// Width of the frame in pixels.
    pub width: u32,
    /// Height of the frame in pixels.
    pub height: u32,
    /// Samples per pixel side.
    pub factor: u32,
    /// The samples' z-depths, `(factor·width) × (factor·height)`.
    pub depth: Vec<f32>,
}

/// Pixels covered in both frames whose test z-depth is off by more than
/// [`WRONG_SURFACE_FRACTION`] from the z-depth of **every** hit sample inside the pixel: a
/// surface the pixel does not contain. [`wrong_surface_px`] compares with the one depth at
/// the pixel's centre, so a pixel on a limb or an occlusion edge, whose depth changes by more
/// than 1 % within the pixel, counts there whenever the test frame hits its right surface a
/// fraction of a pixel away; here it does not. `reference` (the supersampled frame's depth)
/// decides which pixels the reference covers.
pub fn wrong_surface_footprint_px(
    test: &[f32],
    reference: &[f32],
    footprint: &DepthFootprint,
) -> Result<u64, MetricsError> {
    let (w, h, k) = (
        footprint.width as usize,
        footprint.height as usize,
        footprint.factor as usize,
    );
    for (buffer, expected, actual) in [
        ("test depth", w * h, test.len()),
        ("reference depth", w * h, reference.len()),
        ("footprint depth", w * h * k * k, footprint.depth.len()),
    ] {
        if expected != actual {
            return Err(MetricsError::BufferLength {
                buffer,
                expected,
                actual,
            });
        }
    }
    let mut wrong = 0;
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            let t = f64::from(test[i]);
            if !(t.is_finite() && reference[i].is_finite()) {
                continue;
            }
            let contains = (0..k).any(|b| {
                let row = (y * k + b) * w * k + x * k;
                footprint.depth[row..row + k].iter().any(|&z| {
                    let z = f64::from(z);
                    z.is_finite() && (t - z).abs() <= WRONG_SURFACE_FRACTION * z.abs()
                })
            });
            if !contains {
                wrong += 1;
            }
        }
    }
    Ok(wrong)
}

/// Count, median, mean, max and 95th percentile of `errors` (all finite); sorts `errors`.
fn error_stats(errors: &mut [f64]) -> DepthErrorStats {
    let n = errors.len();
    if n == 0 {
        return DepthErrorStats {
            count: 0,
            median: f64::NAN,
            mean: f64::NAN,
            max: f64::NAN,
            p95: f64::NAN,
        };
    }
    errors.sort_unstable_by(f64::total_cmp);
    let median = if n % 2 == 1 {
        errors[n / 2]
    } else {
        f64::midpoint(errors[n / 2 - 1], errors[n / 2])
    };
    DepthErrorStats {
        count: n as u64,
        median,
        mean: errors.iter().sum::<f64>() / n as f64,
        max: errors[n - 1],
        p95: percentile_sorted(errors, 0.95),
    }
}

/// numpy's default (`method="linear"`) percentile of sorted, non-empty data, `q` in [0, 1],
/// including numpy's two-sided lerp.
fn percentile_sorted(sorted: &[f64], q: f64) -> f64 {
    let position = q * (sorted.len() - 1) as f64;
    let lo = position.floor();
    let t = position - lo;
    let lo = lo as usize;
    let hi = (lo + 1).min(sorted.len() - 1);
    let (a, b) = (sorted[lo], sorted[hi]);
    let diff = b - a;
    if t >= 0.5 {
        b - diff * (1.0 - t)
    } else {
        a + diff * t
    }
}

/// Measures `test` against `reference` (same view, same background): PSNR over the full frame,
/// the union and the intersection of the coverage masks, SSIM, MAE, mask statistics and depth
/// error. Colour outside coverage is compared as it is. Where either frame is
/// [translucent](Frame::translucent) (a volume), both are compared as displayed over black
/// (`C + (1 − A)·0`, the seeds' "full frame over black"), and coverage is each frame's own
/// ([`Frame::coverage`]: alpha ≥ 1 for a translucent frame).
pub fn compare(test: &Frame, reference: &Frame) -> Result<Comparison, MetricsError> {
    if (test.width, test.height) != (reference.width, reference.height) {
        return Err(MetricsError::SizeMismatch {
            test_width: test.width,
            test_height: test.height,
            reference_width: reference.width,
            reference_height: reference.height,
        });
    }
    let (width, height) = (test.width, test.height);
    check_len("test colour", test.color.len(), width, height, 4)?;
    check_len("reference colour", reference.color.len(), width, height, 4)?;
    check_len("test depth", test.depth.len(), width, height, 1)?;
    check_len("reference depth", reference.depth.len(), width, height, 1)?;
    let over_black = test.translucent || reference.translucent;
    let (test_color, reference_color) = if over_black {
        let black = [0, 0, 0, 255];
        (
            std::borrow::Cow::Owned(test.with_background(black)),
            std::borrow::Cow::Owned(reference.with_background(black)),
        )
    } else {
        (
            std::borrow::Cow::Borrowed(test.color.as_slice()),
            std::borrow::Cow::Borrowed(reference.color.as_slice()),
        )
    };
    let ssim = ssim(&test_color, &reference_color, width, height)?;
    let mae = mae(&test_color, &reference_color, width, height)?;
    let (test_mask, reference_mask) = (test.coverage(), reference.coverage());

    let (mut sse_full, mut sse_union, mut sse_inter) = (0_u64, 0_u64, 0_u64);
    let (mut union_px, mut intersection_px) = (0_u64, 0_u64);
    let pixels = test_color
        .chunks_exact(4)
        .zip(reference_color.chunks_exact(4));
    let masks = test_mask.iter().zip(&reference_mask);
    for ((pt, pr), (&ct, &cr)) in pixels.zip(masks) {
        let sse = pixel_sse(pt, pr);
        sse_full += sse;
        if ct || cr {
            union_px += 1;
            sse_union += sse;
        }
        if ct && cr {
            intersection_px += 1;
            sse_inter += sse;
        }
    }
    let pixel_count = test.pixel_count() as u64;
    Ok(Comparison {
        psnr: psnr_from_sse(sse_full, 3 * pixel_count),
        masked_psnr: psnr_from_sse(sse_union, 3 * union_px),
        intersection_psnr: psnr_from_sse(sse_inter, 3 * intersection_px),
        ssim,
        mae,
        mask_mismatch_px: union_px - intersection_px,
        union_px,
        intersection_px,
        depth: depth_errors(&test.depth, &reference.depth)?,
        wrong_surface_px: wrong_surface_px(&test.depth, &reference.depth)?,
    })
}

/// Length of a frame's silhouette in pixels: covered pixels with at least one uncovered
/// 4-neighbour inside the frame (the frame's border is not a silhouette). Dividing the pixels
/// covered in one mask only by this length gives the mean silhouette displacement in pixels
/// (what automatic LOD bounds, `lod`).
pub fn silhouette_px(frame: &Frame) -> u64 {
    let (w, h) = (frame.width as usize, frame.height as usize);
    if frame.depth.len() != w * h {
        return 0;
    }
    let covered = |x: usize, y: usize| frame.depth[y * w + x].is_finite();
    let mut n = 0;
    for y in 0..h {
        for x in 0..w {
            if !covered(x, y) {
                continue;
            }
            let edge = (x > 0 && !covered(x - 1, y))
                || (x + 1 < w && !covered(x + 1, y))
                || (y > 0 && !covered(x, y - 1))
                || (y + 1 < h && !covered(x, y + 1));
            n += u64::from(edge);
        }
    }
    n
}

/// Mean of `values`, NaN when empty.
fn mean_of(values: impl Iterator<Item = f64>) -> f64 {
    let (sum, n) = values.fold((0.0, 0_u64), |(s, n), v| (s + v, n + 1));
    if n == 0 { f64::NAN } else { sum / n as f64 }
}

/// Per-scene numbers from per-view comparisons: every field is the mean of the per-view values
/// (DESIGN §3), with two rules that keep the mean meaningful:
/// - each PSNR is capped at [`PSNR_CAP_DB`] before averaging, so exact views count as 100 dB
///   instead of making the mean `+inf`;
/// - a PSNR whose region is empty in a view (no union, no intersection) is `+inf` by definition
///   but says nothing, so that view is left out of that PSNR's mean; likewise depth statistics
///   are averaged over the views whose masks intersect.
///
/// `None` for no views.
pub fn mean_comparison(views: &[Comparison]) -> Option<MeanComparison> {
    if views.is_empty() {
        return None;
    }
    let capped = |v: f64| v.min(PSNR_CAP_DB);
    let with_depth = || views.iter().filter(|c| c.depth.count > 0).map(|c| &c.depth);
    Some(MeanComparison {
        views: views.len() as u64,
        psnr: mean_of(views.iter().map(|c| capped(c.psnr))),
        masked_psnr: mean_of(
            views
                .iter()
                .filter(|c| c.union_px > 0)
                .map(|c| capped(c.masked_psnr)),
        ),
        intersection_psnr: mean_of(
            views
                .iter()
                .filter(|c| c.intersection_px > 0)
                .map(|c| capped(c.intersection_psnr)),
        ),
        ssim: mean_of(views.iter().map(|c| c.ssim)),
        mae: mean_of(views.iter().map(|c| c.mae)),
        mask_mismatch_px: mean_of(views.iter().map(|c| c.mask_mismatch_px as f64)),
        union_px: mean_of(views.iter().map(|c| c.union_px as f64)),
        intersection_px: mean_of(views.iter().map(|c| c.intersection_px as f64)),
        depth: MeanDepthErrors {
            views: with_depth().count() as u64,
            count: mean_of(views.iter().map(|c| c.depth.count as f64)),
            median: mean_of(with_depth().map(|d| d.median)),
            mean: mean_of(with_depth().map(|d| d.mean)),
            max: mean_of(with_depth().map(|d| d.max)),
            p95: mean_of(with_depth().map(|d| d.p95)),
        },
        wrong_surface_px: mean_of(views.iter().map(|c| c.wrong_surface_px as f64)),
    })
}

/// Serde for f64 that may be non-finite: finite values as numbers, others as the strings
/// `"Infinity"`, `"-Infinity"`, `"NaN"` (serde_json would write `null` and fail to read it back).
mod nonfinite_f64 {
    use serde::de::{self, Visitor};
    use serde::{Deserializer, Serializer};
    use std::fmt;

    // serde's `with` passes `&f64`.
    #[allow(clippy::trivially_copy_pass_by_ref)]
    pub fn serialize<S: Serializer>(value: &f64, serializer: S) -> Result<S::Ok, S::Error> {
        if value.is_finite() {
            serializer.serialize_f64(*value)
        } else if value.is_nan() {
            serializer.serialize_str("NaN")
        } else if *value > 0.0 {
            serializer.serialize_str("Infinity")
        } else {
            serializer.serialize_str("-Infinity")
        }
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(deserializer: D) -> Result<f64, D::Error> {
        deserializer.deserialize_any(F64Visitor)
    }

    struct F64Visitor;

    impl Visitor<'_> for F64Visitor {
        type Value = f64;

        fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
            f.write_str("a number, \"Infinity\", \"-Infinity\", \"NaN\" or null")
        }

        fn visit_f64<E: de::Error>(self, v: f64) -> Result<f64, E> {
            Ok(v)
        }

        fn visit_i64<E: de::Error>(self, v: i64) -> Result<f64, E> {
            Ok(v as f64)
        }

        fn visit_u64<E: de::Error>(self, v: u64) -> Result<f64, E> {
            Ok(v as f64)
        }

        fn visit_str<E: de::Error>(self, v: &str) -> Result<f64, E> {
            match v {
                "Infinity" | "inf" | "+inf" => Ok(f64::INFINITY),
                "-Infinity" | "-inf" => Ok(f64::NEG_INFINITY),
                "NaN" | "nan" => Ok(f64::NAN),
                _ => Err(E::invalid_value(de::Unexpected::Str(v), &self)),
            }
        }

        fn visit_unit<E: de::Error>(self) -> Result<f64, E> {
            Ok(f64::NAN)
        }

        fn visit_none<E: de::Error>(self) -> Result<f64, E> {
            Ok(f64::NAN)
        }
    }
}

/// Golden values come from scikit-image 0.26.0 (numpy 2.4, scipy 1.17) through the script below,
/// which rebuilds the same test images with the same LCG. The tolerance is 1e-9 relative: our
/// window sums are exact integers and scikit-image's separable float filter rounds at ~1e-16 per
/// step, so the two agree to ~1e-13; 1e-9 leaves room for a different libm `log10` or summation
/// order while any real formula error (window, covariance norm, crop, constants) moves SSIM by
/// more than 1e-4 and PSNR by far more. PSNR and MAE are in fact bit-identical.
///
/// ```python
/// # Golden values for lumigraph_core::metrics tests (scikit-image 0.26, numpy 2.x).
/// # Run: python metrics_golden.py   (needs scikit-image==0.26.*)
/// import numpy as np
/// from skimage.metrics import peak_signal_noise_ratio as psnr, structural_similarity as ssim
///
/// M = 2**64
/// class Lcg:
///     def __init__(self, seed): self.s = seed
///     def next(self):
///         self.s = (self.s * 6364136223846793005 + 1442695040888963407) % M
///         return self.s >> 56
///
/// def noise(w, h, seed):
///     r = Lcg(seed)
///     return np.array([r.next() for _ in range(w * h * 4)], np.uint8).reshape(h, w, 4)
///
/// def perturb(img, seed, amp):
///     r, out = Lcg(seed), img.copy()
///     for i in range(img.shape[0]):
///         for j in range(img.shape[1]):
///             for c in range(3):
///                 d = r.next() % (2 * amp + 1) - amp
///                 out[i, j, c] = min(255, max(0, int(img[i, j, c]) + d))
///     return out
///
/// def structured(w, h, shift):
///     out = np.zeros((h, w, 4), np.uint8)
///     for i in range(h):
///         for j in range(w):
///             out[i, j] = (i * 255 // (h - 1), ((j + shift) * 37 + i * 11) % 256,
///                          200 if (i // 4 + (j + shift) // 4) % 2 == 0 else 30, 255)
///     return out
///
/// def flat(w, h, rgb):
///     out = np.zeros((h, w, 4), np.uint8); out[...] = (*rgb, 255); return out
///
/// def disc(w, h, cx, cy, rad, seed):
///     """seed None: exact reference; else colour/depth noise drawn per pixel."""
///     r = Lcg(seed) if seed is not None else None
///     color = np.zeros((h, w, 4), np.uint8); depth = np.full((h, w), np.inf, np.float32)
///     for i in range(h):
///         for j in range(w):
///             draws = [r.next() for _ in range(4)] if r else [5, 5, 5, 8]
///             if (j - cx) ** 2 + (i - cy) ** 2 <= rad * rad:
///                 base = (100 + (i * 3) % 100, 50 + (j * 5) % 150, 128 + (i + j) % 64)
///                 color[i, j, :3] = [min(255, max(0, v + d % 11 - 5)) for v, d in zip(base, draws)]
///                 color[i, j, 3] = 255
///                 depth[i, j] = 2.0 + i / 32 + j / 64 + (draws[3] % 17 - 8) / 256
///     return color, depth
///
/// def report(name, a, b, da=None, db=None):
///     a3, b3 = a[..., :3], b[..., :3]
///     print(f"{name}: psnr={float(psnr(a3, b3, data_range=255))!r} "
///           f"ssim={float(ssim(a3, b3, channel_axis=-1, data_range=255))!r} "
///           f"mae={float(np.mean(np.abs(a3.astype(np.float64) - b3)))!r}")
///     if da is not None:
///         ca, cb = np.isfinite(da), np.isfinite(db)
///         union, inter = ca | cb, ca & cb
///         e = np.abs(da[inter].astype(np.float64) - db[inter].astype(np.float64))
///         print(f"  masked_psnr={float(psnr(a3[union], b3[union], data_range=255))!r} "
///               f"intersection_psnr={float(psnr(a3[inter], b3[inter], data_range=255))!r} "
///               f"mismatch={int((ca != cb).sum())} union={int(union.sum())} inter={int(inter.sum())}")
///         print(f"  depth count={e.size} median={float(np.median(e))!r} mean={float(np.mean(e))!r} "
///               f"max={float(np.max(e))!r} p95={float(np.percentile(e, 95))!r}")
///
/// a = noise(64, 48, 1); report("noise", a, perturb(a, 2, 20))
/// report("structured", structured(40, 33, 0), structured(40, 33, 1))
/// report("minimum", noise(7, 7, 3), noise(7, 7, 4))
/// report("flat", flat(12, 9, (10, 200, 30)), flat(12, 9, (12, 190, 30)))
/// tc, td = disc(50, 50, 26, 24, 14, 7)
/// rc, rd = disc(50, 50, 25, 24, 15, None)
/// report("disc", tc, rc, td, rd)
/// e = np.abs(np.array([0, 1, 2, 3], np.float64) - [0.5, 3, 2.25, 10])
/// print(f"depth small: median={float(np.median(e))!r} p95={float(np.percentile(e, 95))!r} mean={float(np.mean(e))!r}")
/// e = np.array([0.1, 0.7, 0.2, 0.3, 0.9, 0.4, 0.05])
/// print(f"percentile odd: median={float(np.median(e))!r} p95={float(np.percentile(e, 95))!r} p40={float(np.percentile(e, 40))!r}")
/// ```
///
/// Output (the constants asserted below):
///
/// ```text
/// noise: psnr=26.781061992197795 ssim=0.9871471726003973 mae=10.070638020833334
/// structured: psnr=11.085142493664437 ssim=0.5892519375076799 mae=35.09444444444444
/// minimum: psnr=7.757476544252907 ssim=0.017315187983622787 mae=85.00680272108843
/// flat: psnr=32.73168276288792 ssim=0.9942393824379766 mae=4.0
/// disc: psnr=18.90871243554007 ssim=0.7838725387463273 mae=6.196933333333333
///   masked_psnr=13.43577470065036 intersection_psnr=38.161851014846135 mismatch=96 union=709 inter=613
///   depth count=613 median=0.015625 mean=0.01624949021207178 max=0.03125 p95=0.03125
/// depth small: median=1.25 p95=6.249999999999998 mean=2.4375
/// percentile odd: median=0.3 p95=0.8399999999999999 p40=0.24000000000000005
/// ```
#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::FrameStats;
    use proptest::collection::vec;
    use proptest::prelude::*;

    /// Knuth's MMIX LCG; the top byte of the state is the output.
    struct Lcg(u64);

    impl Lcg {
        fn next(&mut self) -> u8 {
            self.0 = self
                .0
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (self.0 >> 56) as u8
        }
    }

    fn noise(w: usize, h: usize, seed: u64) -> Vec<u8> {
        let mut rng = Lcg(seed);
        (0..w * h * 4).map(|_| rng.next()).collect()
    }

    fn perturb(img: &[u8], seed: u64, amp: i32) -> Vec<u8> {
        let mut rng = Lcg(seed);
        let mut out = img.to_vec();
        for px in out.chunks_exact_mut(4) {
            for v in &mut px[..3] {
                let d = i32::from(rng.next()) % (2 * amp + 1) - amp;
                *v = (i32::from(*v) + d).clamp(0, 255) as u8;
            }
        }
        out
    }

    fn structured(w: usize, h: usize, shift: usize) -> Vec<u8> {
        let mut out = Vec::with_capacity(w * h * 4);
        for i in 0..h {
            for j in 0..w {
                let checker = if (i / 4 + (j + shift) / 4).is_multiple_of(2) {
                    200
                } else {
                    30
                };
                out.extend([
                    (i * 255 / (h - 1)) as u8,
                    (((j + shift) * 37 + i * 11) % 256) as u8,
                    checker,
                    255,
                ]);
            }
        }
        out
    }

    fn flat(w: usize, h: usize, rgb: [u8; 3]) -> Vec<u8> {
        [rgb[0], rgb[1], rgb[2], 255].repeat(w * h)
    }

    /// An axis-aligned covered rectangle `[x0, x0 + w) × [y0, y0 + h)` in a `size²` frame.
    fn rect(size: usize, x0: usize, y0: usize, w: usize, h: usize) -> Frame {
        let mut depth = vec![f32::INFINITY; size * size];
        for y in y0..y0 + h {
            depth[y * size + x0..y * size + x0 + w].fill(1.0);
        }
        Frame {
            width: size as u32,
            height: size as u32,
            color: vec![0; size * size * 4],
            depth,
            translucent: false,
            stats: FrameStats::default(),
        }
    }

    #[test]
    fn silhouette_counts_boundary_pixels() {
        // A 10×6 rectangle: 2·10 + 2·4 boundary pixels; the frame border is not a silhouette.
        assert_eq!(silhouette_px(&rect(32, 5, 7, 10, 6)), 28);
        assert_eq!(silhouette_px(&rect(8, 0, 0, 8, 8)), 0);
        assert_eq!(silhouette_px(&rect(8, 0, 0, 8, 3)), 8);
        assert_eq!(silhouette_px(&rect(8, 3, 3, 1, 1)), 1);
        // Shifting a square by one pixel sideways moves two of its four sides by 1 px: the
        // mismatch over the silhouette length is the mean displacement, 0.5 px (exact: 2·s
        // mismatched pixels over 4·(s − 1) boundary pixels, s = 21 → 42 / 80).
        let a = rect(64, 10, 10, 21, 21);
        let b = rect(64, 11, 10, 21, 21);
        let c = compare(&b, &a).expect("same size");
        assert_eq!(c.mask_mismatch_px, 42);
        assert_eq!(silhouette_px(&a), 80);
    }

    /// A shaded disc on transparent black with depth; `seed` adds colour and depth noise.
    fn disc(w: usize, h: usize, cx: i64, cy: i64, rad: i64, seed: Option<u64>) -> Frame {
        let mut rng = seed.map(Lcg);
        let mut color = vec![0_u8; w * h * 4];
        let mut depth = vec![f32::INFINITY; w * h];
        for i in 0..h {
            for j in 0..w {
                let draws: [u8; 4] = match &mut rng {
                    Some(r) => [r.next(), r.next(), r.next(), r.next()],
                    None => [5, 5, 5, 8],
                };
                let (di, dj) = (i as i64 - cy, j as i64 - cx);
                if di * di + dj * dj <= rad * rad {
                    let base = [100 + (i * 3) % 100, 50 + (j * 5) % 150, 128 + (i + j) % 64];
                    let k = i * w + j;
                    for c in 0..3 {
                        let v = base[c] as i32 + i32::from(draws[c]) % 11 - 5;
                        color[4 * k + c] = v.clamp(0, 255) as u8;
                    }
                    color[4 * k + 3] = 255;
                    let noise = f32::from(draws[3] % 17) - 8.0;
                    depth[k] = 2.0 + i as f32 / 32.0 + j as f32 / 64.0 + noise / 256.0;
                }
            }
        }
        Frame {
            width: w as u32,
            height: h as u32,
            color,
            depth,
            translucent: false,
            stats: FrameStats::default(),
        }
    }

    #[track_caller]
    fn assert_close(actual: f64, expected: f64) {
        let tol = 1e-9 * expected.abs().max(1e-300);
        assert!(
            (actual - expected).abs() <= tol,
            "actual {actual:?} vs expected {expected:?} (diff {:e})",
            actual - expected
        );
    }

    /// (psnr, ssim, mae) of a pair against the golden values; also checks symmetry.
    #[track_caller]
    fn check_golden(a: &[u8], b: &[u8], w: usize, h: usize, golden: [f64; 3]) {
        let (w, h) = (w as u32, h as u32);
        assert_close(psnr(a, b, w, h, None).unwrap(), golden[0]);
        assert_close(ssim(a, b, w, h).unwrap(), golden[1]);
        assert_close(mae(a, b, w, h).unwrap(), golden[2]);
        assert_eq!(psnr(a, b, w, h, None), psnr(b, a, w, h, None));
        assert_close(ssim(b, a, w, h).unwrap(), golden[1]);
        assert_eq!(mae(a, b, w, h), mae(b, a, w, h));
    }

    #[test]
    fn golden_noise() {
        let a = noise(64, 48, 1);
        let b = perturb(&a, 2, 20);
        check_golden(
            &a,
            &b,
            64,
            48,
            [
                26.781_061_992_197_795,
                0.987_147_172_600_397_3,
                10.070_638_020_833_334,
            ],
        );
    }

    #[test]
    fn golden_structured_odd_size() {
        let (a, b) = (structured(40, 33, 0), structured(40, 33, 1));
        check_golden(
            &a,
            &b,
            40,
            33,
            [
                11.085_142_493_664_437,
                0.589_251_937_507_679_9,
                35.094_444_444_444_44,
            ],
        );
    }

    #[test]
    fn golden_minimum_size() {
        let (a, b) = (noise(7, 7, 3), noise(7, 7, 4));
        check_golden(
            &a,
            &b,
            7,
            7,
            [
                7.757_476_544_252_907,
                0.017_315_187_983_622_787,
                85.006_802_721_088_43,
            ],
        );
    }

    #[test]
    fn golden_flat() {
        let (a, b) = (flat(12, 9, [10, 200, 30]), flat(12, 9, [12, 190, 30]));
        check_golden(
            &a,
            &b,
            12,
            9,
            [32.731_682_762_887_92, 0.994_239_382_437_976_6, 4.0],
        );
    }

    #[test]
    fn golden_compare_frames() {
        let test = disc(50, 50, 26, 24, 14, Some(7));
        let reference = disc(50, 50, 25, 24, 15, None);
        let c = compare(&test, &reference).unwrap();
        assert_close(c.psnr, 18.908_712_435_540_07);
        assert_close(c.ssim, 0.783_872_538_746_327_3);
        assert_close(c.mae, 6.196_933_333_333_333);
        assert_close(c.masked_psnr, 13.435_774_700_650_36);
        assert_close(c.intersection_psnr, 38.161_851_014_846_135);
        assert_eq!(
            (c.mask_mismatch_px, c.union_px, c.intersection_px),
            (96, 709, 613)
        );
        assert_eq!(c.depth.count, 613);
        assert_close(c.depth.median, 0.015_625);
        assert_close(c.depth.mean, 0.016_249_490_212_071_78);
        assert_close(c.depth.max, 0.031_25);
        assert_close(c.depth.p95, 0.031_25);
        // The masked PSNR is the harsher one; the standalone functions agree with compare.
        assert!(c.masked_psnr < c.psnr && c.psnr < c.intersection_psnr);
        let union: Vec<bool> = test
            .depth
            .iter()
            .zip(&reference.depth)
            .map(|(a, b)| a.is_finite() || b.is_finite())
            .collect();
        assert_eq!(
            psnr(&test.color, &reference.color, 50, 50, Some(&union)).unwrap(),
            c.masked_psnr
        );
        // Symmetric in everything but which frame is called "test".
        let swapped = compare(&reference, &test).unwrap();
        assert_eq!(swapped.psnr, c.psnr);
        assert_eq!(swapped.masked_psnr, c.masked_psnr);
        assert_close(swapped.ssim, c.ssim);
        assert_eq!(swapped.depth, c.depth);
    }

    #[test]
    fn golden_depth_statistics() {
        let test = [0.0, 1.0, 2.0, 3.0, f32::INFINITY, 5.0, f32::NAN];
        let reference = [0.5, 3.0, 2.25, 10.0, 1.0, f32::INFINITY, 1.0];
        let d = depth_errors(&test, &reference).unwrap();
        assert_eq!(d.count, 4);
        assert_eq!(d.median, 1.25);
        assert_eq!(d.mean, 2.4375);
        assert_eq!(d.max, 7.0);
        assert_close(d.p95, 6.249_999_999_999_998);
        let mut odd = [0.1, 0.7, 0.2, 0.3, 0.9, 0.4, 0.05];
        let s = error_stats(&mut odd);
        assert_eq!(s.median, 0.3);
        assert_close(s.p95, 0.839_999_999_999_999_9);
        assert_close(percentile_sorted(&odd, 0.4), 0.240_000_000_000_000_05);
    }

    #[test]
    fn depth_errors_empty_intersection_is_nan() {
        let d = depth_errors(&[1.0, f32::INFINITY], &[f32::INFINITY, 2.0]).unwrap();
        assert_eq!(d.count, 0);
        assert!(d.median.is_nan() && d.mean.is_nan() && d.max.is_nan() && d.p95.is_nan());
        assert!(matches!(
            depth_errors(&[1.0], &[1.0, 2.0]),
            Err(MetricsError::BufferLength {
                expected: 1,
                actual: 2,
                ..
            })
        ));
    }

    #[test]
    fn psnr_hand_computed() {
        // One pixel: R differs by 3, G by 4, B equal; alpha differs and is ignored.
        // MSE = (9 + 16 + 0) / 3, PSNR = 10 log10(255² · 3 / 25).
        let a = [10, 20, 30, 0];
        let b = [13, 16, 30, 255];
        let expected = 10.0 * (255.0_f64 * 255.0 * 3.0 / 25.0).log10();
        assert_close(psnr(&a, &b, 1, 1, None).unwrap(), expected);
        // Every component off by 255: MSE = 255², PSNR = 0 dB.
        assert_eq!(
            psnr(&[0, 0, 0, 0], &[255, 255, 255, 0], 1, 1, None).unwrap(),
            0.0
        );
        // Every component off by 1: PSNR = 20 log10(255) = 48.1308... dB.
        let ones = [1_u8, 1, 1, 1].repeat(4);
        let zeros = [0_u8; 16];
        assert_close(
            psnr(&ones, &zeros, 2, 2, None).unwrap(),
            20.0 * 255.0_f64.log10(),
        );
        assert_eq!(mae(&ones, &zeros, 2, 2).unwrap(), 1.0);
    }

    #[test]
    fn psnr_identical_is_infinite() {
        let a = noise(9, 8, 11);
        let mut b = a.clone();
        for px in b.chunks_exact_mut(4) {
            px[3] = px[3].wrapping_add(1);
        }
        assert_eq!(psnr(&a, &b, 9, 8, None).unwrap(), f64::INFINITY);
        assert_eq!(mae(&a, &b, 9, 8).unwrap(), 0.0);
    }

    #[test]
    fn psnr_mask_selects_pixels() {
        // Pixel 0 equal, pixel 1 off by 10 in every component, pixel 2 off by 255.
        let a = [0, 0, 0, 255, 10, 10, 10, 255, 0, 0, 0, 255];
        let b = [0, 0, 0, 255, 20, 20, 20, 255, 255, 255, 255, 255];
        let only_first = [true, false, false];
        assert_eq!(
            psnr(&a, &b, 3, 1, Some(&only_first)).unwrap(),
            f64::INFINITY
        );
        let first_two = [true, true, false];
        // MSE over 6 components = 3 · 100 / 6 = 50.
        assert_close(
            psnr(&a, &b, 3, 1, Some(&first_two)).unwrap(),
            10.0 * (65025.0_f64 / 50.0).log10(),
        );
        let all = [true; 3];
        assert_eq!(psnr(&a, &b, 3, 1, Some(&all)), psnr(&a, &b, 3, 1, None));
        // An empty mask compares nothing: +inf by definition.
        assert_eq!(
            psnr(&a, &b, 3, 1, Some(&[false; 3])).unwrap(),
            f64::INFINITY
        );
        assert!(matches!(
            psnr(&a, &b, 3, 1, Some(&[true; 2])),
            Err(MetricsError::BufferLength {
                buffer: "mask",
                expected: 3,
                actual: 2
            })
        ));
    }

    #[test]
    fn ssim_of_identical_images_is_one() {
        for (w, h, seed) in [(7, 7, 1), (31, 17, 2), (64, 64, 3)] {
            let a = noise(w, h, seed);
            assert_eq!(ssim(&a, &a, w as u32, h as u32).unwrap(), 1.0);
        }
        let f = flat(10, 10, [0, 0, 0]);
        assert_eq!(ssim(&f, &f, 10, 10).unwrap(), 1.0);
    }

    #[test]
    fn ssim_is_symmetric() {
        let a = structured(23, 19, 0);
        let b = perturb(&a, 5, 40);
        let (ab, ba) = (ssim(&a, &b, 23, 19).unwrap(), ssim(&b, &a, 23, 19).unwrap());
        assert_close(ab, ba);
        assert!(ab < 1.0);
    }

    #[test]
    fn ssim_needs_seven_pixels() {
        for (w, h) in [(6, 7), (7, 6), (0, 0), (100, 3)] {
            let a = vec![0; w * h * 4];
            assert_eq!(
                ssim(&a, &a, w as u32, h as u32),
                Err(MetricsError::TooSmallForSsim {
                    width: w as u32,
                    height: h as u32
                })
            );
        }
    }

    #[test]
    fn buffer_and_size_errors() {
        let a = vec![0; 8 * 8 * 4];
        assert!(matches!(
            psnr(&a, &a[..10], 8, 8, None),
            Err(MetricsError::BufferLength {
                buffer: "second image",
                expected: 256,
                actual: 10
            })
        ));
        assert!(matches!(
            ssim(&a, &a, 9, 8),
            Err(MetricsError::BufferLength { .. })
        ));
        assert!(matches!(
            mae(&a, &a, 8, 9),
            Err(MetricsError::BufferLength { .. })
        ));
        // Sizes whose product overflows never panic.
        assert!(matches!(
            psnr(&a, &a, u32::MAX, u32::MAX, None),
            Err(MetricsError::BufferLength { .. })
        ));

        let small = disc(8, 8, 4, 4, 2, None);
        let mut other = disc(9, 8, 4, 4, 2, None);
        assert!(matches!(
            compare(&small, &other),
            Err(MetricsError::SizeMismatch {
                test_width: 8,
                reference_width: 9,
                ..
            })
        ));
        other = small.clone();
        other.depth.pop();
        assert!(matches!(
            compare(&small, &other),
            Err(MetricsError::BufferLength {
                buffer: "reference depth",
                ..
            })
        ));
        let tiny = disc(6, 6, 3, 3, 2, None);
        assert_eq!(
            compare(&tiny, &tiny),
            Err(MetricsError::TooSmallForSsim {
                width: 6,
                height: 6
            })
        );
    }

    #[test]
    fn compare_identical_and_disjoint_frames() {
        let f = disc(20, 16, 10, 8, 5, Some(3));
        let c = compare(&f, &f).unwrap();
        assert_eq!(c.psnr, f64::INFINITY);
        assert_eq!(c.masked_psnr, f64::INFINITY);
        assert_eq!(c.ssim, 1.0);
        assert_eq!(c.mask_mismatch_px, 0);
        assert_eq!(c.union_px, c.intersection_px);
        assert_eq!(c.depth.max, 0.0);

        let a = disc(20, 16, 4, 8, 3, None);
        let b = disc(20, 16, 15, 8, 3, None);
        let c = compare(&a, &b).unwrap();
        assert_eq!(c.intersection_px, 0);
        assert_eq!(c.mask_mismatch_px, c.union_px);
        assert_eq!(c.intersection_psnr, f64::INFINITY);
        assert_eq!(c.depth.count, 0);
        assert!(c.masked_psnr < c.psnr);
    }

    fn comparison(psnr: f64, union_px: u64, intersection_px: u64, depth_mean: f64) -> Comparison {
        let count = u64::from(depth_mean.is_finite());
        Comparison {
            psnr,
            masked_psnr: psnr,
            intersection_psnr: psnr,
            ssim: 0.5,
            mae: 2.0,
            mask_mismatch_px: union_px - intersection_px,
            union_px,
            intersection_px,
            depth: DepthErrorStats {
                count,
                median: depth_mean,
                mean: depth_mean,
                max: depth_mean,
                p95: depth_mean,
            },
            wrong_surface_px: union_px / 10,
        }
    }

    #[test]
    fn mean_comparison_caps_and_skips() {
        assert_eq!(mean_comparison(&[]), None);
        let views = [
            comparison(30.0, 10, 5, 0.5),
            comparison(f64::INFINITY, 4, 4, 1.5),
            comparison(f64::INFINITY, 0, 0, f64::NAN),
        ];
        let m = mean_comparison(&views).unwrap();
        assert_eq!(m.views, 3);
        // Full frame: (30 + 100 + 100) / 3; masked: the empty third view is left out.
        assert_close(m.psnr, 230.0 / 3.0);
        assert_eq!(m.masked_psnr, 65.0);
        assert_eq!(m.intersection_psnr, 65.0);
        assert_eq!(m.ssim, 0.5);
        assert_eq!(m.mae, 2.0);
        assert_close(m.union_px, 14.0 / 3.0);
        assert_close(m.mask_mismatch_px, 5.0 / 3.0);
        assert_eq!(m.depth.views, 2);
        assert_close(m.depth.count, 2.0 / 3.0);
        assert_eq!(m.depth.mean, 1.0);
        assert_eq!(m.depth.p95, 1.0);
        let none = mean_comparison(&views[2..]).unwrap();
        assert!(none.masked_psnr.is_nan() && none.depth.median.is_nan());
        assert_eq!(none.psnr, PSNR_CAP_DB);
    }

    #[test]
    fn serde_round_trips_non_finite_values() {
        let c = comparison(f64::INFINITY, 0, 0, f64::NAN);
        let json = serde_json::to_string(&c).unwrap();
        assert!(json.contains(r#""psnr":"Infinity""#), "{json}");
        assert!(json.contains(r#""median":"NaN""#), "{json}");
        let back: Comparison = serde_json::from_str(&json).unwrap();
        assert_eq!(back.psnr, f64::INFINITY);
        assert!(back.depth.median.is_nan());
        assert_eq!(serde_json::to_string(&back).unwrap(), json);
        let finite = comparison(31.5, 3, 2, 0.25);
        let json = serde_json::to_string(&finite).unwrap();
        assert_eq!(serde_json::from_str::<Comparison>(&json).unwrap(), finite);
        // Numbers, `null` and -inf are read too.
        let m = mean_comparison(std::slice::from_ref(&finite)).unwrap();
        let mut value = serde_json::to_value(&m).unwrap();
        value["psnr"] = serde_json::json!(null);
        value["mae"] = serde_json::json!(2);
        value["ssim"] = serde_json::json!("-Infinity");
        let back: MeanComparison = serde_json::from_value(value).unwrap();
        assert!(back.psnr.is_nan());
        assert_eq!(back.mae, 2.0);
        assert_eq!(back.ssim, f64::NEG_INFINITY);
        assert!(
            serde_json::from_str::<DepthErrorStats>(
                r#"{"count":0,"median":"x","mean":0,"max":0,"p95":0}"#
            )
            .is_err()
        );
    }

    #[test]
    fn wrong_surface_pixels_are_off_by_more_than_one_percent() {
        let inf = f32::INFINITY;
        let reference = [10.0, 10.0, 10.0, 10.0, inf, 10.0, 200.0];
        // Within 1 %, just beyond it, far behind, in front, uncovered in one frame or the other.
        let test = [10.09, 10.11, 14.0, 9.0, 3.0, inf, 197.9];
        assert_eq!(wrong_surface_px(&test, &reference), Ok(4));
        assert_eq!(wrong_surface_px(&reference, &reference), Ok(0));
        assert!(wrong_surface_px(&test[..3], &reference).is_err());
        let mut a = disc(12, 10, 6, 5, 3, None);
        let b = a.clone();
        a.depth[5 * 12 + 6] *= 1.5;
        let c = compare(&a, &b).unwrap();
        assert_eq!(c.wrong_surface_px, 1);
        assert_eq!(compare(&b, &b).unwrap().wrong_surface_px, 0);
        let views = [
            comparison(30.0, 100, 90, 0.1),
            comparison(40.0, 300, 290, 0.1),
        ];
        let m = mean_comparison(&views).unwrap();
        assert_eq!(m.wrong_surface_px, 20.0);
        let json = serde_json::to_value(&c).unwrap();
        assert_eq!(json["wrong_surface_px"], 1);
    }

    #[test]
    fn footprint_wrong_surface_needs_a_depth_no_sample_of_the_pixel_has() {
        let inf = f32::INFINITY;
        // Three pixels of 2×2 samples: a limb (depth 10 to 13 inside the pixel), an occlusion
        // edge (10 in front of 20), a pixel whose samples all miss.
        let footprint = DepthFootprint {
            width: 3,
            height: 1,
            factor: 2,
            #[rustfmt::skip]
            depth: vec![
                10.0, 11.0, 10.0, 20.0, inf, inf,
                12.0, 13.0, 20.0, 20.0, inf, inf,
            ],
        };
        let reference = [10.0, 20.0, inf];
        // On the limb 3 % behind the centre's depth: a wrong surface by the centre, not here.
        let test = [12.9, 10.05, 5.0];
        assert_eq!(wrong_surface_px(&test, &reference), Ok(2));
        assert_eq!(
            wrong_surface_footprint_px(&test, &reference, &footprint),
            Ok(0)
        );
        // Between the two layers of the edge, and beyond the limb's range: wrong everywhere.
        let test = [13.2, 15.0, 5.0];
        assert_eq!(
            wrong_surface_footprint_px(&test, &reference, &footprint),
            Ok(2)
        );
        assert_eq!(wrong_surface_px(&test, &reference), Ok(2));
        // Never more than the centre count when the centre sample is in the footprint.
        let test = [10.0, 20.0, 5.0];
        assert_eq!(
            wrong_surface_footprint_px(&test, &reference, &footprint),
            Ok(0)
        );
        assert!(wrong_surface_footprint_px(&test[..2], &reference, &footprint).is_err());
        let short = DepthFootprint {
            depth: vec![10.0; 11],
            ..footprint.clone()
        };
        assert!(wrong_surface_footprint_px(&test, &reference, &short).is_err());
    }

    proptest! {
        #[test]
        fn metrics_are_symmetric(
            (w, h, a, b) in (7_usize..24, 7_usize..24).prop_flat_map(|(w, h)| {
                let len = w * h * 4;
                (Just(w), Just(h), vec(any::<u8>(), len), vec(any::<u8>(), len))
            })
        ) {
            let (w32, h32) = (w as u32, h as u32);
            prop_assert_eq!(psnr(&a, &b, w32, h32, None)?, psnr(&b, &a, w32, h32, None)?);
            prop_assert_eq!(mae(&a, &b, w32, h32)?, mae(&b, &a, w32, h32)?);
            let (ab, ba) = (ssim(&a, &b, w32, h32)?, ssim(&b, &a, w32, h32)?);
            prop_assert!((ab - ba).abs() <= 1e-12, "{} vs {}", ab, ba);
            prop_assert!((-1.0..=1.0).contains(&ab));
            prop_assert_eq!(ssim(&a, &a, w32, h32)?, 1.0);
        }
    }
}
