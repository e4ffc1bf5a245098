//! Area-uniform surface sampling of a mesh, and the model diameter.
//!
//! CAD vertex layouts are very irregular (long thin triangles on flat faces, dense fans on
//! curves), so model points come from sampling the surface densely and uniformly by area rather
//! than from the vertices.

use nalgebra::{Point3, Vector3};

use crate::geometry::mesh::Mesh;
use crate::geometry::rng::Rng;
use crate::model::subsample::OrientedPoints;
use crate::{Error, Result};

/// Samples the surface of `mesh` uniformly by area with about `count` points. Normals are the
/// vertex normals interpolated at the sample and normalised (the face normal where they cancel).
pub fn sample_surface(mesh: &Mesh, count: usize, seed: u64) -> Result<OrientedPoints> {
    if mesh.faces.is_empty() {
        return Err(Error::InvalidMesh(
            "cannot sample a surface without faces".into(),
        ));
    }
    let areas: Vec<f32> = mesh
        .faces
        .iter()
        .map(|f| {
            let [a, b, c] = f.map(|i| mesh.positions[i as usize]);
            0.5 * (b - a).cross(&(c - a)).norm()
        })
        .collect();
    let total: f64 = areas.iter().map(|&a| a as f64).sum();
    if total.is_nan() || total <= 0.0 {
        return Err(Error::InvalidMesh("mesh has zero surface area".into()));
    }
    let mut rng = Rng::new(seed);
    let mut out = OrientedPoints::default();
    let per_area = count as f64 / total;
    for (f, &area) in mesh.faces.iter().zip(&areas) {
        // Expected count per face, the fraction decided at random: area-uniform overall, and
        // no face, however small, is systematically skipped.
        let expected = area as f64 * per_area;
        let mut n = expected.floor() as usize;
        if ((rng.uniform() as f32) as f64) < expected - n as f64 {
            n += 1;
        }
        let [ia, ib, ic] = f.map(|i| i as usize);
        let (a, b, c) = (mesh.positions[ia], mesh.positions[ib], mesh.positions[ic]);
        let face_normal = (b - a).cross(&(c - a));
        for _ in 0..n {
            let (mut u, mut v) = ((rng.uniform() as f32), (rng.uniform() as f32));
            if u + v > 1.0 {
                (u, v) = (1.0 - u, 1.0 - v);
            }
            let w = 1.0 - u - v;
            let p = Point3::from(a.coords * w + b.coords * u + c.coords * v);
            let n = mesh.normals[ia] * w + mesh.normals[ib] * u + mesh.normals[ic] * v;
            let n = if n.norm() > 1e-6 {
                n.normalize()
            } else {
                face_normal.normalize()
            };
            out.push(p, n);
        }
    }
    Ok(out)
}

/// The largest distance between two of `points`, mm. The endpoints of a diameter are extreme
/// along some direction; the points extreme along 64 directions, each paired with every point,
/// find it (or a pair within a fraction of a percent of it) in O(64·N).
///
/// The points are taken in blocks of `DIAMETER_BLOCK` with their bounding boxes: a block
/// whose farthest corner is no farther from a candidate than the best pair so far cannot hold a
/// farther point, and is skipped. The result is the same maximum of the same distances; a model
/// store checks every file's diameter against its mesh on load, so this is paid on every load.
pub fn diameter(points: &[Point3<f32>]) -> f32 {
    if points.len() < 2 {
        return 0.0;
    }
    let candidates = extreme_points(points);
    let blocks: Vec<(Vector3<f32>, Vector3<f32>)> = points
        .chunks(DIAMETER_BLOCK)
        .map(|block| {
            block.iter().fold(
                (Vector3::repeat(f32::MAX), Vector3::repeat(f32::MIN)),
                |(lo, hi), p| (lo.inf(&p.coords), hi.sup(&p.coords)),
            )
        })
        .collect();
    let mut best = 0f32;
    for &c in &candidates {
        let pc = points[c].coords;
        for (block, (lo, hi)) in points.chunks(DIAMETER_BLOCK).zip(&blocks) {
            let far = (lo - pc).abs().sup(&(hi - pc).abs());
            // The corner's distance is rounded like a point's; a margin keeps a block whose
            // farthest point would tie or win by rounding.
            if far.norm_squared() * (1.0 + 1e-5) < best {
                continue;
            }
            for p in block {
                best = best.max((p.coords - pc).norm_squared());
            }
        }
    }
    best.sqrt()
}

/// Points per bounding box in [`diameter`].
const DIAMETER_BLOCK: usize = 64;

/// The indices of the points extreme along 64 directions spread over the sphere (a Fibonacci
/// sphere), each once, in increasing order: [`diameter`]'s candidate endpoints.
fn extreme_points(points: &[Point3<f32>]) -> Vec<usize> {
    let mut candidates: Vec<usize> = Vec::new();
    let dirs = 64;
    for i in 0..dirs {
        let z = 1.0 - 2.0 * (i as f32 + 0.5) / dirs as f32;
        let r = (1.0 - z * z).sqrt();
        let phi = i as f32 * 2.399_963;
        let d = Vector3::new(r * phi.cos(), r * phi.sin(), z);
        let (mut lo, mut hi) = (0, 0);
        let (mut lo_v, mut hi_v) = (f32::MAX, f32::MIN);
        for (k, p) in points.iter().enumerate() {
            let s = p.coords.dot(&d);
            if s < lo_v {
                (lo_v, lo) = (s, k);
            }
            if s > hi_v {
                (hi_v, hi) = (s, k);
            }
        }
        candidates.push(lo);
        candidates.push(hi);
    }
    candidates.sort_unstable();
    candidates.dedup();
    candidates
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit_square_mesh(size: f32) -> Mesh {
        Mesh {
            positions: vec![
                Point3::new(0.0, 0.0, 0.0),
                Point3::new(size, 0.0, 0.0),
                Point3::new(size, size, 0.0),
                Point3::new(0.0, size, 0.0),
            ],
            normals: vec![Vector3::z(); 4],
            faces: vec![[0, 1, 2], [0, 2, 3]],
        }
    }

    #[test]
    fn samples_are_uniform_by_area_and_on_the_surface() {
        let mesh = unit_square_mesh(100.0);
        let pts = sample_surface(&mesh, 20_000, 7).unwrap();
        assert!((pts.len() as i64 - 20_000).abs() < 300, "{}", pts.len());
        // Each quadrant holds about a quarter of the samples.
        let q = pts
            .positions
            .iter()
            .filter(|p| p.x < 50.0 && p.y < 50.0)
            .count();
        assert!((q as f32 / pts.len() as f32 - 0.25).abs() < 0.02, "{q}");
        assert!(pts
            .positions
            .iter()
            .all(|p| p.z == 0.0 && (0.0..=100.0).contains(&p.x)));
        assert!(pts.normals.iter().all(|n| (n - Vector3::z()).norm() < 1e-6));
    }

    /// Angles in degrees, sorted.
    fn sorted_degrees(angles: impl Iterator<Item = f32>) -> Vec<f32> {
        let mut v: Vec<f32> = angles.map(|a| a.to_degrees()).collect();
        v.sort_by(f32::total_cmp);
        v
    }

    #[test]
    fn a_cube_without_normals_is_sampled_with_its_face_normals() {
        // Eight shared corners: the mean normal of a corner's faces is 55° off each of them.
        let mesh = crate::geometry::mesh::welded_cube(50.0);
        let pts = sample_surface(&mesh, 20_000, 3).unwrap();
        // The face a sample lies on is the axis along which it is furthest out.
        let errors = sorted_degrees(pts.positions.iter().zip(&pts.normals).map(|(p, n)| {
            let axis = p.coords.iamax();
            let mut face = Vector3::zeros();
            face[axis] = p.coords[axis].signum();
            n.angle(&face)
        }));
        let worst = errors[errors.len() - 1];
        assert!(
            worst < 0.01,
            "sample normals up to {worst:.1}° off their face"
        );
    }

    #[test]
    fn a_capped_cylinder_keeps_a_smooth_side_and_flat_caps() {
        // 24 sides of radius 50 mm, height 100 mm, closed by two fans; no normals given, so
        // a blend of side and cap at every rim vertex would tilt the side's samples by up to 18°.
        let sides = 24;
        let mut positions = Vec::new();
        for z in [-50.0f32, 50.0] {
            for k in 0..sides {
                let t = k as f32 / sides as f32 * std::f32::consts::TAU;
                positions.push(Point3::new(50.0 * t.cos(), 50.0 * t.sin(), z));
            }
        }
        positions.push(Point3::new(0.0, 0.0, -50.0));
        positions.push(Point3::new(0.0, 0.0, 50.0));
        let (bottom, top) = (2 * sides, 2 * sides + 1);
        let mut faces = Vec::new();
        for k in 0..sides {
            let next = (k + 1) % sides;
            faces.push([k, next, sides + next]);
            faces.push([k, sides + next, sides + k]);
            faces.push([bottom, next, k]);
            faces.push([top, sides + k, sides + next]);
        }
        let mesh = Mesh::from_triangles(positions, &faces).unwrap();
        let pts = sample_surface(&mesh, 40_000, 5).unwrap();
        let (mut side, mut caps) = (Vec::new(), Vec::new());
        for (p, n) in pts.positions.iter().zip(&pts.normals) {
            // A cap's samples at the rim (radius 49.5 to 50 mm) are left out: side ones lie there too.
            let radius = p.x.hypot(p.y);
            if p.z.abs() > 49.99 && radius < 49.5 {
                caps.push(n.angle(&(Vector3::z() * p.z.signum())));
            } else if p.z.abs() < 49.99 {
                side.push(n.angle(&Vector3::new(p.x, p.y, 0.0)));
            }
        }
        let (side, caps) = (
            sorted_degrees(side.into_iter()),
            sorted_degrees(caps.into_iter()),
        );
        // Facets are 15° apart: their own normals would put 95 % within 7°.
        let side_p95 = side[side.len() * 95 / 100];
        assert!(side_p95 < 3.0, "side normals: 95 % within {side_p95:.1}°");
        let caps_worst = caps[caps.len() - 1];
        assert!(caps_worst < 0.01, "cap normals up to {caps_worst:.1}° off");
    }

    #[test]
    fn diameter_of_a_box_is_its_space_diagonal() {
        let mut pts = Vec::new();
        for i in 0..=10 {
            for j in 0..=10 {
                for k in 0..=10 {
                    pts.push(Point3::new(i as f32 * 3.0, j as f32 * 4.0, k as f32 * 12.0));
                }
            }
        }
        assert!((diameter(&pts) - 130.0).abs() < 1e-3);
    }

    /// The candidates of [`diameter`] against every point, without skipping a block.
    fn diameter_without_blocks(points: &[Point3<f32>]) -> f32 {
        let mut best = 0f32;
        for c in extreme_points(points) {
            for p in points {
                best = best.max((p - points[c]).norm_squared());
            }
        }
        best.sqrt()
    }

    #[test]
    fn skipping_blocks_leaves_the_diameter_to_the_bit() {
        let mut rng = Rng::new(7);
        for n in [2, 63, 64, 65, 1000, 5000] {
            // Points in mesh-like order (a walk), and scattered ones.
            let mut walk = Vec::with_capacity(n);
            let mut at = Point3::origin();
            for _ in 0..n {
                at += Vector3::new(
                    rng.range(-2.0, 2.0),
                    rng.range(-2.0, 2.0),
                    rng.range(-2.0, 2.0),
                );
                walk.push(at);
            }
            let scattered: Vec<Point3<f32>> = (0..n)
                .map(|_| {
                    Point3::new(
                        rng.range(-80.0, 80.0),
                        rng.range(-30.0, 30.0),
                        rng.range(0.0, 5.0),
                    )
                })
                .collect();
            for pts in [&walk, &scattered] {
                assert_eq!(
                    diameter(pts).to_bits(),
                    diameter_without_blocks(pts).to_bits(),
                    "{n} points"
                );
            }
        }
    }
}
