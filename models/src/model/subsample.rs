//! Subsampling with normal clustering and neighbour filtering (Vidal et al. 2018, §III), shared
//! by model building and scene preparation.
//!
//! A voxel grid groups the points (its leaf `0.05 D` for a model, `0.1 D` for the scene); inside a voxel, points are clustered by
//! normal direction (a point joins the first cluster whose mean normal is within the clustering
//! angle, else starts a new one), and each cluster becomes one oriented point. A voxel on an edge
//! or corner therefore keeps one point per surface orientation. Then neighbouring clusters that
//! carry the same information (closer than the leaf, normals within the clustering angle) are
//! reduced to one.

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

use crate::geometry::grid::CellMap;

/// Oriented points: positions (mm) with unit normals, index-aligned.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct OrientedPoints {
    /// Positions, mm.
    pub positions: Vec<Point3<f32>>,
    /// Unit normals, one per position.
    pub normals: Vec<Vector3<f32>>,
}

impl OrientedPoints {
    /// How many points.
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    /// Whether there are no points.
    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    /// Appends the point `p` with normal `n`.
    pub fn push(&mut self, p: Point3<f32>, n: Vector3<f32>) {
        self.positions.push(p);
        self.normals.push(n);
    }
}

/// Parameters of [`subsample`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SubsampleParams {
    /// Voxel edge, mm. The paper: `0.05 × model diameter`.
    pub leaf_mm: f32,
    /// Two normals belong to one cluster below this angle, radians. The paper: 30°.
    pub cluster_angle: f32,
    /// Remove non-discriminative neighbours after clustering (the paper does).
    pub neighbour_filtering: bool,
}

type VoxelKey = (i32, i32, i32);

#[inline]
fn voxel_of(p: &Point3<f32>, inv_leaf: f32) -> VoxelKey {
    crate::geometry::grid::cell_of(p, inv_leaf)
}

struct Cluster {
    position_sum: Vector3<f32>,
    normal_sum: Vector3<f32>,
    members: u32,
}

/// Every point's voxel with its index, sorted by voxel `(x, y, z)` and then index: points
/// grouped by voxel, each voxel's points in input order.
///
/// A scene frame has a few hundred thousand points and a few thousand voxels per leaf: the
/// points are numbered by voxel through a hash map (consecutive pixels mostly share one, so the
/// last voxel is tried first), only the distinct voxels are sorted, and the points are placed
/// by a counting sort, which keeps input order within a voxel. Sorting every point instead
/// was half the time of subsampling a scene.
fn by_voxel(points: &OrientedPoints, inv_leaf: f32) -> Vec<(VoxelKey, u32)> {
    let keys: Vec<VoxelKey> = points
        .positions
        .par_iter()
        .map(|p| voxel_of(p, inv_leaf))
        .collect();
    let mut ids: CellMap<u32> = CellMap::default();
    let mut distinct: Vec<VoxelKey> = Vec::new();
    let mut voxel: Vec<u32> = Vec::with_capacity(keys.len());
    let mut last: Option<(VoxelKey, u32)> = None;
    for &k in &keys {
        let id = match last {
            Some((lk, id)) if lk == k => id,
            _ => {
                let id = *ids.entry(k).or_insert_with(|| {
                    distinct.push(k);
                    (distinct.len() - 1) as u32
                });
                last = Some((k, id));
                id
            }
        };
        voxel.push(id);
    }
    let mut order: Vec<u32> = (0..distinct.len() as u32).collect();
    order.sort_unstable_by_key(|&v| distinct[v as usize]);
    // Where each voxel's points start in the output, in voxel order.
    let mut start = vec![0u32; distinct.len()];
    for &v in &voxel {
        start[v as usize] += 1;
    }
    let mut next = 0u32;
    for &v in &order {
        let count = start[v as usize];
        start[v as usize] = next;
        next += count;
    }
    let mut out = vec![((0, 0, 0), 0u32); keys.len()];
    for (i, (&v, &k)) in voxel.iter().zip(&keys).enumerate() {
        let slot = &mut start[v as usize];
        out[*slot as usize] = (k, i as u32);
        *slot += 1;
    }
    out
}

/// Subsamples oriented points (normals unit length) with a voxel grid and normal clustering,
/// then neighbour filtering. The output order is deterministic for a given input.
pub fn subsample(points: &OrientedPoints, params: &SubsampleParams) -> OrientedPoints {
    let inv_leaf = 1.0 / params.leaf_mm;
    let cos_cluster = params.cluster_angle.cos();

    let keyed = by_voxel(points, inv_leaf);

    let mut clusters: Vec<(Point3<f32>, Vector3<f32>, u32)> = Vec::new();
    let mut in_voxel: Vec<Cluster> = Vec::new();
    let mut start = 0;
    while start < keyed.len() {
        let key = keyed[start].0;
        let mut end = start;
        in_voxel.clear();
        while end < keyed.len() && keyed[end].0 == key {
            let i = keyed[end].1 as usize;
            let (p, n) = (points.positions[i], points.normals[i]);
            let joined = in_voxel.iter_mut().find(|c| {
                let mean = c.normal_sum;
                let len = mean.norm();
                len > 0.0 && mean.dot(&n) >= cos_cluster * len
            });
            match joined {
                Some(c) => {
                    c.position_sum += p.coords;
                    c.normal_sum += n;
                    c.members += 1;
                }
                None => in_voxel.push(Cluster {
                    position_sum: p.coords,
                    normal_sum: n,
                    members: 1,
                }),
            }
            end += 1;
        }
        for c in &in_voxel {
            let len = c.normal_sum.norm();
            if len > 1e-6 {
                clusters.push((
                    Point3::from(c.position_sum / c.members as f32),
                    c.normal_sum / len,
                    c.members,
                ));
            }
        }
        start = end;
    }

    if !params.neighbour_filtering {
        let mut out = OrientedPoints::default();
        for (p, n, _) in clusters {
            out.push(p, n);
        }
        return out;
    }
    filter_neighbours(clusters, params.leaf_mm, cos_cluster)
}

/// Keeps, among clusters closer than `radius` with normals within the clustering angle, the one
/// with most members (ties: the earlier one).
fn filter_neighbours(
    mut clusters: Vec<(Point3<f32>, Vector3<f32>, u32)>,
    radius: f32,
    cos_cluster: f32,
) -> OrientedPoints {
    // Stable sort: among equal member counts the voxel order stays, so output is deterministic.
    clusters.sort_by_key(|c| std::cmp::Reverse(c.2));
    let inv = 1.0 / radius;
    let r2 = radius * radius;
    let mut grid: CellMap<Vec<u32>> = CellMap::default();
    let mut out = OrientedPoints::default();
    for (p, n, _) in clusters {
        let (kx, ky, kz) = voxel_of(&p, inv);
        let mut redundant = false;
        'search: for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    if let Some(kept) = grid.get(&(kx + dx, ky + dy, kz + dz)) {
                        for &j in kept {
                            let j = j as usize;
                            if (out.positions[j] - p).norm_squared() < r2
                                && out.normals[j].dot(&n) >= cos_cluster
                            {
                                redundant = true;
                                break 'search;
                            }
                        }
                    }
                }
            }
        }
        if !redundant {
            grid.entry((kx, ky, kz)).or_default().push(out.len() as u32);
            out.push(p, n);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn params(filter: bool) -> SubsampleParams {
        SubsampleParams {
            leaf_mm: 10.0,
            cluster_angle: 30f32.to_radians(),
            neighbour_filtering: filter,
        }
    }

    /// A dense grid of points on the plane z = `z` with normal +z, inside one voxel or many.
    fn plane(x0: f32, y0: f32, z: f32, size: f32, step: f32, out: &mut OrientedPoints) {
        let n = (size / step) as i32;
        for i in 0..n {
            for j in 0..n {
                out.push(
                    Point3::new(x0 + i as f32 * step, y0 + j as f32 * step, z),
                    Vector3::z(),
                );
            }
        }
    }

    /// Points come out grouped as sorting the (voxel, index) tuples orders them, with negative
    /// coordinates, huge voxel numbers, voxels met again after others, and runs of consecutive
    /// points in one voxel.
    #[test]
    fn voxels_sort_like_their_tuples() {
        let mut rng = crate::geometry::rng::Rng::new(3);
        for (spread, leaf) in [(500.0f32, 5.0f32), (3000.0, 0.7), (1e9, 1e-3)] {
            let mut pts = OrientedPoints::default();
            for _ in 0..20_000 {
                let p = Point3::new(
                    rng.range(-spread, spread),
                    rng.range(-spread, 0.2 * spread),
                    rng.range(0.0, spread),
                );
                pts.push(p, Vector3::z());
            }
            // Repeated voxels: a few points share a voxel with an earlier one.
            for i in 0..2_000 {
                let p = pts.positions[i * 7];
                pts.push(p, Vector3::x());
            }
            for i in 0..500 {
                let p = pts.positions[i * 11];
                for _ in 0..3 {
                    pts.push(p, Vector3::y());
                }
            }
            let inv = 1.0 / leaf;
            let mut expected: Vec<(VoxelKey, u32)> = pts
                .positions
                .iter()
                .enumerate()
                .map(|(i, p)| (voxel_of(p, inv), i as u32))
                .collect();
            expected.sort_unstable();
            assert_eq!(
                by_voxel(&pts, inv),
                expected,
                "spread {spread}, leaf {leaf}"
            );
        }
        assert!(by_voxel(&OrientedPoints::default(), 1.0).is_empty());
    }

    #[test]
    fn voxel_on_a_plane_keeps_one_point() {
        let mut pts = OrientedPoints::default();
        plane(0.5, 0.5, 5.0, 9.0, 0.5, &mut pts);
        let out = subsample(&pts, &params(false));
        assert_eq!(out.len(), 1);
        assert!((out.normals[0] - Vector3::z()).norm() < 1e-6);
        assert!((out.positions[0].z - 5.0).abs() < 1e-5);
    }

    #[test]
    fn voxel_on_an_edge_keeps_a_point_per_face() {
        // Two faces of a box meeting at an edge inside one voxel: top (normal +z) and side (+x).
        let mut pts = OrientedPoints::default();
        for i in 0..18 {
            for j in 0..18 {
                let (a, b) = (0.5 + i as f32 * 0.5, 0.5 + j as f32 * 0.5);
                pts.push(Point3::new(a * 0.5, b, 9.5), Vector3::z());
                pts.push(Point3::new(9.5, b, a * 0.5 + 4.5), Vector3::x());
            }
        }
        let out = subsample(&pts, &params(true));
        assert_eq!(out.len(), 2, "{out:?}");
        let has = |v: Vector3<f32>| out.normals.iter().any(|n| (n - v).norm() < 1e-5);
        assert!(has(Vector3::z()) && has(Vector3::x()));
        // A gentle bend (10 degrees) stays one cluster.
        let mut bent = OrientedPoints::default();
        let tilted = Vector3::new(10f32.to_radians().sin(), 0.0, 10f32.to_radians().cos());
        for i in 0..10 {
            bent.push(Point3::new(i as f32 * 0.9 + 0.2, 1.0, 1.0), Vector3::z());
            bent.push(Point3::new(i as f32 * 0.9 + 0.2, 2.0, 1.0), tilted);
        }
        assert_eq!(subsample(&bent, &params(true)).len(), 1);
    }

    #[test]
    fn neighbour_filtering_removes_redundant_clusters() {
        // A plane straddling a voxel border: voxel centroids are close (< leaf) with equal
        // normals, so filtering thins them; the spacing left is at least the leaf.
        let mut pts = OrientedPoints::default();
        plane(-15.0, -15.0, 0.0, 30.0, 0.5, &mut pts);
        let raw = subsample(&pts, &params(false));
        let filtered = subsample(&pts, &params(true));
        assert_eq!(raw.len(), 16);
        assert!(filtered.len() < raw.len());
        for i in 0..filtered.len() {
            for j in 0..i {
                assert!((filtered.positions[i] - filtered.positions[j]).norm() >= 10.0 - 1e-4);
            }
        }
        // Opposite normals at the same place are both kept (thin wall).
        let mut wall = OrientedPoints::default();
        plane(0.2, 0.2, 1.0, 9.0, 1.0, &mut wall);
        let n = wall.len();
        for i in 0..n {
            let p = wall.positions[i];
            wall.push(Point3::new(p.x, p.y, 1.5), -Vector3::z());
        }
        assert_eq!(subsample(&wall, &params(true)).len(), 2);
    }
}
