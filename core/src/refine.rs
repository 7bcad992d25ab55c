//! Still-frame refinement: jittered sub-pixel samples of one view accumulated into an
//! anti-aliased frame, with outlier rejection so that a single sample on a wrong surface does
//! not show (docs/refine.md states the rule and its thresholds).
//!
//! Sample 0 is the plain render (jitter (0, 0)), so one sample is the plain frame, bit for bit;
//! the others follow the R2 low-discrepancy sequence in [-0.5, 0.5)². [`refine`] renders and
//! resolves them in one call; [`Refiner`] takes one frame at a time, so a stream can refine a
//! resting view over several frames and show the frame so far at any time.

use crate::frame::{Frame, FrameStats};

/// The most samples a refinement takes.
pub const MAX_SAMPLES: u32 = 256;

/// Two hit depths of one pixel lie on one surface when they differ by at most this fraction
/// of the nearer one (steps between sorted depths; docs/refine.md).
pub const DEPTH_GAP: f32 = 0.01;

/// A colour further than this many 8-bit steps (largest RGB difference), beyond three median
/// absolute deviations, from its surface's median colour is an outlier.
pub const COLOR_OUTLIER_STEPS: f32 = 48.0;

/// Errors of a refinement.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum RefineError {
    /// The sample count is out of range.
    #[error("refine samples {0} must be in 1..={MAX_SAMPLES}")]
    Samples(u32),
    /// A sample's size differs from the first one's.
    #[error("refine sample is {got_width}x{got_height}, the first was {width}x{height}")]
    SizeMismatch {
        /// The first sample's width.
        width: u32,
        /// The first sample's height.
        height: u32,
        /// This sample's width.
        got_width: u32,
        /// This sample's height.
        got_height: u32,
    },
    /// A sample's buffers do not match its size.
    #[error("refine sample buffers do not match its {width}x{height} size")]
    BufferLength {
        /// Width.
        width: u32,
        /// Height.
        height: u32,
    },
    /// Every sample has been added.
    #[error("refinement already holds all {0} samples")]
    Complete(u32),
}

/// Checks a sample count: 1..=[`MAX_SAMPLES`].
///
/// # Errors
/// [`RefineError::Samples`] outside that range.
pub fn validate_samples(samples: u32) -> Result<u32, RefineError> {
    if (1..=MAX_SAMPLES).contains(&samples) {
        Ok(samples)
    } else {
        Err(RefineError::Samples(samples))
    }
}

/// The sub-pixel jitter of sample `index`, in pixels: (0, 0) for sample 0, then the R2
/// sequence (Roberts 2018) shifted into [-0.5, 0.5)².
pub fn jitter(index: u32) -> [f32; 2] {
    // 1/φ₂ and 1/φ₂², φ₂ the plastic number (the real root of x³ = x + 1).
    const A1: f64 = 0.754_877_666_246_692_8;
    const A2: f64 = 0.569_840_290_998_053_3;
    let k = f64::from(index);
    let shift = |a: f64| ((0.5 + a * k).fract() - 0.5) as f32;
    [shift(A1), shift(A2)]
}

/// Renders `samples` jittered frames with `render_one` (given each sample's [`jitter`]) and
/// resolves them into one refined frame; one sample returns `render_one([0, 0])` unchanged.
/// Its stats sum the samples' (render time, rays, steps, fetches): the refinement's cost.
///
/// # Errors
/// [`RefineError::Samples`] for a count outside 1..=[`MAX_SAMPLES`] (nothing is rendered), a
/// sample whose size differs from the first's, or `render_one`'s error.
pub fn refine<E: From<RefineError>>(
    samples: u32,
    mut render_one: impl FnMut([f32; 2]) -> Result<Frame, E>,
) -> Result<Frame, E> {
    let mut refiner = Refiner::new(samples)?;
    while let Some(j) = refiner.next_jitter() {
        refiner.add(render_one(j)?)?;
    }
    Ok(refiner.frame().unwrap_or_default())
}

/// A progressive refinement of one view: feed it the frames rendered at [`Refiner::next_jitter`]
/// one at a time and read the refined frame whenever. It keeps every sample (8 bytes per pixel
/// per sample), since the rejection needs a pixel's samples together.
#[derive(Clone, Debug)]
pub struct Refiner {
    samples: u32,
    width: u32,
    height: u32,
    colors: Vec<Vec<u8>>,
    depths: Vec<Vec<f32>>,
    stats: FrameStats,
    first: Option<Frame>,
}

impl Refiner {
    /// An empty refinement that will take `samples` samples.
    ///
    /// # Errors
    /// [`RefineError::Samples`] outside 1..=[`MAX_SAMPLES`].
    pub fn new(samples: u32) -> Result<Refiner, RefineError> {
        Ok(Refiner {
            samples: validate_samples(samples)?,
            width: 0,
            height: 0,
            colors: Vec::new(),
            depths: Vec::new(),
            stats: FrameStats::default(),
            first: None,
        })
    }

    /// The sample count it was made for.
    pub fn samples(&self) -> u32 {
        self.samples
    }

    /// Samples added so far.
    pub fn accumulated(&self) -> u32 {
        self.colors.len() as u32
    }

    /// Whether every sample has been added.
    pub fn is_complete(&self) -> bool {
        self.accumulated() >= self.samples
    }

    /// The jitter to render the next sample at; `None` once complete.
    pub fn next_jitter(&self) -> Option<[f32; 2]> {
        (!self.is_complete()).then(|| jitter(self.accumulated()))
    }

    /// Adds the frame rendered at [`Refiner::next_jitter`].
    ///
    /// # Errors
    /// [`RefineError::Complete`] when every sample is in; [`RefineError::SizeMismatch`] /
    /// [`RefineError::BufferLength`] for a frame unlike the first.
    pub fn add(&mut self, frame: Frame) -> Result<(), RefineError> {
        if self.is_complete() {
            return Err(RefineError::Complete(self.samples));
        }
        let pixels = frame.pixel_count();
        if frame.color.len() != pixels * 4 || frame.depth.len() != pixels {
            return Err(RefineError::BufferLength {
                width: frame.width,
                height: frame.height,
            });
        }
        if self.first.is_none() {
            self.width = frame.width;
            self.height = frame.height;
        } else if (frame.width, frame.height) != (self.width, self.height) {
            return Err(RefineError::SizeMismatch {
                width: self.width,
                height: self.height,
                got_width: frame.width,
                got_height: frame.height,
            });
        }
        self.stats.render_ms += frame.stats.render_ms;
        self.stats.rays += frame.stats.rays;
        self.stats.steps += frame.stats.steps;
        self.stats.fetches += frame.stats.fetches;
        self.colors.push(frame.color.clone());
        self.depths.push(frame.depth.clone());
        if self.first.is_none() {
            self.first = Some(frame);
        }
        Ok(())
    }

    /// The refined frame from the samples so far (`None` before the first): the first frame
    /// itself while it is the only one; its stats sum every sample's.
    pub fn frame(&self) -> Option<Frame> {
        let first = self.first.as_ref()?;
        if self.colors.len() == 1 {
            return Some(first.clone());
        }
        let pixels = first.pixel_count();
        let mut color = vec![0_u8; pixels * 4];
        let mut depth = vec![f32::INFINITY; pixels];
        let offsets: Vec<f32> = (0..self.accumulated())
            .map(|k| {
                let [x, y] = jitter(k);
                x * x + y * y
            })
            .collect();
        let mut scratch = Scratch::default();
        for p in 0..pixels {
            scratch.clear();
            for (k, (c, d)) in self.colors.iter().zip(&self.depths).enumerate() {
                if d[p].is_finite() {
                    let rgb = [c[4 * p], c[4 * p + 1], c[4 * p + 2]];
                    scratch.hits.push(Sample {
                        z: d[p],
                        rgb,
                        offset: offsets[k],
                    });
                }
            }
            let resolved = resolve_pixel(&mut scratch, self.colors.len());
            color[4 * p..4 * p + 4].copy_from_slice(&resolved.rgba);
            depth[p] = resolved.z;
        }
        Some(Frame {
            width: self.width,
            height: self.height,
            color,
            depth,
            translucent: false,
            stats: self.stats.clone(),
        })
    }
}

/// One sample that hit: z-depth, colour, squared distance from the pixel centre.
#[derive(Clone, Copy, Debug)]
struct Sample {
    z: f32,
    rgb: [u8; 3],
    offset: f32,
}

/// Per-pixel buffers reused across pixels.
#[derive(Default)]
struct Scratch {
    hits: Vec<Sample>,
    keep: Vec<bool>,
    deviations: Vec<f32>,
    channel: Vec<u8>,
}

impl Scratch {
    fn clear(&mut self) {
        self.hits.clear();
        self.keep.clear();
    }
}

struct Resolved {
    rgba: [u8; 4],
    z: f32,
}

/// Median of `values` (sorted in place; the lower middle one for an even count).
fn median_u8(values: &mut [u8]) -> u8 {
    values.sort_unstable();
    values[(values.len() - 1) / 2]
}

fn median_f32(values: &mut [f32]) -> f32 {
    values.sort_unstable_by(f32::total_cmp);
    values[(values.len() - 1) / 2]
}

/// Resolves one pixel from its hits (`scratch.hits`) out of `total` samples (docs/refine.md):
/// depth clusters too small to be a surface and colour outliers within a cluster are rejected;
/// colour is the inliers' mean times the covered fraction (alpha); where at least half the
/// samples hit, depth is the sample nearest the pixel centre on the largest surface, else `+inf`.
fn resolve_pixel(scratch: &mut Scratch, total: usize) -> Resolved {
    let hits = &mut scratch.hits;
    if hits.is_empty() {
        return Resolved {
            rgba: [0; 4],
            z: f32::INFINITY,
        };
    }
    hits.sort_unstable_by(|a, b| a.z.total_cmp(&b.z));
    let n = hits.len();
    scratch.keep.resize(n, true);
    // Clusters: runs of sorted depths with relative steps of at most DEPTH_GAP. A cluster with
    // fewer than max(2, total/8) samples is a stray surface unless it is the largest.
    let support = (total / 8).max(2);
    let mut runs: Vec<(usize, usize)> = Vec::new();
    let mut start = 0;
    for i in 1..=n {
        if i == n || hits[i].z - hits[i - 1].z > DEPTH_GAP * hits[i - 1].z.abs() {
            runs.push((start, i));
            start = i;
        }
    }
    let largest = runs
        .iter()
        .enumerate()
        .max_by(|(ia, a), (ib, b)| (a.1 - a.0).cmp(&(b.1 - b.0)).then(ib.cmp(ia)))
        .map_or(0, |(i, _)| i);
    for (r, &(s, e)) in runs.iter().enumerate() {
        if r != largest && e - s < support {
            scratch.keep[s..e].fill(false);
            continue;
        }
        if e - s < 3 {
            continue;
        }
        // Colour outliers within the surface: far from its median colour beyond the spread.
        let mut median = [0_u8; 3];
        for (c, m) in median.iter_mut().enumerate() {
            scratch.channel.clear();
            scratch.channel.extend(hits[s..e].iter().map(|h| h.rgb[c]));
            *m = median_u8(&mut scratch.channel);
        }
        let deviation = |h: &Sample| {
            (0..3)
                .map(|c| f32::from(h.rgb[c].abs_diff(median[c])))
                .fold(0.0, f32::max)
        };
        scratch.deviations.clear();
        scratch.deviations.extend(hits[s..e].iter().map(deviation));
        let mad = median_f32(&mut scratch.deviations);
        let limit = COLOR_OUTLIER_STEPS + 3.0 * mad;
        for (h, keep) in hits[s..e].iter().zip(&mut scratch.keep[s..e]) {
            if deviation(h) > limit {
                *keep = false;
            }
        }
    }
    let mut sum = [0_u32; 3];
    let mut kept = 0_u32;
    let mut nearest: Option<Sample> = None;
    let (ls, le) = runs[largest];
    for (i, (h, &keep)) in hits.iter().zip(&scratch.keep).enumerate() {
        if !keep {
            continue;
        }
        kept += 1;
        for (acc, &c) in sum.iter_mut().zip(&h.rgb) {
            *acc += u32::from(c);
        }
        if (ls..le).contains(&i) && nearest.is_none_or(|b| h.offset < b.offset) {
            nearest = Some(*h);
        }
    }
    // The largest cluster is never rejected whole, and keeps its median colour, so kept ≥ 1.
    let kept = kept.max(1);
    let covered = n as f32 / total as f32;
    let mean = |c: usize| sum[c] as f32 / kept as f32 * covered;
    let to_u8 = |v: f32| v.round().clamp(0.0, 255.0) as u8;
    let rgba = [
        to_u8(mean(0)),
        to_u8(mean(1)),
        to_u8(mean(2)),
        to_u8(255.0 * covered),
    ];
    let z = if 2 * n >= total {
        nearest.map_or(f32::INFINITY, |s| s.z)
    } else {
        f32::INFINITY
    };
    Resolved { rgba, z }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(width: u32, height: u32, rgba: [u8; 4], z: f32) -> Frame {
        let pixels = (width * height) as usize;
        Frame {
            width,
            height,
            color: rgba.repeat(pixels),
            depth: vec![z; pixels],
            translucent: false,
            stats: FrameStats {
                render_ms: 1.5,
                rays: 10,
                steps: 20,
                fetches: 30,
            },
        }
    }

    #[test]
    fn jitter_starts_at_the_centre_and_stays_in_the_pixel() {
        assert_eq!(jitter(0), [0.0, 0.0]);
        for k in 0..MAX_SAMPLES {
            let [x, y] = jitter(k);
            assert!((-0.5..0.5).contains(&x) && (-0.5..0.5).contains(&y), "{k}");
        }
        // Low discrepancy: 16 samples fill each quadrant with 4 ± 2.
        let mut quadrants = [0; 4];
        for k in 0..16 {
            let [x, y] = jitter(k);
            quadrants[usize::from(x >= 0.0) + 2 * usize::from(y >= 0.0)] += 1;
        }
        assert!(
            quadrants.iter().all(|&q| (2..=6).contains(&q)),
            "{quadrants:?}"
        );
    }

    #[test]
    fn sample_counts_are_validated() {
        assert_eq!(Refiner::new(0).err(), Some(RefineError::Samples(0)));
        assert_eq!(Refiner::new(257).err(), Some(RefineError::Samples(257)));
        assert!(Refiner::new(1).is_ok() && Refiner::new(256).is_ok());
        let mut calls = 0;
        let out: Result<Frame, RefineError> = refine(0, |_| {
            calls += 1;
            Ok(Frame::default())
        });
        assert_eq!(out, Err(RefineError::Samples(0)));
        assert_eq!(calls, 0);
    }

    #[test]
    fn one_sample_is_the_frame_itself() {
        let mut f = frame(3, 2, [10, 20, 30, 255], 2.0);
        f.depth[1] = f32::INFINITY;
        f.color[4..8].copy_from_slice(&[0; 4]);
        let out: Result<Frame, RefineError> = refine(1, |j| {
            assert_eq!(j, [0.0, 0.0]);
            Ok(f.clone())
        });
        assert_eq!(out, Ok(f));
    }

    #[test]
    fn a_single_wrong_surface_sample_vanishes() {
        let mut refiner = Refiner::new(8).expect("valid");
        for k in 0..8 {
            // Sample 3 meets a surface 20 % further away, with another colour.
            let f = if k == 3 {
                frame(1, 1, [200, 0, 0, 255], 12.0)
            } else {
                frame(1, 1, [40, 80, 120, 255], 10.0 + 0.001 * k as f32)
            };
            refiner.add(f).expect("same size");
        }
        assert!(refiner.is_complete() && refiner.next_jitter().is_none());
        let out = refiner.frame().expect("samples");
        assert_eq!(out.color, vec![40, 80, 120, 255]);
        assert_eq!(out.depth, vec![10.0]);
        assert_eq!(out.stats.rays, 80);
        assert!((out.stats.render_ms - 12.0).abs() < 1e-9);
        assert_eq!(
            refiner.add(frame(1, 1, [0; 4], 1.0)),
            Err(RefineError::Complete(8))
        );
    }

    #[test]
    fn a_colour_outlier_on_the_right_surface_vanishes() {
        let mut refiner = Refiner::new(8).expect("valid");
        for k in 0..8 {
            let rgb = if k == 5 {
                [250, 250, 250]
            } else {
                [100, 100, 100]
            };
            refiner
                .add(frame(1, 1, [rgb[0], rgb[1], rgb[2], 255], 5.0))
                .expect("same size");
        }
        let out = refiner.frame().expect("samples");
        assert_eq!(out.color, vec![100, 100, 100, 255]);
    }

    #[test]
    fn occlusion_and_silhouette_edges_are_blended_by_coverage() {
        // Half the samples on a near surface, half on a far one: both are kept (no stray
        // surface), the depth is the centre sample's.
        let mut refiner = Refiner::new(8).expect("valid");
        for k in 0..8 {
            let f = if k % 2 == 0 {
                frame(1, 1, [200, 0, 0, 255], 4.0)
            } else {
                frame(1, 1, [0, 0, 100, 255], 8.0)
            };
            refiner.add(f).expect("same size");
        }
        let out = refiner.frame().expect("samples");
        assert_eq!(out.color, vec![100, 0, 50, 255]);
        assert_eq!(out.depth, vec![4.0]);
        // A quarter of the samples hit: colour weighted by coverage, not covered.
        let mut refiner = Refiner::new(8).expect("valid");
        for k in 0..8 {
            let f = if k < 2 {
                frame(1, 1, [200, 100, 40, 255], 4.0)
            } else {
                frame(1, 1, [0; 4], f32::INFINITY)
            };
            refiner.add(f).expect("same size");
        }
        let out = refiner.frame().expect("samples");
        assert_eq!(out.color, vec![50, 25, 10, 64]);
        assert_eq!(out.depth, vec![f32::INFINITY]);
    }

    #[test]
    fn mismatched_samples_are_refused() {
        let mut refiner = Refiner::new(4).expect("valid");
        refiner.add(frame(2, 2, [0; 4], 1.0)).expect("first");
        assert!(matches!(
            refiner.add(frame(3, 2, [0; 4], 1.0)),
            Err(RefineError::SizeMismatch { .. })
        ));
        let mut bad = frame(2, 2, [0; 4], 1.0);
        bad.depth.pop();
        assert!(matches!(
            refiner.add(bad),
            Err(RefineError::BufferLength { .. })
        ));
        assert_eq!(refiner.accumulated(), 1);
    }
}
