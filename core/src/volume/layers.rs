//! Multi light fields of a volume (seed 002 §6): one named layer per transfer function — per
//! structure, or per label set of a label volume — baked into one asset on one camera set, and
//! composited at render time in depth order with runtime opacities ([`crate::layers`]); or
//! depth layers, the consecutive segments of every ray of one TF (seed 002 §7).
//!
//! `LAYERS.json`:
//!
//! ```json
//! {"layers": [
//!   {"name": "skin",  "tf": "ct-skin", "opacity": 0.4},
//!   {"name": "bone",  "tf": "bone.json"},
//!   {"name": "brain", "tf": {"points": [[0.3, 1, 0.8, 0.7, 0], [0.5, 1, 0.8, 0.7, 0.6]]}}
//! ]}
//! ```
//!
//! `tf` is a preset name, a TF JSON file (relative to `LAYERS.json`) or the TF object itself
//! (DESIGN §9's transfer-function JSON, scalar or label); `opacity` (default 1) is the layer's
//! default runtime opacity. Names are unique and non-empty; every layer uses the same
//! ray-cast options (step, shading, depth threshold) and the same kind of TF.
//!
//! Depth layers (seed 002 §7) split every ray of one TF into consecutive segments, one layer
//! each, at the first samples where the ray's accumulated opacity reaches each threshold
//! (`"opacity"`, strictly increasing in (0, 1)) or its scalar value reaches each isovalue
//! (`"value"`, scalar volumes), in order, or at the first `"labels": N` transitions between
//! visible labels (label volumes) ([`SplitRule`]); one more layer than boundaries:
//!
//! ```json
//! {"tf": "mri-brain", "split": {"opacity": [0.3, 0.8]},
//!  "layers": [{"name": "outer"}, {"name": "middle", "opacity": 0.5}, {"name": "inner"}]}
//! ```
//!
//! Their order along every ray is fixed, so they composite in layer order, not by depth
//! ([`crate::asset::LayerOrder::Ray`]); at opacity 1 each, they add up to the one-layer ray
//! cast exactly.

use std::path::Path;

use serde::Deserialize;

use super::Volume;
use super::raycast::{RaycastError, RaycastOptions, Segment, SplitRule, VolumeImage, VolumeRays};
use super::tf::{PRESETS, TfError, TransferFunction};
use crate::asset::LayerOrder;
use crate::frame::Frame;
use crate::layers::{LayerImage, composite};
use crate::view::View;

/// Most layers one volume asset may bake (each costs a full camera set of maps).
pub const MAX_VOLUME_LAYERS: usize = 16;

/// One layer of a volume multi light field.
#[derive(Clone, Debug, PartialEq)]
pub struct VolumeLayer {
    /// Unique, non-empty name.
    pub name: String,
    /// Its transfer function.
    pub tf: TransferFunction,
    /// Default runtime opacity in [0, 1].
    pub opacity: f32,
    /// For a depth layer, the segment of the split rays it holds; `None`: the whole ray.
    pub segment: Option<Segment>,
}

/// Why a layers file is refused.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum LayersError {
    /// Not the JSON this module documents.
    #[error("layers: {0}")]
    Json(String),
    /// A bad name, opacity or count.
    #[error("layers: {0}")]
    Invalid(String),
    /// A layer's transfer function is bad.
    #[error("layer {layer:?}: {source}")]
    Tf {
        /// The layer.
        layer: String,
        /// What is wrong.
        #[source]
        source: TfError,
    },
    /// A TF file cannot be read.
    #[error("layer {layer:?}: cannot read {path}: {source}")]
    Io {
        /// The layer.
        layer: String,
        /// The file.
        path: String,
        /// The error.
        #[source]
        source: std::io::Error,
    },
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct LayersFile {
    layers: Vec<LayerSpec>,
    /// Depth layers: the one TF whose rays are split.
    tf: Option<serde_json::Value>,
    /// Depth layers: where.
    split: Option<SplitSpec>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct LayerSpec {
    name: String,
    tf: Option<serde_json::Value>,
    #[serde(default = "full")]
    opacity: f32,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SplitSpec {
    opacity: Option<Vec<f64>>,
    value: Option<Vec<f64>>,
    labels: Option<usize>,
}

impl SplitSpec {
    fn rule(self) -> Result<SplitRule, LayersError> {
        let bad = |m: &str| Err(LayersError::Invalid(format!("split: {m}")));
        let rule = match (self.opacity, self.value, self.labels) {
            (Some(b), None, None) => {
                if !b.iter().all(|&x| x > 0.0 && x < 1.0) || !b.windows(2).all(|w| w[0] < w[1]) {
                    return bad("opacity thresholds must increase strictly within (0, 1)");
                }
                SplitRule::Opacity(b)
            }
            (None, Some(b), None) => {
                if !b.iter().all(|x| x.is_finite()) {
                    return bad("isovalues must be finite");
                }
                SplitRule::Value(b)
            }
            (None, None, Some(n)) => SplitRule::Labels(n),
            _ => return bad("give exactly one of \"opacity\", \"value\" and \"labels\""),
        };
        let n = rule.boundary_count();
        if n == 0 || n >= MAX_VOLUME_LAYERS {
            return bad(&format!(
                "1 to {} boundaries (at most {MAX_VOLUME_LAYERS} layers)",
                MAX_VOLUME_LAYERS - 1
            ));
        }
        Ok(rule)
    }
}

/// A layer's TF: a preset name, a TF file relative to `base`, or the TF object.
fn resolve_tf(
    value: &serde_json::Value,
    layer: &str,
    base: &Path,
) -> Result<TransferFunction, LayersError> {
    match value {
        serde_json::Value::String(name) if PRESETS.contains(&name.as_str()) => {
            TransferFunction::preset(name)
        }
        serde_json::Value::String(name) => {
            let path = base.join(name);
            let text = std::fs::read_to_string(&path).map_err(|source| LayersError::Io {
                layer: layer.to_owned(),
                path: path.display().to_string(),
                source,
            })?;
            TransferFunction::from_json(&text)
        }
        object => TransferFunction::from_json(&object.to_string()),
    }
    .map_err(|source| LayersError::Tf {
        layer: layer.to_owned(),
        source,
    })
}

fn full() -> f32 {
    1.0
}

impl VolumeLayer {
    /// The one layer of a single-TF bake (named `default`, opacity 1).
    pub fn single(tf: &TransferFunction) -> VolumeLayer {
        VolumeLayer {
            name: "default".to_owned(),
            tf: tf.clone(),
            opacity: 1.0,
            segment: None,
        }
    }

    /// The rays of this layer: its TF's, restricted to its segment for a depth layer.
    ///
    /// # Errors
    /// [`RaycastError`] as [`VolumeRays::new`] and [`VolumeRays::with_segment`].
    pub fn rays<'a>(
        &'a self,
        volume: &'a Volume,
        options: &RaycastOptions,
    ) -> Result<VolumeRays<'a>, RaycastError> {
        VolumeRays::new(volume, &self.tf, options)?.with_segment(self.segment.clone())
    }

    /// The layers of a `LAYERS.json` text; TF file names resolve against `base`.
    ///
    /// # Errors
    /// [`LayersError`] naming the bad layer.
    pub fn parse(text: &str, base: &Path) -> Result<Vec<VolumeLayer>, LayersError> {
        let file: LayersFile =
            serde_json::from_str(text).map_err(|e| LayersError::Json(e.to_string()))?;
        let layers = match (file.split, file.tf) {
            (None, None) => file
                .layers
                .into_iter()
                .map(|spec| {
                    let Some(tf) = &spec.tf else {
                        return Err(LayersError::Invalid(format!(
                            "layer {:?} has no \"tf\"",
                            spec.name
                        )));
                    };
                    Ok(VolumeLayer {
                        tf: resolve_tf(tf, &spec.name, base)?,
                        name: spec.name,
                        opacity: spec.opacity,
                        segment: None,
                    })
                })
                .collect::<Result<Vec<_>, LayersError>>()?,
            (Some(split), Some(tf)) => {
                // The layer count against the boundaries: `validate` below.
                let split = split.rule()?;
                if let Some(spec) = file.layers.iter().find(|l| l.tf.is_some()) {
                    return Err(LayersError::Invalid(format!(
                        "depth layer {:?}: depth layers share the top-level \"tf\"",
                        spec.name
                    )));
                }
                let tf = resolve_tf(&tf, "split", base)?;
                if tf.is_labels() && matches!(split, SplitRule::Value(_)) {
                    return Err(LayersError::Invalid(
                        "split: a label volume splits its rays by opacity or labels, not by value"
                            .into(),
                    ));
                }
                if !tf.is_labels() && matches!(split, SplitRule::Labels(_)) {
                    return Err(LayersError::Invalid(
                        "split: label transitions need a label TF ({\"labels\": {...}})".into(),
                    ));
                }
                file.layers
                    .into_iter()
                    .enumerate()
                    .map(|(index, spec)| VolumeLayer {
                        name: spec.name,
                        tf: tf.clone(),
                        opacity: spec.opacity,
                        segment: Some(Segment {
                            split: split.clone(),
                            index,
                        }),
                    })
                    .collect()
            }
            _ => {
                return Err(LayersError::Invalid(
                    "depth layers need both a top-level \"tf\" and \"split\"".into(),
                ));
            }
        };
        validate(&layers)?;
        Ok(layers)
    }

    /// The layers as JSON (TFs inline): what an asset records in its provenance, readable
    /// back by [`VolumeLayer::parse`].
    pub fn to_json(layers: &[VolumeLayer]) -> serde_json::Value {
        if let Some(Segment { split, .. }) = layers.first().and_then(|l| l.segment.as_ref()) {
            let split = match split {
                SplitRule::Opacity(b) => serde_json::json!({ "opacity": b }),
                SplitRule::Value(b) => serde_json::json!({ "value": b }),
                SplitRule::Labels(n) => serde_json::json!({ "labels": n }),
            };
            return serde_json::json!({
                "tf": layers[0].tf.to_json(),
                "split": split,
                "layers": layers
                    .iter()
                    .map(|l| serde_json::json!({"name": l.name, "opacity": l.opacity}))
                    .collect::<Vec<_>>()
            });
        }
        serde_json::json!({
            "layers": layers
                .iter()
                .map(|l| serde_json::json!({
                    "name": l.name,
                    "tf": l.tf.to_json(),
                    "opacity": l.opacity,
                }))
                .collect::<Vec<_>>()
        })
    }

    /// How `layers` composite: the depth layers of split rays in their order along the ray
    /// ([`LayerOrder::Ray`]), any others by depth.
    pub fn order(layers: &[VolumeLayer]) -> LayerOrder {
        if layers.iter().any(|l| l.segment.is_some()) {
            LayerOrder::Ray
        } else {
            LayerOrder::Depth
        }
    }
}

/// Checks the count, names, opacities, that every TF is of one kind and that depth layers are
/// the segments of one split, in order, all of them.
///
/// # Errors
/// [`LayersError::Invalid`].
pub fn validate(layers: &[VolumeLayer]) -> Result<(), LayersError> {
    if layers.is_empty() || layers.len() > MAX_VOLUME_LAYERS {
        return Err(LayersError::Invalid(format!(
            "{} layers given; a volume bakes 1 to {MAX_VOLUME_LAYERS}",
            layers.len()
        )));
    }
    for (i, layer) in layers.iter().enumerate() {
        if layer.name.is_empty() || layer.name.contains([',', '=', ':']) {
            return Err(LayersError::Invalid(format!(
                "layer {i}: name {:?} must be non-empty without ',', '=' or ':'",
                layer.name
            )));
        }
        if layers[..i].iter().any(|l| l.name == layer.name) {
            return Err(LayersError::Invalid(format!(
                "layer name {:?} is used twice",
                layer.name
            )));
        }
        if !(layer.opacity.is_finite() && (0.0..=1.0).contains(&layer.opacity)) {
            return Err(LayersError::Invalid(format!(
                "layer {:?}: opacity must be in [0, 1], got {}",
                layer.name, layer.opacity
            )));
        }
        let expected = layers[0].segment.as_ref().map(|s| (&s.split, i));
        if layer.segment.as_ref().map(|s| (&s.split, s.index)) != expected {
            return Err(LayersError::Invalid(
                "depth layers are the segments 0, 1, … of one split, none mixed with TF layers"
                    .to_owned(),
            ));
        }
        if layer.segment.is_some() && layer.tf != layers[0].tf {
            return Err(LayersError::Invalid(
                "depth layers split the rays of one TF".to_owned(),
            ));
        }
        if layer.tf.is_labels() != layers[0].tf.is_labels() {
            return Err(LayersError::Invalid(
                "every layer's TF must be of one kind: all scalar or all label TFs".to_owned(),
            ));
        }
    }
    if let Some(s) = &layers[0].segment
        && layers.len() != s.split.boundary_count() + 1
    {
        return Err(LayersError::Invalid(format!(
            "{} boundaries make {} depth layers, not {}",
            s.split.boundary_count(),
            s.split.boundary_count() + 1,
            layers.len()
        )));
    }
    Ok(())
}

/// The depth at which a ray-cast layer composites (its sort depth): where its `A` reached
/// `τ_d`, else its opacity-weighted mean depth — what a bake stores in its depth maps.
fn layer_image(image: &VolumeImage, sort_depth: &[f64]) -> LayerImage {
    let frame = image.to_frame();
    let mut premultiplied = Vec::with_capacity(image.rgba.len() * 4);
    for &[r, g, b, a] in &image.rgba {
        if (255.0 * a).round() < 1.0 {
            premultiplied.extend([0; 4]);
            continue;
        }
        for c in [r, g, b, a] {
            premultiplied.push((255.0 * c).round().clamp(0.0, 255.0) as u8);
        }
    }
    LayerImage {
        width: frame.width,
        height: frame.height,
        premultiplied,
        depth: sort_depth.iter().map(|&z| z as f32).collect(),
        translucent: true,
        stats: frame.stats,
    }
}

/// The direct (CPU) reference of a multi light field: every layer ray-cast with its TF (and,
/// for depth layers, its segment) along each pixel's ray, then composited exactly as the
/// renderer composites the baked layers — by depth, or in ray order for depth layers — with
/// `opacities` (one per layer).
///
/// # Errors
/// [`RaycastError`] from a layer's ray cast, or for an opacity count that does not match.
pub fn reference_layers(
    volume: &Volume,
    layers: &[VolumeLayer],
    view: &View,
    options: &RaycastOptions,
    opacities: &[f32],
) -> Result<Frame, RaycastError> {
    if opacities.len() != layers.len() {
        return Err(RaycastError::View(format!(
            "{} opacities for {} layers",
            opacities.len(),
            layers.len()
        )));
    }
    let mut images = Vec::with_capacity(layers.len());
    for layer in layers {
        let (image, sort) = super::raycast::raycast_rays(&layer.rays(volume, options)?, view)?;
        images.push(layer_image(&image, &sort));
    }
    let pairs: Vec<(&LayerImage, f32)> = images.iter().zip(opacities.iter().copied()).collect();
    Ok(composite(
        &pairs,
        view.width,
        view.height,
        options.depth_threshold as f32,
        VolumeLayer::order(layers),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layers_files_parse_and_bad_ones_are_refused() {
        let dir = tempfile::tempdir().expect("tempdir");
        std::fs::write(
            dir.path().join("brain.json"),
            r#"{"points": [[0, 0, 0, 0, 0], [1, 1, 1, 1, 0.5]]}"#,
        )
        .expect("write");
        let text = r#"{"layers": [
            {"name": "skin", "tf": "ct-skin", "opacity": 0.4},
            {"name": "brain", "tf": "brain.json"},
            {"name": "inline", "tf": {"points": [[0, 1, 0, 0, 0], [1, 1, 0, 0, 1]]}}
        ]}"#;
        let layers = VolumeLayer::parse(text, dir.path()).expect("valid");
        assert_eq!(layers.len(), 3);
        assert_eq!(layers[0].opacity, 0.4);
        assert_eq!(layers[1].opacity, 1.0);
        // The provenance form reads back as the same layers.
        let again = VolumeLayer::parse(&VolumeLayer::to_json(&layers).to_string(), dir.path())
            .expect("round trip");
        assert_eq!(again, layers);
        for bad in [
            r#"{"layers": []}"#,
            r#"{"layers": [{"name": "", "tf": "ct-skin"}]}"#,
            r#"{"layers": [{"name": "a,b", "tf": "ct-skin"}]}"#,
            r#"{"layers": [{"name": "a", "tf": "ct-skin"}, {"name": "a", "tf": "ct-bone"}]}"#,
            r#"{"layers": [{"name": "a", "tf": "ct-skin", "opacity": 1.5}]}"#,
            r#"{"layers": [{"name": "a", "tf": "missing.json"}]}"#,
            r#"{"layers": [{"name": "a", "tf": {"points": []}}]}"#,
            r#"{"layers": [{"name": "a", "tf": "ct-skin", "colour": 1}]}"#,
            r#"{"layers": [{"name": "a", "tf": "ct-skin"}, {"name": "b", "tf": {"labels": {"1": [1, 0, 0, 1]}}}]}"#,
            "[]",
        ] {
            assert!(VolumeLayer::parse(bad, dir.path()).is_err(), "{bad}");
        }
    }

    #[test]
    fn depth_layer_files_parse_and_bad_ones_are_refused() {
        let dir = tempfile::tempdir().expect("tempdir");
        let text = r#"{"tf": "mri-brain", "split": {"opacity": [0.3, 0.8]},
            "layers": [{"name": "outer"}, {"name": "middle", "opacity": 0.5}, {"name": "inner"}]}"#;
        let layers = VolumeLayer::parse(text, dir.path()).expect("valid");
        assert_eq!(VolumeLayer::order(&layers), LayerOrder::Ray);
        assert_eq!(layers.len(), 3);
        for (i, l) in layers.iter().enumerate() {
            let s = l.segment.as_ref().expect("a segment");
            assert_eq!(
                (s.index, &s.split),
                (i, &SplitRule::Opacity(vec![0.3, 0.8]))
            );
            assert_eq!(l.tf, layers[0].tf);
        }
        assert_eq!(layers[1].opacity, 0.5);
        // The provenance form (the whole object) reads back as the same layers.
        let again = VolumeLayer::parse(&VolumeLayer::to_json(&layers).to_string(), dir.path())
            .expect("round trip");
        assert_eq!(again, layers);
        let by_value = VolumeLayer::parse(
            r#"{"tf": "ct-bone", "split": {"value": [300]}, "layers": [{"name": "a"}, {"name": "b"}]}"#,
            dir.path(),
        )
        .expect("isovalue split");
        assert_eq!(
            by_value[1].segment.as_ref().map(|s| &s.split),
            Some(&SplitRule::Value(vec![300.0]))
        );
        for bad in [
            // Count of layers against boundaries.
            r#"{"tf": "ct-bone", "split": {"opacity": [0.5]}, "layers": [{"name": "a"}]}"#,
            // Thresholds not increasing, outside (0, 1), none, both rules, neither.
            r#"{"tf": "ct-bone", "split": {"opacity": [0.6, 0.5]}, "layers": [{"name": "a"}, {"name": "b"}, {"name": "c"}]}"#,
            r#"{"tf": "ct-bone", "split": {"opacity": [1.0]}, "layers": [{"name": "a"}, {"name": "b"}]}"#,
            r#"{"tf": "ct-bone", "split": {"opacity": []}, "layers": [{"name": "a"}]}"#,
            r#"{"tf": "ct-bone", "split": {"opacity": [0.5], "value": [1]}, "layers": [{"name": "a"}, {"name": "b"}]}"#,
            r#"{"tf": "ct-bone", "split": {}, "layers": [{"name": "a"}, {"name": "b"}]}"#,
            // A TF per depth layer, a split without a TF, a TF without a split.
            r#"{"tf": "ct-bone", "split": {"opacity": [0.5]}, "layers": [{"name": "a", "tf": "ct-skin"}, {"name": "b"}]}"#,
            r#"{"split": {"opacity": [0.5]}, "layers": [{"name": "a"}, {"name": "b"}]}"#,
            r#"{"tf": "ct-bone", "layers": [{"name": "a"}]}"#,
            // Isovalues of labels.
            r#"{"tf": {"labels": {"1": [1, 0, 0, 1]}}, "split": {"value": [1]}, "layers": [{"name": "a"}, {"name": "b"}]}"#,
            // Label transitions of a scalar TF; none of them.
            r#"{"tf": "ct-bone", "split": {"labels": 1}, "layers": [{"name": "a"}, {"name": "b"}]}"#,
            r#"{"tf": {"labels": {"1": [1, 0, 0, 1]}}, "split": {"labels": 0}, "layers": [{"name": "a"}]}"#,
            // A layer with no TF outside a split.
            r#"{"layers": [{"name": "a"}]}"#,
        ] {
            assert!(VolumeLayer::parse(bad, dir.path()).is_err(), "{bad}");
        }
        let by_label = VolumeLayer::parse(
            r#"{"tf": {"labels": {"1": [1, 0, 0, 1]}}, "split": {"labels": 2},
                "layers": [{"name": "a"}, {"name": "b"}, {"name": "c"}]}"#,
            dir.path(),
        )
        .expect("label transitions");
        assert_eq!(
            by_label[2].segment.as_ref().map(|s| &s.split),
            Some(&SplitRule::Labels(2))
        );
        assert_eq!(
            VolumeLayer::parse(&VolumeLayer::to_json(&by_label).to_string(), dir.path())
                .expect("round trip"),
            by_label
        );
        // Depth layers are all the segments of one split, in order.
        let mut shuffled = layers.clone();
        shuffled.swap(0, 1);
        assert!(validate(&shuffled).is_err());
        assert!(validate(&layers[..2]).is_err());
    }
}
