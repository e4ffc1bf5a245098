//! Whether a mesh makes sense as an object in millimetres, checked before a model is built from
//! it: a diameter outside [`limits::MIN_DIAMETER_MM`]..=[`limits::MAX_DIAMETER_MM`] (a mesh in
//! metres, or another unit) and a single plane are refused, since their models would build and
//! then never match, or match any flat surface; normals that point inward on a closed mesh are
//! reported, for the caller to flip ([`Mesh::flip_normals`]).

use std::collections::HashMap;

use nalgebra::{Point3, Vector3};

use crate::geometry::mesh::Mesh;
use crate::limits;
use crate::model::sampling::diameter;
use crate::{Error, Result};

/// A mesh's extent is a single plane when its thickness along its thinnest direction is below
/// this fraction of its diameter (a 1 mm sheet of 140 mm diameter is 0.007).
pub const PLANE_THICKNESS_FRACTION: f32 = 1e-3;

/// What the checks found in a mesh that passed them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeshReport {
    /// The largest distance between two vertices, mm.
    pub diameter_mm: f32,
    /// Edge lengths of the axis-aligned bounding box, mm.
    pub size_mm: Vector3<f32>,
    /// Every edge is shared by exactly two faces (vertices welded by position).
    pub closed: bool,
    /// Closed, and its normals point inward for the most part (the flux of the normals through
    /// the surface is negative).
    pub inward_normals: bool,
}

impl MeshReport {
    /// The warning of a diameter below [`limits::SMALL_DIAMETER_MM`]
    /// ([`limits::small_diameter`]), for the caller to give; the model is built all the same.
    pub fn small_warning(&self) -> Option<String> {
        limits::small_diameter(self.diameter_mm)
    }

    /// "diameter 103.2 mm, size 80.0 × 60.0 × 40.0 mm".
    pub fn describe(&self) -> String {
        let s = self.size_mm;
        format!(
            "diameter {:.1} mm, size {:.1} × {:.1} × {:.1} mm",
            self.diameter_mm, s.x, s.y, s.z
        )
    }
}

/// Checks `mesh` (see the module documentation); refusals say what is wrong and what to do.
pub fn check_mesh(mesh: &Mesh) -> Result<MeshReport> {
    let diameter_mm = diameter(&mesh.positions);
    if let Some(reason) = limits::diameter_out_of_range(diameter_mm) {
        return Err(Error::InvalidMesh(reason));
    }
    let thickness = thinnest_extent(&mesh.positions);
    if thickness < PLANE_THICKNESS_FRACTION * diameter_mm {
        return Err(Error::InvalidMesh(format!(
            "the mesh is a single plane ({thickness} mm thick at a diameter of {diameter_mm} mm): \
             a flat model matches any flat surface; give the object's whole surface"
        )));
    }
    let size_mm = mesh
        .bounding_box()
        .map_or_else(Vector3::zeros, |b| b.size());
    let closed = is_closed(mesh);
    let inward_normals = closed && normal_flux(mesh) < 0.0;
    Ok(MeshReport {
        diameter_mm,
        size_mm,
        closed,
        inward_normals,
    })
}

/// The extent of `points` along their direction of least variance, mm.
fn thinnest_extent(points: &[Point3<f32>]) -> f32 {
    let n = points.len().max(1) as f64;
    let mean = points
        .iter()
        .fold(Vector3::<f64>::zeros(), |a, p| a + p.coords.cast::<f64>())
        / n;
    let cov = points
        .iter()
        .fold(nalgebra::Matrix3::<f64>::zeros(), |a, p| {
            let d = p.coords.cast::<f64>() - mean;
            a + d * d.transpose()
        })
        / n;
    let eigen = cov.symmetric_eigen();
    let axis = eigen
        .eigenvectors
        .column(eigen.eigenvalues.imin())
        .into_owned();
    let (lo, hi) = points.iter().fold((f64::MAX, f64::MIN), |(lo, hi), p| {
        let s = (p.coords.cast::<f64>() - mean).dot(&axis);
        (lo.min(s), hi.max(s))
    });
    (hi - lo).max(0.0) as f32
}

/// Whether every edge of `mesh` is shared by exactly two faces, with vertices of equal
/// position taken as one (a mesh split at creases for its normals is still closed).
fn is_closed(mesh: &Mesh) -> bool {
    if mesh.faces.is_empty() {
        return false;
    }
    let mut welded: HashMap<[u32; 3], u32> = HashMap::new();
    let ids: Vec<u32> = mesh
        .positions
        .iter()
        .map(|p| {
            let key = [p.x, p.y, p.z].map(|c| (c + 0.0).to_bits());
            let next = welded.len() as u32;
            *welded.entry(key).or_insert(next)
        })
        .collect();
    let mut edges: HashMap<(u32, u32), u32> = HashMap::new();
    for f in &mesh.faces {
        let [a, b, c] = f.map(|i| ids[i as usize]);
        for (u, v) in [(a, b), (b, c), (c, a)] {
            *edges.entry((u.min(v), u.max(v))).or_insert(0) += 1;
        }
    }
    edges.values().all(|&n| n == 2)
}

/// The flux of the vertex normals (of the faces' winding, for a mesh without normals) through
/// the surface about the centroid: positive when they point outward (on a closed surface it is
/// three times the enclosed volume for exact normals).
fn normal_flux(mesh: &Mesh) -> f64 {
    let n = mesh.positions.len() as f64;
    let centre = mesh
        .positions
        .iter()
        .fold(Vector3::<f64>::zeros(), |a, p| a + p.coords.cast::<f64>())
        / n;
    mesh.faces
        .iter()
        .map(|f| {
            let [a, b, c] = f.map(|i| mesh.positions[i as usize].coords.cast::<f64>());
            let area = 0.5 * (b - a).cross(&(c - a)).norm();
            // The vertex normals where the mesh has them, else its winding's.
            let normal: Vector3<f64> = if mesh.normals.len() == mesh.positions.len() {
                f.iter()
                    .map(|&i| mesh.normals[i as usize].cast::<f64>())
                    .sum()
            } else {
                (b - a).cross(&(c - a))
            };
            area * ((a + b + c) / 3.0 - centre).dot(&normal)
        })
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synthetic::parts::box_mesh;

    #[test]
    fn a_part_in_millimetres_passes_with_its_size() {
        let r = check_mesh(&box_mesh(Vector3::new(60.0, 40.0, 20.0))).unwrap();
        assert!((r.diameter_mm - 74.83).abs() < 0.1, "{r:?}");
        assert!((r.size_mm - Vector3::new(60.0, 40.0, 20.0)).norm() < 1e-3);
        assert!(r.closed && !r.inward_normals, "{r:?}");
        assert!(r.describe().contains("60.0 × 40.0 × 20.0 mm"));
    }

    /// A mesh of a 100 mm part in centimetres passes, with the warning that names the scale.
    #[test]
    fn a_mesh_in_centimetres_passes_with_a_warning() {
        let r = check_mesh(&box_mesh(Vector3::new(8.0, 4.0, 4.4))).unwrap();
        let w = r.small_warning().unwrap();
        assert!(w.contains("centimetres") && w.contains("--scale"), "{w}");
        let r = check_mesh(&box_mesh(Vector3::new(60.0, 40.0, 20.0))).unwrap();
        assert!(r.small_warning().is_none(), "{r:?}");
    }

    #[test]
    fn a_mesh_in_metres_is_refused_with_the_scale() {
        let e = check_mesh(&box_mesh(Vector3::new(0.06, 0.04, 0.02))).unwrap_err();
        let m = e.to_string();
        assert!(m.contains("metres") && m.contains("--scale 1000"), "{m}");
    }

    #[test]
    fn a_single_triangle_is_refused_as_a_plane() {
        let mesh = Mesh::from_triangles(
            vec![
                Point3::new(0.0, 0.0, 0.0),
                Point3::new(100.0, 0.0, 0.0),
                Point3::new(0.0, 100.0, 0.0),
            ],
            &[[0, 1, 2]],
        )
        .unwrap();
        let m = check_mesh(&mesh).unwrap_err().to_string();
        assert!(m.contains("single plane"), "{m}");
    }

    #[test]
    fn inward_normals_on_a_closed_mesh_are_found_and_flipped() {
        let mut mesh = box_mesh(Vector3::new(60.0, 40.0, 20.0));
        mesh.flip_normals();
        assert!(check_mesh(&mesh).unwrap().inward_normals);
        mesh.flip_normals();
        assert!(!check_mesh(&mesh).unwrap().inward_normals);
    }
}
