//! Triangle meshes: an object's surface, in millimetres.
//!
//! A [`Mesh`] comes from a PLY file ([`Mesh::from_ply_file`], [`Mesh::from_ply_reader`]) or from
//! generated triangles ([`Mesh::from_triangles`]). Either way every vertex carries a unit normal.

use std::path::Path;

use nalgebra::{Point3, Vector3};

use crate::{Error, Pose, Result};

mod ply;

/// Largest deviation from 1 that [`Mesh::validate`] accepts in a normal's length.
const UNIT_NORMAL_TOLERANCE: f32 = 1e-3;

/// A triangle mesh with one unit normal per vertex.
///
/// A mesh read from a PLY file without normals gets normals from its faces, with a vertex per
/// side of each crease ([`CREASE_ANGLE_DEG`]). A mesh
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

/// An axis-aligned box, millimetres.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BoundingBox {
    /// The corner with the smallest coordinates.
    pub min: Point3<f32>,
    /// The corner with the largest coordinates.
    pub max: Point3<f32>,
}

impl BoundingBox {
    /// Edge lengths along x, y and z.
    pub fn size(&self) -> Vector3<f32> {
        self.max - self.min
    }

    /// The centre of the box.
    pub fn centre(&self) -> Point3<f32> {
        nalgebra::center(&self.min, &self.max)
    }
}

impl Mesh {
    /// Reads a PLY file (ASCII, binary little or big endian).
    ///
    /// Vertices need `x`, `y`, `z` (float, double or integer); `nx`, `ny`, `nz` are optional and
    /// normalised when present; other vertex properties and other elements are ignored. Faces
    /// are read from the `face` element's `vertex_indices` (or `vertex_index`) list of any
    /// integer type; polygons are fan-triangulated and degenerate triangles (a repeated index or
    /// zero area) are skipped, and then vertices that no face uses are dropped (a file without
    /// faces is read as a point cloud, every vertex kept). A file without normals gets them from
    /// its faces, as
    /// [`Mesh::from_triangles`] does (split at creases); a vertex whose normal in the file has
    /// zero length gets the area-weighted normal of its faces.
    ///
    /// Errors: [`Error::Io`] when the file cannot be opened, [`Error::File`] for a special file
    /// or one beyond [`crate::limits::MESH_FILE`] or whose header declares more vertices or
    /// faces than [`crate::limits::MAX_MESH_VERTICES`] or [`crate::limits::MAX_MESH_FACES`],
    /// [`Error::Ply`] naming what is wrong
    /// and where for anything malformed (truncated data, a missing coordinate, a non-finite
    /// value, a face index out of range, no vertices, a point cloud's vertex with a zero normal).
    pub fn from_ply_file(path: impl AsRef<Path>) -> Result<Mesh> {
        let path = path.as_ref();
        let bytes = crate::file::read_bounded(path, &crate::limits::MESH_FILE)?;
        ply::read_mesh(&bytes[..], path)
    }

    /// Reads a PLY mesh from any reader, exactly as [`Mesh::from_ply_file`] does; errors name
    /// `name_for_errors` as the path.
    pub fn from_ply_reader<R: std::io::Read>(
        reader: R,
        name_for_errors: impl AsRef<Path>,
    ) -> Result<Mesh> {
        ply::read_mesh(reader, name_for_errors.as_ref())
    }

    /// Builds a mesh from vertex positions and triangles, with normals from the faces
    /// ([`CREASE_ANGLE_DEG`]: a vertex on a crease becomes one vertex per side).
    ///
    /// Degenerate triangles (a repeated index or zero area) are dropped. Refuses (with
    /// [`Error::InvalidMesh`]) an empty vertex list, non-finite positions, indices out of range,
    /// and vertices that lie on no triangle of non-zero area (they can get no normal).
    pub fn from_triangles(positions: Vec<Point3<f32>>, faces: &[[u32; 3]]) -> Result<Mesh> {
        if positions.is_empty() {
            return Err(Error::InvalidMesh("the mesh has no vertices".into()));
        }
        if let Some(i) = positions
            .iter()
            .position(|p| !p.coords.iter().all(|c| c.is_finite()))
        {
            return Err(Error::InvalidMesh(format!(
                "vertex {i} has a non-finite position {:?}",
                positions[i].coords.as_slice()
            )));
        }
        let mut kept = Vec::with_capacity(faces.len());
        for (f, face) in faces.iter().enumerate() {
            if let Some(&bad) = face.iter().find(|&&v| v as usize >= positions.len()) {
                return Err(Error::InvalidMesh(format!(
                    "face {f}: vertex index {bad} is out of range (the mesh has {} vertices)",
                    positions.len()
                )));
            }
            if !is_degenerate(&positions, *face) {
                kept.push(*face);
            }
        }
        with_normals_from_faces(&positions, &kept).map_err(|i| {
            Error::InvalidMesh(format!(
                "vertex {i} lies on no triangle of non-zero area, so it has no normal"
            ))
        })
    }

    /// Turns every normal around and reverses every face's winding, so that both point the
    /// other way: for a mesh whose normals point inward
    /// ([`crate::model::sanity::MeshReport::inward_normals`]).
    pub fn flip_normals(&mut self) {
        for n in &mut self.normals {
            *n = -*n;
        }
        for f in &mut self.faces {
            f.swap(1, 2);
        }
    }

    /// Scales every position by `factor` (normals keep their direction): a mesh in another unit
    /// brought into millimetres.
    pub fn scale(&mut self, factor: f32) {
        for p in &mut self.positions {
            p.coords *= factor;
        }
    }

    /// Checks the invariants the rest of the crate relies on: at least one vertex, one normal
    /// per vertex, finite positions, unit normals (within 1e-3), face indices in range.
    pub fn validate(&self) -> Result<()> {
        if self.positions.is_empty() {
            return Err(Error::InvalidMesh("the mesh has no vertices".into()));
        }
        if self.normals.len() != self.positions.len() {
            return Err(Error::InvalidMesh(format!(
                "{} vertices need as many normals, got {}",
                self.positions.len(),
                self.normals.len()
            )));
        }
        for (i, (p, n)) in self.positions.iter().zip(&self.normals).enumerate() {
            if !p.coords.iter().all(|c| c.is_finite()) {
                return Err(Error::InvalidMesh(format!(
                    "vertex {i} has a non-finite position {:?}",
                    p.coords.as_slice()
                )));
            }
            let length = n.norm();
            if length.is_nan() || (length - 1.0).abs() > UNIT_NORMAL_TOLERANCE {
                return Err(Error::InvalidMesh(format!(
                    "vertex {i}: normal {:?} has length {length}, expected 1",
                    n.as_slice()
                )));
            }
        }
        for (f, face) in self.faces.iter().enumerate() {
            if let Some(&bad) = face.iter().find(|&&v| v as usize >= self.positions.len()) {
                return Err(Error::InvalidMesh(format!(
                    "face {f}: vertex index {bad} is out of range (the mesh has {} vertices)",
                    self.positions.len()
                )));
            }
        }
        Ok(())
    }

    /// The smallest axis-aligned box holding every vertex; `None` for a mesh with no vertices.
    pub fn bounding_box(&self) -> Option<BoundingBox> {
        let first = *self.positions.first()?;
        let (min, max) = self.positions.iter().fold((first, first), |(lo, hi), p| {
            (
                lo.coords.inf(&p.coords).into(),
                hi.coords.sup(&p.coords).into(),
            )
        });
        Some(BoundingBox { min, max })
    }

    /// Total area of the triangles, square millimetres (0 for a mesh without faces).
    pub fn surface_area(&self) -> f32 {
        let twice: f64 = self
            .faces
            .iter()
            .map(|&[a, b, c]| {
                let [a, b, c] = [a, b, c].map(|i| self.positions[i as usize].cast::<f64>());
                (b - a).cross(&(c - a)).norm()
            })
            .sum();
        (0.5 * twice) as f32
    }

    /// This mesh moved by `pose`: positions transformed, normals rotated, faces unchanged.
    pub fn transformed(&self, pose: &Pose) -> Mesh {
        Mesh {
            positions: self.positions.iter().map(|p| pose * p).collect(),
            normals: self.normals.iter().map(|n| pose.rotation * n).collect(),
            faces: self.faces.clone(),
        }
    }

    /// The mesh as an ASCII PLY file (positions, normals, triangles). [`Mesh::from_ply_reader`]
    /// reads back the same positions and triangles exactly (floats are written with enough digits
    /// to round-trip) and the same normals to within rounding (it normalises them again).
    pub fn to_ply_ascii(&self) -> String {
        use std::fmt::Write;
        let mut text = format!(
            "ply\nformat ascii 1.0\nelement vertex {}\nproperty float x\nproperty float y\n\
             property float z\nproperty float nx\nproperty float ny\nproperty float nz\n\
             element face {}\nproperty list uchar int vertex_indices\nend_header\n",
            self.positions.len(),
            self.faces.len()
        );
        for (i, p) in self.positions.iter().enumerate() {
            let n = self.normals.get(i).copied().unwrap_or_else(Vector3::zeros);
            let _ = writeln!(text, "{} {} {} {} {} {}", p.x, p.y, p.z, n.x, n.y, n.z);
        }
        for [a, b, c] in &self.faces {
            let _ = writeln!(text, "3 {a} {b} {c}");
        }
        text
    }

    /// A fingerprint of the geometry a model is built from, to tell whether a model still
    /// belongs to this mesh: the CRC-32 of the vertex count, every position and normal, the
    /// triangle count and every triangle, in that order, as little-endian `u32`/`f32` bytes
    /// (`-0.0` counted as `0.0`). It depends only on these numbers, so a mesh read from an ASCII
    /// or a binary PLY file with the same values gets the same fingerprint; normals count because
    /// the model's oriented points interpolate them.
    pub fn fingerprint(&self) -> u32 {
        let mut crc = crc32fast::Hasher::new();
        let mut buf = Vec::with_capacity(24 * 1024);
        let mut flush = |buf: &mut Vec<u8>, force: bool| {
            if force || buf.len() >= 24 * 1023 {
                crc.update(buf);
                buf.clear();
            }
        };
        // Adding 0.0 turns -0.0 into 0.0 and leaves every other value as it is.
        let put_f32 = |buf: &mut Vec<u8>, x: f32| buf.extend_from_slice(&(x + 0.0).to_le_bytes());
        buf.extend_from_slice(&(self.positions.len() as u64).to_le_bytes());
        for (i, p) in self.positions.iter().enumerate() {
            p.coords.iter().for_each(|&x| put_f32(&mut buf, x));
            let n = self.normals.get(i).copied().unwrap_or_else(Vector3::zeros);
            n.iter().for_each(|&x| put_f32(&mut buf, x));
            flush(&mut buf, false);
        }
        buf.extend_from_slice(&(self.faces.len() as u64).to_le_bytes());
        for face in &self.faces {
            face.iter()
                .for_each(|i| buf.extend_from_slice(&i.to_le_bytes()));
            flush(&mut buf, false);
        }
        flush(&mut buf, true);
        crc.finalize()
    }
}

/// True when a triangle has a repeated index or (numerically) zero area.
fn is_degenerate(positions: &[Point3<f32>], [a, b, c]: [u32; 3]) -> bool {
    if a == b || b == c || a == c {
        return true;
    }
    let [pa, pb, pc] = [a, b, c].map(|i| positions[i as usize].cast::<f64>());
    let (e1, e2) = (pb - pa, pc - pa);
    let twice_area = e1.cross(&e2).norm();
    // Relative test: sin of the angle at `a` below 1e-9 is collinear up to rounding.
    twice_area.is_nan() || twice_area <= 1e-9 * e1.norm() * e2.norm()
}

/// Faces meeting at a vertex at more than this angle (degrees) meet at a crease, where normals
/// taken from faces do not blend: the vertex becomes one vertex per side, each with the normal
/// of its own side.
///
/// A mesh without normals, as CAD exports often are, needs this: the mean normal of all of a
/// cube corner's faces is 55° from each of them, and interpolated across a face it tilts the
/// face's samples by up to 50° where the sensor sees a flat face. Curved surfaces tessellated
/// finely enough to be modelled (faces a few degrees apart) stay smooth. The value is the
/// normal-clustering angle of subsampling.
pub const CREASE_ANGLE_DEG: f64 = 30.0;

/// The mesh of `positions` and the non-degenerate `faces`, with normals from the faces split at
/// creases ([`CREASE_ANGLE_DEG`]), or the first vertex that lies on no face (it could get no
/// normal).
pub(crate) fn with_normals_from_faces(
    positions: &[Point3<f32>],
    faces: &[[u32; 3]],
) -> std::result::Result<Mesh, usize> {
    let mut used = vec![false; positions.len()];
    for f in faces {
        for &v in f {
            used[v as usize] = true;
        }
    }
    if let Some(unused) = used.iter().position(|&u| !u) {
        return Err(unused);
    }
    let positions: Vec<Point3<f64>> = positions.iter().map(|p| p.cast()).collect();
    Ok(split_creases(
        &positions,
        faces,
        CREASE_ANGLE_DEG.to_radians(),
    ))
}

/// Gives every face corner the angle-weighted mean normal of the faces around its vertex that lie
/// within `crease_rad` of the corner's own face, and makes one output vertex per distinct
/// (position, normal).
pub(crate) fn split_creases(
    positions: &[Point3<f64>],
    faces: &[[u32; 3]],
    crease_rad: f64,
) -> Mesh {
    let cos_crease = crease_rad.cos();
    let cos_half_crease = (crease_rad / 2.0).cos();
    // Unit normal per face; zero for a face without area, which then joins no side.
    let face_normals: Vec<Vector3<f64>> = faces
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| positions[i as usize]);
            (b - a)
                .cross(&(c - a))
                .try_normalize(0.0)
                .unwrap_or_else(Vector3::zeros)
        })
        .collect();
    // Per corner, its angle: the weight of its face's normal at the vertex.
    let corner_angles: Vec<[f64; 3]> = faces
        .iter()
        .map(|t| {
            [0, 1, 2].map(|k| {
                let p = positions[t[k] as usize];
                let (e1, e2) = (
                    positions[t[(k + 1) % 3] as usize] - p,
                    positions[t[(k + 2) % 3] as usize] - p,
                );
                let angle = e1.angle(&e2);
                if angle.is_finite() {
                    angle
                } else {
                    0.0
                }
            })
        })
        .collect();
    // The corners (face, corner) around each vertex, flat.
    let mut offsets = vec![0usize; positions.len() + 1];
    for t in faces {
        for &v in t {
            offsets[v as usize + 1] += 1;
        }
    }
    for v in 0..positions.len() {
        offsets[v + 1] += offsets[v];
    }
    let mut next = offsets.clone();
    let mut around = vec![(0usize, 0usize); offsets[positions.len()]];
    for (f, t) in faces.iter().enumerate() {
        for (k, &v) in t.iter().enumerate() {
            around[next[v as usize]] = (f, k);
            next[v as usize] += 1;
        }
    }
    let mut mesh = Mesh::default();
    let mut out_faces = vec![[0u32; 3]; faces.len()];
    let mut made: Vec<(Vector3<f64>, u32)> = Vec::new();
    for v in 0..positions.len() {
        let corners = &around[offsets[v]..offsets[v + 1]];
        let weighted = |&(g, kg): &(usize, usize)| face_normals[g] * corner_angles[g][kg];
        let mean = corners
            .iter()
            .map(weighted)
            .sum::<Vector3<f64>>()
            .try_normalize(0.0);
        let add = |n: Vector3<f64>, mesh: &mut Mesh| {
            mesh.positions.push(positions[v].cast::<f32>());
            mesh.normals.push(n.cast::<f32>().normalize());
            (mesh.positions.len() - 1) as u32
        };
        // Every face within half the crease angle of the mean: any two are within the crease
        // angle, so every corner has the same side, all of them (a flat or gently curved fan
        // of any size, in one pass).
        if let Some(m) = mean.filter(|m| {
            corners.iter().all(|&(g, _)| {
                face_normals[g] == Vector3::zeros() || face_normals[g].dot(m) >= cos_half_crease
            })
        }) {
            let index = add(m, &mut mesh);
            for &(f, k) in corners {
                out_faces[f][k] = index;
            }
            continue;
        }
        made.clear();
        for &(f, k) in corners {
            let nf = face_normals[f];
            let n = corners
                .iter()
                .filter(|&&(g, _)| face_normals[g].dot(&nf) >= cos_crease)
                .map(weighted)
                .sum::<Vector3<f64>>()
                .try_normalize(0.0)
                // A corner of a face without area takes the mean of the vertex's faces.
                .or(mean)
                .unwrap_or_else(Vector3::z);
            let index = match made.iter().find(|(m, _)| (m - n).norm() < 1e-6) {
                Some(&(_, i)) => i,
                None => {
                    let i = add(n, &mut mesh);
                    made.push((n, i));
                    i
                }
            };
            out_faces[f][k] = index;
        }
    }
    mesh.faces = out_faces;
    mesh
}

/// Per vertex, the area-weighted mean of its triangles' normals, or `None` for a vertex on no
/// triangle of non-zero area.
///
/// Where the normals cancel out (a two-sided sheet: the same triangle twice with opposite
/// windings), the vertex takes the normal of its largest triangle instead: either side is as
/// good as the other, and the vertex keeps its place in the mesh.
fn vertex_normals_from_faces(
    positions: &[Point3<f32>],
    faces: &[[u32; 3]],
) -> Vec<Option<Vector3<f32>>> {
    // f64 so that large meshes do not lose small triangles.
    let mut sums = vec![Vector3::<f64>::zeros(); positions.len()];
    let mut total_area = vec![0.0f64; positions.len()];
    let mut largest = vec![(0.0f64, Vector3::<f64>::zeros()); positions.len()];
    for &[a, b, c] in faces {
        let [pa, pb, pc] = [a, b, c].map(|i| positions[i as usize].cast::<f64>());
        let weighted = (pb - pa).cross(&(pc - pa));
        let area = weighted.norm();
        for i in [a, b, c].map(|i| i as usize) {
            sums[i] += weighted;
            total_area[i] += area;
            if area > largest[i].0 {
                largest[i] = (area, weighted);
            }
        }
    }
    (0..positions.len())
        .map(|i| {
            if sums[i].norm() > 1e-6 * total_area[i] {
                unit_f32(&sums[i])
            } else {
                unit_f32(&largest[i].1)
            }
        })
        .collect()
}

/// `v` scaled to unit length in f32, or `None` when it has no direction.
fn unit_f32(v: &Vector3<f64>) -> Option<Vector3<f32>> {
    let length = v.norm();
    if !(length > 0.0 && length.is_finite()) {
        return None;
    }
    let n = (v / length).cast::<f32>();
    // Re-normalise in f32 so that the stored length is 1 to f32 precision.
    Some(n / n.norm())
}

/// The sides of a cube whose corner `i` has the coordinate signs of bits 1, 2 and 4 of `i`, as
/// quads counter-clockwise seen from outside.
#[cfg(test)]
pub(crate) const CUBE_QUADS: [[u32; 4]; 6] = [
    [0, 4, 6, 2],
    [1, 3, 7, 5],
    [0, 1, 5, 4],
    [2, 6, 7, 3],
    [0, 2, 3, 1],
    [4, 5, 7, 6],
];

/// A cube of half-size `half` mm centred at the origin, as a CAD export without normals gives
/// it: 8 corners shared by 12 outward-facing triangles, normals taken from the faces.
#[cfg(test)]
pub(crate) fn welded_cube(half: f32) -> Mesh {
    let positions: Vec<Point3<f32>> = (0..8u32)
        .map(|i| {
            let s = |bit: u32| if i & bit != 0 { half } else { -half };
            Point3::new(s(1), s(2), s(4))
        })
        .collect();
    let faces: Vec<[u32; 3]> = CUBE_QUADS
        .iter()
        .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
        .collect();
    Mesh::from_triangles(positions, &faces).unwrap()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    /// A 20 mm cube centred at the origin.
    fn cube() -> Mesh {
        welded_cube(10.0)
    }

    #[test]
    fn ascii_ply_reads_back_to_the_same_mesh() {
        let mesh = crate::synthetic::parts::Part::TPipe.mesh();
        let text = mesh.to_ply_ascii();
        let back = Mesh::from_ply_reader(text.as_bytes(), "t_pipe.ply").unwrap();
        assert!(back.positions == mesh.positions, "positions differ");
        assert!(back.faces == mesh.faces, "faces differ");
        assert_eq!(back.normals.len(), mesh.normals.len());
        let worst = back
            .normals
            .iter()
            .zip(&mesh.normals)
            .map(|(a, b)| (a - b).norm())
            .fold(0.0f32, f32::max);
        assert!(worst < 1e-6, "a normal moved by {worst}");
    }

    #[test]
    fn cube_normals_point_outward_and_are_unit() {
        let mesh = cube();
        mesh.validate().unwrap();
        for (p, n) in mesh.positions.iter().zip(&mesh.normals) {
            assert!((n.norm() - 1.0).abs() < 1e-6);
            assert!(
                n.dot(&p.coords.normalize()) > 0.5,
                "normal {n:?} at {p:?} points inward"
            );
        }
    }

    #[test]
    fn cube_area_and_box() {
        let mesh = cube();
        assert!(
            (mesh.surface_area() - 2400.0).abs() < 1e-3,
            "area {}",
            mesh.surface_area()
        );
        let bb = mesh.bounding_box().unwrap();
        assert_eq!(bb.min, Point3::new(-10.0, -10.0, -10.0));
        assert_eq!(bb.max, Point3::new(10.0, 10.0, 10.0));
        assert_eq!(bb.size(), Vector3::new(20.0, 20.0, 20.0));
        assert_eq!(bb.centre(), Point3::origin());
        assert!(Mesh::default().bounding_box().is_none());
    }

    #[test]
    fn degenerate_triangles_are_dropped() {
        let positions = vec![
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(1.0, 0.0, 0.0),
            Point3::new(0.0, 1.0, 0.0),
            Point3::new(2.0, 0.0, 0.0),
        ];
        // Repeated index, then collinear points, then one good triangle.
        let mesh = Mesh::from_triangles(positions, &[[0, 0, 1], [0, 1, 3], [0, 1, 2], [1, 3, 2]]);
        let mesh = mesh.unwrap();
        assert_eq!(mesh.faces, vec![[0, 1, 2], [1, 3, 2]]);
        assert!(mesh
            .normals
            .iter()
            .all(|n| (n - Vector3::z()).norm() < 1e-6));
    }

    /// A face without area (three points in a line) among others: every normal stays a unit
    /// vector, the face's corners taking the mean of their vertex's faces.
    #[test]
    fn a_face_without_area_gets_no_broken_normal() {
        let positions: Vec<Point3<f64>> = vec![
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(1.0, 0.0, 0.0),
            Point3::new(0.0, 1.0, 0.0),
            Point3::new(2.0, 0.0, 0.0),
        ];
        let mesh = split_creases(&positions, &[[0, 1, 2], [0, 1, 3]], 30f64.to_radians());
        assert!(mesh
            .normals
            .iter()
            .all(|n| (n.norm() - 1.0).abs() < 1e-6 && (n - Vector3::z()).norm() < 1e-6));
        mesh.validate().unwrap();
    }

    #[test]
    fn two_sided_sheet_gets_a_vertex_per_side() {
        let positions = vec![
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(1.0, 0.0, 0.0),
            Point3::new(0.0, 1.0, 0.0),
        ];
        let mesh = Mesh::from_triangles(positions, &[[0, 1, 2], [1, 0, 2]]).unwrap();
        assert_eq!(mesh.positions.len(), 6);
        for (face, side) in mesh.faces.iter().zip([1.0, -1.0]) {
            for &v in face {
                let n = mesh.normals[v as usize];
                assert!((n - Vector3::z() * side).norm() < 1e-6, "{n:?}");
            }
        }
    }

    #[test]
    fn vertex_on_no_face_is_refused() {
        let positions = vec![
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(1.0, 0.0, 0.0),
            Point3::new(0.0, 1.0, 0.0),
            Point3::new(5.0, 5.0, 5.0),
        ];
        let err = Mesh::from_triangles(positions, &[[0, 1, 2]]).unwrap_err();
        assert!(matches!(err, Error::InvalidMesh(_)));
        assert!(err.to_string().contains("vertex 3"), "{err}");
    }

    #[test]
    fn transformed_moves_points_and_rotates_normals() {
        let mesh = cube();
        let pose = Pose::from_parts(
            Translation3::new(100.0, -50.0, 700.0),
            UnitQuaternion::from_euler_angles(0.3, -1.1, 2.0),
        );
        let moved = mesh.transformed(&pose);
        moved.validate().unwrap();
        assert_eq!(moved.faces, mesh.faces);
        for i in 0..mesh.positions.len() {
            let expected = pose.rotation * mesh.positions[i] + pose.translation.vector;
            assert!((moved.positions[i] - expected).norm() < 1e-3);
            assert!((moved.normals[i] - pose.rotation * mesh.normals[i]).norm() < 1e-6);
        }
        assert!((moved.surface_area() - mesh.surface_area()).abs() < 1e-2);
    }

    #[test]
    fn validate_catches_broken_meshes() {
        let good = cube();
        let mut short = good.clone();
        short.normals.pop();
        assert!(short
            .validate()
            .unwrap_err()
            .to_string()
            .contains("normals"));
        let mut long_normal = good.clone();
        long_normal.normals[3] *= 2.0;
        assert!(long_normal
            .validate()
            .unwrap_err()
            .to_string()
            .contains("vertex 3"));
        let mut bad_face = good.clone();
        bad_face.faces[5] = [0, 1, good.positions.len() as u32];
        assert!(bad_face
            .validate()
            .unwrap_err()
            .to_string()
            .contains("face 5"));
        let mut nan = good;
        nan.positions[2].x = f32::NAN;
        assert!(nan.validate().unwrap_err().to_string().contains("vertex 2"));
        assert!(Mesh::default().validate().is_err());
    }

    #[test]
    fn fingerprint_follows_positions_normals_and_faces() {
        let good = cube();
        let reference = good.fingerprint();
        assert_eq!(cube().fingerprint(), reference, "deterministic");
        let mut moved = good.clone();
        moved.positions[4].z += 0.001;
        let mut turned = good.clone();
        turned.normals[4] = -turned.normals[4];
        let mut rewound = good.clone();
        rewound.faces[7].swap(1, 2);
        let mut fewer = good.clone();
        fewer.faces.pop();
        let others = [&moved, &turned, &rewound, &fewer].map(Mesh::fingerprint);
        for (i, f) in others.iter().enumerate() {
            assert_ne!(*f, reference, "change {i}");
        }
        // -0.0 and 0.0 are one number.
        let mut flat = good.clone();
        flat.positions[0].x = 0.0;
        let mut negative_zero = good;
        negative_zero.positions[0].x = -0.0;
        assert_eq!(flat.fingerprint(), negative_zero.fingerprint());
    }
}
