//! Flags and value parsers shared by several commands: shading, views, depth output (the
//! quality flags are core's `Quality`), and how a quality decision is described.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use lumigraph_core::calibration::Choice;
use lumigraph_core::lod::{Level, LodDecision};
use lumigraph_core::quality::Decision;
use lumigraph_core::shading::Shading;

/// Shading flags shared by `bake` and `reference` (DESIGN §3).
#[derive(Debug, Args, Clone, Default)]
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
    /// Shadows: the light is tested for occlusion from every shaded point, a shadow ray through
    /// the mesh (DESIGN §9).
    #[arg(long)]
    pub shadows: bool,
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
        shading.shadows = self.shadows;
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

/// `X,Y,Z` as f64, each finite.
pub(super) fn parse_vec3_f64(s: &str) -> Result<[f64; 3], String> {
    parse_f64s(s)
}

/// `N` comma-separated f64s, each finite.
pub(super) fn parse_f64s<const N: usize>(s: &str) -> Result<[f64; N], String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if parts.len() != N {
        return Err(format!("expected {N} comma-separated numbers, got `{s}`"));
    }
    let mut out = [0.0; N];
    for (value, part) in out.iter_mut().zip(parts) {
        *value = match part.parse::<f64>() {
            Ok(v) if v.is_finite() => v,
            _ => return Err(format!("`{part}` is not a finite number")),
        };
    }
    Ok(out)
}

/// `NxM` (a camera grid or an image size) as two whole numbers.
pub(super) fn parse_size_pair(s: &str) -> Result<[u32; 2], String> {
    parse_sizes(s, "NxM, e.g. 8x8")
}

/// `WxHxD` (a stack's columns, rows and slices) as three whole numbers.
pub(super) fn parse_size_triple(s: &str) -> Result<[u32; 3], String> {
    parse_sizes(s, "WxHxD, e.g. 1024x1024x61")
}

/// `N` whole numbers separated by `x`; `form` shows the expected form in the error.
fn parse_sizes<const N: usize>(s: &str, form: &str) -> Result<[u32; N], String> {
    let bad = || format!("`{s}`: give {N} whole numbers as {form}");
    let parts: Vec<&str> = s.split(['x', 'X']).collect();
    if parts.len() != N {
        return Err(bad());
    }
    let mut out = [0; N];
    for (value, part) in out.iter_mut().zip(parts) {
        *value = part.trim().parse().map_err(|_| bad())?;
    }
    Ok(out)
}

fn parse_pair(s: &str) -> Result<(f32, f32), String> {
    let v = parse_floats(s, 2)?;
    Ok((v[0], v[1]))
}

/// One line on what a quality plan decided for a view (`None` for explicit knobs).
pub(super) fn describe_decision(decision: &Decision, pixels: u64) -> Option<String> {
    match (&decision.choice, &decision.lod) {
        (Some(choice), _) => Some(describe(choice)),
        (None, Some(lod)) => Some(describe_lod(lod, pixels)),
        (None, None) => None,
    }
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
