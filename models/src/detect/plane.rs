//! The supporting plane of a scene: the table or bin floor the objects rest on.
//!
//! Choosing the reference points is left open by the method (METHOD.md §2.3: "a fraction of the
//! subsampled scene points"). A reference point on the supporting plane pairs with hundreds of
//! coplanar partners whose features all fall under the few keys of the model's flat patches: it
//! casts most of a frame's votes and proposes only planar impostors, which the filters then have
//! to reject. [`SupportingPlane::find`] fits the dominant plane of the scene by RANSAC on a
//! sample of its oriented points, and [`SupportingPlane::find_all`] the next few large planes
//! (a floor below the table, a wall behind it); points on them (close to one, normal along its
//! normal) are not taken as reference points, nor as their partners: they cannot be model
//! points, so their pairs with a point on an object only add votes for wrong poses. On the LM-O
//! frame dropping them as partners cut voting by about a tenth and left every result as it was;
//! on synth-lmo-dev recall went from 0.926 to 0.931.
//!
//! An object resting on the supporting plane lies on the camera's side of it. Points behind it
//! (the floor beyond the table's edge, shelves and clutter below it) are taken neither as
//! reference points nor as partners ([`PlaneParams::exclude_behind`]). On the LM-O frame half of
//! the duck's reference points lay there: excluding them took the eight objects to about 0.58 of
//! the time with the same six of eight best poses correct, and synth-lmo-dev kept its recall
//! (0.935) in 0.85 of the time (docs/METHOD.md §2.3).
//!
//! This takes the dominant plane for the support. Where it need not be, a cell turns the
//! exclusion off (`plane.exclude_behind=false`): objects on a lower shelf beyond a large table,
//! or a large flat item whose top outweighs the table in view, with smaller objects beside it
//! (the table and those objects lie behind the top's plane).
//!
//! A plane narrower than an object's diameter may be one of that object's own faces (a box's
//! top): for that object its points stay reference points. Objects whose coplanar faces together
//! span more than their diameter (boxes side by side, tops at one height) would still count as a
//! plane: such cells should disable this ([`PlaneParams::enabled`]).

use nalgebra::{Matrix3, Point3, SymmetricEigen, Vector3};
use rayon::prelude::*;

use crate::geometry::rng::Rng;
use crate::model::subsample::OrientedPoints;

/// Parameters of the supporting plane search.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlaneParams {
    /// Look for a supporting plane and take no reference points on it.
    pub enabled: bool,
    /// A point lies on the plane within `tolerance_mm + tolerance_fraction × depth` (the
    /// sensor's noise grows with depth).
    pub tolerance_mm: f32,
    /// The part of that tolerance that grows with depth, a fraction of the point's depth.
    pub tolerance_fraction: f32,
    /// ... and with its normal within this angle of the plane's.
    pub max_normal_angle_deg: f32,
    /// The dominant plane counts only when at least this fraction of the scene lies on it.
    pub min_inlier_fraction: f32,
    /// Further planes (up to `max_planes` in all) count when at least this fraction of the
    /// scene lies on them.
    pub min_secondary_fraction: f32,
    /// The most planes found, the dominant one included; 0 finds none.
    pub max_planes: usize,
    /// Points behind the dominant plane (farther from the camera, beyond the plane's
    /// tolerance) are neither reference points nor partners: an object resting on the plane
    /// lies on the camera's side of it. Only the dominant plane: behind a wall or a box's side
    /// lie the table and the objects on it.
    pub exclude_behind: bool,
    /// RANSAC: planes tried, and scene points sampled to judge them.
    pub iterations: u32,
    /// Scene points sampled (every point when the scene holds fewer).
    pub samples: u32,
    /// Seed of the sampling (the result is deterministic for a frame).
    pub seed: u64,
}

impl Default for PlaneParams {
    fn default() -> Self {
        Self {
            enabled: true,
            tolerance_mm: 4.0,
            tolerance_fraction: 0.004,
            max_normal_angle_deg: 30.0,
            min_inlier_fraction: 0.15,
            min_secondary_fraction: 0.05,
            max_planes: 3,
            exclude_behind: true,
            iterations: 300,
            samples: 3000,
            seed: 0x5EED_F1A7,
        }
    }
}

/// A plane `normal · p + offset = 0` with a unit normal, and how it judges points.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SupportingPlane {
    /// Unit normal, facing the camera.
    pub normal: Vector3<f32>,
    /// Offset, mm: `normal · p + offset` is positive on the camera's side.
    pub offset: f32,
    /// Fraction of the sampled scene points on it.
    pub inlier_fraction: f32,
    /// Its narrower size, mm: the 5–95 % range of its points along the shorter of its two
    /// principal directions. A plane narrower than an object's diameter may be that object's
    /// own face, and is not excluded for it (see [`SupportingPlane::excludes_for`]).
    pub extent_mm: f32,
    tolerance_mm: f32,
    tolerance_fraction: f32,
    cos_normal: f32,
    /// Points behind it are excluded too (the dominant plane, when
    /// [`PlaneParams::exclude_behind`]).
    excludes_behind: bool,
}

impl SupportingPlane {
    /// Signed distance of `p` from the plane, millimetres.
    #[inline]
    pub fn distance(&self, p: &Point3<f32>) -> f32 {
        self.normal.dot(&p.coords) + self.offset
    }

    /// Whether this plane is too large to be a face of an object of diameter `diameter_mm`, so
    /// that its points are not taken as that object's reference points.
    #[inline]
    pub fn excludes_for(&self, diameter_mm: f32) -> bool {
        self.extent_mm > diameter_mm
    }

    /// Whether the oriented point `(p, n)` lies on the plane.
    #[inline]
    pub fn holds(&self, p: &Point3<f32>, n: &Vector3<f32>) -> bool {
        self.distance(p).abs() <= self.tolerance_mm + self.tolerance_fraction * p.z.abs()
            && self.normal.dot(n).abs() >= self.cos_normal
    }

    /// Whether `p` lies behind the plane, seen from the camera, farther than its tolerance, and
    /// the plane excludes such points (see [`PlaneParams::exclude_behind`]).
    #[inline]
    pub fn hides(&self, p: &Point3<f32>) -> bool {
        self.excludes_behind
            && self.distance(p) < -(self.tolerance_mm + self.tolerance_fraction * p.z.abs())
    }

    /// The points of `points` that no plane of `planes` hides from an object of diameter
    /// `diameter_mm` (see [`SupportingPlane::hides`] and [`SupportingPlane::excludes_for`]), in
    /// their order; `None` when no plane hides any. Given the largest diameter of a request's
    /// objects, what it keeps is what every object may vote with, so the scene clouds are
    /// subsampled from it: a hidden point would only be skipped by each object's voting, and a
    /// voxel that mixed it with points in front would average them into a point between.
    pub fn drop_hidden(
        points: &OrientedPoints,
        planes: &[SupportingPlane],
        diameter_mm: f32,
    ) -> Option<OrientedPoints> {
        let hiding: Vec<&SupportingPlane> = planes
            .iter()
            .filter(|pl| pl.excludes_behind && pl.excludes_for(diameter_mm))
            .collect();
        if hiding.is_empty() {
            return None;
        }
        let (positions, normals) = points
            .positions
            .par_iter()
            .zip(&points.normals)
            .filter(|(p, _)| !hiding.iter().any(|pl| pl.hides(p)))
            .map(|(p, n)| (*p, *n))
            .unzip();
        Some(OrientedPoints { positions, normals })
    }

    /// Whether the oriented point `(p, n)` lies on the plane or hidden behind it: for an object
    /// the plane [`excludes_for`](Self::excludes_for), neither a reference point nor a partner.
    #[inline]
    pub fn excludes(&self, p: &Point3<f32>, n: &Vector3<f32>) -> bool {
        self.holds(p, n) || self.hides(p)
    }

    /// The dominant plane of `points`, or `None` when no plane holds `min_inlier_fraction` of
    /// them (or the search is disabled, or there are fewer than three points).
    pub fn find(points: &OrientedPoints, params: &PlaneParams) -> Option<SupportingPlane> {
        Self::find_all(points, params).into_iter().next()
    }

    /// The dominant plane (as [`find`](Self::find)) and then, among the points on neither, up to
    /// `max_planes − 1` more planes holding at least `min_secondary_fraction` of the scene each;
    /// largest first. Empty when there is no dominant plane.
    pub fn find_all(points: &OrientedPoints, params: &PlaneParams) -> Vec<SupportingPlane> {
        if !params.enabled || points.len() < 3 || params.iterations == 0 {
            return Vec::new();
        }
        let mut rng = Rng::new(params.seed);
        let n = points.len();
        let all: Vec<usize> = if n <= params.samples as usize {
            (0..n).collect()
        } else {
            (0..params.samples).map(|_| rng.below(n)).collect()
        };
        let mut planes: Vec<SupportingPlane> = Vec::new();
        let mut sample = all.clone();
        while planes.len() < params.max_planes {
            let min_fraction = if planes.is_empty() {
                params.min_inlier_fraction
            } else {
                params.min_secondary_fraction
            };
            let Some(mut plane) = Self::fit(points, &sample, &mut rng, params) else {
                break;
            };
            // The fraction counts against the whole sample, not what is left of it.
            let on_it = sample
                .iter()
                .filter(|&&i| plane.holds(&points.positions[i], &points.normals[i]))
                .count();
            plane.inlier_fraction = on_it as f32 / all.len() as f32;
            if plane.inlier_fraction < min_fraction {
                break;
            }
            sample.retain(|&i| !plane.holds(&points.positions[i], &points.normals[i]));
            plane.excludes_behind = planes.is_empty() && params.exclude_behind;
            planes.push(plane);
            if sample.len() < 3 {
                break;
            }
        }
        planes
    }

    /// The best plane by RANSAC over `sample` (indices into `points`), refined by least squares.
    fn fit(
        points: &OrientedPoints,
        sample: &[usize],
        rng: &mut Rng,
        params: &PlaneParams,
    ) -> Option<SupportingPlane> {
        let shape = |normal: Vector3<f32>, offset: f32| SupportingPlane {
            normal,
            offset,
            inlier_fraction: 0.0,
            extent_mm: 0.0,
            tolerance_mm: params.tolerance_mm,
            tolerance_fraction: params.tolerance_fraction,
            cos_normal: params.max_normal_angle_deg.to_radians().cos(),
            excludes_behind: false,
        };
        let inliers_of = |plane: &SupportingPlane| -> Vec<usize> {
            sample
                .iter()
                .copied()
                .filter(|&i| plane.holds(&points.positions[i], &points.normals[i]))
                .collect()
        };

        let mut best: Option<(usize, SupportingPlane)> = None;
        for _ in 0..params.iterations {
            let (a, b, c) = (
                sample[rng.below(sample.len())],
                sample[rng.below(sample.len())],
                sample[rng.below(sample.len())],
            );
            let (pa, pb, pc) = (
                points.positions[a],
                points.positions[b],
                points.positions[c],
            );
            let cross = (pb - pa).cross(&(pc - pa));
            let norm = cross.norm();
            if norm < 1e-3 {
                continue; // repeated or collinear points
            }
            let normal = cross / norm;
            let candidate = shape(normal, -normal.dot(&pa.coords));
            // The three points must agree with their own normals, or the plane is one through
            // three unrelated surfaces.
            if [a, b, c]
                .iter()
                .any(|&i| !candidate.holds(&points.positions[i], &points.normals[i]))
            {
                continue;
            }
            let count = inliers_of(&candidate).len();
            if best.as_ref().is_none_or(|(c, _)| count > *c) {
                best = Some((count, candidate));
            }
        }
        let (_, rough) = best?;

        // Least squares through the inliers: the smallest principal axis of their scatter.
        let inliers = inliers_of(&rough);
        if inliers.len() < 3 {
            return None;
        }
        let centroid = inliers
            .iter()
            .fold(Vector3::zeros(), |s, &i| s + points.positions[i].coords)
            / inliers.len() as f32;
        let mut scatter = Matrix3::zeros();
        for &i in &inliers {
            let d = points.positions[i].coords - centroid;
            scatter += d * d.transpose();
        }
        let eigen = SymmetricEigen::new(scatter);
        let smallest = eigen.eigenvalues.imin();
        let mut normal = eigen.eigenvectors.column(smallest).into_owned();
        // Orient it towards the camera, as the scene normals are.
        if normal.dot(&centroid) > 0.0 {
            normal = -normal;
        }
        // Its size: the 5–95 % range of the inliers along each in-plane principal axis.
        let mut plane = shape(normal, -normal.dot(&centroid));
        let range_along = |axis: Vector3<f32>| {
            let mut t: Vec<f32> = inliers
                .iter()
                .map(|&i| (points.positions[i].coords - centroid).dot(&axis))
                .collect();
            t.sort_by(f32::total_cmp);
            let at = |q: f32| t[((t.len() - 1) as f32 * q).round() as usize];
            at(0.95) - at(0.05)
        };
        plane.extent_mm = (0..3)
            .filter(|&k| k != smallest)
            .map(|k| range_along(eigen.eigenvectors.column(k).into_owned()))
            .fold(f32::INFINITY, f32::min);
        Some(plane)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 600 × 600 mm table tilted towards the camera at about 800 mm, with a box on it.
    fn table_with_box(noise_mm: f32) -> (OrientedPoints, Vector3<f32>, Vec<bool>) {
        let mut rng = Rng::new(7);
        let tilt = nalgebra::Rotation3::from_axis_angle(&Vector3::x_axis(), 0.6);
        let up = tilt * -Vector3::z(); // the table's normal, facing the camera
        let origin = Point3::new(0.0, 0.0, 800.0);
        let (ex, ey) = (tilt * Vector3::x(), tilt * Vector3::y());
        let mut points = OrientedPoints::default();
        let mut on_table = Vec::new();
        for i in 0..60 {
            for j in 0..60 {
                let p = origin
                    + ex * (i as f32 * 10.0 - 300.0)
                    + ey * (j as f32 * 10.0 - 300.0)
                    + up * (rng.normal() as f32 * noise_mm);
                points.push(p, up);
                on_table.push(true);
            }
        }
        // The box: a 100 mm cube standing on the table; its top and one side face the camera.
        for i in 0..20 {
            for j in 0..20 {
                let (a, b) = (i as f32 * 5.0 - 50.0, j as f32 * 5.0 - 50.0);
                points.push(origin + ex * a + ey * b + up * 100.0, up);
                on_table.push(false);
                points.push(origin + ex * a - ey * 50.0 + up * (b + 50.0), -ey);
                on_table.push(false);
            }
        }
        (points, up, on_table)
    }

    #[test]
    fn finds_the_table_under_a_box() {
        let (points, up, on_table) = table_with_box(1.0);
        let plane = SupportingPlane::find(&points, &PlaneParams::default()).expect("a plane");
        assert!(plane.normal.dot(&up) > 0.999, "normal {:?}", plane.normal);
        for (i, &truth) in on_table.iter().enumerate() {
            let p = &points.positions[i];
            assert_eq!(
                plane.holds(p, &points.normals[i]),
                truth,
                "point {i} at {:?}, {:.1} mm from the plane",
                p,
                plane.distance(p)
            );
        }
        assert!(plane.inlier_fraction > 0.7);
    }

    #[test]
    fn finds_a_floor_below_the_table_too() {
        let (mut points, up, on_table) = table_with_box(1.0);
        let table_points = on_table.iter().filter(|&&t| t).count();
        // A floor 750 mm below the table, seen beside it: 40 x 40 points, 20 mm apart.
        let tilt = nalgebra::Rotation3::from_axis_angle(&Vector3::x_axis(), 0.6);
        let (ex, ey) = (tilt * Vector3::x(), tilt * Vector3::y());
        let floor_origin = Point3::new(0.0, 0.0, 800.0) - up * 750.0 + ex * 900.0;
        for i in 0..40 {
            for j in 0..40 {
                let p = floor_origin + ex * (i as f32 * 20.0) + ey * (j as f32 * 20.0 - 400.0);
                points.push(p, up);
            }
        }
        let planes = SupportingPlane::find_all(&points, &PlaneParams::default());
        // Table, floor, and the box's top (7 % of the scene): a plane, but narrower than the
        // box's diameter (173 mm), so it stays the box's for reference points.
        assert_eq!(planes.len(), 3, "{planes:?}");
        assert!(planes[0].excludes_for(173.0) && planes[1].excludes_for(173.0));
        assert!(!planes[2].excludes_for(173.0), "{:?}", planes[2]);
        assert!((planes[2].extent_mm - 90.0).abs() < 10.0, "{:?}", planes[2]);
        assert!(planes[0].inlier_fraction > planes[1].inlier_fraction);
        let table_on_first = (0..on_table.len())
            .filter(|&i| on_table[i] && planes[0].holds(&points.positions[i], &points.normals[i]))
            .count();
        assert_eq!(table_on_first, table_points);
        let floor_on_second = (on_table.len()..points.len())
            .filter(|&i| planes[1].holds(&points.positions[i], &points.normals[i]))
            .count();
        assert_eq!(floor_on_second, 1600);
        assert!((planes[1].distance(&floor_origin)).abs() < 1.0);
        // The box is on neither table nor floor.
        for (i, _) in on_table.iter().enumerate().filter(|(_, &t)| !t) {
            assert!(planes[..2]
                .iter()
                .all(|pl| !pl.holds(&points.positions[i], &points.normals[i])));
        }
        // With one plane allowed, only the table.
        let one = PlaneParams {
            max_planes: 1,
            ..Default::default()
        };
        assert_eq!(SupportingPlane::find_all(&points, &one).len(), 1);
    }

    /// A box standing on the table is in front of it; a second box 300 mm below the table's
    /// surface (on a shelf beyond its edge) is behind it and hidden, unless
    /// `exclude_behind` is off. A floor found as a second plane hides nothing.
    #[test]
    fn points_behind_the_table_are_hidden() {
        let (mut points, up, on_table) = table_with_box(1.0);
        let in_front = points.len();
        let tilt = nalgebra::Rotation3::from_axis_angle(&Vector3::x_axis(), 0.6);
        let (ex, ey) = (tilt * Vector3::x(), tilt * Vector3::y());
        let below = Point3::new(0.0, 0.0, 800.0) - up * 300.0 + ex * 400.0;
        for i in 0..20 {
            for j in 0..20 {
                let (a, b) = (i as f32 * 5.0 - 50.0, j as f32 * 5.0 - 50.0);
                points.push(below + ex * a + ey * b + up * 100.0, up);
            }
        }
        // Points 5 mm below the surface (within the tolerance at 800 mm) are not hidden.
        let sunk = Point3::new(0.0, 0.0, 800.0) - up * 5.0;
        let planes = SupportingPlane::find_all(&points, &PlaneParams::default());
        let table = &planes[0];
        assert!(table.normal.dot(&up) > 0.999, "{table:?}");
        assert!(!table.hides(&sunk));
        for (i, p) in points.positions.iter().enumerate() {
            let behind = i >= in_front;
            assert_eq!(
                table.hides(p),
                behind,
                "point {i} at {p:?}, on table {:?}",
                on_table.get(i)
            );
            // Only the dominant plane hides.
            assert!(planes[1..].iter().all(|pl| !pl.hides(p)));
        }
        // The clouds are subsampled from the points in front, in their order; for an object
        // wider than the table nothing is hidden (its points may be the object's own face).
        let kept = SupportingPlane::drop_hidden(&points, &planes, 100.0).unwrap();
        assert_eq!(kept.positions, points.positions[..in_front]);
        assert_eq!(kept.normals, points.normals[..in_front]);
        assert!(SupportingPlane::drop_hidden(&points, &planes, table.extent_mm + 1.0).is_none());
        let keep = PlaneParams {
            exclude_behind: false,
            ..Default::default()
        };
        let planes = SupportingPlane::find_all(&points, &keep);
        assert!(points.positions.iter().all(|p| !planes[0].hides(p)));
        assert!(SupportingPlane::drop_hidden(&points, &planes, 100.0).is_none());
    }

    #[test]
    fn no_plane_in_a_scene_without_one() {
        // Points on a sphere: no plane holds 15 % of them.
        let mut rng = Rng::new(3);
        let mut points = OrientedPoints::default();
        for _ in 0..4000 {
            let v = Vector3::new(
                rng.normal() as f32,
                rng.normal() as f32,
                rng.normal() as f32,
            )
            .normalize();
            points.push(Point3::new(0.0, 0.0, 800.0) + v * 200.0, v);
        }
        assert!(SupportingPlane::find(&points, &PlaneParams::default()).is_none());
        let disabled = PlaneParams {
            enabled: false,
            ..Default::default()
        };
        let (table, _, _) = table_with_box(0.0);
        assert!(SupportingPlane::find(&table, &disabled).is_none());
    }
}
