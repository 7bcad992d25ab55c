//! Light states (DESIGN §9, seed 000 §3.3): an asset baked for many light directions, relit at
//! render time for any direction between them.
//!
//! A bake with `lights = N` (12, 42 or 162) stores, next to the base state (the bake's own light,
//! colour and depth), one state `ambient` holding `albedo · ambient`, one state `normal` holding
//! the shading normal, and one state per direction `ℓ_i` of a light proxy (the nested
//! icosphere's level with N vertices, in the asset frame) holding the rest of the DESIGN §9
//! colour for that light, `albedo·(1−ambient)·V_i·max(0, n·ℓ_i) + ks·V_i·max(0, n·h_i)^s`.
//! The light states hold colour (or the normal) only: depth does not depend on the light, so
//! they fall back to the base state's depth (docs/format.md §8.6).
//!
//! A light `ℓ` between the proxy's directions renders as `ambient + Σ w_i · direct_i` over the
//! proxy triangle around `ℓ`, with `w` solving `Σ w_i ℓ_i = ℓ` ([`Blend::Spherical`]): every
//! weight is ≥ 0 inside the triangle, and the diffuse term of a point that all three lights reach
//! (`n·ℓ_i > 0`, unshadowed) is exact, `n · Σ w_i ℓ_i = n·ℓ`. Planar barycentric weights
//! ([`Blend::Planar`], `w / Σ w`, summing to 1) blend the whole colour instead; they darken that
//! diffuse term by `1 − |Σ w_i ℓ_i|`: 20.5 %, 6.8 % and 1.8 % at the centres of 12-, 42- and
//! 162-direction triangles (DESIGN §9; [`centroid_darkening`]). Where some of the three lights
//! face away from the point (the terminator), the clamped terms no longer add up to `n·ℓ`; the
//! default [`Blend::Normal`] scales the sum by `max(0, n·ℓ) / Σ w_i max(0, n·ℓ_i)` from the
//! stored normal, which makes every unshadowed point exact. What remains is the shadows'
//! interpolation: three shadows blended where the truth has one.
//!
//! For assets baked with shadows, the renderer removes that too (`Switches::shadow_rays`, on by
//! default; shaders/render/probe.wgsl `relit_texel`, shade.wgsl `shadow_visible`). A texel is
//! *contested* where, among the proxy lights that weigh in, some light it and some face it but
//! leave it dark. On contested texels the direct part is either 0 or the lit proxies'
//! `albedo·(1−ambient)` (their direct parts over their cosines) times `max(0, n·ℓ)`, and a
//! shadow ray decides which: the ray from outside the camera sphere to the shaded point,
//! against the light, marched through the light field like an eye's ray (the cameras around
//! `ℓ` see what the light sees). It is shadowed where the march meets a surface more than one
//! step before the point. Uncontested texels keep the blend, so a frame at a proxy direction is
//! unchanged and a ray is marched only where shadows move between the proxies (docs/marcher.md).

use std::str::FromStr;

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::asset::{AssetHeader, StateDesc};
use crate::geometry;

/// Light-proxy sizes a bake accepts: the icosphere levels 0–2. Level 3 (642 directions) would
/// exceed the format's 256 states.
pub const LIGHT_COUNTS: [u32; 3] = [12, 42, 162];

/// `StateDesc::params` key naming which part of the colour a light state holds.
pub const PART_KEY: &str = "light_part";
/// `StateDesc::params` key of a direct state's proxy direction (unit, asset frame).
pub const LIGHT_KEY: &str = "light";
/// Name of the ambient state.
pub const AMBIENT_STATE: &str = "ambient";
/// Name of the shading-normal state.
pub const NORMAL_STATE: &str = "normal";

/// Errors of light states and light requests.
#[derive(Debug, thiserror::Error, PartialEq)]
#[non_exhaustive]
pub enum LightError {
    /// A light direction of zero length or with a NaN or infinite component.
    #[error("light {0:?} must be a finite, non-zero direction")]
    BadDirection([f64; 3]),
    /// A light-proxy size that is not an icosphere level.
    #[error("lights {0}: use 12, 42 or 162 directions")]
    BadCount(u32),
    /// A light asked of an asset baked without light states.
    #[error(
        "the asset has no light states: bake it with `--lights 12|42|162` (lights= in Python, \
         \"lights\" in an HTTP bake) to relight it"
    )]
    NoLightStates,
    /// Light states that do not follow docs/format.md.
    #[error("light states: {0}")]
    BadStates(String),
}

/// A world-space light direction (towards the light, any non-zero length), as a request gives
/// it: `X,Y,Z` on the command line, `[x, y, z]` in JSON.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(transparent)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct LightDirection(pub [f64; 3]);

impl LightDirection {
    /// The unit direction.
    ///
    /// # Errors
    /// [`LightError::BadDirection`] for a zero, NaN or infinite direction.
    pub fn unit(&self) -> Result<DVec3, LightError> {
        let v = DVec3::from(self.0);
        let len = v.length();
        if !v.is_finite() || !(len > 1e-12) || !len.is_finite() {
            return Err(LightError::BadDirection(self.0));
        }
        Ok(v / len)
    }
}

impl FromStr for LightDirection {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        let parts: Vec<&str> = s.split(',').map(str::trim).collect();
        let [x, y, z] = parts[..] else {
            return Err(format!("light {s:?}: give X,Y,Z"));
        };
        let parse = |t: &str| {
            t.parse::<f64>()
                .map_err(|_| format!("light {s:?}: {t:?} is not a number"))
        };
        let light = LightDirection([parse(x)?, parse(y)?, parse(z)?]);
        light.unit().map_err(|e| e.to_string())?;
        Ok(light)
    }
}

/// How a light between the proxy's directions blends their states.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Blend {
    /// The default: [`Blend::Spherical`]'s sum scaled per texel by the cosine ratio of the
    /// stored shading normal n, `max(0, n·ℓ) / Σ w_i max(0, n·ℓ_i)` (at most 1). It leaves a
    /// texel all three lights reach unchanged and makes one some of them face away from exact
    /// (the terminator); what remains is the shadows' interpolation. Assets without a normal
    /// state blend as [`Blend::Spherical`].
    #[default]
    Normal,
    /// `ambient + Σ w_i direct_i` with `Σ w_i ℓ_i = ℓ` (see the module doc).
    Spherical,
    /// Planar barycentric weights `w / Σ w` (summing to 1): the baseline DESIGN §9 measures.
    Planar,
}

/// The proxy triangle around a light and the weight of each of its directions.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LightBlend {
    /// Proxy direction indices of the triangle's corners.
    pub directions: [u32; 3],
    /// Those directions (unit, asset frame).
    pub vectors: [DVec3; 3],
    /// Their weights (≥ 0).
    pub weights: [f64; 3],
}

/// The icosphere level with `count` vertices, for a light proxy.
pub fn proxy_level(count: u32) -> Option<u32> {
    LIGHT_COUNTS
        .iter()
        .position(|&c| c == count)
        .map(|l| l as u32)
}

/// The proxy's directions (unit, asset frame): the icosphere's vertices of its level.
pub fn proxy_directions(count: u32) -> Result<Vec<DVec3>, LightError> {
    let level = proxy_level(count).ok_or(LightError::BadCount(count))?;
    Ok(geometry::camera_set()
        .positions_for_level(level)
        .iter()
        .map(|p| p.as_dvec3().normalize())
        .collect())
}

/// The proxy's triangles (direction indices).
fn proxy_triangles(count: u32) -> Result<Vec<[u32; 3]>, LightError> {
    let level = proxy_level(count).ok_or(LightError::BadCount(count))?;
    Ok(geometry::camera_set()
        .level_triangles(level)
        .iter()
        .map(|t| t.v)
        .collect())
}

/// `w` with `w.x·a + w.y·b + w.z·c = l` (Cramer's rule), or `None` for a degenerate triangle.
fn decompose(l: DVec3, a: DVec3, b: DVec3, c: DVec3) -> Option<[f64; 3]> {
    let det = a.dot(b.cross(c));
    if det.abs() < 1e-15 {
        return None;
    }
    Some([
        l.dot(b.cross(c)) / det,
        a.dot(l.cross(c)) / det,
        a.dot(b.cross(l)) / det,
    ])
}

/// The proxy triangle around unit direction `l` (asset frame) of a `count`-direction proxy and
/// its weights under `blend`. A direction on an edge or vertex takes one of the triangles that
/// share it, with the same weights.
///
/// # Errors
/// [`LightError::BadCount`] for a count not in [`LIGHT_COUNTS`], [`LightError::BadDirection`]
/// for a direction that is not finite and unit (within 1e-6).
pub fn blend_for(count: u32, l: DVec3, blend: Blend) -> Result<LightBlend, LightError> {
    if !l.is_finite() || (l.length() - 1.0).abs() > 1e-6 {
        return Err(LightError::BadDirection(l.to_array()));
    }
    let dirs = proxy_directions(count)?;
    let mut best: Option<(f64, [u32; 3], [f64; 3])> = None;
    for t in proxy_triangles(count)? {
        let [a, b, c] = t.map(|i| dirs[i as usize]);
        // Only the triangle's own cone (the one facing l), not the opposite one.
        if (a + b + c).dot(l) <= 0.0 {
            continue;
        }
        let Some(w) = decompose(l, a, b, c) else {
            continue;
        };
        let least = w[0].min(w[1]).min(w[2]);
        if best.as_ref().is_none_or(|(m, _, _)| least > *m) {
            best = Some((least, t, w));
        }
    }
    let (_, directions, w) = best.ok_or(LightError::BadDirection(l.to_array()))?;
    // Inside the triangle every weight is ≥ 0; rounding at an edge may leave −1e-16.
    let w = w.map(|x| x.max(0.0));
    let weights = match blend {
        Blend::Spherical | Blend::Normal => w,
        Blend::Planar => {
            let sum = w[0] + w[1] + w[2];
            w.map(|x| x / sum)
        }
    };
    Ok(LightBlend {
        directions,
        vectors: directions.map(|i| dirs[i as usize]),
        weights,
    })
}

/// The unit centres of the proxy's triangles: the lights farthest from every proxy direction,
/// where blending errs most (the benchmark's worst-case lights).
///
/// # Errors
/// [`LightError::BadCount`].
pub fn centroid_lights(count: u32) -> Result<Vec<DVec3>, LightError> {
    let dirs = proxy_directions(count)?;
    Ok(proxy_triangles(count)?
        .iter()
        .map(|t| {
            t.iter()
                .map(|&i| dirs[i as usize])
                .sum::<DVec3>()
                .normalize()
        })
        .collect())
}

/// The largest loss of the diffuse term under planar weights at a triangle centre of a
/// `count`-direction proxy, `1 − |Σ w_i ℓ_i|` (0 under [`Blend::Spherical`]).
///
/// # Errors
/// [`LightError::BadCount`].
pub fn centroid_darkening(count: u32) -> Result<f64, LightError> {
    let mut worst = 0.0_f64;
    for l in centroid_lights(count)? {
        let b = blend_for(count, l, Blend::Planar)?;
        let blended: DVec3 = (0..3).map(|i| b.weights[i] * b.vectors[i]).sum();
        worst = worst.max(1.0 - blended.length());
    }
    Ok(worst)
}

/// The states a bake with `count` light directions adds after the base state: `ambient`,
/// `normal`, then `light_<i>` for proxy direction i.
///
/// # Errors
/// [`LightError::BadCount`].
pub fn state_descs(count: u32) -> Result<Vec<StateDesc>, LightError> {
    let mut out = vec![
        StateDesc {
            name: AMBIENT_STATE.to_owned(),
            params: serde_json::Map::from_iter([(PART_KEY.to_owned(), "ambient".into())]),
        },
        StateDesc {
            name: NORMAL_STATE.to_owned(),
            params: serde_json::Map::from_iter([(PART_KEY.to_owned(), "normal".into())]),
        },
    ];
    for (i, d) in proxy_directions(count)?.iter().enumerate() {
        out.push(StateDesc {
            name: format!("light_{i}"),
            params: serde_json::Map::from_iter([
                (PART_KEY.to_owned(), "direct".into()),
                (LIGHT_KEY.to_owned(), serde_json::json!(d.to_array())),
            ]),
        });
    }
    Ok(out)
}

/// The unit normal a normal state's RGBA8 texel holds: an octahedral map point with 16 bits per
/// coordinate, x in bytes 0 (high) and 1 (low), y in bytes 2 and 3 (docs/format.md §8.6; the
/// bake's `oct_encode16`, the renderer's `oct_decode16`).
pub fn decode_normal(texel: [u8; 4]) -> DVec3 {
    let coord = |hi: u8, lo: u8| f64::from(u16::from_be_bytes([hi, lo])) / 65535.0 * 2.0 - 1.0;
    let (x, y) = (coord(texel[0], texel[1]), coord(texel[2], texel[3]));
    let mut n = DVec3::new(x, y, 1.0 - x.abs() - y.abs());
    let fold = (-n.z).max(0.0);
    n.x += if n.x >= 0.0 { -fold } else { fold };
    n.y += if n.y >= 0.0 { -fold } else { fold };
    n.normalize()
}

/// Where an asset's light states are: the ambient state and, per proxy direction, its state.
#[derive(Clone, Debug, PartialEq)]
pub struct LightStates {
    /// Directions of the proxy: 12, 42 or 162.
    pub count: u32,
    /// Index of the ambient state.
    pub ambient: u16,
    /// Index of the shading-normal state, if the asset has one.
    pub normal: Option<u16>,
    /// State index of each proxy direction, in the proxy's order.
    pub direct: Vec<u16>,
}

impl LightStates {
    /// The light states of `header`, `None` when it has none.
    ///
    /// # Errors
    /// [`LightError::BadStates`] for states marked as light parts that do not make a whole
    /// proxy: no ambient state, a count not in [`LIGHT_COUNTS`], a direction that is not one of
    /// the proxy's or one given twice, or more than one layer.
    pub fn of(header: &AssetHeader) -> Result<Option<LightStates>, LightError> {
        let bad = |m: String| LightError::BadStates(m);
        let mut ambient = None;
        let mut normal = None;
        let mut found: Vec<(u16, DVec3)> = Vec::new();
        for (i, s) in header.states.iter().enumerate() {
            let Some(part) = s.params.get(PART_KEY) else {
                continue;
            };
            let index = u16::try_from(i).map_err(|_| bad("too many states".to_owned()))?;
            match part.as_str() {
                Some("ambient") if ambient.is_none() => ambient = Some(index),
                Some("ambient") => return Err(bad("two ambient states".to_owned())),
                Some("normal") if normal.is_none() => normal = Some(index),
                Some("normal") => return Err(bad("two normal states".to_owned())),
                Some("direct") => {
                    let d: [f64; 3] = s
                        .params
                        .get(LIGHT_KEY)
                        .and_then(|v| serde_json::from_value(v.clone()).ok())
                        .ok_or_else(|| {
                            bad(format!("state {:?} has no {LIGHT_KEY} [x, y, z]", s.name))
                        })?;
                    found.push((index, DVec3::from(d)));
                }
                _ => {
                    return Err(bad(format!(
                        "state {:?}: {PART_KEY} must be \"ambient\", \"normal\" or \"direct\"",
                        s.name
                    )));
                }
            }
        }
        if ambient.is_none() && normal.is_none() && found.is_empty() {
            return Ok(None);
        }
        let ambient =
            ambient.ok_or_else(|| bad("direct states without an ambient state".into()))?;
        if header.layers.len() != 1 {
            return Err(bad("light states need a single-layer asset".to_owned()));
        }
        let count = u32::try_from(found.len()).unwrap_or(u32::MAX);
        let dirs = proxy_directions(count)
            .map_err(|_| bad(format!("{count} direct states: need 12, 42 or 162")))?;
        let mut direct = vec![None; dirs.len()];
        for (state, d) in found {
            let slot = dirs
                .iter()
                .position(|p| p.distance(d) < 1e-5)
                .ok_or_else(|| bad(format!("direction {d} is not one of the proxy's")))?;
            if direct[slot].replace(state).is_some() {
                return Err(bad(format!("direction {d} given twice")));
            }
        }
        Ok(Some(LightStates {
            count,
            ambient,
            normal,
            direct: direct.into_iter().flatten().collect(),
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spherical_weights_rebuild_the_light_and_planar_ones_sum_to_one() {
        let mut seed = 7_u64;
        let mut next = || {
            seed = seed
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (seed >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        for count in LIGHT_COUNTS {
            let dirs = proxy_directions(count).unwrap();
            for _ in 0..200 {
                let l = DVec3::new(next(), next(), next()).normalize();
                let s = blend_for(count, l, Blend::Spherical).unwrap();
                let rebuilt: DVec3 = (0..3)
                    .map(|i| s.weights[i] * dirs[s.directions[i] as usize])
                    .sum();
                // f64 Cramer's rule on unit vectors: exact to rounding.
                assert!(rebuilt.distance(l) < 1e-12, "{count}: {rebuilt} vs {l}");
                assert!(s.weights.iter().all(|&w| w >= 0.0));
                let p = blend_for(count, l, Blend::Planar).unwrap();
                assert_eq!(p.directions, s.directions);
                assert!((p.weights.iter().sum::<f64>() - 1.0).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn a_proxy_direction_takes_its_own_state_alone() {
        for count in LIGHT_COUNTS {
            for (i, d) in proxy_directions(count).unwrap().iter().enumerate() {
                let b = blend_for(count, *d, Blend::Spherical).unwrap();
                let k = b.directions.iter().position(|&x| x as usize == i).unwrap();
                assert!((b.weights[k] - 1.0).abs() < 1e-9, "{:?}", b.weights);
                assert!(b.weights.iter().sum::<f64>() - 1.0 < 1e-9);
            }
        }
    }

    #[test]
    fn planar_weights_darken_the_centres_as_design_says() {
        // DESIGN §9: up to 20 % / 6.6 % / 1.8 %; 0.1 percentage points for its rounding.
        let got: Vec<f64> = LIGHT_COUNTS
            .iter()
            .map(|&c| centroid_darkening(c).unwrap())
            .collect();
        assert!((got[0] - 0.205).abs() < 0.002, "{got:?}");
        assert!((got[1] - 0.067).abs() < 0.002, "{got:?}");
        assert!((got[2] - 0.018).abs() < 0.001, "{got:?}");
    }

    #[test]
    fn bad_lights_are_errors() {
        for s in ["0,0,0", "nan,1,0", "inf,0,0", "1,2", "a,b,c", "1,2,3,4"] {
            assert!(s.parse::<LightDirection>().is_err(), "{s}");
        }
        assert_eq!(
            "0, 2, 0".parse::<LightDirection>().unwrap().unit().unwrap(),
            DVec3::Y
        );
        assert!(blend_for(12, DVec3::ZERO, Blend::Spherical).is_err());
        assert!(blend_for(12, DVec3::NAN, Blend::Spherical).is_err());
        assert_eq!(
            blend_for(13, DVec3::Y, Blend::Spherical),
            Err(LightError::BadCount(13))
        );
    }

    #[test]
    fn states_round_trip_through_a_header_and_bad_ones_are_refused() {
        use crate::asset::{AssetHeader, Encoding, LfFrame, Provenance};
        let frame = LfFrame {
            center: [0.0; 3],
            radius: 1.0,
        };
        let mut header =
            AssetHeader::new_spherical(0, 16, frame, Encoding::R16, Provenance::default()).unwrap();
        assert_eq!(LightStates::of(&header).unwrap(), None);
        header.states.extend(state_descs(12).unwrap());
        let states = LightStates::of(&header).unwrap().unwrap();
        assert_eq!(states.count, 12);
        assert_eq!((states.ambient, states.normal), (1, Some(2)));
        assert_eq!(states.direct, (3..15).collect::<Vec<u16>>());
        // A direction off the proxy.
        let mut off = header.clone();
        off.states[4].params[LIGHT_KEY] = serde_json::json!([1.0, 0.0, 0.0]);
        assert!(matches!(
            LightStates::of(&off),
            Err(LightError::BadStates(_))
        ));
        // One direct state missing.
        let mut short = header.clone();
        short.states.pop();
        assert!(LightStates::of(&short).is_err());
        // No ambient state.
        let mut no_ambient = header.clone();
        no_ambient.states.remove(1);
        assert!(LightStates::of(&no_ambient).is_err());
    }
}
