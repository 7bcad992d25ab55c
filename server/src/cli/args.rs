//! Flags and value parsers shared by several commands: shading, views, quality knobs, depth
//! output.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use lumigraph_core::asset::AssetFile;
use lumigraph_core::lod::{Ladder, Level, LodDecision, LodPolicy};
use lumigraph_core::render::{Method, RenderOptions};
use lumigraph_core::shading::Shading;
use lumigraph_core::tradeoff::{Calibration, Choice, Goal};
use lumigraph_core::view::View;

/// Shading flags shared by `bake` and `reference` (DESIGN §3).
#[derive(Debug, Args, Clone)]
pub struct ShadingArgs {
    /// Light direction X,Y,Z (world space; normalized).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    pub light: Option<[f32; 3]>,
    /// Ambient term in [0, 1].
    #[arg(long, allow_hyphen_values = true)]
    pub ambient: Option<f32>,
    /// Specular term KS,SHININESS.
    #[arg(long, value_parser = parse_pair, allow_hyphen_values = true)]
    pub specular: Option<(f32, f32)>,
    /// Unlit: colour = albedo.
    #[arg(long)]
    pub unlit: bool,
}

impl ShadingArgs {
    pub(super) fn to_shading(&self) -> Result<Shading> {
        let mut shading = Shading::default();
        if let Some(light) = self.light {
            shading.light = light;
        }
        if let Some(ambient) = self.ambient {
            shading.ambient = ambient;
        }
        shading.specular = self.specular;
        shading.unlit = self.unlit;
        shading.validate()?;
        Ok(shading)
    }
}

/// One view file or a list of views.
#[derive(Debug, Args)]
#[group(required = true, multiple = false)]
pub struct ViewArgs {
    /// A JSON view (DESIGN §3).
    #[arg(long)]
    pub view: Option<PathBuf>,
    /// A JSON list of views; OUT becomes a folder of 000.png, 001.png, …
    #[arg(long)]
    pub views: Option<PathBuf>,
}

/// Quality knobs of `render` and `eval`.
#[derive(Debug, Args, Clone)]
pub struct QualityArgs {
    /// Cameras to use (12, 42, 162, 642; at most the asset's).
    #[arg(long, allow_hyphen_values = true)]
    pub lod: Option<u32>,
    /// Step in bounding-sphere diameters.
    #[arg(long, allow_hyphen_values = true)]
    pub step: Option<f32>,
    /// Tolerance in bounding-sphere diameters (default step/2).
    #[arg(long, allow_hyphen_values = true)]
    pub tolerance: Option<f32>,
    /// Marching method: default or fixed.
    #[arg(long, default_value = "default")]
    pub method: Method,
    /// Coarse-to-fine factor of the default method (2–16; 0 = off; default 4): a coarse pass
    /// renders every F-th pixel per axis and bounds each pixel's march (4: 0.22–0.38× the
    /// unguided time at 512², same masked PSNR on the fixtures).
    #[arg(long, value_name = "F", allow_hyphen_values = true)]
    pub guide: Option<u32>,
    /// Pick the cheapest setting the asset's calibration predicts to reach this masked PSNR (dB).
    #[arg(long, allow_hyphen_values = true, conflicts_with_all = ["lod", "step", "tolerance", "method", "budget_ms"])]
    pub target_psnr: Option<f64>,
    /// Pick the most accurate setting the calibration predicts to render within this time (ms).
    #[arg(long, allow_hyphen_values = true, conflicts_with_all = ["lod", "step", "tolerance", "method"])]
    pub budget_ms: Option<f64>,
    /// Automatic LOD: per view, the cheapest cameras and step whose calibrated silhouette error
    /// at the object's projected size stays under PX pixels (`--auto-lod` = 1 px); a --lod or
    /// --step given as well is kept. Cross-fades near switches (no popping).
    #[arg(long, value_name = "PX", num_args = 0..=1, require_equals = true, default_missing_value = "1", allow_hyphen_values = true, conflicts_with_all = ["target_psnr", "budget_ms"])]
    pub auto_lod: Option<f64>,
    /// With --auto-lod: only settings whose calibrated masked PSNR reaches DB.
    #[arg(
        long,
        value_name = "DB",
        requires = "auto_lod",
        allow_hyphen_values = true
    )]
    pub lod_min_psnr: Option<f64>,
    /// With --auto-lod: only settings within DB of the most accurate level's calibrated masked
    /// PSNR (default 2; inf: no limit).
    #[arg(
        long,
        value_name = "DB",
        requires = "auto_lod",
        allow_hyphen_values = true
    )]
    pub lod_max_psnr_drop: Option<f64>,
    /// With --auto-lod: cross-fade band below each switch, as a fraction of the projected size
    /// (default 0.15; 0 = hard switches).
    #[arg(
        long,
        value_name = "FRACTION",
        requires = "auto_lod",
        allow_hyphen_values = true
    )]
    pub lod_blend: Option<f64>,
}

impl QualityArgs {
    /// The goal (`--target-psnr` / `--budget-ms`, exclusive by clap) with the asset's
    /// calibration, read once; an error says how to get a calibration.
    pub(super) fn goal(&self, asset: &AssetFile) -> Result<Option<(Goal, Calibration)>> {
        let Some(goal) = Goal::from_pair(self.target_psnr, self.budget_ms)? else {
            return Ok(None);
        };
        let calibration = calibration_for(asset, "--target-psnr / --budget-ms need")?;
        Ok(Some((goal, calibration)))
    }

    /// The automatic-LOD ladder (`--auto-lod`) of the asset's calibration, if asked for.
    pub(super) fn ladder(&self, asset: &AssetFile) -> Result<Option<Ladder>> {
        // clap already refuses the floors without --auto-lod and --auto-lod with a goal.
        let Some(policy) = LodPolicy::from_parts(
            self.auto_lod,
            self.lod_min_psnr,
            self.lod_max_psnr_drop,
            self.lod_blend,
            false,
        )?
        else {
            return Ok(None);
        };
        Ok(Some(Ladder::new(
            &calibration_for(asset, "--auto-lod needs")?,
            &policy,
            asset.header().geometry.camera_count,
            &self.options(),
        )?))
    }

    pub(super) fn options(&self) -> RenderOptions {
        RenderOptions {
            lod: self.lod,
            step: self.step,
            tolerance: self.tolerance,
            method: self.method,
            guide: self.guide,
        }
    }
}

/// Depth output flags.
#[derive(Debug, Args)]
pub struct DepthArgs {
    /// Write depth (.npy or .exr; with --views a folder of 000.npy, …).
    #[arg(long)]
    pub depth: Option<PathBuf>,
    /// Depth format inside a --depth folder: npy or exr.
    #[arg(long, default_value = "npy", value_parser = ["npy", "exr"])]
    pub depth_format: String,
}

fn parse_floats(s: &str, n: usize) -> Result<Vec<f32>, String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if parts.len() != n {
        return Err(format!("expected {n} comma-separated numbers, got `{s}`"));
    }
    parts
        .iter()
        .map(|p| match p.parse::<f32>() {
            Ok(v) if v.is_finite() => Ok(v),
            _ => Err(format!("`{p}` is not a finite number")),
        })
        .collect()
}

/// A finite number or a fraction `a/b`.
pub(super) fn parse_fraction(s: &str) -> Result<f32, String> {
    let value = match s.split_once('/') {
        Some((a, b)) => {
            let a: f64 = a
                .trim()
                .parse()
                .map_err(|_| format!("`{s}` is not a number"))?;
            let b: f64 = b
                .trim()
                .parse()
                .map_err(|_| format!("`{s}` is not a number"))?;
            a / b
        }
        None => s
            .trim()
            .parse::<f64>()
            .map_err(|_| format!("`{s}` is not a number"))?,
    };
    if value.is_finite() {
        Ok(value as f32)
    } else {
        Err(format!("`{s}` is not a finite number"))
    }
}

fn parse_vec3(s: &str) -> Result<[f32; 3], String> {
    let v = parse_floats(s, 3)?;
    Ok([v[0], v[1], v[2]])
}

fn parse_pair(s: &str) -> Result<(f32, f32), String> {
    let v = parse_floats(s, 2)?;
    Ok((v[0], v[1]))
}

/// The asset's calibration, or an error that starts with `flags_need` and says how to get one.
pub(super) fn calibration_for(asset: &AssetFile, flags_need: &str) -> Result<Calibration> {
    Calibration::from_quality(asset.header().quality.as_ref())?.ok_or_else(|| {
        anyhow::anyhow!(
            "{flags_need} the asset's calibration, which this asset lacks (baked with \
             --no-calibrate, by the Python API or the service): re-bake it with `lumigraph bake`"
        )
    })
}

/// The calibrated choice for `goal` at the view's size.
pub(super) fn choose(
    asset: &AssetFile,
    (goal, calibration): &(Goal, Calibration),
    view: &View,
) -> Result<Choice> {
    Ok(calibration.choose(
        *goal,
        view.width,
        view.height,
        asset.header().geometry.camera_count,
    )?)
}

pub(super) fn describe(choice: &Choice) -> String {
    format!(
        "chose {} cameras, step 1/{:.0} (default method): predicted masked PSNR {:.2} dB, {:.1} ms{}",
        choice.cameras,
        1.0 / choice.step,
        choice.predicted_psnr,
        choice.predicted_ms,
        if choice.met {
            ""
        } else {
            " (no calibrated setting meets the goal: the closest one)"
        }
    )
}

fn describe_level(level: &Level) -> String {
    format!("{} cameras, step 1/{:.0}", level.cameras, 1.0 / level.step)
}

pub(super) fn describe_lod(d: &LodDecision, pixels: u64) -> String {
    let blend = match d.blend {
        Some((next, w)) => format!(
            ", cross-fading {:.0} % into {}",
            100.0 * w,
            describe_level(&next)
        ),
        None => String::new(),
    };
    format!(
        "auto LOD: object {:.0} px across → {}{blend}: predicted silhouette error {:.2} px{}, \
         masked PSNR {:.2} dB, {:.1} ms",
        d.projected_px,
        describe_level(&d.level),
        d.error_px,
        if d.met {
            ""
        } else {
            " (no setting meets the bound: the most accurate)"
        },
        d.level.masked_psnr,
        d.predicted_ms(pixels)
    )
}
