//! Layers of a multi light field (seed 002 §6–§7, DESIGN §9): runtime opacities per named layer
//! and the per-pixel, depth-ordered compositing of layer images.
//!
//! Every layer (and, in a scene, every object) renders to a [`LayerImage`]: premultiplied RGBA8
//! and a *sort depth* per pixel, the depth of the surface the layer's colour belongs to. For a
//! translucent light field that is the depth the bake stored (where the ray's accumulated
//! opacity reached `τ_d`, else its opacity-weighted mean depth), so even faint haze has a place
//! in the order; for an opaque one it is the hit's depth. [`composite`] sorts each pixel's
//! fragments by that depth (ties keep the input order) and blends them front to back with
//! DESIGN §9's rule `C += (1 − A)·o_i·C_i`, `A += (1 − A)·o_i·α_i`. The seed sorts with an
//! odd-even merge network on the GPU; here the fragments of a pixel are few (a layer or object
//! each), so an insertion sort per pixel on the CPU, after the frames are read back, costs
//! well under a millisecond per layer at 512².
//!
//! A z-buffer alone cannot composite semi-transparent layers: what lies behind a translucent
//! fragment shows through it. Sorting whole fragments is exact where the layers do not
//! interleave in depth along a pixel's ray (each is one fragment per pixel); where they do
//! (two structures that intersect), the result is the seed's approximation — absorption is not
//! additive — and is documented as such (docs/volumes.md).

use std::collections::BTreeMap;
use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

use crate::asset::{LayerDesc, LayerOrder};
use crate::frame::{Frame, FrameStats};

/// Most layers one request may name (the format's limit).
pub const MAX_LAYERS: usize = 256;

/// Runtime opacity per layer name, each in [0, 1]: `skin=0.3,bone=1` on the command line and in
/// a query string, `{"skin": 0.3, "bone": 1}` in JSON (a string in the first form is accepted
/// there too). Layers it does not name keep the asset's default opacity.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
#[serde(transparent)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[cfg_attr(feature = "openapi", schema(value_type = BTreeMap<String, f32>))]
pub struct LayerOpacities(pub BTreeMap<String, f32>);

impl LayerOpacities {
    /// Checks the names (non-empty, at most [`MAX_LAYERS`]) and the opacities (finite, in
    /// [0, 1]).
    ///
    /// # Errors
    /// A message naming the bad entry.
    pub fn validate(&self) -> Result<(), String> {
        if self.0.len() > MAX_LAYERS {
            return Err(format!(
                "{} layer opacities given; at most {MAX_LAYERS}",
                self.0.len()
            ));
        }
        for (name, &o) in &self.0 {
            if name.is_empty() {
                return Err("a layer opacity names no layer".to_owned());
            }
            if !(o.is_finite() && (0.0..=1.0).contains(&o)) {
                return Err(format!(
                    "opacity of layer {name:?} must be in [0, 1], got {o}"
                ));
            }
        }
        Ok(())
    }

    /// The opacity of every layer of an asset, in its order: the named ones as given, the rest
    /// at their default.
    ///
    /// # Errors
    /// A message for a name the asset does not have (listing the ones it has).
    pub fn resolve(&self, layers: &[LayerDesc]) -> Result<Vec<f32>, String> {
        for name in self.0.keys() {
            if !layers.iter().any(|l| &l.name == name) {
                let names: Vec<&str> = layers.iter().map(|l| l.name.as_str()).collect();
                return Err(format!(
                    "the asset has no layer {name:?} (layers: {names:?})"
                ));
            }
        }
        Ok(layers
            .iter()
            .map(|l| self.0.get(&l.name).copied().unwrap_or(l.default_opacity))
            .collect())
    }
}

impl FromStr for LayerOpacities {
    type Err = String;

    /// `name=opacity[,name=opacity...]` (`name:opacity` too, as viewer links spell it); an
    /// empty string is no entry.
    fn from_str(text: &str) -> Result<Self, String> {
        let mut map = BTreeMap::new();
        for item in text.split(',').filter(|s| !s.trim().is_empty()) {
            let Some((name, value)) = item.split_once(['=', ':']) else {
                return Err(format!(
                    "layer opacity {item:?}: expected NAME=OPACITY (e.g. skin=0.3,bone=1)"
                ));
            };
            let name = name.trim();
            let o: f32 = value
                .trim()
                .parse()
                .map_err(|_| format!("layer opacity {item:?}: {value:?} is not a number"))?;
            if map.insert(name.to_owned(), o).is_some() {
                return Err(format!("layer {name:?} is given twice"));
            }
        }
        let out = LayerOpacities(map);
        out.validate()?;
        Ok(out)
    }
}

impl fmt::Display for LayerOpacities {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let items: Vec<String> = self.0.iter().map(|(k, v)| format!("{k}={v}")).collect();
        f.write_str(&items.join(","))
    }
}

impl<'de> Deserialize<'de> for LayerOpacities {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        #[derive(Deserialize)]
        #[serde(untagged)]
        enum Form {
            Map(BTreeMap<String, f32>),
            Text(String),
        }
        let out = match Form::deserialize(d).map_err(|_| {
            serde::de::Error::custom(
                "layers: expected an object of opacities ({\"skin\": 0.3}) or NAME=OPACITY,...",
            )
        })? {
            Form::Map(map) => LayerOpacities(map),
            Form::Text(text) => text.parse().map_err(serde::de::Error::custom)?,
        };
        out.validate().map_err(serde::de::Error::custom)?;
        Ok(out)
    }
}

/// One layer's (or scene object's) contribution to a frame, before compositing.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LayerImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Premultiplied RGBA8 per pixel; alpha 0 is nothing.
    pub premultiplied: Vec<u8>,
    /// Sort depth per pixel (z, world units), `+inf` where there is nothing.
    pub depth: Vec<f32>,
    /// Whether the layer is semi-transparent (its alpha is its opacity) or opaque (alpha 255
    /// wherever it is covered).
    pub translucent: bool,
    /// Statistics of its render.
    pub stats: FrameStats,
}

impl LayerImage {
    /// An opaque frame as a layer: its colour where its depth is finite.
    pub fn from_opaque(frame: &Frame) -> LayerImage {
        let mut premultiplied = frame.color.clone();
        for (px, z) in premultiplied.chunks_exact_mut(4).zip(&frame.depth) {
            if z.is_finite() {
                px[3] = 255;
            } else {
                px.copy_from_slice(&[0; 4]);
            }
        }
        LayerImage {
            width: frame.width,
            height: frame.height,
            premultiplied,
            depth: frame.depth.clone(),
            translucent: false,
            stats: frame.stats.clone(),
        }
    }

    /// Multiplies the depths by `scale` (an instance's object units to world units).
    pub fn scale_depth(&mut self, scale: f64) {
        if scale != 1.0 {
            for z in &mut self.depth {
                *z = (f64::from(*z) * scale) as f32;
            }
        }
    }
}

/// Composites `layers` (each with its opacity) per pixel front to back (DESIGN §9): in depth
/// order ([`LayerOrder::Depth`]), or in the order given ([`LayerOrder::Ray`], depth layers whose
/// order along every ray is fixed by the split: seed 002 §7 omits the sort for them). The
/// result is opaque (`translucent: false`, depth of the nearest fragment) when
/// every layer is opaque at opacity 1 — a plain depth test — and otherwise translucent: straight
/// colour and alpha `round(255·A)`, depth of the first fragment after whose compositing
/// `A ≥ τ_d` (`depth_threshold`), `+inf` elsewhere. Statistics add up.
///
/// # Panics
/// Never for layers of one size; a layer of another size is skipped (callers render every layer
/// at the view's size).
pub fn composite(
    layers: &[(&LayerImage, f32)],
    width: u32,
    height: u32,
    depth_threshold: f32,
    order: LayerOrder,
) -> Frame {
    let pixels = width as usize * height as usize;
    let layers: Vec<(&LayerImage, f32)> = layers
        .iter()
        .copied()
        .filter(|(l, _)| {
            l.width == width
                && l.height == height
                && l.premultiplied.len() == 4 * pixels
                && l.depth.len() == pixels
        })
        .collect();
    let opaque = layers.iter().all(|(l, o)| !l.translucent && *o >= 1.0);
    let by_depth = order == LayerOrder::Depth;
    let mut color = vec![0u8; 4 * pixels];
    let mut depth = vec![f32::INFINITY; pixels];
    // Bands of rows on the CPU cores: the GPU is idle while a frame composites, and a band's
    // pixels depend on nothing else.
    let threads = std::thread::available_parallelism()
        .map_or(1, usize::from)
        .clamp(1, 8);
    let band = pixels.div_ceil(threads).max(1);
    let job = Composite {
        layers: &layers,
        depth_threshold,
        opaque,
        by_depth,
    };
    std::thread::scope(|scope| {
        for (i, (color, depth)) in color
            .chunks_mut(4 * band)
            .zip(depth.chunks_mut(band))
            .enumerate()
        {
            let job = &job;
            scope.spawn(move || job.pixels(i * band, color, depth));
        }
    });
    let mut stats = FrameStats::default();
    for (layer, _) in &layers {
        stats.render_ms += layer.stats.render_ms;
        stats.rays += layer.stats.rays;
        stats.steps += layer.stats.steps;
        stats.fetches += layer.stats.fetches;
    }
    Frame {
        width,
        height,
        color,
        depth,
        translucent: !opaque,
        stats,
    }
}

/// The per-pixel work of [`composite`].
struct Composite<'a> {
    layers: &'a [(&'a LayerImage, f32)],
    depth_threshold: f32,
    opaque: bool,
    by_depth: bool,
}

impl Composite<'_> {
    /// Composites the pixels `first..first + depth.len()` into `color` and `depth`: sorted by
    /// depth, or in the layers' order ([`Self::in_ray_order`]).
    fn pixels(&self, first: usize, color: &mut [u8], depth: &mut [f32]) {
        let layers = self.layers;
        if !self.by_depth {
            self.in_ray_order(first, color, depth);
            return;
        }
        let mut order: Vec<(f32, usize)> = Vec::with_capacity(layers.len());
        for (q, (out, z_px)) in color.chunks_exact_mut(4).zip(depth.iter_mut()).enumerate() {
            let p = first + q;
            order.clear();
            for (index, (layer, o)) in layers.iter().enumerate() {
                if *o > 0.0 && layer.premultiplied[4 * p + 3] > 0 {
                    let z = layer.depth[p];
                    // Insertion sort by depth; equal depths keep the input order. A fragment
                    // with no depth (NaN cannot occur: renderers write +inf) goes last.
                    let at = order.partition_point(|&(d, _)| d <= z);
                    order.insert(at, (z, index));
                }
            }
            if order.is_empty() {
                continue;
            }
            if self.opaque {
                let (z, index) = order[0];
                out.copy_from_slice(&layers[index].0.premultiplied[4 * p..4 * p + 4]);
                *z_px = z;
                continue;
            }
            let mut blend = Blend::new(self.depth_threshold);
            for &(z, index) in &order {
                let (layer, o) = layers[index];
                if blend.add(&layer.premultiplied[4 * p..4 * p + 4], o, z) {
                    break;
                }
            }
            blend.write(out, z_px);
        }
    }

    /// [`Self::pixels`] for layers in their given order: no per-pixel list, each layer blended
    /// as it comes.
    fn in_ray_order(&self, first: usize, color: &mut [u8], depth: &mut [f32]) {
        for (q, (out, z_px)) in color.chunks_exact_mut(4).zip(depth.iter_mut()).enumerate() {
            let p = first + q;
            let mut blend = Blend::new(self.depth_threshold);
            for &(layer, o) in self.layers {
                let px = &layer.premultiplied[4 * p..4 * p + 4];
                if px[3] == 0 || o <= 0.0 {
                    continue;
                }
                if blend.add(px, o, layer.depth[p]) {
                    break;
                }
            }
            blend.write(out, z_px);
        }
    }
}

/// One pixel's front-to-back blend (DESIGN §9): premultiplied colour and alpha so far, and the
/// depth of the fragment after which `A` reached `τ_d`.
struct Blend {
    c: [f32; 3],
    a: f32,
    z: f32,
    tau: f32,
}

impl Blend {
    fn new(tau: f32) -> Blend {
        Blend {
            c: [0.0; 3],
            a: 0.0,
            z: f32::INFINITY,
            tau,
        }
    }

    /// Blends premultiplied RGBA8 `px` at opacity `o` and depth `z` behind what is there;
    /// true once the pixel is opaque (nothing behind can show).
    fn add(&mut self, px: &[u8], o: f32, z: f32) -> bool {
        let w = (1.0 - self.a) * o / 255.0;
        for (c, &v) in self.c.iter_mut().zip(px) {
            *c += w * f32::from(v);
        }
        self.a += w * f32::from(px[3]);
        if self.a >= self.tau && self.z.is_infinite() {
            self.z = z;
        }
        self.a >= 1.0 - 0.5 / 255.0
    }

    /// Straight colour and alpha `round(255·A)` into `out` and the depth into `z_px`, unless
    /// the alpha rounds to 0 (the pixel stays empty).
    fn write(&self, out: &mut [u8], z_px: &mut f32) {
        let alpha = (255.0 * self.a).round().clamp(0.0, 255.0);
        if alpha < 1.0 {
            return;
        }
        let scale = 255.0 / self.a;
        for (o, c) in out.iter_mut().zip(self.c) {
            *o = (c * scale).round().clamp(0.0, 255.0) as u8;
        }
        out[3] = alpha as u8;
        *z_px = self.z;
    }
}

/// One fragment per pixel from a light field's depth layers, composited in their order
/// ([`LayerOrder::Ray`]), for sorting among a scene's other objects: premultiplied colour (the
/// straight composite premultiplied again, within half a code) and, as sort depth, the nearest
/// depth of the fragments that went in.
pub fn flatten_in_ray_order(
    layers: &[(&LayerImage, f32)],
    width: u32,
    height: u32,
    depth_threshold: f32,
) -> LayerImage {
    let frame = composite(layers, width, height, depth_threshold, LayerOrder::Ray);
    let mut premultiplied = frame.color;
    let mut depth = vec![f32::INFINITY; premultiplied.len() / 4];
    for (p, (px, z)) in premultiplied
        .chunks_exact_mut(4)
        .zip(&mut depth)
        .enumerate()
    {
        let a = f32::from(px[3]) / 255.0;
        for c in &mut px[..3] {
            *c = (f32::from(*c) * a).round() as u8;
        }
        if px[3] > 0 {
            *z = layers
                .iter()
                .filter(|(l, o)| *o > 0.0 && l.premultiplied.get(4 * p + 3).is_some_and(|&a| a > 0))
                .filter_map(|(l, _)| l.depth.get(p).copied())
                .fold(f32::INFINITY, f32::min);
        }
    }
    LayerImage {
        width,
        height,
        premultiplied,
        depth,
        translucent: true,
        stats: frame.stats,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image(px: [u8; 4], z: f32, translucent: bool) -> LayerImage {
        LayerImage {
            width: 1,
            height: 1,
            premultiplied: px.to_vec(),
            depth: vec![z],
            translucent,
            stats: FrameStats::default(),
        }
    }

    #[test]
    fn opacities_parse_in_both_forms_and_bad_ones_are_refused() {
        let a: LayerOpacities = "skin=0.3, bone=1".parse().expect("parses");
        assert_eq!(
            "skin:0.3,bone:1"
                .parse::<LayerOpacities>()
                .expect("link form"),
            a
        );
        assert_eq!(a.0.get("skin"), Some(&0.3));
        assert_eq!(a.0.get("bone"), Some(&1.0));
        let b: LayerOpacities =
            serde_json::from_str(r#"{"skin": 0.3, "bone": 1}"#).expect("map form");
        assert_eq!(a, b);
        let c: LayerOpacities = serde_json::from_str(r#""skin=0.3,bone=1""#).expect("text");
        assert_eq!(a, c);
        assert_eq!(
            a.to_string().parse::<LayerOpacities>().expect("round trip"),
            a
        );
        for bad in [
            "skin",
            "skin=x",
            "skin=1.5",
            "skin=-0.1",
            "skin=nan",
            "=1",
            "a=1,a=0",
        ] {
            assert!(bad.parse::<LayerOpacities>().is_err(), "{bad}");
        }
        for bad in [r#"{"skin": 2}"#, r#"{"": 1}"#, "[1]", "3"] {
            assert!(
                serde_json::from_str::<LayerOpacities>(bad).is_err(),
                "{bad}"
            );
        }
        let layers = [
            LayerDesc {
                name: "skin".to_owned(),
                default_opacity: 0.5,
            },
            LayerDesc {
                name: "brain".to_owned(),
                default_opacity: 1.0,
            },
        ];
        let some: LayerOpacities = "brain=0.25".parse().expect("parses");
        assert_eq!(some.resolve(&layers).expect("known"), vec![0.5, 0.25]);
        let unknown = a.resolve(&layers).expect_err("bone is unknown");
        assert!(
            unknown.contains("bone") && unknown.contains("skin"),
            "{unknown}"
        );
    }

    #[test]
    fn fragments_composite_front_to_back_in_depth_order() {
        // A half-transparent red in front (z 1) of an opaque green (z 2), given back to front.
        let green = image([0, 255, 0, 255], 2.0, false);
        let red = image([128, 0, 0, 128], 1.0, true);
        let f = composite(&[(&green, 1.0), (&red, 1.0)], 1, 1, 0.5, LayerOrder::Depth);
        assert!(f.translucent);
        // C = 128/255 red + (1 − 128/255)·green; A = 1.
        let a_red = 128.0 / 255.0;
        let expect = [255.0 * a_red, 255.0 * (1.0 - a_red), 0.0];
        for (got, want) in f.color.iter().zip(expect) {
            assert!((f32::from(*got) - want).abs() <= 0.5, "{:?}", f.color);
        }
        assert_eq!(f.color[3], 255);
        // A reached τ_d = 0.5 at the red fragment (A = 0.502).
        assert_eq!(f.depth[0], 1.0);
        // The input order does not matter.
        assert_eq!(
            composite(&[(&red, 1.0), (&green, 1.0)], 1, 1, 0.5, LayerOrder::Depth),
            f
        );
        // Opacity 0 removes a layer; a half opacity halves its weight.
        let only_green = composite(&[(&green, 1.0), (&red, 0.0)], 1, 1, 0.5, LayerOrder::Depth);
        assert_eq!(&only_green.color, &[0, 255, 0, 255]);
        let half = composite(&[(&red, 0.5)], 1, 1, 0.5, LayerOrder::Depth);
        assert_eq!(half.color, vec![255, 0, 0, 64]);
        assert!(half.depth[0].is_infinite(), "A = 0.25 stays below τ_d");
    }

    #[test]
    fn depth_layers_composite_in_their_order_whatever_their_depths() {
        // Segment 0 (red, half) reconstructed a little behind segment 1 (green, opaque): in ray
        // order red still goes first; by depth green would hide it.
        let red = image([128, 0, 0, 128], 2.0, true);
        let green = image([0, 255, 0, 255], 1.9, true);
        let ray = composite(&[(&red, 1.0), (&green, 1.0)], 1, 1, 0.5, LayerOrder::Ray);
        assert!(ray.color[0] > 120 && ray.color[1] > 120, "{:?}", ray.color);
        assert_eq!(ray.depth, vec![2.0], "A reached τ_d at segment 0");
        let sorted = composite(&[(&red, 1.0), (&green, 1.0)], 1, 1, 0.5, LayerOrder::Depth);
        assert_eq!(sorted.color, vec![0, 255, 0, 255]);
        // Flattened for a scene: the same colour premultiplied, sorted at the nearest depth.
        let flat = flatten_in_ray_order(&[(&red, 1.0), (&green, 1.0)], 1, 1, 0.5);
        assert_eq!(flat.depth, vec![1.9]);
        assert_eq!(flat.premultiplied[3], 255);
        for k in 0..3 {
            assert!(flat.premultiplied[k].abs_diff(ray.color[k]) <= 1);
        }
        // A layer at opacity 0 does not place the flattened fragment.
        let flat = flatten_in_ray_order(&[(&red, 1.0), (&green, 0.0)], 1, 1, 0.5);
        assert_eq!(flat.depth, vec![2.0]);
        assert_eq!(flat.premultiplied, vec![128, 0, 0, 128]);
    }

    #[test]
    fn opaque_layers_at_full_opacity_are_a_depth_test() {
        let near = image([10, 20, 30, 255], 1.0, false);
        let far = image([200, 200, 200, 255], 3.0, false);
        let empty = image([0; 4], f32::INFINITY, false);
        let f = composite(
            &[(&far, 1.0), (&near, 1.0), (&empty, 1.0)],
            1,
            1,
            0.5,
            LayerOrder::Depth,
        );
        assert!(!f.translucent);
        assert_eq!(f.color, vec![10, 20, 30, 255]);
        assert_eq!(f.depth, vec![1.0]);
        // Fading the near one lets the far one through: a translucent result.
        let faded = composite(&[(&far, 1.0), (&near, 0.5)], 1, 1, 0.5, LayerOrder::Depth);
        assert!(faded.translucent);
        assert_eq!(faded.color[3], 255);
        assert!(
            faded.color[0] > 100 && faded.color[0] < 110,
            "{:?}",
            faded.color
        );
        assert_eq!(faded.depth, vec![1.0]);
        let none = composite(&[(&empty, 1.0)], 1, 1, 0.5, LayerOrder::Depth);
        assert!(none.depth[0].is_infinite() && none.color == vec![0; 4]);
    }
}
