//! Two-plane light fields L(u,v,s,t): the plane description and its geometry, the CPU reference
//! of DESIGN §9 ("Two-plane light fields"), an interface like §3.
//!
//! Two parallel rectangles share the unit, orthogonal in-plane axes `right` and `up`; the normal
//! `n = right × up` points from the st plane towards the uv plane. The uv plane holds a grid of
//! `nu × nv` cameras at the centres of its cells, camera `(a, b)` (column a from the left, row b
//! from the top) at
//! `uv.center + ((a + ½)/nu − ½)·w_uv·right + (½ − (b + ½)/nv)·h_uv·up`; every camera images the st
//! rectangle at `ns × nt` texels, texel (row i, column j) centred on the st point
//! `S = st.center + ((j + ½)/ns − ½)·w_st·right + (½ − (i + ½)/nt)·h_st·up`. A camera's texel
//! records the first surface beyond the camera on the line from `C` through `S`; its stored depth
//! is `|hit − C| / |S − C|` (1 on the st plane, below 1 between the planes).
//!
//! A ray `eye + t·d` (t ≥ 0) of a new view is inside the light field when it meets the closed uv
//! rectangle at `t_uv ≥ 0` and the closed st rectangle at `t_st > t_uv` ([`TwoPlanes::cross`]).
//! Its continuous camera and texel coordinates put camera `(a, b)` and texel `(i, j)` at integer
//! values; the outer half cell and half texel clamp to the edge camera and texel.
//!
//! Refocus (Isaksen et al. 2000): a focal plane parallel to st at signed distance `f` (world
//! units, positive towards the uv plane); each camera is read where the line from it through the
//! ray's point on the focal plane meets st ([`TwoPlanes::focal_lookup`]); `f = 0` reads every
//! camera at the ray's own st crossing (plain quadrilinear interpolation).

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::frame::Frame;
use crate::gpu::mesh::GpuMesh;
use crate::reference::{Projection, ReferenceError, ReferenceRenderer};
use crate::shading::Shading;

/// Most cameras in a uv grid: one GPU array layer per camera, within lavapipe's 2048 layers.
pub const MAX_CAMERAS: u32 = 2048;
/// Largest st resolution per axis, texels.
pub const MAX_ST_RESOLUTION: u32 = 8192;
/// How far `right` and `up` may be from unit length, and their dot product from 0.
pub const AXIS_TOLERANCE: f64 = 1e-6;

/// Why a plane description is refused.
#[derive(Debug, thiserror::Error, PartialEq)]
#[non_exhaustive]
pub enum TwoPlaneError {
    /// The JSON does not parse, or has unknown or missing fields.
    #[error("two-plane JSON: {0}")]
    Json(String),
    /// A coordinate or size is NaN or infinite.
    #[error("{0} must be finite")]
    NotFinite(&'static str),
    /// `right` or `up` is not of unit length.
    #[error("{name} must be a unit vector (length {length})")]
    NotUnit {
        /// `right` or `up`.
        name: &'static str,
        /// Its length.
        length: f64,
    },
    /// `right` and `up` are not orthogonal.
    #[error("right and up must be orthogonal (dot product {0})")]
    NotOrthogonal(f64),
    /// A rectangle's width or height is not positive.
    #[error("{0} size must be positive")]
    Size(&'static str),
    /// The uv grid is empty or has more cameras than one GPU array holds.
    #[error("uv grid {nu}x{nv} must have 1..={max} cameras, each side at least 1", max = MAX_CAMERAS)]
    Grid {
        /// Cameras per row.
        nu: u32,
        /// Rows.
        nv: u32,
    },
    /// The st resolution is out of range.
    #[error("st resolution {ns}x{nt} must be 1..={max} per side", max = MAX_ST_RESOLUTION)]
    Resolution {
        /// Texels per row.
        ns: u32,
        /// Rows.
        nt: u32,
    },
    /// The uv plane does not lie on the normal's side of the st plane.
    #[error(
        "the uv plane must lie on the side of the st plane that right × up points to (signed \
         distance {0}); swap right or up, or the planes"
    )]
    PlaneOrder(f64),
}

/// The uv (camera) rectangle.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct UvPlane {
    /// Centre, world units.
    pub center: [f64; 3],
    /// Width (along `right`) and height (along `up`), world units.
    pub size: [f64; 2],
    /// Cameras per row `nu` and rows `nv`.
    pub grid: [u32; 2],
}

/// The st (image) rectangle.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StPlane {
    /// Centre, world units.
    pub center: [f64; 3],
    /// Width (along `right`) and height (along `up`), world units.
    pub size: [f64; 2],
    /// Texels per row `ns` and rows `nt` of every camera's image.
    pub resolution: [u32; 2],
}

/// The plane description of a two-plane light field (DESIGN §9's JSON, exactly).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TwoPlanes {
    /// Unit in-plane axis, left to right in every camera image.
    pub right: [f64; 3],
    /// Unit in-plane axis, bottom to top; orthogonal to `right`.
    pub up: [f64; 3],
    /// The camera plane.
    pub uv: UvPlane,
    /// The image plane.
    pub st: StPlane,
}

/// Near clipping distance of a capture camera, as a fraction of the plane separation: the
/// capture records the first surface beyond the camera (geometry between the planes included),
/// so only what lies within this sliver in front of the uv plane is lost.
pub const CAPTURE_NEAR_FRACTION: f64 = 1e-6;

/// Where a ray crosses the two planes ([`TwoPlanes::cross`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Crossing {
    /// Ray parameter at the uv plane (≥ 0).
    pub t_uv: f64,
    /// Ray parameter at the st plane (> `t_uv`).
    pub t_st: f64,
    /// Continuous camera column (camera `a` at `a`), clamped to `[0, nu − 1]`.
    pub a: f64,
    /// Continuous camera row (camera `b` at `b`), clamped to `[0, nv − 1]`.
    pub b: f64,
    /// Continuous texel column (texel `j` at `j`), clamped to `[0, ns − 1]`.
    pub j: f64,
    /// Continuous texel row (texel `i` at `i`), clamped to `[0, nt − 1]`.
    pub i: f64,
}

impl TwoPlanes {
    /// Parses and validates DESIGN §9's plane JSON.
    ///
    /// # Errors
    /// [`TwoPlaneError::Json`] for malformed JSON, unknown or missing fields; the
    /// [`Self::validate`] errors.
    pub fn from_json(text: &str) -> Result<TwoPlanes, TwoPlaneError> {
        let planes: TwoPlanes =
            serde_json::from_str(text).map_err(|e| TwoPlaneError::Json(e.to_string()))?;
        planes.validate()?;
        Ok(planes)
    }

    /// Checks the description: finite values, unit and orthogonal axes (within
    /// [`AXIS_TOLERANCE`]), positive sizes, a grid of 1..=[`MAX_CAMERAS`] cameras, an st
    /// resolution of 1..=[`MAX_ST_RESOLUTION`] per side, and the uv plane strictly on the
    /// normal's side of the st plane.
    ///
    /// # Errors
    /// The [`TwoPlaneError`] naming the first violation.
    pub fn validate(&self) -> Result<(), TwoPlaneError> {
        let finite = |v: &[f64], what| {
            if v.iter().all(|x| x.is_finite()) {
                Ok(())
            } else {
                Err(TwoPlaneError::NotFinite(what))
            }
        };
        finite(&self.right, "right")?;
        finite(&self.up, "up")?;
        finite(&self.uv.center, "uv.center")?;
        finite(&self.uv.size, "uv.size")?;
        finite(&self.st.center, "st.center")?;
        finite(&self.st.size, "st.size")?;
        for (name, v) in [("right", self.right), ("up", self.up)] {
            let length = DVec3::from(v).length();
            if (length - 1.0).abs() > AXIS_TOLERANCE {
                return Err(TwoPlaneError::NotUnit { name, length });
            }
        }
        let dot = DVec3::from(self.right).dot(DVec3::from(self.up));
        if dot.abs() > AXIS_TOLERANCE {
            return Err(TwoPlaneError::NotOrthogonal(dot));
        }
        for (name, [w, h]) in [("uv", self.uv.size), ("st", self.st.size)] {
            if !(w > 0.0 && h > 0.0) {
                return Err(TwoPlaneError::Size(name));
            }
        }
        let [nu, nv] = self.uv.grid;
        if nu == 0 || nv == 0 || u64::from(nu) * u64::from(nv) > u64::from(MAX_CAMERAS) {
            return Err(TwoPlaneError::Grid { nu, nv });
        }
        let [ns, nt] = self.st.resolution;
        if !(1..=MAX_ST_RESOLUTION).contains(&ns) || !(1..=MAX_ST_RESOLUTION).contains(&nt) {
            return Err(TwoPlaneError::Resolution { ns, nt });
        }
        let separation = self.separation();
        if !(separation > 0.0 && separation.is_finite()) {
            return Err(TwoPlaneError::PlaneOrder(separation));
        }
        Ok(())
    }

    /// The unit normal `right × up`, from the st plane towards the uv plane (the axes made
    /// exactly orthonormal: `up` is re-orthogonalised against `right`).
    pub fn normal(&self) -> DVec3 {
        let (right, up) = self.axes();
        right.cross(up)
    }

    /// `right` and `up` made exactly orthonormal (Gram–Schmidt; they are within
    /// [`AXIS_TOLERANCE`] of it after validation).
    pub fn axes(&self) -> (DVec3, DVec3) {
        let right = DVec3::from(self.right).normalize();
        let up = DVec3::from(self.up);
        let up = (up - right * right.dot(up)).normalize();
        (right, up)
    }

    /// Signed distance of the uv plane from the st plane along the normal (positive when valid).
    pub fn separation(&self) -> f64 {
        (DVec3::from(self.uv.center) - DVec3::from(self.st.center)).dot(self.normal())
    }

    /// Number of cameras, `nu · nv`.
    pub fn camera_count(&self) -> u32 {
        self.uv.grid[0] * self.uv.grid[1]
    }

    /// Position of camera `(a, b)`: column `a` from the left, row `b` from the top, at the
    /// centre of its uv cell.
    pub fn camera(&self, a: u32, b: u32) -> DVec3 {
        let (right, up) = self.axes();
        let [nu, nv] = self.uv.grid;
        let [w, h] = self.uv.size;
        DVec3::from(self.uv.center)
            + ((f64::from(a) + 0.5) / f64::from(nu) - 0.5) * w * right
            + (0.5 - (f64::from(b) + 0.5) / f64::from(nv)) * h * up
    }

    /// The st point at the centre of texel (row `i`, column `j`).
    pub fn st_point(&self, i: u32, j: u32) -> DVec3 {
        let (right, up) = self.axes();
        let [ns, nt] = self.st.resolution;
        let [w, h] = self.st.size;
        DVec3::from(self.st.center)
            + ((f64::from(j) + 0.5) / f64::from(ns) - 0.5) * w * right
            + (0.5 - (f64::from(i) + 0.5) / f64::from(nt)) * h * up
    }

    /// The surface point of camera `(a, b)`'s texel `(i, j)` with stored depth `depth`
    /// (`C + depth · (S − C)`; depth 1 is on the st plane).
    pub fn hit(&self, a: u32, b: u32, i: u32, j: u32, depth: f64) -> DVec3 {
        let c = self.camera(a, b);
        c + depth * (self.st_point(i, j) - c)
    }

    /// The off-axis pinhole of camera `(a, b)`: it looks along `−normal` from its uv position,
    /// and its `ns × nt` pixels are exactly the st texels (texel `(i, j)`'s centre `S` projects
    /// to the centre of pixel `(i, j)`). Its near distance is [`CAPTURE_NEAR_FRACTION`] of the
    /// separation.
    pub fn projection(&self, a: u32, b: u32) -> Projection {
        let (right, up) = self.axes();
        let forward = -self.normal();
        let eye = self.camera(a, b);
        let distance = self.separation();
        let [ns, nt] = self.st.resolution;
        let [w, h] = self.st.size;
        let focal = [f64::from(ns) * distance / w, f64::from(nt) * distance / h];
        // The st centre relative to the camera, across the view; it projects to the image
        // centre, so the principal point sits opposite it.
        let to_center = DVec3::from(self.st.center) - eye;
        Projection {
            eye,
            right,
            up,
            forward,
            width: ns,
            height: nt,
            focal_px: focal,
            center_px: [
                -focal[0] * to_center.dot(right) / distance,
                -focal[1] * to_center.dot(up) / distance,
            ],
            near: CAPTURE_NEAR_FRACTION * distance,
        }
    }

    /// The stored depth of a surface point `hit` seen by camera `(a, b)` through texel
    /// `(i, j)`: `|hit − C| / |S − C|`.
    pub fn depth_of(&self, a: u32, b: u32, i: u32, j: u32, hit: DVec3) -> f64 {
        let c = self.camera(a, b);
        (hit - c).length() / (self.st_point(i, j) - c).length()
    }

    /// Where the ray `eye + t·dir` (t ≥ 0) crosses the planes, when it is inside the light
    /// field: it meets the closed uv rectangle at `t_uv ≥ 0` and the closed st rectangle at
    /// `t_st > t_uv`. `None` otherwise (parallel to the planes, missing a rectangle, going away
    /// from the st plane, not finite).
    pub fn cross(&self, eye: DVec3, dir: DVec3) -> Option<Crossing> {
        let n = self.normal();
        let along = dir.dot(n);
        if !(along.is_finite() && eye.is_finite()) || along == 0.0 {
            return None;
        }
        let t_at = |center: [f64; 3]| (DVec3::from(center) - eye).dot(n) / along;
        let (t_uv, t_st) = (t_at(self.uv.center), t_at(self.st.center));
        if !(t_uv >= 0.0 && t_st > t_uv && t_st.is_finite()) {
            return None;
        }
        let (right, up) = self.axes();
        // Local coordinates in units of the rectangle's size, (0, 0) at its top-left corner.
        let local = |t: f64, center: [f64; 3], [w, h]: [f64; 2]| {
            let p = eye + t * dir - DVec3::from(center);
            (p.dot(right) / w + 0.5, 0.5 - p.dot(up) / h)
        };
        let inside = |(x, y): (f64, f64)| (0.0..=1.0).contains(&x) && (0.0..=1.0).contains(&y);
        let uv = local(t_uv, self.uv.center, self.uv.size);
        let st = local(t_st, self.st.center, self.st.size);
        if !(inside(uv) && inside(st)) {
            return None;
        }
        let cell =
            |x: f64, n: u32| (x * f64::from(n) - 0.5).clamp(0.0, f64::from(n.saturating_sub(1)));
        Some(Crossing {
            t_uv,
            t_st,
            a: cell(uv.0, self.uv.grid[0]),
            b: cell(uv.1, self.uv.grid[1]),
            j: cell(st.0, self.st.resolution[0]),
            i: cell(st.1, self.st.resolution[1]),
        })
    }

    /// Refocus lookup: where camera `(a, b)` is read for a ray whose point on the focal plane
    /// (parallel to st, `focus` world units from it towards the uv plane) is `on_focal`, as
    /// continuous texel coordinates `(i, j)` (not clamped: outside `[−½, n − ½]` the camera does
    /// not see that point). `None` when the line from the camera through the point is parallel
    /// to the planes.
    pub fn focal_lookup(&self, a: u32, b: u32, on_focal: DVec3) -> Option<(f64, f64)> {
        let n = self.normal();
        let c = self.camera(a, b);
        let towards = on_focal - c;
        let along = towards.dot(n);
        if along == 0.0 || !along.is_finite() {
            return None;
        }
        let u = (DVec3::from(self.st.center) - c).dot(n) / along;
        let s = c + u * towards - DVec3::from(self.st.center);
        let (right, up) = self.axes();
        let [w, h] = self.st.size;
        let [ns, nt] = self.st.resolution;
        let j = (s.dot(right) / w + 0.5) * f64::from(ns) - 0.5;
        let i = (0.5 - s.dot(up) / h) * f64::from(nt) - 0.5;
        Some((i, j))
    }

    /// The point where the ray `eye + t·dir` meets the focal plane `focus` world units from the
    /// st plane towards the uv plane; `None` when the ray is parallel to it.
    pub fn focal_point(&self, eye: DVec3, dir: DVec3, focus: f64) -> Option<DVec3> {
        let n = self.normal();
        let along = dir.dot(n);
        if along == 0.0 || !along.is_finite() {
            return None;
        }
        let plane = DVec3::from(self.st.center) + focus * n;
        let t = (plane - eye).dot(n) / along;
        t.is_finite().then(|| eye + t * dir)
    }
}

/// Captures a two-plane light field of `mesh` (DESIGN §9): one off-axis rasterization per camera,
/// row by row from the top-left camera (`b · nu + a`), each an `ns × nt` [`Frame`] whose colour
/// is the shaded surface and whose depth is the stored depth `|hit − C| / |S − C|` (the
/// camera's z-depth over the plane separation, since `S` lies at the separation along the
/// viewing axis), `+inf` where the line meets nothing. `progress(done, total)` after each camera.
///
/// # Errors
/// [`ReferenceError`] for bad shading or a device failure; invalid planes are refused as
/// [`ReferenceError::Projection`] with the reason.
pub fn capture(
    reference: &ReferenceRenderer,
    mesh: &GpuMesh,
    planes: &TwoPlanes,
    shading: &Shading,
    progress: &mut dyn FnMut(u32, u32),
) -> Result<Vec<Frame>, ReferenceError> {
    planes
        .validate()
        .map_err(|e| ReferenceError::Projection(e.to_string()))?;
    let [nu, nv] = planes.uv.grid;
    let total = planes.camera_count();
    let mut frames = Vec::with_capacity(total as usize);
    for b in 0..nv {
        for a in 0..nu {
            frames.push(capture_camera(reference, mesh, planes, (a, b), shading)?);
            progress(b * nu + a + 1, total);
        }
    }
    Ok(frames)
}

/// Camera `(a, b)`'s capture: its off-axis rasterization with the z-depth (world units) turned
/// into the stored depth by dividing by the plane separation (`+inf` stays `+inf`).
fn capture_camera(
    reference: &ReferenceRenderer,
    mesh: &GpuMesh,
    planes: &TwoPlanes,
    (a, b): (u32, u32),
    shading: &Shading,
) -> Result<Frame, ReferenceError> {
    let distance = planes.separation();
    let mut frame = reference.render_projection(mesh, &planes.projection(a, b), shading)?;
    for d in &mut frame.depth {
        *d = (f64::from(*d) / distance) as f32;
    }
    Ok(frame)
}

/// Planes fitted to a bounding sphere (`center`, `radius`): the st plane through the centre,
/// facing `axis` (the side the cameras are on), the uv plane `3·radius` from it, a uv rectangle
/// of `2·radius` square (cameras spread over the object's diameter), and the st rectangle just
/// large enough that every camera sees the whole sphere: half side
/// `(r + u)·D/(D − r) − u` with `u = radius` the uv half side and `D` the separation. `right`
/// and `up` follow world +y as up (world +z when `axis` is along y).
///
/// # Errors
/// [`TwoPlaneError`] for a zero or non-finite axis or radius, and the grid and resolution
/// checks of [`TwoPlanes::validate`].
pub fn fit_planes(
    center: DVec3,
    radius: f64,
    axis: DVec3,
    grid: [u32; 2],
    resolution: [u32; 2],
) -> Result<TwoPlanes, TwoPlaneError> {
    if !(center.is_finite() && axis.is_finite()) {
        return Err(TwoPlaneError::NotFinite("axis"));
    }
    if !(radius.is_finite() && radius > 0.0) {
        return Err(TwoPlaneError::Size("bounding sphere"));
    }
    let n = axis
        .try_normalize()
        .ok_or(TwoPlaneError::NotFinite("axis"))?;
    let world_up = if n.cross(DVec3::Y).length() > 1e-3 {
        DVec3::Y
    } else {
        DVec3::Z
    };
    let up = (world_up - n * n.dot(world_up)).normalize();
    let right = up.cross(n);
    let distance = 3.0 * radius;
    let uv_half = radius;
    let st_half = (radius + uv_half) * distance / (distance - radius) - uv_half;
    let planes = TwoPlanes {
        right: right.to_array(),
        up: up.to_array(),
        uv: UvPlane {
            center: (center + distance * n).to_array(),
            size: [2.0 * uv_half; 2],
            grid,
        },
        st: StPlane {
            center: center.to_array(),
            size: [2.0 * st_half; 2],
            resolution,
        },
    };
    planes.validate()?;
    Ok(planes)
}

/// What [`bake_to_file`] made.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TwoPlaneBakeReport {
    /// Cameras captured.
    pub cameras: u32,
    /// st resolution `[ns, nt]`.
    pub resolution: [u32; 2],
    /// Wall-clock time, ms.
    pub bake_ms: f64,
    /// Bytes of the written asset.
    pub asset_bytes: u64,
    /// Fraction of all texels that hit the mesh.
    pub coverage: f64,
}

/// Why a two-plane bake failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum TwoPlaneBakeError {
    /// Rendering a camera failed (bad shading, device loss, invalid planes).
    #[error(transparent)]
    Render(#[from] ReferenceError),
    /// Writing the asset failed.
    #[error(transparent)]
    Asset(#[from] crate::asset::AssetError),
}

/// Whether a two-plane asset's depth was captured: true for bakes and for imports with depth
/// images, false for an import of colour alone (whose depth is the st plane everywhere, so the
/// depth-corrected filter has nothing to correct with).
pub fn has_captured_depth(header: &crate::asset::AssetHeader) -> bool {
    header.provenance.bake_options["import"]["depth"] != serde_json::Value::Bool(false)
}

/// The colour and depth pages of one captured camera, as the asset stores them: straight RGBA8
/// with alpha 255 where the line hits the mesh and (0, 0, 0, 0) elsewhere, and the depth as
/// little-endian f32 (`+inf` for no hit).
pub fn encode_capture(frame: &Frame) -> (Vec<u8>, Vec<u8>) {
    let mut color = frame.color.clone();
    for (px, d) in color.chunks_exact_mut(4).zip(&frame.depth) {
        if d.is_finite() {
            px[3] = 255;
        } else {
            px.copy_from_slice(&[0; 4]);
        }
    }
    let depth = frame
        .depth
        .iter()
        .flat_map(|d| {
            let d = if d.is_finite() { *d } else { f32::INFINITY };
            d.to_le_bytes()
        })
        .collect();
    (color, depth)
}

/// Captures a two-plane light field of `mesh` ([`capture`], one camera at a time) and writes it
/// to `path` atomically (`.lfa` version 5, kind `two_plane`, docs/format.md §8.7).
/// `provenance.bake_options` is the caller's; the bake time is filled in here.
///
/// # Errors
/// [`TwoPlaneBakeError`]; on error nothing is left at `path`.
pub fn bake_to_file(
    reference: &ReferenceRenderer,
    mesh: &GpuMesh,
    planes: &TwoPlanes,
    shading: &Shading,
    provenance: crate::asset::Provenance,
    path: &std::path::Path,
    progress: &mut dyn FnMut(u32, u32),
) -> Result<TwoPlaneBakeReport, TwoPlaneBakeError> {
    bake_to_file_with(
        reference, mesh, planes, shading, provenance, None, path, progress,
    )
}

/// [`bake_to_file`] with the colour pages block-compressed by `color_codec` (`bc1` or `bc7`;
/// format version 6, docs/format.md §7.1); `None` is [`bake_to_file`].
///
/// # Errors
/// [`TwoPlaneBakeError`] (a codec that does not fit RGBA8 colour, an st resolution that is not
/// whole 4 × 4 blocks); on error nothing is left at `path`.
#[allow(clippy::too_many_arguments)]
pub fn bake_to_file_with(
    reference: &ReferenceRenderer,
    mesh: &GpuMesh,
    planes: &TwoPlanes,
    shading: &Shading,
    provenance: crate::asset::Provenance,
    color_codec: Option<crate::asset::BlockCodec>,
    path: &std::path::Path,
    progress: &mut dyn FnMut(u32, u32),
) -> Result<TwoPlaneBakeReport, TwoPlaneBakeError> {
    let mut header = two_plane_header(planes, provenance)?;
    header.set_compression(crate::asset::Channel::Color, color_codec)?;
    let mut writer = crate::asset::AssetWriter::create(path, header)?;
    let (bake_ms, coverage) = capture_each(
        reference,
        mesh,
        planes,
        shading,
        progress,
        &mut |key, bytes| writer.add_image(key, bytes),
    )?;
    writer.set_bake_ms(bake_ms);
    writer.finish()?;
    Ok(TwoPlaneBakeReport {
        cameras: planes.camera_count(),
        resolution: planes.st.resolution,
        bake_ms,
        asset_bytes: std::fs::metadata(path).map_or(0, |m| m.len()),
        coverage,
    })
}

/// [`bake_to_file`] into memory: the encoded asset and its report.
///
/// # Errors
/// [`TwoPlaneBakeError`].
pub fn bake_to_bytes(
    reference: &ReferenceRenderer,
    mesh: &GpuMesh,
    planes: &TwoPlanes,
    shading: &Shading,
    provenance: crate::asset::Provenance,
    progress: &mut dyn FnMut(u32, u32),
) -> Result<(Vec<u8>, TwoPlaneBakeReport), TwoPlaneBakeError> {
    let header = two_plane_header(planes, provenance)?;
    let mut writer = crate::asset::MemoryWriter::new(header)?;
    let (bake_ms, coverage) = capture_each(
        reference,
        mesh,
        planes,
        shading,
        progress,
        &mut |key, bytes| writer.add_image(key, bytes),
    )?;
    writer.set_bake_ms(bake_ms);
    let bytes = writer.finish()?;
    let report = TwoPlaneBakeReport {
        cameras: planes.camera_count(),
        resolution: planes.st.resolution,
        bake_ms,
        asset_bytes: bytes.len() as u64,
        coverage,
    };
    Ok((bytes, report))
}

fn two_plane_header(
    planes: &TwoPlanes,
    provenance: crate::asset::Provenance,
) -> Result<crate::asset::AssetHeader, TwoPlaneBakeError> {
    planes
        .validate()
        .map_err(|e| ReferenceError::Projection(e.to_string()))?;
    Ok(crate::asset::AssetHeader::new_two_plane(
        *planes,
        crate::asset::DEFAULT_PAGE_SIZE,
        provenance,
    )?)
}

/// Where [`capture_each`] hands each image: a file or an in-memory writer.
type ImageSink<'a> =
    dyn FnMut(crate::asset::ImageKey, &[u8]) -> Result<(), crate::asset::AssetError> + 'a;

/// Captures every camera and hands its colour and depth images to `add`: the wall time (ms)
/// and the fraction of texels that hit.
fn capture_each(
    reference: &ReferenceRenderer,
    mesh: &GpuMesh,
    planes: &TwoPlanes,
    shading: &Shading,
    progress: &mut dyn FnMut(u32, u32),
    add: &mut ImageSink<'_>,
) -> Result<(f64, f64), TwoPlaneBakeError> {
    use crate::asset::{Channel, ImageKey};
    let start = std::time::Instant::now();
    let [nu, nv] = planes.uv.grid;
    let total = planes.camera_count();
    let mut hits = 0u64;
    for b in 0..nv {
        for a in 0..nu {
            let frame = capture_camera(reference, mesh, planes, (a, b), shading)?;
            hits += frame.depth.iter().filter(|d| d.is_finite()).count() as u64;
            let (color, depth) = encode_capture(&frame);
            let camera = b * nu + a;
            add(ImageKey::new(0, 0, camera, Channel::Color), &color)?;
            add(ImageKey::new(0, 0, camera, Channel::Depth), &depth)?;
            progress(camera + 1, total);
        }
    }
    let [ns, nt] = planes.st.resolution;
    let texels = u64::from(total) * u64::from(ns) * u64::from(nt);
    Ok((
        start.elapsed().as_secs_f64() * 1e3,
        hits as f64 / texels as f64,
    ))
}

/// The four cameras (or texels) around a continuous coordinate pair and their bilinear weights,
/// clamped to the grid `n0 × n1` (`x` along the first axis): `[(x0, y0, w), …]`, weights summing
/// to 1. Used for the `bilinear` uv filter and the st lookup alike. An empty grid side counts as
/// one; a NaN coordinate as 0.
pub fn bilinear(x: f64, y: f64, n0: u32, n1: u32) -> [(u32, u32, f64); 4] {
    let (n0, n1) = (n0.max(1), n1.max(1));
    let clamp = |v: f64, n: u32| {
        if v.is_nan() {
            0.0
        } else {
            v.clamp(0.0, f64::from(n - 1))
        }
    };
    let (x, y) = (clamp(x, n0), clamp(y, n1));
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let (x0, y0) = (x0 as u32, y0 as u32);
    let (x1, y1) = ((x0 + 1).min(n0 - 1), (y0 + 1).min(n1 - 1));
    [
        (x0, y0, (1.0 - fx) * (1.0 - fy)),
        (x1, y0, fx * (1.0 - fy)),
        (x0, y1, (1.0 - fx) * fy),
        (x1, y1, fx * fy),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// The example of DESIGN §9's shape: planes facing +z, uv at z = 2, st at z = 0.
    const EXAMPLE: &str = r#"{"right": [1, 0, 0], "up": [0, 1, 0],
        "uv": {"center": [0, 0, 2], "size": [1, 0.5], "grid": [8, 4]},
        "st": {"center": [0, 0, 0], "size": [2, 1], "resolution": [256, 128]}}"#;

    fn example() -> TwoPlanes {
        TwoPlanes::from_json(EXAMPLE).expect("the example is valid")
    }

    /// A valid description turned by an arbitrary rotation, shifted and scaled.
    fn placed(scale: f64, rotation: glam::DQuat, shift: DVec3) -> TwoPlanes {
        let p = example();
        let r = |v: [f64; 3]| (rotation * DVec3::from(v)).to_array();
        let at = |v: [f64; 3]| (rotation * DVec3::from(v) * scale + shift).to_array();
        TwoPlanes {
            right: r(p.right),
            up: r(p.up),
            uv: UvPlane {
                center: at(p.uv.center),
                size: p.uv.size.map(|x| x * scale),
                ..p.uv
            },
            st: StPlane {
                center: at(p.st.center),
                size: p.st.size.map(|x| x * scale),
                ..p.st
            },
        }
    }

    #[test]
    fn the_json_is_exactly_design_9() {
        let p = example();
        assert_eq!(p.uv.grid, [8, 4]);
        assert_eq!(p.st.resolution, [256, 128]);
        assert_eq!(p.camera_count(), 32);
        assert!((p.separation() - 2.0).abs() < 1e-15);
        assert_eq!(p.normal(), DVec3::Z);
        // Round trip through serde.
        let text = serde_json::to_string(&p).expect("json");
        assert_eq!(TwoPlanes::from_json(&text).expect("again"), p);
    }

    #[test]
    fn bad_descriptions_are_refused_with_the_reason() {
        let with = |from: &str, to: &str| {
            assert!(EXAMPLE.contains(from), "{from}");
            TwoPlanes::from_json(&EXAMPLE.replace(from, to))
        };
        assert!(matches!(
            with(r#""grid": [8, 4]"#, r#""grid": [8, 4], "extra": 1"#),
            Err(TwoPlaneError::Json(m)) if m.contains("unknown field")
        ));
        assert!(matches!(
            with(r#""up": [0, 1, 0],"#, ""),
            Err(TwoPlaneError::Json(m)) if m.contains("missing field")
        ));
        assert!(matches!(
            with("[1, 0, 0]", "[1.1, 0, 0]"),
            Err(TwoPlaneError::NotUnit { name: "right", .. })
        ));
        assert!(matches!(
            with("[0, 1, 0]", "[0.6, 0.8, 0]"),
            Err(TwoPlaneError::NotOrthogonal(_))
        ));
        assert!(matches!(
            with("[1, 0.5]", "[0, 0.5]"),
            Err(TwoPlaneError::Size("uv"))
        ));
        assert!(matches!(
            with("[2, 1]", "[2, -1]"),
            Err(TwoPlaneError::Size("st"))
        ));
        assert!(matches!(
            with("[8, 4]", "[0, 4]"),
            Err(TwoPlaneError::Grid { nu: 0, nv: 4 })
        ));
        assert!(matches!(
            with("[8, 4]", "[64, 33]"),
            Err(TwoPlaneError::Grid { nu: 64, nv: 33 })
        ));
        assert!(with("[8, 4]", "[64, 32]").is_ok(), "2048 cameras fit");
        assert!(matches!(
            with("[256, 128]", "[256, 9000]"),
            Err(TwoPlaneError::Resolution { .. })
        ));
        // uv behind st (the normal points the other way), or on it.
        assert!(matches!(
            with("[0, 0, 2]", "[0, 0, -2]"),
            Err(TwoPlaneError::PlaneOrder(d)) if d < 0.0
        ));
        assert!(matches!(
            with("[0, 0, 2]", "[0, 0, 0]"),
            Err(TwoPlaneError::PlaneOrder(_))
        ));
        // JSON has no NaN or inf literals; huge values that overflow are not finite.
        assert!(matches!(
            with("[0, 0, 2]", "[0, 0, 1e400]"),
            Err(TwoPlaneError::Json(_))
        ));
        let mut p = example();
        p.st.center[1] = f64::NAN;
        assert_eq!(p.validate(), Err(TwoPlaneError::NotFinite("st.center")));
        p = example();
        p.uv.size[0] = f64::INFINITY;
        assert_eq!(p.validate(), Err(TwoPlaneError::NotFinite("uv.size")));
    }

    #[test]
    fn cameras_and_texels_sit_at_cell_centres_from_the_top_left() {
        let p = example();
        // 8 × 4 cameras on a 1 × 0.5 rectangle: cells of 0.125; camera (0, 0) top left.
        let c = p.camera(0, 0);
        assert!(
            (c - DVec3::new(-0.4375, 0.1875, 2.0)).length() < 1e-15,
            "{c}"
        );
        let c = p.camera(7, 3);
        assert!(
            (c - DVec3::new(0.4375, -0.1875, 2.0)).length() < 1e-15,
            "{c}"
        );
        let s = p.st_point(0, 0);
        let half = 1.0 / 256.0;
        assert!(
            (s - DVec3::new(-1.0 + half, 0.5 - half, 0.0)).length() < 1e-15,
            "{s}"
        );
        let s = p.st_point(127, 255);
        assert!(
            (s - DVec3::new(1.0 - half, -0.5 + half, 0.0)).length() < 1e-15,
            "{s}"
        );
    }

    #[test]
    fn a_cameras_texel_ray_crosses_at_that_camera_and_texel() {
        let p = example();
        for (a, b, i, j) in [
            (0, 0, 0, 0),
            (3, 2, 64, 100),
            (7, 3, 127, 255),
            (5, 0, 0, 255),
        ] {
            let c = p.camera(a, b);
            let s = p.st_point(i, j);
            // From a point behind the uv plane on the same line, and from the camera itself
            // (t_uv = 0 is inside: a closed rectangle, t ≥ 0).
            for eye in [c - (s - c), c] {
                let x = p.cross(eye, s - c).expect("inside");
                assert!((x.a - f64::from(a)).abs() < 1e-9, "{x:?}");
                assert!((x.b - f64::from(b)).abs() < 1e-9, "{x:?}");
                assert!((x.i - f64::from(i)).abs() < 1e-9, "{x:?}");
                assert!((x.j - f64::from(j)).abs() < 1e-9, "{x:?}");
                assert!((eye + x.t_st * (s - c) - s).length() < 1e-12);
            }
        }
    }

    #[test]
    fn rays_outside_the_light_field_are_empty() {
        let p = example();
        let eye = DVec3::new(0.0, 0.0, 3.0);
        // Parallel to the planes; pointing away; from between the planes or beyond st; past the
        // uv rectangle; past the st rectangle; not finite.
        assert!(p.cross(eye, DVec3::X).is_none());
        assert!(p.cross(eye, DVec3::Z).is_none());
        assert!(p.cross(DVec3::new(0.0, 0.0, 1.0), -DVec3::Z).is_none());
        assert!(p.cross(DVec3::new(0.0, 0.0, -1.0), -DVec3::Z).is_none());
        assert!(p.cross(DVec3::new(0.6, 0.0, 3.0), -DVec3::Z).is_none());
        assert!(
            p.cross(eye, DVec3::new(0.45, 0.0, -1.0)).is_none(),
            "misses st"
        );
        assert!(p.cross(eye, DVec3::new(f64::NAN, 0.0, -1.0)).is_none());
        assert!(
            p.cross(DVec3::new(f64::INFINITY, 0.0, 3.0), -DVec3::Z)
                .is_none()
        );
        // The rectangles are closed: exactly on the uv edge is inside, and clamps to the edge
        // camera; the outer half cell clamps too.
        let edge = p
            .cross(DVec3::new(0.5, 0.25, 3.0), -DVec3::Z)
            .expect("the corner of uv is inside");
        assert_eq!((edge.a, edge.b), (7.0, 0.0));
        let half_cell = p
            .cross(DVec3::new(-0.49, 0.0, 3.0), -DVec3::Z)
            .expect("inside");
        assert_eq!(half_cell.a, 0.0);
    }

    /// Every camera's projection maps each texel centre to that pixel's centre (DESIGN §3's
    /// pixel convention with the off-axis principal point), in any placement.
    #[test]
    fn capture_projections_put_texels_on_pixel_centres() {
        let rotation = glam::DQuat::from_axis_angle(DVec3::new(1.0, 2.0, 0.5).normalize(), 0.7);
        for p in [
            example(),
            placed(1e-3, rotation, DVec3::new(5.0, -2.0, 1.0)),
        ] {
            for (a, b) in [(0, 0), (7, 3), (3, 1)] {
                let pr = p.projection(a, b);
                assert!((pr.near / p.separation() - CAPTURE_NEAR_FRACTION).abs() < 1e-18);
                for (i, j) in [(0, 0), (127, 255), (40, 3)] {
                    let q = p.st_point(i, j) - pr.eye;
                    let z = q.dot(pr.forward);
                    assert!((z - p.separation()).abs() < 1e-9 * p.separation());
                    let col = 0.5 * f64::from(pr.width)
                        + pr.center_px[0]
                        + pr.focal_px[0] * q.dot(pr.right) / z;
                    let row = 0.5 * f64::from(pr.height)
                        - pr.center_px[1]
                        - pr.focal_px[1] * q.dot(pr.up) / z;
                    assert!((col - (f64::from(j) + 0.5)).abs() < 1e-6, "{col} vs {j}");
                    assert!((row - (f64::from(i) + 0.5)).abs() < 1e-6, "{row} vs {i}");
                }
            }
        }
    }

    #[test]
    fn depth_is_the_fraction_of_the_way_to_the_st_plane() {
        let p = example();
        let (a, b, i, j) = (2, 1, 40, 200);
        let s = p.st_point(i, j);
        assert!((p.hit(a, b, i, j, 1.0) - s).length() < 1e-15);
        assert!((p.hit(a, b, i, j, 0.0) - p.camera(a, b)).length() < 1e-15);
        for depth in [0.0, 0.25, 0.999, 1.0, 1.7] {
            let hit = p.hit(a, b, i, j, depth);
            assert!(
                (p.depth_of(a, b, i, j, hit) - depth).abs() < 1e-12,
                "{depth}"
            );
        }
    }

    #[test]
    fn refocus_reads_every_camera_at_the_projection_of_the_focal_point() {
        let p = example();
        let eye = DVec3::new(0.1, 0.05, 3.0);
        let dir = DVec3::new(-0.05, 0.02, -1.0);
        // f = 0: every camera reads the ray's own st crossing.
        let x = p.cross(eye, dir).expect("inside");
        let q = p.focal_point(eye, dir, 0.0).expect("not parallel");
        for (a, b) in [(0, 0), (4, 2), (7, 3)] {
            let (i, j) = p.focal_lookup(a, b, q).expect("lookup");
            assert!((i - x.i).abs() < 1e-9 && (j - x.j).abs() < 1e-9);
        }
        // f ≠ 0: the line from each camera through its lookup passes through the focal point.
        for focus in [-0.5, 0.3, 1.5] {
            let q = p.focal_point(eye, dir, focus).expect("not parallel");
            assert!((q.z - focus).abs() < 1e-12);
            for (a, b) in [(0, 0), (4, 2), (7, 3)] {
                let (i, j) = p.focal_lookup(a, b, q).expect("lookup");
                let c = p.camera(a, b);
                // The continuous texel back to a world point on st.
                let [w, h] = p.st.size;
                let s = DVec3::new(
                    ((j + 0.5) / 256.0 - 0.5) * w,
                    (0.5 - (i + 0.5) / 128.0) * h,
                    0.0,
                );
                let off_line = (s - c).normalize().cross((q - c).normalize()).length();
                assert!(off_line < 1e-12, "{focus} ({a}, {b}): {off_line}");
            }
        }
        assert!(p.focal_point(eye, DVec3::X, 0.0).is_none());
    }

    #[test]
    fn bilinear_weights_sum_to_one_and_clamp_at_the_edges() {
        let w = bilinear(2.25, 0.5, 8, 4);
        assert_eq!((w[0].0, w[0].1, w[3].0, w[3].1), (2, 0, 3, 1));
        assert!((w.iter().map(|x| x.2).sum::<f64>() - 1.0).abs() < 1e-15);
        assert!((w[0].2 - 0.375).abs() < 1e-15 && (w[3].2 - 0.125).abs() < 1e-15);
        // Past the last camera: all weight on it.
        let edge = bilinear(9.0, -3.0, 8, 4);
        let total: f64 = edge
            .iter()
            .filter(|x| (x.0, x.1) == (7, 0))
            .map(|x| x.2)
            .sum();
        assert!((total - 1.0).abs() < 1e-15, "{edge:?}");
        // A 1 × 1 grid.
        let one = bilinear(0.4, 0.7, 1, 1);
        assert!(one.iter().all(|x| (x.0, x.1) == (0, 0)));
    }

    proptest! {
        /// Placement, rotation and scale (1e-6 to 1e6 world units) do not change where a
        /// camera's texel ray crosses: the coordinates are relative to the planes (tolerance
        /// 1e-6 of a cell, f64 rounding of positions up to 1e6 with cells of 1e-7 of them).
        #[test]
        fn crossings_do_not_depend_on_placement(
            scale_exp in -6.0f64..6.0,
            axis in (-1.0f64..1.0, -1.0f64..1.0, 0.1f64..1.0),
            angle in -3.0f64..3.0,
            shift in (-10.0f64..10.0, -10.0f64..10.0, -10.0f64..10.0),
            a in 0u32..8, b in 0u32..4, i in 0u32..128, j in 0u32..256,
        ) {
            let scale = 10f64.powf(scale_exp);
            let rotation = glam::DQuat::from_axis_angle(
                DVec3::new(axis.0, axis.1, axis.2).normalize(), angle);
            let p = placed(scale, rotation, DVec3::new(shift.0, shift.1, shift.2) * scale);
            prop_assert!(p.validate().is_ok(), "{:?}", p.validate());
            let c = p.camera(a, b);
            let s = p.st_point(i, j);
            let x = p.cross(c - 0.5 * (s - c), s - c).expect("inside");
            prop_assert!((x.a - f64::from(a)).abs() < 1e-6, "{:?}", x);
            prop_assert!((x.b - f64::from(b)).abs() < 1e-6, "{:?}", x);
            prop_assert!((x.i - f64::from(i)).abs() < 1e-6, "{:?}", x);
            prop_assert!((x.j - f64::from(j)).abs() < 1e-6, "{:?}", x);
        }
    }
}
