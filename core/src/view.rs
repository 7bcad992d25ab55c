//! The view description shared by every front (DESIGN §3) and the pinhole ray model it defines.

use glam::DVec3;
use serde::{Deserialize, Serialize};

/// Largest width or height a view may ask for unless a caller sets its own cap.
pub const DEFAULT_MAX_VIEW_PX: u32 = 8192;

/// Errors in a view description.
#[derive(Debug, thiserror::Error, PartialEq)]
#[non_exhaustive]
pub enum ViewError {
    /// A number in the view is NaN or infinite.
    #[error("view field `{0}` must be a finite number")]
    NotFinite(&'static str),
    /// `yfov_deg` outside the open interval (0, 180).
    #[error("yfov_deg must be in (0, 180), got {0}")]
    BadFov(f64),
    /// Width or height is zero or above the cap.
    #[error("view size {width}x{height} is out of range: each side must be in 1..={max}")]
    BadSize {
        /// Requested width.
        width: u32,
        /// Requested height.
        height: u32,
        /// The cap in force.
        max: u32,
    },
    /// `eye` equals `target`, so there is no viewing direction.
    #[error("view eye and target coincide: there is no viewing direction")]
    EyeIsTarget,
    /// `up` is zero or parallel to the viewing direction.
    #[error("view up vector is zero or parallel to the viewing direction")]
    BadUp,
    /// The JSON could not be parsed as a view or a list of views.
    #[error("invalid view JSON: {0}")]
    Json(String),
}

fn default_up() -> [f64; 3] {
    [0.0, 1.0, 0.0]
}

/// A pinhole view: `{"eye","target","up","yfov_deg","width","height"}` in the input's world
/// coordinates. `up` defaults to +y.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct View {
    /// Eye position, world units.
    pub eye: [f64; 3],
    /// Point looked at, world units.
    pub target: [f64; 3],
    /// Approximate up direction; made orthogonal to the viewing direction.
    #[serde(default = "default_up")]
    pub up: [f64; 3],
    /// Vertical field of view in degrees, in (0, 180).
    pub yfov_deg: f64,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
}

/// A validated view with its orthonormal basis (DESIGN §3).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ViewBasis {
    /// Eye position.
    pub eye: DVec3,
    /// `normalize(target - eye)`.
    pub forward: DVec3,
    /// `normalize(forward × up)`.
    pub right: DVec3,
    /// `right × forward`.
    pub true_up: DVec3,
    /// Focal length in pixels: `(H/2) / tan(yfov/2)`.
    pub focal_px: f64,
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
}

impl View {
    /// A view looking from `eye` at `target` with +y up.
    pub fn look_at(
        eye: [f64; 3],
        target: [f64; 3],
        yfov_deg: f64,
        width: u32,
        height: u32,
    ) -> Self {
        Self {
            eye,
            target,
            up: default_up(),
            yfov_deg,
            width,
            height,
        }
    }

    /// Checks every field and derives the basis; `max_px` caps width and height.
    pub fn basis(&self, max_px: u32) -> Result<ViewBasis, ViewError> {
        for (name, v) in [("eye", self.eye), ("target", self.target), ("up", self.up)] {
            if v.iter().any(|x| !x.is_finite()) {
                return Err(ViewError::NotFinite(name));
            }
        }
        if !self.yfov_deg.is_finite() {
            return Err(ViewError::NotFinite("yfov_deg"));
        }
        if !(self.yfov_deg > 0.0 && self.yfov_deg < 180.0) {
            return Err(ViewError::BadFov(self.yfov_deg));
        }
        if self.width == 0 || self.height == 0 || self.width > max_px || self.height > max_px {
            return Err(ViewError::BadSize {
                width: self.width,
                height: self.height,
                max: max_px,
            });
        }
        let eye = DVec3::from(self.eye);
        let delta = DVec3::from(self.target) - eye;
        let scale = eye
            .abs()
            .max_element()
            .max(DVec3::from(self.target).abs().max_element())
            .max(f64::MIN_POSITIVE);
        if !(delta.length() > scale * 1e-12) {
            return Err(ViewError::EyeIsTarget);
        }
        let forward = delta.normalize();
        let up = DVec3::from(self.up);
        if !(up.length() > 0.0) {
            return Err(ViewError::BadUp);
        }
        let cross = forward.cross(up.normalize());
        if !(cross.length() > 1e-9) {
            return Err(ViewError::BadUp);
        }
        let right = cross.normalize();
        let true_up = right.cross(forward);
        let focal_px = (f64::from(self.height) / 2.0) / (self.yfov_deg.to_radians() / 2.0).tan();
        Ok(ViewBasis {
            eye,
            forward,
            right,
            true_up,
            focal_px,
            width: self.width,
            height: self.height,
        })
    }

    /// Parses either one view object or a JSON list of views.
    pub fn parse_many(json: &str) -> Result<Vec<View>, ViewError> {
        let value: serde_json::Value =
            serde_json::from_str(json).map_err(|e| ViewError::Json(e.to_string()))?;
        let views = if value.is_array() {
            serde_json::from_value::<Vec<View>>(value)
        } else {
            serde_json::from_value::<View>(value).map(|v| vec![v])
        }
        .map_err(|e| ViewError::Json(e.to_string()))?;
        Ok(views)
    }
}

impl ViewBasis {
    /// Unit direction of pixel (row `i` from the top, column `j`), sampled at the pixel centre.
    pub fn pixel_dir(&self, i: u32, j: u32) -> DVec3 {
        let x = (f64::from(j) + 0.5 - f64::from(self.width) / 2.0) / self.focal_px;
        let y = -(f64::from(i) + 0.5 - f64::from(self.height) / 2.0) / self.focal_px;
        (x * self.right + y * self.true_up + self.forward).normalize()
    }

    /// Diameter in pixels of the image of a sphere (`center`, `radius`, world units) seen from
    /// the eye: `2·f·r / √(d² − r²)` for an eye at distance `d > r` (the cone of tangent rays,
    /// measured across its axis, so it does not change as the view turns); infinite with the
    /// eye inside or on the sphere.
    pub fn projected_diameter_px(&self, center: DVec3, radius: f64) -> f64 {
        let d = (center - self.eye).length();
        if !(d > radius) {
            return f64::INFINITY;
        }
        let px = 2.0 * self.focal_px * radius / ((d - radius) * (d + radius)).sqrt();
        if px.is_nan() { f64::INFINITY } else { px }
    }
}

/// Distance of the evaluation orbit's eye from the object's centre, in bounding radii.
pub const EVALUATION_DISTANCE_RADII: f64 = 2.5;
/// Vertical field of view of the evaluation views, degrees.
pub const EVALUATION_YFOV_DEG: f64 = 40.0;

/// The evaluation orbit every measurement uses (`eval`, calibration, reports): `n` square views
/// of `size_px` with the eye uniformly random (from `seed`) at [`EVALUATION_DISTANCE_RADII`]
/// bounding radii from `center`, looking at it with a [`EVALUATION_YFOV_DEG`] field of view.
pub fn evaluation_views(
    center: [f64; 3],
    radius: f64,
    n: usize,
    seed: u64,
    size_px: u32,
) -> Vec<View> {
    random_orbit_views(
        center,
        EVALUATION_DISTANCE_RADII * radius,
        n,
        seed,
        EVALUATION_YFOV_DEG,
        size_px,
    )
}

/// `n` views with the eye uniformly random on a sphere of radius `distance` around `center`,
/// looking at `center` (the `eval` default: distance 2.5 × bounding radius, 40°, 256×256).
pub fn random_orbit_views(
    center: [f64; 3],
    distance: f64,
    n: usize,
    seed: u64,
    yfov_deg: f64,
    size_px: u32,
) -> Vec<View> {
    use rand::{RngExt, SeedableRng};
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
    let c = DVec3::from(center);
    (0..n)
        .map(|_| {
            // Uniform on the sphere: z uniform in [-1,1], azimuth uniform.
            let z: f64 = rng.random_range(-1.0..1.0);
            let phi: f64 = rng.random_range(0.0..std::f64::consts::TAU);
            let s = (1.0 - z * z).max(0.0).sqrt();
            let dir = DVec3::new(s * phi.cos(), z, s * phi.sin());
            let eye = c + dir * distance;
            // +y up unless the eye is (almost) straight above or below.
            let up = if dir.y.abs() > 0.99 {
                [0.0, 0.0, 1.0]
            } else {
                [0.0, 1.0, 0.0]
            };
            View {
                eye: eye.to_array(),
                target: center,
                up,
                yfov_deg,
                width: size_px,
                height: size_px,
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn view() -> View {
        View::look_at([0.0, 0.0, 5.0], [0.0, 0.0, 0.0], 40.0, 64, 48)
    }

    #[test]
    fn basis_is_orthonormal_and_right_handed() {
        let b = view().basis(DEFAULT_MAX_VIEW_PX).unwrap();
        assert!((b.forward - DVec3::new(0.0, 0.0, -1.0)).length() < 1e-12);
        assert!((b.right - DVec3::new(1.0, 0.0, 0.0)).length() < 1e-12);
        assert!((b.true_up - DVec3::new(0.0, 1.0, 0.0)).length() < 1e-12);
    }

    #[test]
    fn pixel_rays_follow_design_convention() {
        let v = View::look_at([0.0, 0.0, 5.0], [0.0, 0.0, 0.0], 90.0, 2, 2);
        let b = v.basis(64).unwrap();
        // f = 1 / tan(45°) = 1: the top-left pixel centre is at x = -0.5, y = +0.5.
        let d = b.pixel_dir(0, 0);
        let want = DVec3::new(-0.5, 0.5, -1.0).normalize();
        assert!((d - want).length() < 1e-12);
    }

    #[test]
    fn rejects_bad_views() {
        let mut v = view();
        v.eye[1] = f64::NAN;
        assert_eq!(v.basis(64), Err(ViewError::NotFinite("eye")));
        let mut v = view();
        v.yfov_deg = 180.0;
        assert!(matches!(v.basis(64), Err(ViewError::BadFov(_))));
        let mut v = view();
        v.width = 0;
        assert!(matches!(v.basis(64), Err(ViewError::BadSize { .. })));
        let mut v = view();
        v.width = 65;
        assert!(matches!(v.basis(64), Err(ViewError::BadSize { .. })));
        let mut v = view();
        v.target = v.eye;
        assert_eq!(v.basis(64), Err(ViewError::EyeIsTarget));
        let mut v = view();
        v.up = [0.0, 0.0, 2.0];
        assert_eq!(v.basis(64), Err(ViewError::BadUp));
        v.up = [0.0; 3];
        assert_eq!(v.basis(64), Err(ViewError::BadUp));
    }

    #[test]
    fn parses_one_or_many() {
        let one = r#"{"eye":[0,0,5],"target":[0,0,0],"yfov_deg":40,"width":8,"height":8}"#;
        assert_eq!(View::parse_many(one).unwrap().len(), 1);
        let many = format!("[{one},{one}]");
        assert_eq!(View::parse_many(&many).unwrap().len(), 2);
        assert!(View::parse_many(r#"{"eye":[0,0]}"#).is_err());
        assert!(
            View::parse_many(
                r#"{"eye":[0,0,5],"target":[0,0,0],"yfov_deg":40,"width":8,"height":8,"zoom":1}"#
            )
            .is_err()
        );
    }

    #[test]
    fn projected_diameter_matches_tangent_rays() {
        // Eye on +z at distance d, sphere radius r at the origin, looking at it: the tangent
        // ray's angle is asin(r / d), so the image radius is f · tan(asin(r / d)).
        let view = View::look_at([0.0, 0.0, 5.0], [0.0, 0.0, 0.0], 40.0, 256, 256);
        let basis = view.basis(4096).expect("view");
        let px = basis.projected_diameter_px(DVec3::ZERO, 2.0);
        let expected = 2.0 * basis.focal_px * (2.0_f64 / 5.0).asin().tan();
        assert!(
            (px - expected).abs() < 1e-9 * expected,
            "{px} vs {expected}"
        );
        // Turning the view does not change it; the eye inside or on the sphere gives infinity.
        let turned = View::look_at([0.0, 0.0, 5.0], [3.0, 1.0, 0.0], 40.0, 256, 256);
        let px2 = turned
            .basis(4096)
            .expect("view")
            .projected_diameter_px(DVec3::ZERO, 2.0);
        assert!((px2 - px).abs() < 1e-9 * px);
        assert!(basis.projected_diameter_px(DVec3::ZERO, 5.0).is_infinite());
        assert!(basis.projected_diameter_px(DVec3::ZERO, 6.0).is_infinite());
        // Scale invariance at the extremes: 1e-4 and 1e4 scenes project the same.
        for s in [1e-4, 1e4] {
            let v = View::look_at([0.0, 0.0, 5.0 * s], [0.0, 0.0, 0.0], 40.0, 256, 256);
            let p = v
                .basis(4096)
                .expect("view")
                .projected_diameter_px(DVec3::ZERO, 2.0 * s);
            assert!((p - px).abs() < 1e-9 * px, "scale {s}: {p}");
        }
    }

    #[test]
    fn evaluation_views_orbit_at_two_and_a_half_radii() {
        let views = evaluation_views([1.0, 0.0, 0.0], 2.0, 3, 5, 64);
        assert_eq!(
            views,
            random_orbit_views([1.0, 0.0, 0.0], 5.0, 3, 5, 40.0, 64)
        );
    }

    #[test]
    fn random_views_are_deterministic_and_on_the_sphere() {
        let a = random_orbit_views([1.0, 2.0, 3.0], 2.5, 10, 7, 40.0, 256);
        let b = random_orbit_views([1.0, 2.0, 3.0], 2.5, 10, 7, 40.0, 256);
        assert_eq!(a, b);
        for v in &a {
            let d = (DVec3::from(v.eye) - DVec3::new(1.0, 2.0, 3.0)).length();
            assert!((d - 2.5).abs() < 1e-12);
            v.basis(DEFAULT_MAX_VIEW_PX).unwrap();
        }
    }
}
