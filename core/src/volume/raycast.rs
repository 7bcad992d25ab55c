//! The direct volume ray caster on the CPU: DESIGN §9's sampling, transfer function,
//! integration, shading, depth and coverage, followed literally. It is the ground truth the
//! volume bake and renderer are measured against, so it favours being
//! obviously the convention over speed; rows are spread over the CPU cores.
//!
//! Per pixel ray `eye + t·d` (§3's `pixel_dir`, `|d| = 1`, so `t` is in world units):
//! - the box `M·[−½, dims − ½] + o` is clipped analytically in index space
//!   (`u = M⁻¹(p − o)` is affine in `t`), giving `t_in`, `t_out`; `t0 = max(t_in, 0)`;
//! - samples at `t_k = t0 + (k + ½)·Δ` for every `k ≥ 0` with `t_k < t_out`;
//! - scalar volumes are sampled trilinearly with the index clamped to the edge voxels
//!   (`[0, dims − 1]`), label volumes at the nearest voxel `clamp(floor(u + ½))`;
//! - `α_k = 1 − (1 − a)^(Δ/ref_step)`; front to back, premultiplied: `C += (1 − A)·α_k·c_k`,
//!   `A += (1 − A)·α_k`; the ray stops once `A ≥ 0.995` (A is not renormalised);
//! - with `shade`, `c_k = rgb · (ambient + (1 − ambient)·|∇S·ℓ| / |∇S|)`, central differences
//!   of `T` one spacing along each world axis (offsets clamp like samples), and the TF colour
//!   unchanged where `|∇S|·min(s) < 1e−6·(max S − min S)`. The spacing along world axis x is
//!   `s_x = |row x of M|`, a voxel's extent along x: `sx` of `diag(sx, sy, sz)` as DESIGN §9
//!   writes it, and the same world offsets whatever order the file stores the axes in;
//! - depth: the z-depth (`t · d·forward`) of the first sample after whose compositing
//!   `A ≥ τ_d`, `+inf` where `A` never reaches it.
//!
//! Depth layers (seed 002 §7) cut each ray into consecutive segments ([`SplitRule`]): a
//! segment ends after the sample at which the next split event first holds (the ray's
//! accumulated opacity reaches a threshold, or its scalar value reaches an isovalue), the
//! events taken in order; at a label transition the next segment starts with the first sample
//! of the new label. A segment is integrated like a whole ray that starts empty at its
//! first sample (its own `C`, `A`, `τ_d` crossing and mean depth), while the split events and
//! the early stop follow the whole ray's `A`; so compositing the segments front to back in
//! their order gives the whole ray's `C` and `A` exactly.

use glam::DVec3;

use super::tf::{TransferFunction, opacity_for_step};
use super::{Volume, Voxels};
use crate::frame::Frame;
use crate::shading::{DEFAULT_AMBIENT, DEFAULT_LIGHT};
use crate::view::View;

/// Accumulated opacity at which a ray stops.
pub const EARLY_STOP_ALPHA: f64 = 0.995;
/// Default `τ_d`: the accumulated opacity that places the depth.
pub const DEFAULT_DEPTH_THRESHOLD: f64 = 0.5;
/// Most samples one ray may take (a step far below the voxel size on a large volume is refused
/// rather than run for hours).
pub const MAX_SAMPLES_PER_RAY: f64 = 1e6;

/// Why a ray cast is refused.
#[derive(Debug, thiserror::Error, PartialEq)]
#[non_exhaustive]
pub enum RaycastError {
    /// The view is invalid.
    #[error("view: {0}")]
    View(String),
    /// A bad option.
    #[error("{0}")]
    Options(String),
    /// The transfer function does not fit the volume.
    #[error("{0}")]
    Mismatch(&'static str),
}

/// Ray-cast settings (DESIGN §9 defaults).
#[derive(Clone, Debug, PartialEq)]
pub struct RaycastOptions {
    /// Sample spacing Δ, world units; `None`: half the TF's reference step.
    pub step: Option<f64>,
    /// Gradient shading (scalar volumes only).
    pub shade: bool,
    /// World-space direction towards the light (normalized here).
    pub light: [f64; 3],
    /// Ambient term of the shading.
    pub ambient: f64,
    /// `τ_d` in (0, 1].
    pub depth_threshold: f64,
}

impl Default for RaycastOptions {
    fn default() -> Self {
        Self {
            step: None,
            shade: false,
            light: DEFAULT_LIGHT.map(f64::from),
            ambient: f64::from(DEFAULT_AMBIENT),
            depth_threshold: DEFAULT_DEPTH_THRESHOLD,
        }
    }
}

/// Where depth layers split a ray (seed 002 §7): the boundaries, in the order the ray meets
/// them. A segment ends after the sample at which the next boundary's event first holds.
#[derive(Clone, Debug, PartialEq)]
pub enum SplitRule {
    /// The whole ray's accumulated opacity `A` reaches each threshold (strictly increasing, in
    /// (0, 1)): opacity peeling.
    Opacity(Vec<f64>),
    /// The sampled scalar value reaches each value (`S ≥ v`), the first hit of each isosurface
    /// in turn (scalar volumes).
    Value(Vec<f64>),
    /// The first this many transitions between segmented regions (label volumes): a visible
    /// sample (TF opacity above 0) whose label differs from the last visible label before it
    /// starts the next segment, itself included.
    Labels(usize),
}

impl SplitRule {
    /// The number of boundaries (one fewer than the segments).
    pub fn boundary_count(&self) -> usize {
        match self {
            SplitRule::Opacity(b) | SplitRule::Value(b) => b.len(),
            SplitRule::Labels(n) => *n,
        }
    }

    /// The thresholds of an opacity or value split (empty for labels).
    pub fn thresholds(&self) -> &[f64] {
        match self {
            SplitRule::Opacity(b) | SplitRule::Value(b) => b,
            SplitRule::Labels(_) => &[],
        }
    }

    /// Whether boundary `k`'s event holds after a sample of value `value` that left the whole
    /// ray's opacity at `a` (label transitions are found before their sample instead).
    fn fires(&self, k: usize, value: f64, a: f64) -> bool {
        match self {
            SplitRule::Opacity(b) => a >= b[k],
            SplitRule::Value(b) => value >= b[k],
            SplitRule::Labels(_) => false,
        }
    }
}

/// One segment of a split ray: the rule and which segment (0 = nearest the eye).
#[derive(Clone, Debug, PartialEq)]
pub struct Segment {
    /// Where the ray is split.
    pub split: SplitRule,
    /// This segment's index, `0..=boundaries`.
    pub index: usize,
}

/// A ray-cast image: premultiplied RGBA and depth per pixel, row-major from the top.
#[derive(Clone, Debug, PartialEq)]
pub struct VolumeImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Premultiplied `[C, A]` per pixel.
    pub rgba: Vec<[f64; 4]>,
    /// z-depth in world units, `+inf` where `A` never reached `τ_d`.
    pub depth: Vec<f64>,
    /// Samples taken over all pixels.
    pub samples: u64,
}

impl VolumeImage {
    /// The 8-bit frame: straight colour `round(255·C/A)`, alpha `round(255·A)` (as PNG stores
    /// it), depth as `f32`. Coverage is `round(255·A) ≥ 1` (DESIGN §9); a covered pixel without a
    /// depth (`A` below `τ_d`) keeps `+inf` in the frame's depth, so [`Frame::coverage`] is the
    /// depth test there, not the alpha one: use [`Self::coverage`] for volumes.
    pub fn to_frame(&self) -> Frame {
        let mut color = Vec::with_capacity(self.rgba.len() * 4);
        for &[r, g, b, a] in &self.rgba {
            let alpha = (255.0 * a).round().clamp(0.0, 255.0);
            if alpha >= 1.0 {
                for c in [r, g, b] {
                    color.push((255.0 * c / a).round().clamp(0.0, 255.0) as u8);
                }
            } else {
                color.extend([0, 0, 0]);
            }
            color.push(alpha as u8);
        }
        Frame {
            width: self.width,
            height: self.height,
            color,
            depth: self.depth.iter().map(|&d| d as f32).collect(),
            translucent: true,
            stats: crate::frame::FrameStats {
                steps: self.samples,
                ..Default::default()
            },
        }
    }

    /// DESIGN §9 coverage: `round(255·A) ≥ 1`.
    pub fn coverage(&self) -> Vec<bool> {
        self.rgba
            .iter()
            .map(|p| (255.0 * p[3]).round() >= 1.0)
            .collect()
    }
}

/// The validated settings of a ray cast through one volume: casts single rays
/// ([`VolumeRays::cast`]), so that a bake can check each of its texels against the
/// convention, and whole views ([`raycast`]).
pub struct VolumeRays<'a> {
    sampler: Sampler<'a>,
    tf: &'a TransferFunction,
    step: f64,
    ref_step: f64,
    tau: f64,
    shading: Option<Shading>,
    segment: Option<Segment>,
}

/// What one ray gathered.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RaySample {
    /// Premultiplied `[C, A]`.
    pub rgba: [f64; 4],
    /// Ray parameter of the depth sample (the first after which `A ≥ τ_d`), `+inf` if none.
    pub t_depth: f64,
    /// Where within that sample's slab `[t − Δ/2, t + Δ/2]` the opacity crossed `τ_d`, found
    /// by linear interpolation of `A` across the slab; `+inf` if none. It lies within half a
    /// step of `t_depth`, but moves continuously with the surface rather than in steps of `Δ`:
    /// the depth a bake stores, so that reprojection sees a smooth surface instead of a
    /// staircase.
    pub t_cross: f64,
    /// Ray parameter averaged over the samples weighted by what each added to `A`
    /// (`(1 − A)·α_k`), `+inf` where nothing was added: where the opacity sits along the ray
    /// (the bake's depth where `A` stays below `τ_d`).
    pub t_mean: f64,
    /// Samples taken.
    pub samples: u64,
}

impl<'a> VolumeRays<'a> {
    /// Checks the volume, transfer function and options against each other (DESIGN §9
    /// defaults for what `options` leaves open).
    ///
    /// # Errors
    /// [`RaycastError`] naming the mismatch or the bad option.
    pub fn new(
        volume: &'a Volume,
        tf: &'a TransferFunction,
        options: &RaycastOptions,
    ) -> Result<Self, RaycastError> {
        let labels = matches!(volume.voxels, Voxels::Labels(_));
        if labels != tf.is_labels() {
            return Err(RaycastError::Mismatch(if labels {
                "a label volume needs a label transfer function ({\"labels\": {...}})"
            } else {
                "a scalar volume needs a scalar transfer function ({\"points\": [...]})"
            }));
        }
        if options.shade && labels {
            return Err(RaycastError::Options(
                "shading needs a scalar volume (label volumes have no gradient)".into(),
            ));
        }
        let ref_step = tf.ref_step_for(volume);
        let step = options.step.unwrap_or(ref_step / 2.0);
        if !(step.is_finite() && step > 0.0) {
            return Err(RaycastError::Options(format!(
                "step {step} is not a finite length > 0"
            )));
        }
        let tau = options.depth_threshold;
        if !(tau > 0.0 && tau <= 1.0) {
            return Err(RaycastError::Options(format!(
                "depth threshold {tau} is not in (0, 1]"
            )));
        }
        let light = DVec3::from(options.light);
        if !(light.is_finite() && light.length() > 0.0) {
            return Err(RaycastError::Options(
                "light must be a finite, non-zero direction".into(),
            ));
        }
        let ambient = options.ambient;
        if !(0.0..=1.0).contains(&ambient) {
            return Err(RaycastError::Options(format!(
                "ambient {ambient} is not in [0, 1]"
            )));
        }
        let sampler = Sampler::new(volume);
        let diagonal = sampler.world_diagonal();
        if diagonal / step > MAX_SAMPLES_PER_RAY {
            return Err(RaycastError::Options(format!(
                "step {step} gives {:.0} samples across the volume (at most {MAX_SAMPLES_PER_RAY})",
                diagonal / step
            )));
        }
        let shading = options.shade.then(|| Shading {
            light: light.normalize(),
            ambient,
            flat_below: 1e-6 * (sampler.range.1 - sampler.range.0),
        });
        Ok(Self {
            sampler,
            tf,
            step,
            ref_step,
            tau,
            shading,
            segment: None,
        })
    }

    /// These rays restricted to one segment of a split ray (see the module documentation):
    /// what they gather is that segment's alone.
    ///
    /// # Errors
    /// [`RaycastError::Options`] for a segment index beyond the rule's boundaries, a value
    /// split of a label volume or a label split of a scalar one.
    pub fn with_segment(mut self, segment: Option<Segment>) -> Result<Self, RaycastError> {
        if let Some(s) = &segment {
            if s.index > s.split.boundary_count() {
                return Err(RaycastError::Options(format!(
                    "segment {} of a ray split at {} boundaries",
                    s.index,
                    s.split.boundary_count()
                )));
            }
            let labels = matches!(self.sampler.volume.voxels, Voxels::Labels(_));
            if matches!(s.split, SplitRule::Value(_)) && labels {
                return Err(RaycastError::Options(
                    "a label volume splits its rays by opacity or label, not by value".into(),
                ));
            }
            if matches!(s.split, SplitRule::Labels(_)) && !labels {
                return Err(RaycastError::Options(
                    "only a label volume splits its rays at label transitions".into(),
                ));
            }
        }
        self.segment = segment;
        Ok(self)
    }

    /// The sample spacing Δ in world units.
    pub fn step(&self) -> f64 {
        self.step
    }

    /// The transfer function's reference length in world units.
    pub fn ref_step(&self) -> f64 {
        self.ref_step
    }

    /// `1e−6·(max S − min S)`: the gradient norm (times the smallest spacing) below which
    /// shading keeps the TF colour.
    pub fn flat_below(&self) -> f64 {
        1e-6 * (self.sampler.range.1 - self.sampler.range.0)
    }

    /// Spacing of the gradient's offsets along world x, y, z: the row norms of `M`.
    pub fn gradient_spacing(&self) -> [f64; 3] {
        self.sampler.spacing
    }

    /// `M⁻¹`, row-major: index space from world offsets.
    pub fn index_from_world(&self) -> [[f64; 3]; 3] {
        self.sampler.inverse
    }

    /// Casts the ray `eye + t·dir` (`dir` a unit vector, so `t` is in world units).
    pub fn cast(&self, eye: [f64; 3], dir: [f64; 3]) -> RaySample {
        let ray = self.sampler.march(
            self.tf,
            DVec3::from(eye),
            DVec3::from(dir),
            self.step,
            self.ref_step,
            self.tau,
            self.shading.as_ref(),
            self.segment.as_ref(),
        );
        RaySample {
            rgba: ray.rgba,
            t_depth: ray.t_depth,
            t_cross: ray.t_cross,
            t_mean: ray.t_mean,
            samples: ray.samples,
        }
    }
}

/// Ray-casts `volume` through `tf` for `view` (see the module documentation).
///
/// # Errors
/// [`RaycastError`] for a bad view, a mismatched transfer function or a bad option.
pub fn raycast(
    volume: &Volume,
    tf: &TransferFunction,
    view: &View,
    options: &RaycastOptions,
) -> Result<VolumeImage, RaycastError> {
    raycast_with_sort_depth(volume, tf, view, options).map(|(image, _)| image)
}

/// [`raycast`] with each pixel's sort depth (z, world units): where its `A` crossed `τ_d`
/// (interpolated within the sample's slab, [`RaySample::t_cross`]), else the opacity-weighted
/// mean of its samples ([`RaySample::t_mean`]), `+inf` where the ray gathered nothing — the
/// depth a bake stores, at which a layer composites ([`super::layers`]).
///
/// # Errors
/// As [`raycast`].
pub fn raycast_with_sort_depth(
    volume: &Volume,
    tf: &TransferFunction,
    view: &View,
    options: &RaycastOptions,
) -> Result<(VolumeImage, Vec<f64>), RaycastError> {
    raycast_rays(&VolumeRays::new(volume, tf, options)?, view)
}

/// [`raycast_with_sort_depth`] through prepared rays (a segment of split rays, for one).
///
/// # Errors
/// [`RaycastError::View`] for a bad view.
pub fn raycast_rays(
    rays: &VolumeRays<'_>,
    view: &View,
) -> Result<(VolumeImage, Vec<f64>), RaycastError> {
    let basis = view
        .basis(crate::view::DEFAULT_MAX_VIEW_PX)
        .map_err(|e| RaycastError::View(e.to_string()))?;
    let (width, height) = (basis.width as usize, basis.height as usize);
    let mut rgba = vec![[0.0; 4]; width * height];
    let mut depth = vec![f64::INFINITY; width * height];
    let mut sort = vec![f64::INFINITY; width * height];
    let threads = std::thread::available_parallelism()
        .map_or(1, usize::from)
        .min(height.max(1));
    let rows_per = height.div_ceil(threads.max(1)).max(1);
    let samples: u64 = std::thread::scope(|scope| {
        let mut handles = Vec::new();
        for (band, ((rgba, depth), sort)) in rgba
            .chunks_mut(rows_per * width)
            .zip(depth.chunks_mut(rows_per * width))
            .zip(sort.chunks_mut(rows_per * width))
            .enumerate()
        {
            let basis = &basis;
            handles.push(scope.spawn(move || {
                let mut samples = 0u64;
                for (n, ((out, z), s)) in rgba
                    .iter_mut()
                    .zip(depth.iter_mut())
                    .zip(sort.iter_mut())
                    .enumerate()
                {
                    let i = (band * rows_per + n / width) as u32;
                    let j = (n % width) as u32;
                    let dir = basis.pixel_dir(i, j);
                    let ray = rays.cast(basis.eye.to_array(), dir.to_array());
                    *out = ray.rgba;
                    *z = ray.t_depth * dir.dot(basis.forward);
                    let t = if ray.t_depth.is_finite() {
                        ray.t_cross
                    } else {
                        ray.t_mean
                    };
                    *s = t * dir.dot(basis.forward);
                    samples += ray.samples;
                }
                samples
            }));
        }
        handles.into_iter().map(|h| h.join().unwrap_or(0)).sum()
    });
    Ok((
        VolumeImage {
            width: basis.width,
            height: basis.height,
            rgba,
            depth,
            samples,
        },
        sort,
    ))
}

struct Shading {
    light: DVec3,
    ambient: f64,
    flat_below: f64,
}

struct Ray {
    rgba: [f64; 4],
    /// Ray parameter of the depth sample, `+inf` if none.
    t_depth: f64,
    /// Interpolated τ_d crossing ([`RaySample::t_cross`]).
    t_cross: f64,
    /// Opacity-weighted mean ray parameter ([`RaySample::t_mean`]).
    t_mean: f64,
    samples: u64,
}

/// Index-space access to a volume.
struct Sampler<'a> {
    volume: &'a Volume,
    /// `M⁻¹` row-major.
    inverse: [[f64; 3]; 3],
    dims: [f64; 3],
    /// Gradient offsets along world x, y, z.
    spacing: [f64; 3],
    range: (f64, f64),
}

impl<'a> Sampler<'a> {
    fn new(volume: &'a Volume) -> Self {
        // M column-major → rows; invert by the adjugate (M was checked non-singular on load).
        let m = |r: usize, c: usize| volume.affine[c][r];
        let det = m(0, 0) * (m(1, 1) * m(2, 2) - m(1, 2) * m(2, 1))
            - m(0, 1) * (m(1, 0) * m(2, 2) - m(1, 2) * m(2, 0))
            + m(0, 2) * (m(1, 0) * m(2, 1) - m(1, 1) * m(2, 0));
        let cof = |r: usize, c: usize| {
            let (r1, r2) = ((r + 1) % 3, (r + 2) % 3);
            let (c1, c2) = ((c + 1) % 3, (c + 2) % 3);
            m(r1, c1) * m(r2, c2) - m(r1, c2) * m(r2, c1)
        };
        // inverse[r][c] = cofactor(c, r) / det.
        let inverse = [0, 1, 2].map(|r| [0, 1, 2].map(|c| cof(c, r) / det));
        Self {
            volume,
            inverse,
            dims: volume.dims.map(f64::from),
            // Row norms of M: the voxel extent along each world axis.
            spacing: [0, 1, 2].map(|r| {
                (0..3)
                    .map(|c| volume.affine[c][r] * volume.affine[c][r])
                    .sum::<f64>()
                    .sqrt()
            }),
            range: volume.range(),
        }
    }

    fn to_index(&self, v: DVec3) -> DVec3 {
        let r = &self.inverse;
        DVec3::new(
            r[0][0] * v.x + r[0][1] * v.y + r[0][2] * v.z,
            r[1][0] * v.x + r[1][1] * v.y + r[1][2] * v.z,
            r[2][0] * v.x + r[2][1] * v.y + r[2][2] * v.z,
        )
    }

    /// An upper bound of any chord through the box, world units: `Σ |M_c|·dims_c`.
    fn world_diagonal(&self) -> f64 {
        let columns = self.volume.spacing();
        (0..3).map(|c| columns[c] * self.dims[c]).sum()
    }

    /// `T` at index-space `u`, clamped to the edge voxels.
    fn trilinear(&self, u: DVec3) -> f64 {
        let Voxels::Scalar(v) = &self.volume.voxels else {
            return self.nearest(u);
        };
        let [nx, ny, nz] = self.volume.dims.map(|d| d as usize);
        let clamp = |x: f64, n: f64| x.clamp(0.0, n - 1.0);
        let (x, y, z) = (
            clamp(u.x, self.dims[0]),
            clamp(u.y, self.dims[1]),
            clamp(u.z, self.dims[2]),
        );
        let (x0, y0, z0) = (x.floor() as usize, y.floor() as usize, z.floor() as usize);
        let (fx, fy, fz) = (x - x0 as f64, y - y0 as f64, z - z0 as f64);
        let (x1, y1, z1) = (
            (x0 + 1).min(nx - 1),
            (y0 + 1).min(ny - 1),
            (z0 + 1).min(nz - 1),
        );
        let at = |i: usize, j: usize, k: usize| f64::from(v[i + nx * (j + ny * k)]);
        let lerp = |a: f64, b: f64, t: f64| a + (b - a) * t;
        let c00 = lerp(at(x0, y0, z0), at(x1, y0, z0), fx);
        let c10 = lerp(at(x0, y1, z0), at(x1, y1, z0), fx);
        let c01 = lerp(at(x0, y0, z1), at(x1, y0, z1), fx);
        let c11 = lerp(at(x0, y1, z1), at(x1, y1, z1), fx);
        lerp(lerp(c00, c10, fy), lerp(c01, c11, fy), fz)
    }

    /// The label (or value) of the nearest voxel `clamp(floor(u + ½))`.
    fn nearest(&self, u: DVec3) -> f64 {
        let [nx, ny, _] = self.volume.dims.map(|d| d as usize);
        let pick = |x: f64, n: f64| ((x + 0.5).floor().clamp(0.0, n - 1.0)) as usize;
        let (i, j, k) = (
            pick(u.x, self.dims[0]),
            pick(u.y, self.dims[1]),
            pick(u.z, self.dims[2]),
        );
        let n = i + nx * (j + ny * k);
        match &self.volume.voxels {
            Voxels::Scalar(v) => f64::from(v[n]),
            Voxels::Labels(v) => f64::from(v[n]),
        }
    }

    #[allow(clippy::too_many_arguments)]
    fn march(
        &self,
        tf: &TransferFunction,
        eye: DVec3,
        dir: DVec3,
        step: f64,
        ref_step: f64,
        tau: f64,
        shading: Option<&Shading>,
        segment: Option<&Segment>,
    ) -> Ray {
        let mut ray = Ray {
            rgba: [0.0; 4],
            t_depth: f64::INFINITY,
            t_cross: f64::INFINITY,
            t_mean: f64::INFINITY,
            samples: 0,
        };
        let origin = DVec3::from(self.volume.origin);
        let u0 = self.to_index(eye - origin);
        let ud = self.to_index(dir);
        // Slab test against [−½, dims − ½] per index axis.
        let (mut t_in, mut t_out) = (f64::NEG_INFINITY, f64::INFINITY);
        for a in 0..3 {
            let (lo, hi) = (-0.5, self.dims[a] - 0.5);
            if ud[a] == 0.0 {
                if u0[a] < lo || u0[a] > hi {
                    return ray;
                }
                continue;
            }
            let (t1, t2) = ((lo - u0[a]) / ud[a], (hi - u0[a]) / ud[a]);
            t_in = t_in.max(t1.min(t2));
            t_out = t_out.min(t1.max(t2));
        }
        let t0 = t_in.max(0.0);
        if !(t0 < t_out) {
            return ray;
        }
        let labels = matches!(self.volume.voxels, Voxels::Labels(_));
        // This segment's C and A (the whole ray's when it is not split), and the whole ray's A,
        // which drives the split events and the early stop.
        let (mut c, mut a, mut whole) = (DVec3::ZERO, 0.0, 0.0);
        let (want, boundaries) = segment.map_or((0, 0), |s| (s.index, s.split.boundary_count()));
        let by_label = segment.is_some_and(|s| matches!(s.split, SplitRule::Labels(_)));
        // The last visible label met (label transitions).
        let mut last_label: Option<f64> = None;
        // The segment the next sample belongs to.
        let mut current = 0;
        // Σ (1 − A)·α_k·t_k: with A itself, the opacity-weighted mean t.
        let mut weighted_t = 0.0;
        let mut k = 0u64;
        loop {
            let t = t0 + (k as f64 + 0.5) * step;
            if t >= t_out {
                break;
            }
            k += 1;
            let u = u0 + ud * t;
            let value = if labels {
                self.nearest(u)
            } else {
                self.trilinear(u)
            };
            let [r, g, b, opacity] = tf.eval(value);
            let alpha = opacity_for_step(opacity, step, ref_step);
            if by_label && alpha > 0.0 {
                if last_label.is_some_and(|l| l != value) && current < boundaries {
                    current += 1;
                }
                last_label = Some(value);
                if current > want {
                    break;
                }
            }
            if alpha > 0.0 {
                if current == want {
                    let mut rgb = DVec3::new(r, g, b);
                    if let Some(s) = shading {
                        rgb *= self.shade_factor(eye + dir * t, s);
                    }
                    c += (1.0 - a) * alpha * rgb;
                    weighted_t += (1.0 - a) * alpha * t;
                    let before = a;
                    a += (1.0 - a) * alpha;
                    if a >= tau && ray.t_depth.is_infinite() {
                        ray.t_depth = t;
                        ray.t_cross =
                            t - 0.5 * step + step * ((tau - before) / (a - before)).clamp(0.0, 1.0);
                    }
                }
                whole += (1.0 - whole) * alpha;
                if whole >= EARLY_STOP_ALPHA {
                    break;
                }
            }
            if let Some(s) = segment {
                while current < boundaries && s.split.fires(current, value, whole) {
                    current += 1;
                }
                if current > want {
                    break;
                }
            }
        }
        ray.samples = k;
        ray.rgba = [c.x, c.y, c.z, a];
        if a > 0.0 {
            ray.t_mean = weighted_t / a;
        }
        ray
    }

    /// `ambient + (1 − ambient)·|∇S·ℓ| / |∇S|`, or 1 where the gradient is flat.
    fn shade_factor(&self, p: DVec3, s: &Shading) -> f64 {
        let origin = DVec3::from(self.volume.origin);
        let t = |q: DVec3| self.trilinear(self.to_index(q - origin));
        let axes = [DVec3::X, DVec3::Y, DVec3::Z];
        let g = DVec3::from([0, 1, 2].map(|a| {
            let h = self.spacing[a];
            (t(p + axes[a] * h) - t(p - axes[a] * h)) / (2.0 * h)
        }));
        let min_spacing = self.spacing.iter().copied().fold(f64::INFINITY, f64::min);
        let norm = g.length();
        if norm * min_spacing < s.flat_below || norm == 0.0 {
            return 1.0;
        }
        s.ambient + (1.0 - s.ambient) * g.dot(s.light).abs() / norm
    }
}
