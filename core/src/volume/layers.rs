//! Multi light fields of a volume (seed 002 §6): one named layer per transfer function — per
//! structure, or per label set of a label volume — baked into one asset on one camera set, and
//! composited at render time in depth order with runtime opacities ([`crate::layers`]).
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

use std::path::Path;

use serde::Deserialize;

use super::Volume;
use super::raycast::{RaycastError, RaycastOptions, VolumeImage};
use super::tf::{PRESETS, TfError, TransferFunction};
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
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct LayerSpec {
    name: String,
    tf: serde_json::Value,
    #[serde(default = "full")]
    opacity: f32,
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
        }
    }

    /// The layers of a `LAYERS.json` text; TF file names resolve against `base`.
    ///
    /// # Errors
    /// [`LayersError`] naming the bad layer.
    pub fn parse(text: &str, base: &Path) -> Result<Vec<VolumeLayer>, LayersError> {
        let file: LayersFile =
            serde_json::from_str(text).map_err(|e| LayersError::Json(e.to_string()))?;
        let layers = file
            .layers
            .into_iter()
            .map(|spec| {
                let tf = match &spec.tf {
                    serde_json::Value::String(name) if PRESETS.contains(&name.as_str()) => {
                        TransferFunction::preset(name)
                    }
                    serde_json::Value::String(name) => {
                        let path = base.join(name);
                        let text =
                            std::fs::read_to_string(&path).map_err(|source| LayersError::Io {
                                layer: spec.name.clone(),
                                path: path.display().to_string(),
                                source,
                            })?;
                        TransferFunction::from_json(&text)
                    }
                    object => TransferFunction::from_json(&object.to_string()),
                }
                .map_err(|source| LayersError::Tf {
                    layer: spec.name.clone(),
                    source,
                })?;
                Ok(VolumeLayer {
                    name: spec.name,
                    tf,
                    opacity: spec.opacity,
                })
            })
            .collect::<Result<Vec<_>, LayersError>>()?;
        validate(&layers)?;
        Ok(layers)
    }

    /// The layers as JSON (TFs inline): what an asset records in its provenance, readable
    /// back by [`VolumeLayer::parse`].
    pub fn to_json(layers: &[VolumeLayer]) -> serde_json::Value {
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
}

/// Checks the count, names, opacities and that every TF is of one kind.
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
        if layer.tf.is_labels() != layers[0].tf.is_labels() {
            return Err(LayersError::Invalid(
                "every layer's TF must be of one kind: all scalar or all label TFs".to_owned(),
            ));
        }
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

/// The direct (CPU) reference of a multi light field: every layer ray-cast with its TF along
/// each pixel's ray, then composited exactly as the renderer composites the baked layers, with
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
        let (image, sort) =
            super::raycast::raycast_with_sort_depth(volume, &layer.tf, view, options)?;
        images.push(layer_image(&image, &sort));
    }
    let pairs: Vec<(&LayerImage, f32)> = images.iter().zip(opacities.iter().copied()).collect();
    Ok(composite(
        &pairs,
        view.width,
        view.height,
        options.depth_threshold as f32,
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
}
