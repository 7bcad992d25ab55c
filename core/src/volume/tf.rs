//! Transfer functions (DESIGN §9, an interface): value → colour and opacity.
//!
//! JSON, scalar volumes: `{"points": [[value, r, g, b, a], ...], "ref_step": L}`: points sorted
//! by value (equal values make a step), piecewise linear between them and clamped beyond the
//! ends; colours and `a` in [0, 1]; `a` is the opacity of a slab `ref_step` world units thick
//! (default: the smallest column norm of the volume's affine, resolved by
//! [`TransferFunction::ref_step_for`]). Label volumes: `{"labels": {"LABEL": [r, g, b, a],
//! ...}}`; unlisted labels are empty. A sample of length `Δ` has opacity
//! `α = 1 − (1 − a)^(Δ / ref_step)` ([`opacity_for_step`]).
//!
//! Presets ([`TransferFunction::preset`], [`PRESETS`]) are starting points, documented with
//! their points in `docs/volumes.md`:
//! - `ct-bone`: CT in Hounsfield units; transparent below 150 HU, bone from 300 HU.
//! - `ct-skin`: CT in Hounsfield units; the air–skin boundary (−600…−300 HU) as a thin
//!   skin-coloured shell, transparent inside.
//! - `mri-brain`: an 8-bit T1 MRI such as the MNI152 template (values 0–255): background and
//!   dark fluid transparent, grey matter faint, white matter (≥ 180) opaque.

use std::collections::BTreeMap;

use serde::Deserialize;

use super::Volume;

/// The named presets.
pub const PRESETS: [&str; 3] = ["ct-bone", "ct-skin", "mri-brain"];
/// Most points (or labels) a transfer function may have.
pub const MAX_POINTS: usize = 4096;

/// Why a transfer function is refused.
#[derive(Debug, thiserror::Error, PartialEq)]
#[non_exhaustive]
pub enum TfError {
    /// Not the JSON of either form.
    #[error("transfer function JSON: {0}")]
    Json(String),
    /// A value, colour or opacity is out of range or not finite.
    #[error("transfer function: {0}")]
    Invalid(String),
    /// An unknown preset name.
    #[error("unknown transfer function preset {0:?} (presets: ct-bone, ct-skin, mri-brain)")]
    UnknownPreset(String),
    /// A label TF on a scalar volume or a scalar TF on labels.
    #[error("{0}")]
    Mismatch(&'static str),
}

/// A validated transfer function.
#[derive(Clone, Debug, PartialEq)]
pub enum TransferFunction {
    /// Piecewise linear over scalar values.
    Scalar {
        /// `[value, r, g, b, a]`, sorted by value.
        points: Vec<[f64; 5]>,
        /// Reference length of `a`, world units; `None`: the volume's smallest spacing.
        ref_step: Option<f64>,
    },
    /// One colour per label.
    Labels {
        /// Label → `[r, g, b, a]`.
        labels: BTreeMap<u32, [f64; 4]>,
        /// Reference length of `a`, as for scalar TFs.
        ref_step: Option<f64>,
    },
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Json {
    points: Option<Vec<[f64; 5]>>,
    labels: Option<BTreeMap<String, [f64; 4]>>,
    ref_step: Option<f64>,
}

impl TransferFunction {
    /// Parses and validates DESIGN §9's JSON.
    pub fn from_json(text: &str) -> Result<TransferFunction, TfError> {
        let json: Json = serde_json::from_str(text).map_err(|e| TfError::Json(e.to_string()))?;
        let tf = match (json.points, json.labels) {
            (Some(points), None) => TransferFunction::Scalar {
                points,
                ref_step: json.ref_step,
            },
            (None, Some(labels)) => {
                let mut out = BTreeMap::new();
                for (key, rgba) in labels {
                    let label: u32 = key.trim().parse().map_err(|_| {
                        TfError::Invalid(format!("label {key:?} is not a non-negative integer"))
                    })?;
                    if out.insert(label, rgba).is_some() {
                        return Err(TfError::Invalid(format!("label {label} is listed twice")));
                    }
                }
                TransferFunction::Labels {
                    labels: out,
                    ref_step: json.ref_step,
                }
            }
            _ => {
                return Err(TfError::Json(
                    "give exactly one of \"points\" (scalar volumes) or \"labels\"".into(),
                ));
            }
        };
        tf.validate()?;
        Ok(tf)
    }

    /// A named preset (see the module documentation and [`PRESETS`]).
    pub fn preset(name: &str) -> Result<TransferFunction, TfError> {
        let points: &[[f64; 5]] = match name {
            "ct-bone" => &[
                [-1000.0, 0.0, 0.0, 0.0, 0.0],
                [150.0, 0.0, 0.0, 0.0, 0.0],
                [300.0, 0.91, 0.85, 0.72, 0.35],
                [1000.0, 0.98, 0.95, 0.88, 0.85],
                [3000.0, 1.0, 1.0, 1.0, 1.0],
            ],
            "ct-skin" => &[
                [-1000.0, 0.0, 0.0, 0.0, 0.0],
                [-600.0, 0.0, 0.0, 0.0, 0.0],
                [-450.0, 0.93, 0.73, 0.62, 0.6],
                [-300.0, 0.93, 0.73, 0.62, 0.0],
                [3000.0, 0.93, 0.73, 0.62, 0.0],
            ],
            "mri-brain" => &[
                [0.0, 0.0, 0.0, 0.0, 0.0],
                [70.0, 0.0, 0.0, 0.0, 0.0],
                [100.0, 0.85, 0.62, 0.55, 0.03],
                [150.0, 0.85, 0.62, 0.55, 0.03],
                [180.0, 0.96, 0.92, 0.86, 0.6],
                [255.0, 1.0, 1.0, 1.0, 0.9],
            ],
            other => return Err(TfError::UnknownPreset(other.to_owned())),
        };
        Ok(TransferFunction::Scalar {
            points: points.to_vec(),
            ref_step: None,
        })
    }

    /// Checks the ranges (see the module documentation).
    pub fn validate(&self) -> Result<(), TfError> {
        let bad = |m: String| Err(TfError::Invalid(m));
        let unit = |x: f64| x.is_finite() && (0.0..=1.0).contains(&x);
        let ref_step = match self {
            TransferFunction::Scalar { points, ref_step } => {
                if points.is_empty() || points.len() > MAX_POINTS {
                    return bad(format!("{} points; 1..={MAX_POINTS} needed", points.len()));
                }
                for (n, p) in points.iter().enumerate() {
                    if !p[0].is_finite() {
                        return bad(format!("point {n} has value {}", p[0]));
                    }
                    if !p[1..].iter().all(|&x| unit(x)) {
                        return bad(format!(
                            "point {n} has a colour or opacity outside [0, 1]: {p:?}"
                        ));
                    }
                    if n > 0 && p[0] < points[n - 1][0] {
                        return bad(format!("points are not sorted by value (point {n})"));
                    }
                }
                ref_step
            }
            TransferFunction::Labels { labels, ref_step } => {
                if labels.len() > MAX_POINTS {
                    return bad(format!("{} labels; at most {MAX_POINTS}", labels.len()));
                }
                if let Some((l, c)) = labels.iter().find(|(_, c)| !c.iter().all(|&x| unit(x))) {
                    return bad(format!(
                        "label {l} has a colour or opacity outside [0, 1]: {c:?}"
                    ));
                }
                ref_step
            }
        };
        if let Some(s) = ref_step
            && !(s.is_finite() && *s > 0.0)
        {
            return bad(format!("ref_step {s} is not a finite length > 0"));
        }
        Ok(())
    }

    /// `[r, g, b, a]` at a scalar value (piecewise linear, clamped at the ends; at a step the
    /// later point wins). For a label TF, the label's colour (`value` rounded) or empty.
    pub fn eval(&self, value: f64) -> [f64; 4] {
        match self {
            TransferFunction::Scalar { points, .. } => {
                let rgba = |p: &[f64; 5]| [p[1], p[2], p[3], p[4]];
                let first = &points[0];
                if value.is_nan() || value < first[0] {
                    return rgba(first);
                }
                // The first point strictly above the value.
                let upper = points.partition_point(|p| p[0] <= value);
                if upper == points.len() {
                    return rgba(&points[points.len() - 1]);
                }
                let (lo, hi) = (&points[upper - 1], &points[upper]);
                let t = (value - lo[0]) / (hi[0] - lo[0]);
                [0, 1, 2, 3].map(|c| lo[c + 1] + t * (hi[c + 1] - lo[c + 1]))
            }
            TransferFunction::Labels { labels, .. } => {
                if value.is_nan() || value < 0.0 {
                    return [0.0; 4];
                }
                labels
                    .get(&(value.round() as u32))
                    .copied()
                    .unwrap_or([0.0; 4])
            }
        }
    }

    /// Whether the opacity is above zero anywhere on the scalar range `[lo, hi]` (a piecewise
    /// linear function peaks at an end or a breakpoint, so those are the only places to look).
    /// For a label TF: whether some label in `[lo, hi]` is listed with `a > 0`.
    pub fn opaque_somewhere(&self, lo: f64, hi: f64) -> bool {
        match self {
            TransferFunction::Scalar { points, .. } => {
                self.eval(lo)[3] > 0.0
                    || self.eval(hi)[3] > 0.0
                    || points
                        .iter()
                        .any(|p| p[0] >= lo && p[0] <= hi && p[4] > 0.0)
            }
            TransferFunction::Labels { labels, .. } => labels
                .iter()
                .any(|(&l, c)| f64::from(l) >= lo && f64::from(l) <= hi && c[3] > 0.0),
        }
    }

    /// The reference length for `volume`: the TF's own, else the smallest column norm of the
    /// volume's affine (its smallest spacing).
    pub fn ref_step_for(&self, volume: &Volume) -> f64 {
        let own = match self {
            TransferFunction::Scalar { ref_step, .. }
            | TransferFunction::Labels { ref_step, .. } => *ref_step,
        };
        own.unwrap_or_else(|| volume.spacing().into_iter().fold(f64::INFINITY, f64::min))
    }

    /// DESIGN §9's JSON of this TF (what [`TransferFunction::from_json`] reads back).
    pub fn to_json(&self) -> serde_json::Value {
        match self {
            TransferFunction::Scalar { points, ref_step } => {
                let mut json = serde_json::json!({ "points": points });
                if let Some(step) = ref_step {
                    json["ref_step"] = serde_json::json!(step);
                }
                json
            }
            TransferFunction::Labels { labels, ref_step } => {
                let map: serde_json::Map<String, serde_json::Value> = labels
                    .iter()
                    .map(|(label, rgba)| (label.to_string(), serde_json::json!(rgba)))
                    .collect();
                let mut json = serde_json::json!({ "labels": map });
                if let Some(step) = ref_step {
                    json["ref_step"] = serde_json::json!(step);
                }
                json
            }
        }
    }

    /// Whether this TF is for label volumes.
    pub fn is_labels(&self) -> bool {
        matches!(self, TransferFunction::Labels { .. })
    }
}

/// A sample's opacity: `1 − (1 − a)^(Δ / ref_step)` (DESIGN §9).
pub fn opacity_for_step(a: f64, step: f64, ref_step: f64) -> f64 {
    if a >= 1.0 {
        return 1.0;
    }
    1.0 - (1.0 - a).powf(step / ref_step)
}
