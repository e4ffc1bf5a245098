//! Triangle meshes: an object's surface, in millimetres.

use nalgebra::{Point3, Vector3};

/// A triangle mesh with one unit normal per vertex.
///
/// A mesh read from a PLY file without normals gets area-weighted normals from its faces. A mesh
/// may have no faces (a point cloud with normals); then it cannot be sampled or rendered, only
/// used point by point.
#[derive(Clone, Debug, Default)]
pub struct Mesh {
    /// Vertex positions, millimetres.
    pub positions: Vec<Point3<f32>>,
    /// One unit normal per vertex.
    pub normals: Vec<Vector3<f32>>,
    /// Triangles as indices into `positions` (counter-clockwise seen from outside).
    pub faces: Vec<[u32; 3]>,
}
