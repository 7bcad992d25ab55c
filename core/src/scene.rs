//! Scenes: light-field instances and polygon meshes, each with its own world transform, rendered
//! into one frame with a shared depth buffer (seed 000 §3.2; format in
//! `docs/scene.md`).
//!
//! Every object is rendered by the pipeline it belongs to (light fields by [`Renderer`], meshes
//! by the [`ReferenceRenderer`] rasterizer) with the view carried into the object's own frame by
//! the inverse of its transform — a similarity (rotation, uniform scale, translation), so a
//! pinhole view stays a pinhole view and z-depth scales by the object's scale. The layers are
//! then composited per pixel by z-depth (nearest wins). Instances of one asset (or one mesh
//! file) share a single upload: the GPU holds each asset once however many times it is placed.
//!
//! Lighting is baked into a light field in its own frame, so it turns with the instance; a
//! mesh object is shaded in its own frame the same way, so both kinds stay consistent. An
//! instance of an asset with light states may be relit: its `options.light` is a world-space
//! direction, carried into the instance's frame. An instance of an asset with deformation states
//! or an animation shows the `state`, `time` or `frame` it names (the base state by default).

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::{DQuat, DVec3};
use serde::Deserialize;

use crate::asset::{AssetError, AssetFile};
use crate::frame::Frame;
use crate::gpu::GpuError;
use crate::gpu::mesh::GpuMesh;
use crate::layers::LayerImage;
use crate::lod::LodPolicy;
use crate::mesh::{MeshError, load_mesh};
use crate::quality::{Plan, Quality, QualityError};
use crate::reference::{ReferenceError, ReferenceRenderer};
use crate::render::{GpuLightField, Method, RenderError, RenderOptions, Renderer};
use crate::shading::Shading;
use crate::view::{View, ViewError};

/// Most objects in one scene.
pub const MAX_OBJECTS: usize = 1024;

/// Errors of scenes.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SceneError {
    /// The scene file is not valid JSON of the documented shape, or a value is out of range.
    #[error("scene {path}: {message}")]
    Invalid {
        /// The scene file.
        path: String,
        /// What is wrong.
        message: String,
    },
    /// The scene file cannot be read.
    #[error("cannot read scene {path}: {source}")]
    Io {
        /// The scene file.
        path: String,
        /// The cause.
        source: std::io::Error,
    },
    /// An object's asset cannot be opened.
    #[error("scene object {index} ({path}): {source}")]
    Asset {
        /// Object index.
        index: usize,
        /// Asset path.
        path: String,
        /// The cause.
        source: AssetError,
    },
    /// An object's mesh cannot be loaded.
    #[error("scene object {index} ({path}): {source}")]
    Mesh {
        /// Object index.
        index: usize,
        /// Mesh path.
        path: String,
        /// The cause.
        source: MeshError,
    },
    /// A light-field render failed (or an object's options are invalid).
    #[error("scene object {index}: {source}")]
    Render {
        /// Object index.
        index: usize,
        /// The cause.
        source: RenderError,
    },
    /// An object's quality cannot be served (bad knobs or policy, no calibration) or its
    /// render failed.
    #[error("scene object {index} ({path}): {source}")]
    Quality {
        /// Object index.
        index: usize,
        /// Asset path.
        path: String,
        /// The cause.
        source: QualityError,
    },
    /// A mesh render failed.
    #[error("scene object {index}: {source}")]
    Reference {
        /// Object index.
        index: usize,
        /// The cause.
        source: ReferenceError,
    },
    /// The device failed.
    #[error(transparent)]
    Gpu(#[from] GpuError),
    /// The view is invalid.
    #[error(transparent)]
    View(#[from] ViewError),
}

/// A rotation about an axis (right-handed), in degrees.
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Rotation {
    /// Axis (normalized when used; must not be zero).
    pub axis: [f64; 3],
    /// Angle in degrees.
    pub degrees: f64,
}

fn one() -> f64 {
    1.0
}

/// An object's placement: `world = translation + scale · rotation(local)`.
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Transform {
    /// Translation, world units.
    #[serde(default)]
    pub translation: [f64; 3],
    /// Rotation (none: identity).
    #[serde(default)]
    pub rotation: Option<Rotation>,
    /// Uniform scale (> 0).
    #[serde(default = "one")]
    pub scale: f64,
}

impl Default for Transform {
    fn default() -> Self {
        Transform {
            translation: [0.0; 3],
            rotation: None,
            scale: 1.0,
        }
    }
}

/// A validated similarity transform.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Similarity {
    rotation: DQuat,
    scale: f64,
    translation: DVec3,
}

impl Transform {
    /// Checks the values and builds the similarity.
    ///
    /// # Errors
    /// A message naming the bad value.
    pub fn similarity(&self) -> Result<Similarity, String> {
        let translation = DVec3::from(self.translation);
        if !translation.is_finite() {
            return Err("translation must be finite".to_owned());
        }
        if !(self.scale.is_finite() && self.scale > 1e-12 && self.scale < 1e12) {
            return Err(format!(
                "scale {} must be finite and in (1e-12, 1e12)",
                self.scale
            ));
        }
        let rotation = match self.rotation {
            None => DQuat::IDENTITY,
            Some(r) => {
                let axis = DVec3::from(r.axis);
                let len = axis.length();
                if !(axis.is_finite() && len > 1e-12) {
                    return Err("rotation axis must be finite and non-zero".to_owned());
                }
                if !r.degrees.is_finite() {
                    return Err("rotation degrees must be finite".to_owned());
                }
                DQuat::from_axis_angle(axis / len, r.degrees.to_radians())
            }
        };
        Ok(Similarity {
            rotation,
            scale: self.scale,
            translation,
        })
    }
}

impl Similarity {
    /// World coordinates of an object point.
    pub fn to_world(&self, p: DVec3) -> DVec3 {
        self.translation + self.scale * (self.rotation * p)
    }

    /// Object coordinates of a world point.
    pub fn to_local(&self, p: DVec3) -> DVec3 {
        self.rotation.inverse() * (p - self.translation) / self.scale
    }

    /// The view as seen in the object's frame (same image, z-depth divided by the scale).
    pub fn view_to_local(&self, view: &View) -> View {
        let up = self.rotation.inverse() * DVec3::from(view.up);
        View {
            eye: self.to_local(DVec3::from(view.eye)).to_array(),
            target: self.to_local(DVec3::from(view.target)).to_array(),
            up: up.to_array(),
            ..view.clone()
        }
    }

    /// Uniform scale.
    pub fn scale(&self) -> f64 {
        self.scale
    }
}

/// One object of a scene file.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(tag = "type", rename_all = "lowercase", deny_unknown_fields)]
pub enum SceneObject {
    /// A light-field instance.
    Lightfield {
        /// `.lfa` path, relative to the scene file.
        asset: PathBuf,
        /// Placement.
        #[serde(default)]
        transform: Transform,
        /// Quality knobs for this instance.
        #[serde(default)]
        options: RenderOptions,
        /// Automatic LOD for this instance (the asset's calibration picks cameras and step from
        /// the instance's projected size); knobs set in `options` stay fixed.
        #[serde(default)]
        auto_lod: Option<LodPolicy>,
        /// A deformation state of the asset to show, by name (`bake --state`; the quality key
        /// `state`); default the base state. Instances of one asset share its upload whatever
        /// state or frame each shows.
        #[serde(default)]
        state: Option<String>,
        /// Seconds into the asset's animation (`bake --animation`; the quality key `time`).
        #[serde(default)]
        time: Option<f64>,
        /// A frame of the asset's animation (the quality key `frame`).
        #[serde(default)]
        frame: Option<u32>,
    },
    /// A polygon mesh (any format `lumigraph bake` reads), rasterized.
    Mesh {
        /// Mesh path, relative to the scene file.
        mesh: PathBuf,
        /// Placement.
        #[serde(default)]
        transform: Transform,
        /// Shading, in the mesh's own frame.
        #[serde(default)]
        shading: Shading,
    },
}

/// A scene file: `{"objects": [...]}`.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    /// The objects, at least one.
    pub objects: Vec<SceneObject>,
}

impl SceneFile {
    /// Parses scene JSON and checks everything that needs no file and no device: the object
    /// count, every transform and every mesh shading. [`Scene::from_json`] starts here.
    ///
    /// # Errors
    /// What is wrong, naming the object.
    pub fn parse(text: &str) -> Result<SceneFile, String> {
        let file: SceneFile = serde_json::from_str(text).map_err(|e| e.to_string())?;
        if file.objects.is_empty() || file.objects.len() > MAX_OBJECTS {
            return Err(format!(
                "{} objects: give 1 to {MAX_OBJECTS}",
                file.objects.len()
            ));
        }
        for (index, object) in file.objects.iter().enumerate() {
            let transform = match object {
                SceneObject::Lightfield { transform, .. } => transform,
                SceneObject::Mesh {
                    transform, shading, ..
                } => {
                    shading
                        .validate()
                        .map_err(|e| format!("object {index}: {e}"))?;
                    transform
                }
            };
            transform
                .similarity()
                .map_err(|m| format!("object {index}: {m}"))?;
        }
        Ok(file)
    }
}

enum Layer {
    Field {
        field: usize,
        placement: Similarity,
        plan: Box<Plan>,
        path: String,
    },
    Mesh {
        mesh: usize,
        placement: Similarity,
        shading: Shading,
    },
}

/// A scene with its assets and meshes on the GPU (each file uploaded once).
pub struct Scene {
    layers: Vec<Layer>,
    fields: Vec<Arc<GpuLightField>>,
    meshes: Vec<GpuMesh>,
}

impl Scene {
    /// Reads, validates and uploads the scene at `path`.
    ///
    /// # Errors
    /// [`SceneError`] naming the object and what is wrong.
    pub fn load(
        path: &Path,
        renderer: &Renderer,
        reference: &ReferenceRenderer,
    ) -> Result<Scene, SceneError> {
        let text = std::fs::read_to_string(path).map_err(|source| SceneError::Io {
            path: path.display().to_string(),
            source,
        })?;
        let base = path.parent().unwrap_or_else(|| Path::new("."));
        Scene::from_json(&text, base, renderer, reference).map_err(|e| match e {
            SceneError::Invalid { message, .. } => SceneError::Invalid {
                path: path.display().to_string(),
                message,
            },
            other => other,
        })
    }

    /// [`Scene::load`] from JSON text; relative paths resolve against `base`.
    ///
    /// # Errors
    /// [`SceneError`].
    pub fn from_json(
        text: &str,
        base: &Path,
        renderer: &Renderer,
        reference: &ReferenceRenderer,
    ) -> Result<Scene, SceneError> {
        let invalid = |message: String| SceneError::Invalid {
            path: "(json)".to_owned(),
            message,
        };
        let file = SceneFile::parse(text).map_err(invalid)?;
        // Asset index → its header (plans read the cameras and calibration from it).
        let mut headers: Vec<crate::asset::AssetHeader> = Vec::new();
        let mut field_index: HashMap<PathBuf, usize> = HashMap::new();
        let mut mesh_index: HashMap<PathBuf, usize> = HashMap::new();
        let mut fields = Vec::new();
        let mut meshes = Vec::new();
        let mut layers = Vec::with_capacity(file.objects.len());
        for (index, object) in file.objects.iter().enumerate() {
            match object {
                SceneObject::Lightfield {
                    asset,
                    transform,
                    options,
                    auto_lod,
                    state,
                    time,
                    frame,
                } => {
                    let placement = transform
                        .similarity()
                        .map_err(|m| invalid(format!("object {index}: {m}")))?;
                    let path = base.join(asset);
                    let key = path.canonicalize().unwrap_or_else(|_| path.clone());
                    let field = if let Some(&i) = field_index.get(&key) {
                        i
                    } else {
                        let file = AssetFile::open(&path).map_err(|source| SceneError::Asset {
                            index,
                            path: path.display().to_string(),
                            source,
                        })?;
                        let uploaded = renderer
                            .upload(&file)
                            .map_err(|source| SceneError::Render { index, source })?;
                        fields.push(Arc::new(uploaded));
                        headers.push(file.header().clone());
                        field_index.insert(key, fields.len() - 1);
                        fields.len() - 1
                    };
                    let shown = path.display().to_string();
                    // The instance's pose: the quality keys of the same names.
                    let quality = Quality {
                        state: state.clone(),
                        time: *time,
                        frame: *frame,
                        ..object_quality(options, auto_lod.as_ref(), &placement)
                    };
                    let plan =
                        quality
                            .plan(&headers[field])
                            .map_err(|source| SceneError::Quality {
                                index,
                                path: shown.clone(),
                                source,
                            })?;
                    layers.push(Layer::Field {
                        field,
                        placement,
                        plan: Box::new(plan),
                        path: shown,
                    });
                }
                SceneObject::Mesh {
                    mesh,
                    transform,
                    shading,
                } => {
                    let placement = transform
                        .similarity()
                        .map_err(|m| invalid(format!("object {index}: {m}")))?;
                    shading
                        .validate()
                        .map_err(|e| invalid(format!("object {index}: {e}")))?;
                    let path = base.join(mesh);
                    let key = path.canonicalize().unwrap_or_else(|_| path.clone());
                    let mesh = if let Some(&i) = mesh_index.get(&key) {
                        i
                    } else {
                        let loaded = load_mesh(&path).map_err(|source| SceneError::Mesh {
                            index,
                            path: path.display().to_string(),
                            source,
                        })?;
                        meshes.push(reference.upload(&loaded)?);
                        mesh_index.insert(key, meshes.len() - 1);
                        meshes.len() - 1
                    };
                    layers.push(Layer::Mesh {
                        mesh,
                        placement,
                        shading: *shading,
                    });
                }
            }
        }
        Ok(Scene {
            layers,
            fields,
            meshes,
        })
    }

    /// Number of light-field assets on the GPU (instances of one asset count once).
    pub fn uploaded_fields(&self) -> usize {
        self.fields.len()
    }

    /// Number of meshes on the GPU.
    pub fn uploaded_meshes(&self) -> usize {
        self.meshes.len()
    }

    /// Number of objects.
    pub fn objects(&self) -> usize {
        self.layers.len()
    }

    /// Renders every object from `view` and composites them per pixel in depth order: every
    /// layer of every light field and every mesh is one fragment per pixel, sorted by depth and
    /// blended front to back ([`crate::layers::composite`]), so semi-transparent light fields
    /// (volumes) show the meshes and light fields behind them. Only opaque objects: a plain
    /// depth test.
    ///
    /// # Errors
    /// [`SceneError`] for a bad view or a failed render.
    pub fn render(
        &self,
        renderer: &Renderer,
        reference: &ReferenceRenderer,
        view: &View,
    ) -> Result<Frame, SceneError> {
        view.basis(crate::view::DEFAULT_MAX_VIEW_PX)?;
        let mut images: Vec<(LayerImage, f32)> = Vec::new();
        for (index, layer) in self.layers.iter().enumerate() {
            match layer {
                Layer::Field {
                    field,
                    placement,
                    plan,
                    path,
                } => {
                    let local = placement.view_to_local(view);
                    let lf = &self.fields[*field];
                    let (layers, _) =
                        plan.render_layers(renderer, lf, &local).map_err(|source| {
                            SceneError::Quality {
                                index,
                                path: path.clone(),
                                source,
                            }
                        })?;
                    if lf.layer_order == crate::asset::LayerOrder::Ray {
                        // Depth layers keep their order along the ray: one fragment for the
                        // object, sorted among the others.
                        let pairs: Vec<(&LayerImage, f32)> = layers
                            .iter()
                            .zip(plan.opacities().iter().copied())
                            .collect();
                        let mut image = crate::layers::flatten_in_ray_order(
                            &pairs,
                            view.width,
                            view.height,
                            lf.depth_threshold(),
                        );
                        image.scale_depth(placement.scale());
                        images.push((image, 1.0));
                    } else {
                        for (mut image, &o) in layers.into_iter().zip(plan.opacities()) {
                            image.scale_depth(placement.scale());
                            images.push((image, o));
                        }
                    }
                }
                Layer::Mesh {
                    mesh,
                    placement,
                    shading,
                } => {
                    let local = placement.view_to_local(view);
                    let frame = reference
                        .render(&self.meshes[*mesh], &local, shading)
                        .map_err(|source| SceneError::Reference { index, source })?;
                    let mut image = LayerImage::from_opaque(&frame);
                    image.scale_depth(placement.scale());
                    images.push((image, 1.0));
                }
            }
        }
        let pairs: Vec<(&LayerImage, f32)> = images.iter().map(|(i, o)| (i, *o)).collect();
        Ok(crate::layers::composite(
            &pairs,
            view.width,
            view.height,
            crate::volume::raycast::DEFAULT_DEPTH_THRESHOLD as f32,
            crate::asset::LayerOrder::Depth,
        ))
    }
}

/// The quality of a light-field object: its `options` knobs, with automatic LOD when it has an
/// `auto_lod` policy (`max_psnr_drop: null` there means no limit), and its world-space `light`
/// carried into the instance's frame (the asset's light states are in that frame).
fn object_quality(
    options: &RenderOptions,
    auto_lod: Option<&LodPolicy>,
    placement: &Similarity,
) -> Quality {
    let light = options.light.map(|l| {
        crate::light::LightDirection((placement.rotation.inverse() * DVec3::from(l.0)).to_array())
    });
    Quality {
        light,
        lod: options.lod,
        step: options.step,
        tolerance: options.tolerance,
        method: (options.method != Method::Default).then_some(options.method),
        guide: options.guide,
        auto_lod: auto_lod.map(|p| p.max_error_px),
        lod_min_psnr: auto_lod.and_then(|p| p.min_psnr),
        lod_max_psnr_drop: auto_lod.map(|p| p.max_psnr_drop.unwrap_or(f64::INFINITY)),
        lod_blend: auto_lod.map(|p| p.blend_band),
        ..Quality::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn similarity_round_trips_views_and_scales_depth() {
        let t = Transform {
            translation: [1.0, -2.0, 3.0],
            rotation: Some(Rotation {
                axis: [0.0, 2.0, 0.0],
                degrees: 90.0,
            }),
            scale: 2.0,
        }
        .similarity()
        .expect("valid");
        // World point (1,-2,3) + 2·R(1,0,0) with R = 90° about y: R(1,0,0) = (0,0,-1).
        let local = t.to_local(DVec3::new(1.0, -2.0, 1.0));
        assert!((local - DVec3::X).length() < 1e-12, "{local}");
        let view = View::look_at([5.0, 1.0, 7.0], [1.0, -2.0, 3.0], 40.0, 8, 8);
        let lv = t.view_to_local(&view);
        // Distances shrink by the scale; the viewing direction turns with the rotation.
        let d_world = (DVec3::from(view.eye) - DVec3::from(view.target)).length();
        let d_local = (DVec3::from(lv.eye) - DVec3::from(lv.target)).length();
        assert!((d_world / d_local - 2.0).abs() < 1e-12);
        assert!(lv.target.iter().all(|c| c.abs() < 1e-12), "{:?}", lv.target);
        let p = DVec3::new(0.3, -0.7, 2.0);
        assert!((t.to_world(t.to_local(p)) - p).length() < 1e-12);
    }

    #[test]
    fn bad_transforms_and_scene_json_are_rejected() {
        let bad = [
            Transform {
                scale: 0.0,
                ..Default::default()
            },
            Transform {
                scale: -1.0,
                ..Default::default()
            },
            Transform {
                scale: f64::NAN,
                ..Default::default()
            },
            Transform {
                translation: [f64::INFINITY, 0.0, 0.0],
                ..Default::default()
            },
            Transform {
                rotation: Some(Rotation {
                    axis: [0.0; 3],
                    degrees: 10.0,
                }),
                ..Default::default()
            },
            Transform {
                rotation: Some(Rotation {
                    axis: [1.0, 0.0, 0.0],
                    degrees: f64::NAN,
                }),
                ..Default::default()
            },
        ];
        for t in bad {
            assert!(t.similarity().is_err(), "{t:?}");
        }
        for text in [
            r#"{"objects": [{"type": "lightfield"}]}"#,
            r#"{"objects": [{"type": "sphere", "radius": 1}]}"#,
            r#"{"objects": [{"type": "mesh", "mesh": "a.obj", "colour": 1}]}"#,
            r#"{"objects": [], "extra": 1}"#,
            r#"{"objects": [{"type": "lightfield", "asset": "a.lfa", "transform": {"scale": "big"}}]}"#,
        ] {
            assert!(serde_json::from_str::<SceneFile>(text).is_err(), "{text}");
        }
        let ok: SceneFile = serde_json::from_str(
            r#"{"objects": [{"type": "lightfield", "asset": "a.lfa",
                "transform": {"translation": [1, 2, 3], "rotation": {"axis": [0, 1, 0], "degrees": 30}, "scale": 0.5},
                "options": {"lod": 42, "step": 0.0625}},
               {"type": "mesh", "mesh": "floor.obj"}]}"#,
        )
        .expect("valid scene");
        assert_eq!(ok.objects.len(), 2);
    }
}
