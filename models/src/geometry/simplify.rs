//! Coarser copies of meshes, for rendering silhouettes cheaply.

use nalgebra::Point3;

use crate::geometry::mesh::Mesh;

/// A coarser copy of `mesh` for silhouettes: vertices merged on a grid of `cell_mm` (each
/// cell's vertices replaced by their mean), faces that collapse dropped. Scanned models carry
/// tens of thousands of triangles of a millimetre or so, most smaller than a pixel at working
/// distance; merging them keeps the outline within a cell and makes rendering several times
/// cheaper. The detector's cell is 0.04 D (see
/// [`crate::detect::rescoring::RescoringParams::silhouette_mesh_cell_fraction`]): 4–10 mm for the LM-O
/// objects, 2–6 pixels at 1 m.
pub fn simplified_mesh(mesh: &Mesh, cell_mm: f32) -> Mesh {
    if cell_mm.is_nan() || cell_mm <= 0.0 {
        return mesh.clone();
    }
    let inv = 1.0 / cell_mm;
    let mut cell_of: crate::geometry::grid::CellMap<u32> = Default::default();
    let mut sums: Vec<(nalgebra::Vector3<f32>, u32)> = Vec::new();
    let remap: Vec<u32> = mesh
        .positions
        .iter()
        .map(|p| {
            let key = crate::geometry::grid::cell_of(p, inv);
            let id = *cell_of.entry(key).or_insert_with(|| {
                sums.push((nalgebra::Vector3::zeros(), 0));
                (sums.len() - 1) as u32
            });
            sums[id as usize].0 += p.coords;
            sums[id as usize].1 += 1;
            id
        })
        .collect();
    let positions = sums
        .iter()
        .map(|(s, n)| Point3::from(s / *n as f32))
        .collect();
    let faces = mesh
        .faces
        .iter()
        .map(|f| f.map(|i| remap[i as usize]))
        .filter(|f| f[0] != f[1] && f[1] != f[2] && f[0] != f[2])
        .collect();
    Mesh {
        positions,
        normals: Vec::new(),
        faces,
    }
}
