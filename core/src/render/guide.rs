//! Coarse-to-fine rules of a guided frame: the coarse passes' sizes and steps, and where the
//! interior pass may share work between pixels.

use crate::geometry;

/// Bisection iterations of the coarse passes (pre-coarse and coarse) of a guided frame, whose
/// depths only bound the finer pass's marches (with a quarter step of margin) and decide which
/// quads are flat: two lose nothing against three, one is too few (docs/marcher.md).
pub(super) const COARSE_REFINE_ITERATIONS: u32 = 2;
/// Step of the coarse passes (pre-coarse and coarse) of a guided frame, in steps of the frame's
/// setting. A pixel next to a coarse near miss marches from one coarse step before where the
/// miss first came near (shaders/render/main.wgsl `guided_bounds`), as the coarse ray sampled
/// that far apart. Longer than 1.5, the coarse rays step over the band in which a ray counts as
/// near a surface ([`GUIDE_REACH`]; docs/marcher.md).
pub(super) const COARSE_STEP_SCALE: f32 = 1.5;

/// Ratio of a guided frame's coarse pass to the pre-coarse pass that guides it in turn: an
/// unguided coarse pass marches every ray over the whole box and cost a quarter of a 512²
/// frame; guided, its rays march a few steps like the frame's.
pub(super) const PRE_FACTOR: u32 = 4;

/// How close (in coarse pixels, as seen from the eye) a coarse ray must pass to a surface some
/// camera sees for its miss to count as near: the fine pixels around it then march from a step
/// before where it first came near to the end of the box.
/// Two coarse pixels cover the 3×3 neighbourhood each fine pixel reads.
pub(super) const GUIDE_REACH: f32 = 2.0;

/// The interior pass shades a 2×2 block of pixels per invocation with the cameras of the
/// triangle met by the ray through the block's centre (shaders/render/shade.wgsl `shade_interior_block`)
/// where the angle between any of its pixels' entries into the camera sphere and the centre
/// ray's cannot exceed this (radians): the direction lookup's own reach
/// ([`geometry::DIRECTION_LOOKUP_REACH`]), so a pixel lies no further outside the triangle whose
/// weights it takes than the lookup alone may put it, plus that much again. For an eye at
/// distance `e` from the centre (light-field units, camera sphere radius 1), rays at most
/// `√2/2` pixel (`0.71 / focal_px` rad) from the centre ray meet the camera sphere at most
/// `e + 1` along them, and an interior pixel's ray passes within the bounding sphere (radius
/// `1/√2`), so it meets the camera sphere at least 45° from grazing: the angle is at most
/// `√2 · (e + 1) · 0.71 / focal_px = (e + 1) / focal_px` ([`interior_block_angle`]; a test
/// checks it on sampled rays). At 512² and 40° (focal 703 px) that holds up to `e` = 1.95
/// (2.76 bounding radii from the centre).
pub(super) const INTERIOR_BLOCK_REACH: f64 = geometry::DIRECTION_LOOKUP_REACH;

/// The bound of [`INTERIOR_BLOCK_REACH`] for an eye at distance `eye` from the centre
/// (light-field units) and a focal length of `focal_px` pixels.
pub(super) fn interior_block_angle(eye: f64, focal_px: f64) -> f64 {
    (eye + 1.0) / focal_px
}

/// Whether the centres of every 2×2 block of pixels (`(2i, 2j)` to `(2i + 1, 2j + 1)`) of a
/// `width`×`height` frame guided at `factor` lie in one cell between four coarse pixels, which
/// the interior pass then loads once per block (shaders/render/shade.wgsl `shade_interior_block`). Pixel `p`'s
/// centre lies at `(p + 0.5 − width/2)/factor + coarse/2 − 0.5` coarse pixels (shaders/render/tiles.wgsl
/// `coarse_position`); when `width` is `factor · coarse`, a cell boundary (an integer `n`)
/// falls at `p = factor·n + factor/2 − 0.5`, which is odd minus a half when `factor` is a
/// multiple of 4: between an odd pixel and the next even one, never inside a block, and half a
/// fine pixel from both (a sixteenth of a cell or more up to factor 8, far above f32
/// rounding). The same holds per row. For factors 2 and 4 no other size keeps every block in
/// one cell with its centres off the cells' boundaries; for larger factors a few more would (a
/// test checks the rule with the shader's f32 arithmetic).
pub(super) fn blocks_share_coarse_cells(width: u32, height: u32, factor: u32) -> bool {
    factor >= 4
        && factor.is_multiple_of(4)
        && width.is_multiple_of(factor)
        && height.is_multiple_of(factor)
}

/// Whether all pixels of every 4×4 quad (shaders/render/tiles.wgsl `frame_quads`) of a `width`×`height` frame
/// guided at `factor` have the same nearest coarse pixel (shaders/render/tiles.wgsl `coarse_nearest`): the tile
/// pass then reads the 3×3 coarse pixels around each quad instead of 4×4 (shaders/render/tiles.wgsl
/// `TILE_SPAN`). The same rule as [`blocks_share_coarse_cells`]: when `width` is
/// `factor · coarse`, the fine pixels nearest to coarse pixel `n` are `factor·n` to
/// `factor·n + factor − 1`, whole quads when `factor` is a multiple of 4, each centre at least
/// half a fine pixel from the midpoint between two coarse pixels (tested with the shader's f32
/// arithmetic).
pub(super) fn quads_share_nearest_coarse(width: u32, height: u32, factor: u32) -> bool {
    blocks_share_coarse_cells(width, height, factor)
}

/// Largest second difference of a flat quad's coarse z-depths (shaders/render/tiles.wgsl
/// `cs_tiles`), in tolerances: bilinear interpolation between them is then within an eighth of
/// it per axis of a smooth surface through them, at most one tolerance in all. There the
/// cameras' colours still get some weight (full weight within half a tolerance), a depth that
/// far off shifts where each camera is read by about a tenth of a texel, and the interior
/// pass's Newton step corrects the depth it reports (docs/marcher.md).
pub(super) const INTERIOR_CURVATURE: f32 = 4.0;

/// Coarse-pass size for a frame guided with `factor`, or `None` when guidance is off or the
/// frame is too small (under 4 coarse pixels a side).
pub(super) fn coarse_size(width: u32, height: u32, factor: u32) -> Option<(u32, u32)> {
    (factor >= 2 && width >= 4 * factor && height >= 4 * factor)
        .then(|| (width.div_ceil(factor), height.div_ceil(factor)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::FRAC_1_SQRT_2;

    use crate::render::upload::tests::{
        lookup_error_at, random_directions, signed_uniform, smallest_height,
        vertices_and_edge_midpoints,
    };

    #[test]
    fn coarse_alignment_holds_where_the_rules_say() {
        // shaders/render/tiles.wgsl `coarse_position` in f32, as the shader computes it.
        let position = |p: u32, width: u32, factor: u32| -> f32 {
            let coarse = width.div_ceil(factor);
            (p as f32 + 0.5 - 0.5 * width as f32) / factor as f32 + 0.5 * coarse as f32 - 0.5
        };
        let mut conservative = 0;
        for factor in 2..=12 {
            for width in 4 * factor..=1100 {
                // Pairs (2m, 2m + 1) inside the frame whose centres lie in different cells.
                let straddling = (0..width / 2)
                    .filter(|m| 2 * m + 1 < width)
                    .filter(|m| {
                        position(2 * m, width, factor).floor()
                            != position(2 * m + 1, width, factor).floor()
                    })
                    .count();
                // How close a centre comes to a cell boundary (in cells).
                let margin = (0..width)
                    .map(|p| {
                        let c = position(p, width, factor);
                        (c - c.round()).abs()
                    })
                    .fold(f32::INFINITY, f32::min);
                if !blocks_share_coarse_cells(width, width, factor) {
                    // Exact for factors up to 4: every size refused has a straddling block or
                    // a centre on a boundary, where rounding decides its cell.
                    let qualifies = straddling == 0 && margin > 1e-3;
                    assert!(factor > 4 || !qualifies, "width {width}, factor {factor}");
                    conservative += usize::from(qualifies);
                    continue;
                }
                assert_eq!(straddling, 0, "width {width}, factor {factor}");
                // Quads: one nearest coarse pixel (`coarse_nearest`: WGSL's `round`, ties to
                // even) for all four pixels of a quad's row, each centre at least half a fine
                // pixel from the midpoint between two coarse pixels.
                assert!(quads_share_nearest_coarse(width, width, factor));
                for q in 0..width / 4 {
                    let nearest = position(4 * q, width, factor).round_ties_even();
                    for p in 4 * q..4 * q + 4 {
                        let c = position(p, width, factor);
                        assert_eq!(
                            c.round_ties_even(),
                            nearest,
                            "width {width}, factor {factor}"
                        );
                        assert!(
                            0.5 - (c - nearest).abs() >= 0.5 / factor as f32 - 1e-4,
                            "width {width}, factor {factor}, pixel {p}"
                        );
                    }
                }
                // Every centre at least half a fine pixel from a cell boundary (less 1e-4 of a
                // cell for f32 rounding): a division done as a multiplication by the reciprocal,
                // or any other rounding, cannot move a centre across one.
                assert!(
                    margin >= 0.5 / factor as f32 - 1e-4,
                    "width {width}, factor {factor}: {margin}"
                );
            }
        }
        // The rule refuses frames whose blocks would straddle a cell: a width not a multiple of
        // the factor, or a factor not a multiple of 4.
        for (width, factor) in [(510, 4), (514, 4), (512, 2), (516, 6), (518, 8)] {
            assert!(!blocks_share_coarse_cells(width, width, factor));
            let straddling = (0..width / 2).any(|m| {
                position(2 * m, width, factor).floor() != position(2 * m + 1, width, factor).floor()
            });
            assert!(straddling, "width {width}, factor {factor}");
        }
        eprintln!("sizes the rule refuses though they would do (factors 5–12): {conservative}");
        // Both axes: a frame qualifies only when both sides do.
        assert!(blocks_share_coarse_cells(512, 256, 4));
        assert!(!blocks_share_coarse_cells(512, 510, 4));
    }

    #[test]
    fn interior_blocks_meet_the_camera_sphere_within_the_bound() {
        // The rays of a 2×2 block of pixels and the ray through its centre, all passing within
        // the bounding sphere (as an interior pixel's does), from eyes near and far, outside
        // and inside the camera sphere, at several focal lengths: where each pixel's ray enters
        // the camera sphere lies within `interior_block_angle` of where the centre ray does
        // (f64).
        let mut raw = crate::xorshift(0x9e37_79b9_7f4a_7c15);
        let mut next = || (raw() >> 11) as f64 / (1u64 << 53) as f64;
        let entry = |o: glam::DVec3, d: glam::DVec3| -> Option<glam::DVec3> {
            let b = o.dot(d);
            let h = 1.0 - (o - b * d).length_squared();
            (h >= 0.0).then(|| (o + (-b - h.sqrt()) * d).normalize())
        };
        let within = |o: glam::DVec3, d: glam::DVec3| (o - o.dot(d) * d).length() <= FRAC_1_SQRT_2;
        let mut worst = 0.0f64;
        let mut checked = 0;
        for &eye in &[0.8, 1.05, 1.77, 3.0, 10.0, 100.0] {
            for &focal in &[50.0, 352.0, 703.0, 2000.0] {
                let bound = interior_block_angle(eye, focal);
                for _ in 0..400 {
                    // An eye at distance `eye`, looking at a random point of the bounding
                    // sphere: the block's centre ray; its pixels' rays half a pixel off it
                    // along two perpendicular image axes.
                    let random = |next: &mut dyn FnMut() -> f64| {
                        glam::DVec3::new(next() - 0.5, next() - 0.5, next() - 0.5).normalize()
                    };
                    let o = random(&mut next) * eye;
                    let target = random(&mut next) * next().cbrt() * FRAC_1_SQRT_2;
                    let centre = (target - o).normalize();
                    let (right, up) = centre.any_orthonormal_pair();
                    let Some(ec) = entry(o, centre) else {
                        continue;
                    };
                    for (sx, sy) in [(-0.5, -0.5), (0.5, -0.5), (-0.5, 0.5), (0.5, 0.5)] {
                        let d = (centre + (right * sx + up * sy) / focal).normalize();
                        if !within(o, d) {
                            continue;
                        }
                        let Some(e) = entry(o, d) else {
                            continue;
                        };
                        let angle = e.angle_between(ec);
                        worst = worst.max(angle / bound);
                        assert!(
                            angle <= bound,
                            "eye {eye}, focal {focal}: {angle} > {bound}"
                        );
                        checked += 1;
                    }
                }
            }
        }
        eprintln!("{checked} pixels, the angle at most {worst} of the bound");
        assert!(checked > 20_000, "{checked}");
        // At 512² and 40° the blocks cover the benchmarks' eyes (2.5 bounding radii).
        let focal_512 = 256.0 / 20f64.to_radians().tan();
        assert!(interior_block_angle(2.5 * FRAC_1_SQRT_2, focal_512) <= INTERIOR_BLOCK_REACH);
    }

    #[test]
    fn interior_block_weights_stay_within_twice_the_lookups_error() {
        // A pixel of an interior block takes the weights of the triangle found for the block's
        // centre, at most INTERIOR_BLOCK_REACH away, which may itself lie up to
        // DIRECTION_LOOKUP_REACH outside the centre's triangle: the pixel lies at most the sum
        // outside the triangle it is weighed in, and its weights are off by at most that sum
        // over the triangle's height, twice (as in the lookup's own test), per level. Centres
        // at random, at the cameras and at edge midpoints; pixels at the full angle in 8
        // directions around them.
        let mut next = signed_uniform(0x5851_f42d_4c95_7f2d);
        let mut centres = random_directions(&mut next, 4000);
        centres.extend(vertices_and_edge_midpoints());
        let angle = INTERIOR_BLOCK_REACH as f32;
        let reach = (geometry::DIRECTION_LOOKUP_REACH + INTERIOR_BLOCK_REACH).sin() as f32 + 1e-5;
        for level in 0..=3u32 {
            let height = smallest_height(level);
            let bound = 2.0 * reach / height;
            let (mut worst_w, mut worst_out) = (0.0f32, f32::NEG_INFINITY);
            for &c in &centres {
                let (u, v) = c.any_orthonormal_pair();
                for k in 0..8 {
                    let a = k as f32 * std::f32::consts::FRAC_PI_4;
                    let p =
                        (c * angle.cos() + (u * a.cos() + v * a.sin()) * angle.sin()).normalize();
                    let (w, out) = lookup_error_at(c, p, level);
                    worst_w = worst_w.max(w);
                    worst_out = worst_out.max(out);
                }
            }
            eprintln!(
                "level {level}: weights off by up to {worst_w} (bound {bound}), outside by up \
                 to {worst_out} (reach {reach})"
            );
            assert!(worst_out <= reach, "level {level}: {worst_out} > {reach}");
            assert!(worst_w <= bound, "level {level}: {worst_w} > {bound}");
        }
    }
}
