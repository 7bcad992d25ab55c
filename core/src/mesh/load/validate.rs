//! The one validation step every loader ends with ([`Mesh::finish`]), normal generation and the
//! bounding sphere.

use glam::DVec3;

use super::{bounding, texture};
use crate::mesh::{BoundingSphere, Material, Mesh, MeshError};

/// Format name used in [`MeshError::Parse`] for problems found by [`Mesh::finish`] itself.
const MESH: &str = "mesh";

/// Normal of a vertex that no (non-degenerate) triangle uses: +y, the world's up.
const UNUSED_VERTEX_NORMAL: [f32; 3] = [0.0, 1.0, 0.0];

impl Mesh {
    /// Validates and normalizes a mesh; every loader ends with it.
    ///
    /// In order:
    /// 1. [`MeshError::Empty`] if there are no triangles;
    /// 2. [`MeshError::AttributeLength`] when `normals` (unless empty), `uvs`, `colors` do not
    ///    have one entry per vertex, or `triangle_materials` (unless empty, which means
    ///    material 0 everywhere) one per triangle;
    /// 3. [`MeshError::NonFinite`] for any NaN or infinite position, UV or colour;
    /// 4. [`MeshError::IndexOutOfRange`] for a triangle index past the vertex array;
    /// 5. degenerate triangles (a repeated index, or zero area computed in f64) are dropped;
    ///    [`MeshError::AllDegenerate`] if none remain;
    /// 6. normals: kept and normalized where finite and non-zero; computed (area-weighted face
    ///    normals, f64 accumulation) for every vertex where `normals` is empty, zero or
    ///    non-finite — a file's broken normal is repaired rather than rejected. A vertex whose
    ///    incident face normals cancel gets its largest incident face's normal; one that no
    ///    triangle uses gets +y;
    /// 7. materials: a default one is added if there is none; every triangle's material and
    ///    every material's texture index must be in range and every factor finite
    ///    ([`MeshError::Parse`] otherwise); factors and vertex colours are clamped to `[0, 1]`;
    /// 8. textures: `width * height * 4 == rgba8.len()` and both sides non-zero
    ///    ([`MeshError::Texture`] otherwise); a side above
    ///    [`MAX_TEXTURE_PX`](crate::mesh::MAX_TEXTURE_PX) is downscaled (aspect kept,
    ///    triangle filter).
    pub fn finish(mut self) -> Result<Mesh, MeshError> {
        if self.triangles.is_empty() {
            return Err(MeshError::Empty);
        }
        self.check_lengths()?;
        self.check_finite()?;
        self.check_indices()?;
        self.drop_degenerate()?;
        self.fix_normals();
        self.check_materials()?;
        if let Some(colors) = &mut self.colors {
            for color in colors.iter_mut() {
                *color = color.map(|c| c.clamp(0.0, 1.0));
            }
        }
        for (index, tex) in self.textures.iter_mut().enumerate() {
            texture::validate_and_limit(index, tex)?;
        }
        Ok(self)
    }

    /// The smallest sphere found around the vertices that triangles use (all vertices if no
    /// triangle refers to any), computed in f64.
    ///
    /// Ritter's algorithm, Ericson's shrink-and-regrow refinement passes, then a core-set
    /// refinement (exact minimal sphere of the extreme points plus the farthest outliers) that
    /// in practice reaches the minimal sphere; details in the `bounding` module. The sphere
    /// always contains every such vertex: its radius is the largest distance from the final
    /// centre, plus a relative 1e-9. The radius is > 0 for a finished mesh (it has a triangle of
    /// non-zero area); for a single point or no points it is the smallest positive f64.
    pub fn bounding_sphere(&self) -> BoundingSphere {
        let points = self.referenced_points();
        bounding::bounding_sphere_of(&points)
    }

    fn check_lengths(&mut self) -> Result<(), MeshError> {
        let expected = self.positions.len();
        let check = |attribute: &'static str, got: usize| {
            if got == expected {
                Ok(())
            } else {
                Err(MeshError::AttributeLength {
                    attribute,
                    got,
                    expected,
                })
            }
        };
        if !self.normals.is_empty() {
            check("normals", self.normals.len())?;
        }
        if let Some(uvs) = &self.uvs {
            check("uvs", uvs.len())?;
        }
        if let Some(colors) = &self.colors {
            check("colors", colors.len())?;
        }
        if self.triangle_materials.is_empty() {
            self.triangle_materials = vec![0; self.triangles.len()];
        } else if self.triangle_materials.len() != self.triangles.len() {
            return Err(MeshError::AttributeLength {
                attribute: "triangle_materials",
                got: self.triangle_materials.len(),
                expected: self.triangles.len(),
            });
        }
        Ok(())
    }

    fn check_finite(&self) -> Result<(), MeshError> {
        if let Some(index) = first_non_finite(&self.positions) {
            return Err(MeshError::NonFinite {
                attribute: "position",
                index,
            });
        }
        if let Some(index) = self.uvs.as_deref().and_then(first_non_finite) {
            return Err(MeshError::NonFinite {
                attribute: "uv",
                index,
            });
        }
        if let Some(index) = self.colors.as_deref().and_then(first_non_finite) {
            return Err(MeshError::NonFinite {
                attribute: "color",
                index,
            });
        }
        Ok(())
    }

    fn check_indices(&self) -> Result<(), MeshError> {
        let vertex_count = self.positions.len();
        for (triangle, tri) in self.triangles.iter().enumerate() {
            if let Some(&vertex) = tri.iter().find(|&&v| v as usize >= vertex_count) {
                return Err(MeshError::IndexOutOfRange {
                    triangle,
                    vertex: u64::from(vertex),
                    vertex_count,
                });
            }
        }
        Ok(())
    }

    /// Drops triangles with a repeated index or zero area; indices must be in range.
    fn drop_degenerate(&mut self) -> Result<(), MeshError> {
        let positions = &self.positions;
        let mut kept = 0;
        for i in 0..self.triangles.len() {
            let tri = self.triangles[i];
            if face_cross(positions, tri) != DVec3::ZERO {
                self.triangles[kept] = tri;
                self.triangle_materials[kept] = self.triangle_materials[i];
                kept += 1;
            }
        }
        if kept == 0 {
            return Err(MeshError::AllDegenerate);
        }
        if kept < self.triangles.len() {
            tracing::debug!(
                dropped = self.triangles.len() - kept,
                "dropped degenerate triangles"
            );
        }
        self.triangles.truncate(kept);
        self.triangle_materials.truncate(kept);
        Ok(())
    }

    /// Normalizes usable normals and computes the others; indices must be in range.
    fn fix_normals(&mut self) {
        let vertex_count = self.positions.len();
        let mut missing = vec![self.normals.is_empty(); vertex_count];
        if self.normals.is_empty() {
            self.normals = vec![[0.0; 3]; vertex_count];
        } else {
            for (normal, missing) in self.normals.iter_mut().zip(&mut missing) {
                match unit_f32(DVec3::from(normal.map(f64::from))) {
                    Some(unit) => *normal = unit,
                    None => *missing = true,
                }
            }
        }
        if !missing.contains(&true) {
            return;
        }
        // The cross product's length is twice the triangle's area: summing it area-weights.
        let mut sums = vec![DVec3::ZERO; vertex_count];
        for &tri in &self.triangles {
            let cross = face_cross(&self.positions, tri);
            for v in tri {
                sums[v as usize] += cross;
            }
        }
        let mut unresolved = Vec::new();
        for (v, sum) in sums.iter().enumerate() {
            if missing[v] {
                match unit_f32(*sum) {
                    Some(unit) => self.normals[v] = unit,
                    None => unresolved.push(v),
                }
            }
        }
        if unresolved.is_empty() {
            return;
        }
        // Incident face normals cancel (or no triangle uses the vertex): use the largest face.
        let mut largest = vec![DVec3::ZERO; vertex_count];
        for &tri in &self.triangles {
            let cross = face_cross(&self.positions, tri);
            for v in tri {
                let best = &mut largest[v as usize];
                if cross.length_squared() > best.length_squared() {
                    *best = cross;
                }
            }
        }
        for v in unresolved {
            self.normals[v] = unit_f32(largest[v]).unwrap_or(UNUSED_VERTEX_NORMAL);
        }
    }

    fn check_materials(&mut self) -> Result<(), MeshError> {
        if self.materials.is_empty() {
            self.materials.push(Material::default());
        }
        let material_count = self.materials.len();
        if let Some((triangle, material)) = self
            .triangle_materials
            .iter()
            .enumerate()
            .find(|(_, m)| **m as usize >= material_count)
        {
            return Err(MeshError::Parse {
                format: MESH,
                message: format!(
                    "triangle {triangle} uses material {material}, but there are {material_count} materials"
                ),
            });
        }
        let texture_count = self.textures.len();
        for (index, material) in self.materials.iter_mut().enumerate() {
            if let Some(texture) = material.base_color_texture
                && texture as usize >= texture_count
            {
                return Err(MeshError::Parse {
                    format: MESH,
                    message: format!(
                        "material {index} uses texture {texture}, but there are {texture_count} textures"
                    ),
                });
            }
            if !material.base_color_factor.iter().all(|c| c.is_finite()) {
                return Err(MeshError::Parse {
                    format: MESH,
                    message: format!("material {index} has a non-finite base colour factor"),
                });
            }
            material.base_color_factor = material.base_color_factor.map(|c| c.clamp(0.0, 1.0));
        }
        Ok(())
    }

    /// The distinct vertices that triangles use, in f64 (all vertices if there are no
    /// triangles or their indices are out of range).
    fn referenced_points(&self) -> Vec<DVec3> {
        let mut used = vec![false; self.positions.len()];
        let mut any = false;
        for tri in &self.triangles {
            for &v in tri {
                if let Some(flag) = used.get_mut(v as usize) {
                    *flag = true;
                    any = true;
                }
            }
        }
        self.positions
            .iter()
            .zip(&used)
            .filter(|(_, used)| **used || !any)
            .map(|(p, _)| DVec3::from(p.map(f64::from)))
            .collect()
    }
}

/// The index of the first vector with a NaN or infinite component.
fn first_non_finite<const N: usize>(values: &[[f32; N]]) -> Option<usize> {
    values.iter().position(|v| !v.iter().all(|c| c.is_finite()))
}

/// `(b - a) × (c - a)` in f64 (twice the area times the unit normal); zero for a repeated
/// index. Indices must be in range.
fn face_cross(positions: &[[f32; 3]], [a, b, c]: [u32; 3]) -> DVec3 {
    if a == b || b == c || a == c {
        return DVec3::ZERO;
    }
    let p = |i: u32| DVec3::from(positions[i as usize].map(f64::from));
    let (pa, pb, pc) = (p(a), p(b), p(c));
    (pb - pa).cross(pc - pa)
}

/// The unit vector along `v` as f32, or `None` when `v` is zero or not finite.
fn unit_f32(v: DVec3) -> Option<[f32; 3]> {
    let length = v.length();
    if !(length.is_finite() && length > 0.0) {
        return None;
    }
    let unit = v / length;
    Some([unit.x as f32, unit.y as f32, unit.z as f32])
}
