//! The Pareto plot of `lumigraph bench tradeoff`: ms per frame (log axis) against masked PSNR,
//! one marker per setting (colour = method, size = output resolution), the Pareto front joined
//! and labelled. Drawn with `plotters` into memory and written atomically as PNG; text uses the
//! DejaVu Sans face embedded by the `dejavu` crate, so the plot has labels on a server without
//! any fonts installed.

use std::path::Path;
use std::sync::Once;

use anyhow::{Result, anyhow};
use lumigraph_core::render::Method;
use lumigraph_core::tradeoff::Point;
use plotters::prelude::*;

const WIDTH: u32 = 1200;
const HEIGHT: u32 = 800;
const FONT: &str = "sans-serif";

fn register_font() -> Result<()> {
    static ONCE: Once = Once::new();
    let mut result = Ok(());
    ONCE.call_once(|| {
        result = plotters::style::register_font(
            FONT,
            FontStyle::Normal,
            dejavu::sans_condensed::regular(),
        )
        .map_err(|_| anyhow!("the embedded plot font is unreadable"));
    });
    result
}

/// Short label of a setting on the front: `162c 1/32 t.5 16b 512`, with `g4` for a
/// coarse-to-fine guide.
fn label(p: &Point) -> String {
    let s = &p.setting;
    let method = if s.method == Method::Fixed { "F " } else { "" };
    let guide = if s.guide > 0 {
        format!(" g{}", s.guide)
    } else {
        String::new()
    };
    format!(
        "{method}{}c 1/{:.0} t{:.2} {}b {}{guide}",
        s.cameras,
        1.0 / s.step,
        s.tolerance / s.step,
        s.depth_bits,
        s.size
    )
}

/// Draws `points` and writes the PNG to `path` (atomically).
///
/// # Errors
/// No finite points, a drawing failure or an unwritable path.
pub fn pareto_png(path: &Path, title: &str, points: &[Point]) -> Result<()> {
    register_font()?;
    let finite: Vec<&Point> = points
        .iter()
        .filter(|p| p.ms_per_frame.is_finite() && p.ms_per_frame > 0.0 && p.masked_psnr.is_finite())
        .collect();
    if finite.is_empty() {
        return Err(anyhow!("no finite points to plot"));
    }
    let (mut x_min, mut x_max, mut y_min, mut y_max) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for p in &finite {
        x_min = x_min.min(p.ms_per_frame);
        x_max = x_max.max(p.ms_per_frame);
        y_min = y_min.min(p.masked_psnr);
        y_max = y_max.max(p.masked_psnr);
    }
    // Log axis drawn as log10(ms) on a linear axis with 10^x labels: plotters' own log axis
    // labels only decades, and a sweep usually spans less than two.
    let (x_min, x_max) = ((x_min / 1.25).log10(), (x_max * 1.25).log10());
    let (y_min, y_max) = (y_min.floor() - 0.5, y_max.ceil() + 0.5);
    let sizes: Vec<u32> = {
        let mut s: Vec<u32> = finite.iter().map(|p| p.setting.size).collect();
        s.sort_unstable();
        s.dedup();
        s
    };
    let radius = |size: u32| -> i32 {
        let rank = sizes.iter().position(|&s| s == size).unwrap_or(0);
        4 + 2 * rank as i32
    };
    let mut buffer = vec![0u8; (WIDTH * HEIGHT * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buffer, (WIDTH, HEIGHT)).into_drawing_area();
        let err = |e: &dyn std::fmt::Display| anyhow!("cannot draw the plot: {e}");
        root.fill(&WHITE).map_err(|e| err(&e))?;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, (FONT, 26))
            .margin(20)
            .x_label_area_size(55)
            .y_label_area_size(70)
            .build_cartesian_2d(x_min..x_max, y_min..y_max)
            .map_err(|e| err(&e))?;
        chart
            .configure_mesh()
            .x_desc("ms per frame (log scale)")
            .y_desc("masked PSNR (dB)")
            .label_style((FONT, 16))
            .x_labels(12)
            .y_labels(12)
            .x_label_formatter(&|v| {
                let ms = 10f64.powf(*v);
                if ms >= 100.0 {
                    format!("{ms:.0}")
                } else if ms >= 10.0 {
                    format!("{ms:.1}")
                } else {
                    format!("{ms:.2}")
                }
            })
            .light_line_style(RGBColor(238, 238, 238))
            .axis_desc_style((FONT, 18))
            .draw()
            .map_err(|e| err(&e))?;
        let default_color = RGBColor(31, 119, 180);
        let fixed_color = RGBColor(255, 127, 14);
        for (method, color, name) in [
            (Method::Default, default_color, "method default"),
            (Method::Fixed, fixed_color, "method fixed (seed baseline)"),
        ] {
            let series: Vec<&&Point> = finite
                .iter()
                .filter(|p| p.setting.method == method)
                .collect();
            if series.is_empty() {
                continue;
            }
            chart
                .draw_series(series.iter().map(|p| {
                    Circle::new(
                        (p.ms_per_frame.log10(), p.masked_psnr),
                        radius(p.setting.size),
                        color.mix(0.55).filled(),
                    )
                }))
                .map_err(|e| err(&e))?
                .label(name)
                .legend(move |(x, y)| Circle::new((x, y), 5, color.filled()));
        }
        let mut front: Vec<&&Point> = finite.iter().filter(|p| p.pareto).collect();
        front.sort_by(|a, b| a.ms_per_frame.total_cmp(&b.ms_per_frame));
        chart
            .draw_series(LineSeries::new(
                front
                    .iter()
                    .map(|p| (p.ms_per_frame.log10(), p.masked_psnr)),
                RED.stroke_width(2),
            ))
            .map_err(|e| err(&e))?
            .label("Pareto front")
            .legend(|(x, y)| PathElement::new(vec![(x - 10, y), (x + 10, y)], RED.stroke_width(2)));
        chart
            .draw_series(front.iter().map(|p| {
                Circle::new(
                    (p.ms_per_frame.log10(), p.masked_psnr),
                    radius(p.setting.size) + 2,
                    RED.stroke_width(2),
                )
            }))
            .map_err(|e| err(&e))?;
        chart
            .draw_series(front.iter().map(|p| {
                EmptyElement::at((p.ms_per_frame.log10(), p.masked_psnr))
                    + Text::new(label(p), (10, 4), (FONT, 12).into_font().color(&BLACK))
            }))
            .map_err(|e| err(&e))?;
        chart
            .configure_series_labels()
            .label_font((FONT, 16))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .position(SeriesLabelPosition::LowerRight)
            .draw()
            .map_err(|e| err(&e))?;
        let sizes_note = sizes
            .iter()
            .map(|s| format!("{s}²"))
            .collect::<Vec<_>>()
            .join(" < ");
        root.draw(&Text::new(
            format!("marker size: output {sizes_note}; label: cameras, 1/step, tolerance/step, depth bits, size"),
            (90, (HEIGHT - 18) as i32),
            (FONT, 13).into_font().color(&BLACK),
        ))
        .map_err(|e| err(&e))?;
        root.present().map_err(|e| err(&e))?;
    }
    let rgba: Vec<u8> = buffer
        .chunks_exact(3)
        .flat_map(|c| [c[0], c[1], c[2], 255])
        .collect();
    lumigraph_core::image_io::write_png_rgba8(path, WIDTH, HEIGHT, &rgba)
        .map_err(|e| anyhow!("cannot write {}: {e}", path.display()))
}
