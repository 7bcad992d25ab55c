//! `lumigraph bench lights`: an asset with light states relit at proxy directions, at the
//! centres of the proxy's triangles (where blending errs most) and at random lights, scored
//! against the reference with the same light (and the bake's shadows), with its error split
//! into the light field's and the light interpolation's; and relit frames timed against static
//! ones, interleaved.

use std::collections::HashMap;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::Args;
use lumigraph_core::asset::{AssetFile, Channel};
use lumigraph_core::bake::BakeOptions;
use lumigraph_core::frame::Frame;
use lumigraph_core::glam::DVec3;
use lumigraph_core::gpu::mesh::GpuMesh;
use lumigraph_core::light::{self, Blend, LightDirection, LightStates};
use lumigraph_core::metrics::{self, Comparison, MeanComparison};
use lumigraph_core::reference::ReferenceRenderer;
use lumigraph_core::render::{RenderOptions, Renderer, Switches};
use lumigraph_core::shading::Shading;
use lumigraph_core::view::{View, evaluation_views};
use serde::Serialize;

use super::common::{gpu, load_source, progress_bar};

/// `lumigraph bench lights`.
#[derive(Debug, Args)]
pub struct LightsArgs {
    /// Light-field asset baked with `--lights`.
    pub asset: PathBuf,
    /// Source mesh of the asset.
    #[arg(long, required_unless_present = "demo", conflicts_with = "demo")]
    pub mesh: Option<PathBuf>,
    /// The asset was baked from the built-in demo scene.
    #[arg(long)]
    pub demo: bool,
    /// Random orbit views (DESIGN §3 evaluation views).
    #[arg(long, default_value_t = 3)]
    pub views: usize,
    /// Side of the square views in pixels.
    #[arg(long, default_value_t = 512)]
    pub size: u32,
    /// Seed of the views and the random lights.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Lights of each kind (proxy directions, triangle centres, random) per view.
    #[arg(long, default_value_t = 4)]
    pub lights: usize,
    /// Static, relit and blended-shadow relit frames per view for the timing, interleaved; the
    /// median is kept.
    #[arg(long, default_value_t = 7)]
    pub repeats: usize,
    /// Write the report as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Write each relit frame beside its reference, the frame with blended shadows and the
    /// planar weights' frame into this folder (`V-KIND-I.png`: reference | relit | blended
    /// shadows | planar, side by side).
    #[arg(long)]
    pub images: Option<PathBuf>,
}

/// One kind of light's scores, each the mean over views and lights.
#[derive(Debug, Serialize)]
struct KindReport {
    kind: &'static str,
    lights: usize,
    /// Relit frame against the reference with that light.
    total: MeanComparison,
    /// Relit frame against the same blend of references (the light field's own error).
    light_field: MeanComparison,
    /// The blend of references against the reference (the light interpolation's error).
    interpolation: MeanComparison,
    /// Planar barycentric weights' relit frame against the reference.
    planar: MeanComparison,
    /// The relit frame without shadow rays (the three proxy lights' shadows blended) against
    /// the reference.
    blended_shadows: MeanComparison,
    /// Relit frames at the three proxy directions around each light (the corners of its proxy
    /// triangle), each against its own reference, in the same views: the same asset at proxy
    /// directions, paired with the lights between them (none for the proxy directions).
    corners: Option<MeanComparison>,
}

/// One relit frame's scores.
#[derive(Debug, Serialize)]
struct LightScore {
    kind: &'static str,
    view: usize,
    light: [f64; 3],
    /// Masked PSNR of the relit frame, of the planar one and of the one with blended shadows.
    masked_psnr: f64,
    planar_masked_psnr: f64,
    blended_shadows_masked_psnr: f64,
    /// Mean masked PSNR of the relit frames at the three proxy directions around the light
    /// (none for a proxy direction).
    corners_masked_psnr: Option<f64>,
}

#[derive(Debug, Serialize)]
struct Report {
    asset: String,
    adapter: String,
    light_directions: u32,
    shadows: bool,
    views: usize,
    size: u32,
    gpu_bytes: u64,
    bytes_per_light_state_per_camera: u64,
    static_ms: f64,
    relit_ms: f64,
    /// Median over the timed pairs of relit / static (each pair the same view, back to back).
    relit_over_static: f64,
    /// The relit frame without shadow rays (blended shadows).
    blended_ms: f64,
    blended_over_static: f64,
    kinds: Vec<KindReport>,
    per_light: Vec<LightScore>,
}

/// Deterministic uniform directions (splitmix64).
fn random_lights(n: usize, seed: u64) -> Vec<DVec3> {
    let mut state = seed ^ 0x9e37_79b9_7f4a_7c15;
    let mut next = || {
        state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        (z ^ (z >> 31)) as f64 / u64::MAX as f64
    };
    (0..n)
        .map(|_| {
            let z = 2.0 * next() - 1.0;
            let phi = std::f64::consts::TAU * next();
            let r = (1.0 - z * z).max(0.0).sqrt();
            DVec3::new(r * phi.cos(), z, r * phi.sin())
        })
        .collect()
}

/// `n` items of `all`, evenly spaced from `offset`.
fn spaced(all: &[DVec3], n: usize, offset: usize) -> Vec<DVec3> {
    let step = (all.len() / n.max(1)).max(1);
    (0..n.min(all.len()))
        .map(|i| all[(offset + i * step) % all.len()])
        .collect()
}

fn lit(l: DVec3) -> RenderOptions {
    RenderOptions {
        light: Some(LightDirection(l.to_array())),
        ..RenderOptions::default()
    }
}

/// The reference's blend of the proxy lights around `l`, as the light states blend them with
/// `blend`: `ambient + Σ w_i (reference_i − ambient)` per pixel in floating point, for
/// [`Blend::Normal`] scaled by the cosine ratio `max(0, n·ℓ) / Σ w_i max(0, n·ℓ_i)`, which
/// unshadowed references with no ambient give per pixel (their albedo cancels), at most 1; with
/// the coverage and depth of `truth` (all references of a view share them).
fn reference_blend(
    reference: &ReferenceRenderer,
    mesh: &GpuMesh,
    view: &View,
    (shading, mode): (&Shading, Blend),
    (count, l): (u32, DVec3),
    truth: &Frame,
) -> Result<Frame> {
    let blend = light::blend_for(count, l, mode)?;
    let render = |shading: Shading| reference.render(mesh, view, &shading);
    let albedo = render(Shading {
        unlit: true,
        ..*shading
    })?;
    let ambient: Vec<f64> = albedo
        .color
        .iter()
        .map(|&c| f64::from(c) * f64::from(shading.ambient))
        .collect();
    let mut parts = Vec::with_capacity(3);
    let mut cosines = Vec::with_capacity(3);
    let cosine_shading = |light: DVec3| Shading {
        light: light.as_vec3().to_array(),
        ambient: 0.0,
        shadows: false,
        specular: None,
        ..*shading
    };
    for &light in &blend.vectors {
        parts.push(
            render(Shading {
                light: light.as_vec3().to_array(),
                ..*shading
            })?
            .color,
        );
        if mode == Blend::Normal {
            cosines.push(render(cosine_shading(light))?.color);
        }
    }
    let here = if mode == Blend::Normal {
        render(cosine_shading(l))?.color
    } else {
        Vec::new()
    };
    let mut out = truth.clone();
    for (i, px) in out.color.chunks_exact_mut(4).enumerate() {
        for (c, value) in px.iter_mut().take(3).enumerate() {
            let at = 4 * i + c;
            let direct: f64 = (0..3)
                .map(|k| blend.weights[k] * (f64::from(parts[k][at]) - ambient[at]))
                .sum();
            let scale = if mode == Blend::Normal {
                let denominator: f64 = (0..3)
                    .map(|k| blend.weights[k] * f64::from(cosines[k][at]))
                    .sum();
                if denominator > 0.5 {
                    (f64::from(here[at]) / denominator).min(1.0)
                } else {
                    0.0
                }
            } else {
                1.0
            };
            *value = (ambient[at] + scale * direct).round().clamp(0.0, 255.0) as u8;
        }
    }
    Ok(out)
}

/// Writes frames of one size side by side into a PNG.
fn side_by_side(path: &std::path::Path, frames: &[&Frame]) -> Result<()> {
    let (w, h) = (frames[0].width as usize, frames[0].height as usize);
    let mut out = vec![0u8; 4 * w * h * frames.len()];
    for (i, f) in frames.iter().enumerate() {
        for y in 0..h {
            let row = &f.color[4 * y * w..4 * (y + 1) * w];
            let at = 4 * (y * w * frames.len() + i * w);
            out[at..at + 4 * w].copy_from_slice(row);
        }
    }
    let width = u32::try_from(w * frames.len())?;
    lumigraph_core::image_io::write_png_rgba8(path, width, frames[0].height, &out)
        .with_context(|| format!("cannot write {}", path.display()))
}

fn median(values: &[f64]) -> f64 {
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}

pub(super) fn bench_lights(args: &LightsArgs) -> Result<()> {
    if args.views == 0 || args.views > 100 || args.lights == 0 || args.lights > 64 {
        bail!("--views 1..=100 and --lights 1..=64");
    }
    if args.repeats == 0 || args.repeats > 100 {
        bail!("--repeats {}: give 1 to 100", args.repeats);
    }
    if let Some(dir) = &args.images {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    let asset = AssetFile::open(&args.asset)
        .with_context(|| format!("cannot open asset {}", args.asset.display()))?;
    let header = asset.header().clone();
    let states = LightStates::of(&header)?
        .context("the asset has no light states: bake it with --lights 12|42|162")?;
    let count = states.count;
    let shading = BakeOptions::of(&header).shading;
    let (mesh, _) = load_source(args.mesh.as_deref(), args.demo)?;
    let gpu = gpu()?;
    let renderer = Renderer::new(gpu.clone());
    let planar = Renderer::with_switches(
        gpu.clone(),
        Switches {
            light_blend: Blend::Planar,
            ..Switches::default()
        },
    );
    let blended = Renderer::with_switches(
        gpu.clone(),
        Switches {
            shadow_rays: false,
            ..Switches::default()
        },
    );
    let reference = ReferenceRenderer::new(gpu.clone());
    let field = renderer.upload(&asset)?;
    let gpu_mesh = reference.upload(&mesh)?;
    let frame = &header.frame;
    let views = evaluation_views(frame.center, frame.radius, args.views, args.seed, args.size);
    let proxy = light::proxy_directions(count)?;
    let centroids = light::centroid_lights(count)?;
    let randoms = random_lights(args.views * args.lights, args.seed);
    let kinds: [&'static str; 3] = ["proxy", "centroid", "random"];
    let mut scores: Vec<[Vec<Comparison>; 6]> = (0..3).map(|_| Default::default()).collect();
    let mut per_light = Vec::new();
    let (mut static_ms, mut relit_ms, mut blended_ms) = (Vec::new(), Vec::new(), Vec::new());
    let bar = progress_bar(
        (views.len() * (3 * args.lights + 1)) as u64,
        "relighting views",
    );
    let truth_at = |view: &View, l: DVec3| {
        reference.render(
            &gpu_mesh,
            view,
            &Shading {
                light: l.as_vec3().to_array(),
                ..shading
            },
        )
    };
    for (v, view) in views.iter().enumerate() {
        // The relit frame at each proxy direction that is some light's corner in this view,
        // against its reference: neighbouring lights share corners.
        let mut at_corner: HashMap<u32, Comparison> = HashMap::new();
        // Timing: static, relit and blended-shadow frames interleaved, so drift hits all alike.
        let timing_light = randoms[v * args.lights];
        renderer.render(&field, view, &RenderOptions::default())?;
        renderer.render(&field, view, &lit(timing_light))?;
        blended.render(&field, view, &lit(timing_light))?;
        for _ in 0..args.repeats {
            let t = Instant::now();
            renderer.render(&field, view, &RenderOptions::default())?;
            static_ms.push(t.elapsed().as_secs_f64() * 1e3);
            let t = Instant::now();
            renderer.render(&field, view, &lit(timing_light))?;
            relit_ms.push(t.elapsed().as_secs_f64() * 1e3);
            let t = Instant::now();
            blended.render(&field, view, &lit(timing_light))?;
            blended_ms.push(t.elapsed().as_secs_f64() * 1e3);
        }
        bar.inc(1);
        let per_kind = [
            spaced(&proxy, args.lights, v),
            spaced(&centroids, args.lights, v * 7),
            randoms[v * args.lights..(v + 1) * args.lights].to_vec(),
        ];
        for (k, lights) in per_kind.iter().enumerate() {
            for &l in lights {
                let truth = truth_at(view, l)?;
                let relit = renderer.render(&field, view, &lit(l))?;
                // Relit frames bind the light states with the renderer's own layout, so the
                // planar renderer draws the one upload (162 lights: 7 GB once, not twice).
                let flat = planar.render(&field, view, &lit(l))?;
                let soft = blended.render(&field, view, &lit(l))?;
                let blend = reference_blend(
                    &reference,
                    &gpu_mesh,
                    view,
                    (&shading, renderer.switches().light_blend),
                    (count, l),
                    &truth,
                )?;
                scores[k][0].push(metrics::compare(&relit, &truth)?);
                scores[k][1].push(metrics::compare(&relit, &blend)?);
                scores[k][2].push(metrics::compare(&blend, &truth)?);
                scores[k][3].push(metrics::compare(&flat, &truth)?);
                scores[k][5].push(metrics::compare(&soft, &truth)?);
                let mut corners = Vec::with_capacity(3);
                let around = light::blend_for(count, l, Blend::Spherical)?;
                let pairs = around.directions.into_iter().zip(around.vectors);
                for (index, corner) in pairs.filter(|_| kinds[k] != "proxy") {
                    if let Some(score) = at_corner.get(&index) {
                        corners.push(score.clone());
                        continue;
                    }
                    let relit = renderer.render(&field, view, &lit(corner))?;
                    let score = metrics::compare(&relit, &truth_at(view, corner)?)?;
                    at_corner.insert(index, score.clone());
                    corners.push(score);
                }
                let corners_psnr = (!corners.is_empty()).then(|| {
                    corners.iter().map(|c| c.masked_psnr).sum::<f64>() / corners.len() as f64
                });
                scores[k][4].extend(corners);
                if let Some(dir) = &args.images {
                    let name = format!("{v}-{}-{}.png", kinds[k], per_light.len() % args.lights);
                    side_by_side(&dir.join(name), &[&truth, &relit, &soft, &flat])?;
                }
                let last = |i: usize| scores[k][i].last().map_or(f64::NAN, |c| c.masked_psnr);
                per_light.push(LightScore {
                    kind: kinds[k],
                    view: v,
                    light: l.to_array(),
                    masked_psnr: last(0),
                    planar_masked_psnr: last(3),
                    blended_shadows_masked_psnr: last(5),
                    corners_masked_psnr: corners_psnr,
                });
                bar.inc(1);
            }
        }
    }
    bar.finish_and_clear();
    let mean = |c: &[Comparison]| metrics::mean_comparison(c).context("no comparisons");
    let mut reports = Vec::new();
    for (k, kind) in kinds.iter().enumerate() {
        reports.push(KindReport {
            kind,
            lights: scores[k][0].len(),
            total: mean(&scores[k][0])?,
            light_field: mean(&scores[k][1])?,
            interpolation: mean(&scores[k][2])?,
            planar: mean(&scores[k][3])?,
            blended_shadows: mean(&scores[k][5])?,
            corners: metrics::mean_comparison(&scores[k][4]),
        });
    }
    // Each frame over the static one timed beside it (the same view, back to back): the
    // median of those ratios does not mix views of different cost, nor drift.
    let ratio = |frames: &[f64], base: &[f64]| {
        median(
            &frames
                .iter()
                .zip(base)
                .map(|(f, b)| f / b)
                .collect::<Vec<_>>(),
        )
    };
    let (s, r, b) = (median(&static_ms), median(&relit_ms), median(&blended_ms));
    let report = Report {
        asset: args.asset.display().to_string(),
        adapter: gpu.adapter_summary(),
        light_directions: count,
        shadows: shading.shadows,
        views: args.views,
        size: args.size,
        gpu_bytes: field.gpu_bytes,
        bytes_per_light_state_per_camera: header.image_bytes(Channel::Color).unwrap_or(0),
        static_ms: s,
        relit_ms: r,
        relit_over_static: ratio(&relit_ms, &static_ms),
        blended_ms: b,
        blended_over_static: ratio(&blended_ms, &static_ms),
        kinds: reports,
        per_light,
    };
    println!(
        "{}: {count} light directions, shadows {}; {} views of {}² on {}",
        report.asset, report.shadows, args.views, args.size, report.adapter
    );
    println!(
        "frame ms: static {s:.2}, relit {r:.2} ({:.3}×), blended shadows {b:.2} ({:.3}×); GPU \
         memory {:.1} MiB, {} bytes per light state per camera",
        report.relit_over_static,
        report.blended_over_static,
        report.gpu_bytes as f64 / 1_048_576.0,
        report.bytes_per_light_state_per_camera
    );
    println!(
        "kind      lights  masked  ∩ masks  wrong px  | LF masked  interp masked | planar masked \
         | blended masked | corners masked"
    );
    for k in &report.kinds {
        println!(
            "{:<8}  {:>6}  {:>6.2}  {:>7.2}  {:>8.0}  | {:>9.2}  {:>13.2} | {:>13.2} | {:>14.2} | \
             {:>14.2}",
            k.kind,
            k.lights,
            k.total.masked_psnr,
            k.total.intersection_psnr,
            k.total.wrong_surface_px,
            k.light_field.masked_psnr,
            k.interpolation.masked_psnr,
            k.planar.masked_psnr,
            k.blended_shadows.masked_psnr,
            k.corners.as_ref().map_or(f64::NAN, |c| c.masked_psnr)
        );
    }
    if let Some(path) = &args.json {
        let json = serde_json::to_vec_pretty(&report)?;
        lumigraph_core::atomic_write(path, |w| std::io::Write::write_all(w, &json))
            .with_context(|| format!("cannot write {}", path.display()))?;
    }
    Ok(())
}
