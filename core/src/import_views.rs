//! Import of external renders (seed 000 §3.4): perspective colour images with unfiltered
//! z-depth (DESIGN §3 views and depth convention), rendered elsewhere with whatever shading the
//! renderer has (shadows, global illumination), become a light field.
//!
//! As the seed does, each image becomes a view-dependent depth relief: a mesh with a vertex per
//! pixel, at the pixel's centre ray pushed to its depth and carrying its colour, triangulated
//! between neighbours whose depths agree (a jump larger than [`ImportOptions::max_depth_jump`]
//! of the depth is a silhouette and stays open). The reliefs of all images together are then
//! baked unlit into the parabolic camera maps by the ordinary ray-traced bake, which projects
//! them onto every camera's hemisphere with exact per-texel depth, the nearest relief winning
//! where several overlap.

use std::path::Path;

use glam::DVec3;

use crate::mesh::{Mesh, MeshError};
use crate::view::{View, ViewError};

/// Default largest relative depth difference inside one relief triangle: a surface tilted 86°
/// from a 512² 40° view stays closed, a silhouette opens (BENCHMARKS.md, "Import of external
/// renders").
pub const DEFAULT_MAX_DEPTH_JUMP: f32 = 0.03;

/// Most pixels the reliefs of one import may hold (two triangles a pixel, 48 bytes a vertex on
/// the device): 16 M, e.g. 64 views of 512².
pub const MAX_IMPORT_PIXELS: u64 = 16 << 20;

/// Errors of an import.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ImportError {
    /// The folder, its `views.json` or an image could not be read.
    #[error("{path}: {message}")]
    Read {
        /// The file.
        path: String,
        /// What went wrong.
        message: String,
    },
    /// A bad view.
    #[error("view {index}: {source}")]
    View {
        /// Its index in `views.json`.
        index: usize,
        /// Why.
        #[source]
        source: ViewError,
    },
    /// An image whose size is not its view's.
    #[error(
        "view {index}: the {what} image is {width}×{height} but the view is {view_width}×{view_height}"
    )]
    Size {
        /// Its index.
        index: usize,
        /// `colour` or `depth`.
        what: &'static str,
        /// Image size.
        width: u32,
        /// Image size.
        height: u32,
        /// View size.
        view_width: u32,
        /// View size.
        view_height: u32,
    },
    /// A depth that is negative or NaN (no hit is `+inf`).
    #[error(
        "view {index}: depth {value} at pixel ({x}, {y}); depth is z ≥ 0, +inf where nothing was hit"
    )]
    Depth {
        /// Its index.
        index: usize,
        /// Column.
        x: u32,
        /// Row.
        y: u32,
        /// The value.
        value: f32,
    },
    /// No views, too many pixels, or no surface at all.
    #[error("{0}")]
    Input(String),
    /// A bad option.
    #[error("max_depth_jump {0}: give a finite value in (0, 10]")]
    BadJump(f32),
    /// A bad option.
    #[error("min_facing {0}: give a value in [0, 1)")]
    BadFacing(f32),
    /// The relief mesh failed validation.
    #[error(transparent)]
    Mesh(#[from] MeshError),
}

/// One external render: its view, RGBA8 colour and z-depth per pixel (row-major, top row first).
#[derive(Clone, Debug)]
pub struct ViewImage {
    /// The DESIGN §3 view it was rendered with.
    pub view: View,
    /// `width × height × 4` bytes.
    pub color: Vec<u8>,
    /// `width × height` z-depths along the view's forward axis, world units; `+inf` = no hit.
    pub depth: Vec<f32>,
}

/// Options of [`relief_mesh`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImportOptions {
    /// Largest `max(z) / min(z) − 1` over a relief triangle's corners.
    pub max_depth_jump: f32,
    /// Smallest `|cos|` between a relief triangle's normal and the ray to its eye: a surface
    /// seen more obliquely is left to the views that see it better (its pixels are stretched
    /// across it, and its relief lies in front of theirs half the time).
    pub min_facing: f32,
}

/// Default [`ImportOptions::min_facing`]: surfaces seen within 75° of face-on.
pub const DEFAULT_MIN_FACING: f32 = 0.25;

impl Default for ImportOptions {
    fn default() -> Self {
        Self {
            max_depth_jump: DEFAULT_MAX_DEPTH_JUMP,
            min_facing: DEFAULT_MIN_FACING,
        }
    }
}

/// The perspective views an external renderer would be asked for: from the first `count`
/// directions of the camera set ([`crate::geometry::camera_set`]), the eye 2.5 radii from
/// `center`, looking at it, 40°, `size`² (up +y; +z for an eye on the y axis).
pub fn surround_views(center: DVec3, radius: f64, count: usize, size: u32) -> Vec<View> {
    crate::geometry::camera_set()
        .positions
        .iter()
        .take(count)
        .map(|p| {
            let eye = center + p.as_dvec3().normalize() * radius * 2.5;
            let up = if p.x.abs() + p.z.abs() < 1e-6 {
                [0.0, 0.0, 1.0]
            } else {
                [0.0, 1.0, 0.0]
            };
            View {
                up,
                ..View::look_at(eye.to_array(), center.to_array(), 40.0, size, size)
            }
        })
        .collect()
}

/// Reads `dir/views.json` (a JSON list of DESIGN §3 views, as `--views` takes) and, for view
/// `i`, the colour `dir/iii.png` and the depth `dir/iii.npy` or `dir/iii.exr` (`iii` = `i`
/// with three digits): what `lumigraph reference MESH --views views.json -o DIR --depth DIR`
/// writes.
///
/// # Errors
/// [`ImportError`] naming the file or view.
pub fn read_views(dir: &Path) -> Result<Vec<ViewImage>, ImportError> {
    let read_err = |path: &Path, message: String| ImportError::Read {
        path: path.display().to_string(),
        message,
    };
    let list = dir.join("views.json");
    let text = std::fs::read_to_string(&list).map_err(|e| read_err(&list, e.to_string()))?;
    let views = View::parse_many(&text).map_err(|e| read_err(&list, e.to_string()))?;
    if views.is_empty() {
        return Err(ImportError::Input(format!("{}: no views", list.display())));
    }
    let mut out = Vec::with_capacity(views.len());
    let mut pixels = 0u64;
    for (index, view) in views.into_iter().enumerate() {
        view.basis(u32::MAX)
            .map_err(|source| ImportError::View { index, source })?;
        pixels += u64::from(view.width) * u64::from(view.height);
        if pixels > MAX_IMPORT_PIXELS {
            return Err(ImportError::Input(format!(
                "the views hold more than {MAX_IMPORT_PIXELS} pixels; import fewer or smaller \
                 views"
            )));
        }
        let color_path = dir.join(format!("{index:03}.png"));
        let (w, h, color) = crate::image_io::read_png_rgba8(&color_path)
            .map_err(|e| read_err(&color_path, e.to_string()))?;
        check_size(index, "colour", (w, h), &view)?;
        let depth_path = ["npy", "exr"]
            .iter()
            .map(|ext| dir.join(format!("{index:03}.{ext}")))
            .find(|p| p.exists())
            .ok_or_else(|| {
                read_err(
                    &dir.join(format!("{index:03}.npy")),
                    "no depth image (.npy or .exr) for this view".to_owned(),
                )
            })?;
        let (w, h, depth) = crate::image_io::read_depth(&depth_path)
            .map_err(|e| read_err(&depth_path, e.to_string()))?;
        check_size(index, "depth", (w, h), &view)?;
        out.push(ViewImage { view, color, depth });
    }
    Ok(out)
}

fn check_size(
    index: usize,
    what: &'static str,
    (width, height): (u32, u32),
    view: &View,
) -> Result<(), ImportError> {
    if (width, height) == (view.width, view.height) {
        Ok(())
    } else {
        Err(ImportError::Size {
            index,
            what,
            width,
            height,
            view_width: view.width,
            view_height: view.height,
        })
    }
}

/// The depth reliefs of `images` as one mesh with vertex colours (the pixels' colours, alpha
/// ignored): a vertex per pixel with a finite depth and non-zero alpha, at `eye + z ·
/// dir / (dir · forward)` for its centre ray `dir`; each 2×2 block of such pixels gives two
/// triangles (split along its diagonal of closer depths), or one where three are valid, where
/// the corners' depths agree within `max_depth_jump`.
///
/// # Errors
/// [`ImportError`] for a bad view, image size or depth, or no triangle at all.
pub fn relief_mesh(images: &[ViewImage], options: &ImportOptions) -> Result<Mesh, ImportError> {
    let jump = options.max_depth_jump;
    if !(jump.is_finite() && jump > 0.0 && jump <= 10.0) {
        return Err(ImportError::BadJump(jump));
    }
    if !(options.min_facing.is_finite() && (0.0..1.0).contains(&options.min_facing)) {
        return Err(ImportError::BadFacing(options.min_facing));
    }
    let mut positions: Vec<[f32; 3]> = Vec::new();
    let mut colors: Vec<[f32; 4]> = Vec::new();
    let mut triangles: Vec<[u32; 3]> = Vec::new();
    for (index, image) in images.iter().enumerate() {
        let basis = image
            .view
            .basis(u32::MAX)
            .map_err(|source| ImportError::View { index, source })?;
        let (w, h) = (image.view.width, image.view.height);
        let n = w as usize * h as usize;
        if image.color.len() != 4 * n || image.depth.len() != n {
            return Err(ImportError::Size {
                index,
                what: if image.depth.len() == n {
                    "colour"
                } else {
                    "depth"
                },
                width: w,
                height: h,
                view_width: w,
                view_height: h,
            });
        }
        // Vertex index of each pixel, or u32::MAX where it holds no surface.
        let mut vertex = vec![u32::MAX; n];
        for y in 0..h {
            for x in 0..w {
                let p = y as usize * w as usize + x as usize;
                let z = image.depth[p];
                if z.is_nan() || z < 0.0 {
                    return Err(ImportError::Depth {
                        index,
                        x,
                        y,
                        value: z,
                    });
                }
                if !z.is_finite() || image.color[4 * p + 3] == 0 {
                    continue;
                }
                let dir = basis.pixel_dir(y, x);
                let point: DVec3 = basis.eye + dir * (f64::from(z) / dir.dot(basis.forward));
                let Ok(at) = u32::try_from(positions.len()) else {
                    return Err(ImportError::Input("too many relief vertices".to_owned()));
                };
                vertex[p] = at;
                positions.push(point.as_vec3().to_array());
                let c = &image.color[4 * p..4 * p + 4];
                colors.push([
                    f32::from(c[0]) / 255.0,
                    f32::from(c[1]) / 255.0,
                    f32::from(c[2]) / 255.0,
                    1.0,
                ]);
            }
        }
        let facing = |positions: &[[f32; 3]], t: [u32; 3]| {
            if options.min_facing <= 0.0 {
                return true;
            }
            let [a, b, c] = t.map(|v| glam::Vec3::from(positions[v as usize]));
            let n = (b - a).cross(c - a);
            let to_eye = basis.eye.as_vec3() - (a + b + c) / 3.0;
            let denominator = n.length() * to_eye.length();
            denominator > 0.0 && n.dot(to_eye).abs() >= options.min_facing * denominator
        };
        let agree = |ps: &[usize]| {
            let (lo, hi) = ps
                .iter()
                .map(|&p| image.depth[p])
                .fold((f32::INFINITY, 0.0_f32), |(lo, hi), z| {
                    (lo.min(z), hi.max(z))
                });
            hi <= lo * (1.0 + jump)
        };
        for y in 0..h.saturating_sub(1) {
            for x in 0..w.saturating_sub(1) {
                let at = |dx: u32, dy: u32| (y + dy) as usize * w as usize + (x + dx) as usize;
                // a b
                // c d   (image rows go down; the triangles face the camera)
                let (a, b, c, d) = (at(0, 0), at(1, 0), at(0, 1), at(1, 1));
                let valid = |p: usize| vertex[p] != u32::MAX;
                let all = [a, b, c, d].iter().all(|&p| valid(p));
                let z = |p: usize| image.depth[p];
                let candidates: Vec<[usize; 3]> = if all {
                    // Split along the diagonal whose ends are closer in depth.
                    if (z(a) - z(d)).abs() <= (z(b) - z(c)).abs() {
                        vec![[a, c, d], [a, d, b]]
                    } else {
                        vec![[a, c, b], [b, c, d]]
                    }
                } else {
                    [[a, c, d], [a, d, b], [a, c, b], [b, c, d]]
                        .into_iter()
                        .filter(|t| t.iter().all(|&p| valid(p)))
                        .take(1)
                        .collect()
                };
                for t in candidates {
                    if agree(&t) && facing(&positions, t.map(|p| vertex[p])) {
                        triangles.push(t.map(|p| vertex[p]));
                    }
                }
            }
        }
    }
    if triangles.is_empty() {
        return Err(ImportError::Input(
            "the views hold no surface: every depth is +inf (or alpha 0), or no neighbouring \
             depths agree"
                .to_owned(),
        ));
    }
    let mut mesh = Mesh::from_arrays(positions, triangles, Some(colors))?;
    // The vertex colours are the colours: no default albedo scales them.
    for material in &mut mesh.materials {
        material.base_color_factor = [1.0; 4];
    }
    Ok(mesh)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 4×3 view of a plane at z = 2 (every pixel), with one far pixel (a silhouette).
    fn plane() -> ViewImage {
        let view = View::look_at([0.0, 0.0, 5.0], [0.0, 0.0, 0.0], 40.0, 4, 3);
        let mut depth = vec![2.0; 12];
        depth[5] = 4.0;
        ViewImage {
            view,
            color: vec![200; 48],
            depth,
        }
    }

    #[test]
    fn a_relief_puts_pixels_at_their_depth_and_opens_at_jumps() {
        let image = plane();
        let mesh =
            relief_mesh(std::slice::from_ref(&image), &ImportOptions::default()).expect("mesh");
        assert_eq!(mesh.positions.len(), 12);
        // z-depth 2 from an eye at z = 5 looking down −z: on the plane z = 3 (the far pixel on
        // z = 1).
        for (i, p) in mesh.positions.iter().enumerate() {
            let z = if i == 5 { 1.0 } else { 3.0 };
            assert!((p[2] - z).abs() < 1e-5, "{i}: {p:?}");
        }
        // 6 blocks × 2 triangles, less the four triangles touching the far pixel (pixel 5:
        // column 1, row 1, a corner of 4 blocks; each block keeps the triangle without it).
        assert_eq!(mesh.triangles.len(), 12 - 4);
        assert!(mesh.triangles.iter().all(|t| !t.contains(&5)));
        assert!(
            mesh.colors
                .as_ref()
                .expect("colours")
                .iter()
                .all(|c| (c[0] - 200.0 / 255.0).abs() < 1e-6)
        );
        assert_eq!(mesh.materials[0].base_color_factor, [1.0; 4]);
        // A jump threshold above the far pixel's joins it (with no facing limit: the
        // triangles to it are steep).
        let loose = |min_facing| {
            relief_mesh(
                std::slice::from_ref(&image),
                &ImportOptions {
                    max_depth_jump: 1.5,
                    min_facing,
                },
            )
            .expect("mesh")
            .triangles
            .len()
        };
        assert_eq!(loose(0.0), 12);
        // Those seen most obliquely from the eye are left out by the default facing limit.
        let facing = loose(DEFAULT_MIN_FACING);
        assert!((8..12).contains(&facing), "{facing}");
    }

    #[test]
    fn bad_depths_and_options_are_errors() {
        let mut image = plane();
        image.depth[3] = f32::NAN;
        assert!(matches!(
            relief_mesh(&[image], &ImportOptions::default()),
            Err(ImportError::Depth { x: 3, y: 0, .. })
        ));
        let mut image = plane();
        image.depth[7] = -1.0;
        assert!(matches!(
            relief_mesh(&[image], &ImportOptions::default()),
            Err(ImportError::Depth { .. })
        ));
        let mut empty = plane();
        empty.depth = vec![f32::INFINITY; 12];
        assert!(matches!(
            relief_mesh(&[empty], &ImportOptions::default()),
            Err(ImportError::Input(_))
        ));
        for bad in [0.0, -1.0, f32::NAN, 11.0] {
            assert!(matches!(
                relief_mesh(
                    &[plane()],
                    &ImportOptions {
                        max_depth_jump: bad,
                        ..ImportOptions::default()
                    }
                ),
                Err(ImportError::BadJump(_))
            ));
        }
        let mut short = plane();
        short.color.truncate(8);
        assert!(matches!(
            relief_mesh(&[short], &ImportOptions::default()),
            Err(ImportError::Size { .. })
        ));
    }
}
