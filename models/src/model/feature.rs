//! The point pair feature (Drost et al. 2010) and its quantisation, with the paper's
//! quantisation-error neighbour rule (Vidal et al. 2018, Fig. 4).
//!
//! For two oriented points `(m1, n1)`, `(m2, n2)` with `d = m2 − m1` the feature is
//! `F = (‖d‖, ∠(n1, d), ∠(n2, d), ∠(n1, n2))`. A [`Quantizer`] turns it into a key of the dense
//! lookup table; [`Quantizer::keys_with_neighbours`] also yields the neighbouring cells that sensor
//! noise could have pushed the value into.
//!
//! [`LocalFrame`] is the transform `T` that moves a reference point to the origin and turns its
//! normal onto +x; [`LocalFrame::alpha`] is the angle about x that brings a second point into the
//! half-plane `y = 0, z > 0`. A model pair and a scene pair that match give the pose
//! `T_s⁻¹ · R_x(α_m − α_s) · T_m`.

use std::f32::consts::PI;

use nalgebra::{Isometry3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};

/// The four values of a point pair feature: distance in millimetres, three angles in radians in
/// `[0, π]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PointPairFeature {
    /// `‖d‖`, millimetres.
    pub distance_mm: f32,
    /// `∠(n1, d)`.
    pub angle_n1_d: f32,
    /// `∠(n2, d)`.
    pub angle_n2_d: f32,
    /// `∠(n1, n2)`.
    pub angle_n1_n2: f32,
}

/// Angle between two unit vectors, robust to rounding just outside `[-1, 1]`.
#[inline]
fn angle_between_unit(a: &Vector3<f32>, b: &Vector3<f32>) -> f32 {
    fast_acos(a.dot(b).clamp(-1.0, 1.0))
}

/// `acos(x)` for `x` in `[-1, 1]` within 7e-5 rad (Abramowitz & Stegun 4.4.45): a twentieth of
/// a degree is nothing against 12° bins, and the voting loop computes three per pair.
#[inline]
fn fast_acos(x: f32) -> f32 {
    let a = x.abs();
    let r =
        (1.0 - a).sqrt() * (1.570_728_8 + a * (-0.212_114_4 + a * (0.074_261 - 0.018_729_3 * a)));
    if x < 0.0 {
        PI - r
    } else {
        r
    }
}

/// `atan2(y, x)` within 2e-5 rad: a polynomial for `atan` on `[0, 1]` and the octant by
/// swaps and signs. Used for `α` in the voting loop, once per pair.
#[inline]
fn fast_atan2(y: f32, x: f32) -> f32 {
    let (ax, ay) = (x.abs(), y.abs());
    let (lo, hi) = if ax > ay { (ay, ax) } else { (ax, ay) };
    if hi == 0.0 {
        return 0.0;
    }
    let z = lo / hi;
    let z2 = z * z;
    let mut a = z
        * (0.999_977_26
            + z2 * (-0.332_623_47
                + z2 * (0.193_543_46
                    + z2 * (-0.116_432_87 + z2 * (0.052_653_32 - 0.011_721_2 * z2)))));
    if ay > ax {
        a = std::f32::consts::FRAC_PI_2 - a;
    }
    if x < 0.0 {
        a = PI - a;
    }
    if y < 0.0 {
        -a
    } else {
        a
    }
}

impl PointPairFeature {
    /// The feature of the ordered pair; `None` when the points coincide (no direction).
    /// Normals must be unit length.
    #[inline]
    pub fn compute(
        p1: &Point3<f32>,
        n1: &Vector3<f32>,
        p2: &Point3<f32>,
        n2: &Vector3<f32>,
    ) -> Option<Self> {
        let f = Self::compute_any(p1, n1, p2, n2);
        (f.distance_mm > f32::EPSILON).then_some(f)
    }

    /// [`PointPairFeature::compute`] without the check: for coincident points the angles are
    /// NaN. No branch, so that a loop over many pairs vectorises.
    #[inline(always)]
    fn compute_any(
        p1: &Point3<f32>,
        n1: &Vector3<f32>,
        p2: &Point3<f32>,
        n2: &Vector3<f32>,
    ) -> Self {
        let d = p2 - p1;
        let distance_mm = d.norm();
        let d = d / distance_mm;
        Self {
            distance_mm,
            angle_n1_d: angle_between_unit(n1, &d),
            angle_n2_d: angle_between_unit(n2, &d),
            angle_n1_n2: angle_between_unit(n1, n2),
        }
    }
}

/// One reference point's partners, coordinate by coordinate, and what the voting loop needs of
/// each pair: the feature's continuous bin coordinates ([`Quantizer::coordinates_of`]) and
/// `α_s` in fixed point.
///
/// The pairs' features are computed in one loop over these arrays, which the compiler turns
/// into SIMD lanes (four or eight pairs at a time); the keys, which branch on the table, come
/// after. The values are those of [`PointPairFeature::compute`], [`Quantizer`] and
/// [`LocalFrame::alpha`] pair by pair, to the bit: the same operations in the same order.
#[derive(Clone, Debug, Default)]
pub struct PairBatch {
    x: Vec<f32>,
    y: Vec<f32>,
    z: Vec<f32>,
    nx: Vec<f32>,
    ny: Vec<f32>,
    nz: Vec<f32>,
    /// Per partner, the feature's bin coordinates; [`PairBatch::COINCIDENT`] when the points
    /// coincide.
    pub coordinates: Vec<[f32; 4]>,
    /// Per partner, `α_s` as [`crate::model::table::alpha_to_fixed`] gives it.
    pub alpha_fixed: Vec<u16>,
}

impl PairBatch {
    /// The coordinates of a partner that coincides with the reference point: it has no
    /// feature, and a distance past every bin gives it no key.
    pub const COINCIDENT: [f32; 4] = [f32::INFINITY, 0.0, 0.0, 0.0];

    /// Starts over with no partners.
    pub fn clear(&mut self) {
        for v in [
            &mut self.x,
            &mut self.y,
            &mut self.z,
            &mut self.nx,
            &mut self.ny,
            &mut self.nz,
        ] {
            v.clear();
        }
    }

    /// Adds the partner `(p, n)`.
    #[inline]
    pub fn push(&mut self, p: &Point3<f32>, n: &Vector3<f32>) {
        self.x.push(p.x);
        self.y.push(p.y);
        self.z.push(p.z);
        self.nx.push(n.x);
        self.ny.push(n.y);
        self.nz.push(n.z);
    }

    /// How many partners it holds.
    pub fn len(&self) -> usize {
        self.x.len()
    }

    /// Whether it holds no partner.
    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    /// Fills [`PairBatch::coordinates`] and [`PairBatch::alpha_fixed`] for the pairs of the
    /// reference point `(p, n)`, whose frame is `frame`, with every partner.
    pub fn compute(
        &mut self,
        p: &Point3<f32>,
        n: &Vector3<f32>,
        frame: &LocalFrame,
        q: &Quantizer,
    ) {
        let len = self.len();
        self.coordinates.resize(len, [0.0; 4]);
        self.alpha_fixed.resize(len, 0);
        let (x, y, z) = (&self.x[..len], &self.y[..len], &self.z[..len]);
        let (nx, ny, nz) = (&self.nx[..len], &self.ny[..len], &self.nz[..len]);
        let coordinates = &mut self.coordinates[..len];
        let alpha_fixed = &mut self.alpha_fixed[..len];
        for j in 0..len {
            let pi = Point3::new(x[j], y[j], z[j]);
            let ni = Vector3::new(nx[j], ny[j], nz[j]);
            let f = PointPairFeature::compute_any(p, n, &pi, &ni);
            let c = q.coordinates_of(&f);
            coordinates[j] = if f.distance_mm > f32::EPSILON {
                c
            } else {
                Self::COINCIDENT
            };
            alpha_fixed[j] = crate::model::table::alpha_to_fixed(frame.alpha(&pi));
        }
    }
}

/// Number of cells of the key space for the given bin counts.
pub const fn key_count(distance_bins: u32, angle_bins: u32) -> usize {
    (distance_bins * angle_bins * angle_bins * angle_bins) as usize
}

/// Turns features into lookup-table keys.
///
/// Distance bins are `distance_step_mm` wide starting at 0 (the paper: `D / 20`); angle bins
/// split `[0, π]` evenly (the paper: 15 bins of 12°).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Quantizer {
    /// Width of a distance bin, mm: `D / distance_bins`.
    pub distance_step_mm: f32,
    /// Distance bins from 0 (the paper: 20 over `[0, D]`).
    pub distance_bins: u32,
    /// Bins of each angle over `[0, π]` (the paper: 15).
    pub angle_bins: u32,
}

/// At most this many keys come out of the neighbour rule: the exact cell plus up to 15.
pub const MAX_KEYS: usize = 16;

impl Quantizer {
    /// A quantiser whose distance bins cover `[0, diameter_mm]`.
    pub fn new(diameter_mm: f32, distance_bins: u32, angle_bins: u32) -> Self {
        Self {
            distance_step_mm: diameter_mm / distance_bins as f32,
            distance_bins,
            angle_bins,
        }
    }

    /// Size of the key space.
    pub fn key_count(&self) -> usize {
        key_count(self.distance_bins, self.angle_bins)
    }

    /// Continuous bin coordinates of the four dimensions (bin index + fraction inside the bin).
    ///
    /// Multiplied by the bins per unit rather than divided by the bin width: the voting loop
    /// computes these for every pair, and the reciprocals are the same for all of them.
    #[inline(always)]
    pub fn coordinates_of(&self, f: &PointPairFeature) -> [f32; 4] {
        let per_mm = 1.0 / self.distance_step_mm;
        let per_radian = self.angle_bins as f32 * std::f32::consts::FRAC_1_PI;
        [
            f.distance_mm * per_mm,
            f.angle_n1_d * per_radian,
            f.angle_n2_d * per_radian,
            f.angle_n1_n2 * per_radian,
        ]
    }

    #[inline]
    fn bins(&self) -> [u32; 4] {
        [
            self.distance_bins,
            self.angle_bins,
            self.angle_bins,
            self.angle_bins,
        ]
    }

    #[inline]
    fn pack(&self, b: [u32; 4]) -> u32 {
        ((b[0] * self.angle_bins + b[1]) * self.angle_bins + b[2]) * self.angle_bins + b[3]
    }

    /// Bin of one dimension. A value exactly on the upper end (distance = diameter, angle = π)
    /// belongs to the last bin; a distance past it has no bin.
    #[inline]
    fn bin_of(x: f32, bins: u32, clamp: bool) -> Option<u32> {
        if x < 0.0 {
            return if clamp { Some(0) } else { None };
        }
        // Truncation is the floor for x >= 0 (and gives 0 for NaN, as the floor would).
        let b = x as u32;
        if b < bins {
            Some(b)
        } else if clamp || x <= bins as f32 {
            Some(bins - 1)
        } else {
            None
        }
    }

    /// The key of the cell the feature falls in; `None` if its distance is beyond the last bin.
    #[inline]
    pub fn key(&self, f: &PointPairFeature) -> Option<u32> {
        self.key_at(self.coordinates_of(f))
    }

    /// [`Quantizer::key`] of the feature whose bin coordinates are `c`.
    #[inline]
    pub fn key_at(&self, c: [f32; 4]) -> Option<u32> {
        let n = self.bins();
        let mut b = [0u32; 4];
        for i in 0..4 {
            b[i] = Self::bin_of(c[i], n[i], i > 0)?;
        }
        Some(self.pack(b))
    }

    /// The paper's rule (Fig. 4c): per dimension, a value in the lower third of its bin also
    /// uses the bin below, one in the upper third also the bin above. Writes the cartesian
    /// product (the exact key first, at most [`MAX_KEYS`]) into `out` and returns how many.
    /// Angle bins clamp at 0 and π; distance bins outside the table are dropped.
    ///
    /// Whether a dimension has a neighbour is a coin toss per pair, and the voting loop calls
    /// this for every pair: so the product is formed without branches on it, from a table of
    /// which neighbours each of its keys takes (`NEIGHBOUR_MASKS`). All 16 slots of
    /// `out` are written; those past the returned count hold repeats of the exact key.
    #[inline]
    pub fn keys_with_neighbours(&self, f: &PointPairFeature, out: &mut [u32; MAX_KEYS]) -> usize {
        self.keys_with_neighbours_at(self.coordinates_of(f), out)
    }

    /// [`Quantizer::keys_with_neighbours`] of the feature whose bin coordinates are `c`
    /// ([`Quantizer::coordinates_of`]).
    #[inline]
    pub fn keys_with_neighbours_at(&self, c: [f32; 4], out: &mut [u32; MAX_KEYS]) -> usize {
        let n = self.bins();
        let a = self.angle_bins;
        // A key's stride per dimension, distance first (as `pack`).
        let stride = [a * a * a, a * a, a, 1];
        let mut exact = 0u32;
        // Per dimension, the step from the exact key to the neighbour's (0: no neighbour).
        let mut step = [0i32; 4];
        let mut present = 0u32;
        for i in 0..4 {
            let Some(b) = Self::bin_of(c[i], n[i], i > 0) else {
                return 0;
            };
            exact += b * stride[i];
            let frac = c[i] - b as f32;
            let down = (frac < 1.0 / 3.0) & (b > 0);
            let up = (frac > 2.0 / 3.0) & (b + 1 < n[i]);
            step[i] = (up as i32 - down as i32) * stride[i] as i32;
            present |= ((up | down) as u32) << i;
        }
        // The product's keys, the exact one first: each takes the neighbours of the dimensions
        // its slot's masks name, in a loop of fixed length that vectorises.
        let p = present as usize;
        for (j, key) in out.iter_mut().enumerate() {
            let mut k = exact;
            for (i, &s) in step.iter().enumerate() {
                k = k.wrapping_add(NEIGHBOUR_MASKS[i][p][j] & s as u32);
            }
            *key = k;
        }
        1 << present.count_ones()
    }
}

/// `NEIGHBOUR_MASKS[i][p][j]`: whether the `j`-th key of the product takes the neighbour of
/// dimension `i` (all ones) or its exact bin (zero), when the dimensions with a neighbour are
/// the bits of `p`. The keys run through the subsets of `p` in increasing order, so the first
/// takes no neighbour: the exact key. Slots past the product's `2^|p|` keys are unused.
const NEIGHBOUR_MASKS: [[[u32; MAX_KEYS]; 16]; 4] = neighbour_masks();

const fn neighbour_masks() -> [[[u32; MAX_KEYS]; 16]; 4] {
    let mut masks = [[[0u32; MAX_KEYS]; 16]; 4];
    let mut p = 0;
    while p < 16 {
        let (mut slot, mut choice) = (0, 0);
        while choice < 16 {
            if choice & !p == 0 {
                let mut i = 0;
                while i < 4 {
                    if (choice >> i) & 1 == 1 {
                        masks[i][p][slot] = u32::MAX;
                    }
                    i += 1;
                }
                slot += 1;
            }
            choice += 1;
        }
        p += 1;
    }
    masks
}

/// The transform of a reference point into its local coordinates: the point to the origin, its
/// normal onto +x (Drost et al. 2010).
#[derive(Clone, Copy, Debug)]
pub struct LocalFrame {
    rotation: Rotation3<f32>,
    origin: Point3<f32>,
}

impl LocalFrame {
    /// The frame of the oriented point `(p, n)`; `n` must be unit length.
    pub fn new(p: &Point3<f32>, n: &Vector3<f32>) -> Self {
        let x = Vector3::x();
        let cos = n.dot(&x).clamp(-1.0, 1.0);
        let rotation = if cos > 1.0 - 1e-7 {
            Rotation3::identity()
        } else if cos < -1.0 + 1e-7 {
            // Antiparallel: any half turn about an axis perpendicular to x.
            Rotation3::from_axis_angle(&Vector3::z_axis(), PI)
        } else {
            let axis = nalgebra::Unit::new_normalize(n.cross(&x));
            Rotation3::from_axis_angle(&axis, cos.acos())
        };
        Self {
            rotation,
            origin: *p,
        }
    }

    /// `T · q`: a point in this frame's local coordinates.
    #[inline]
    fn transform(&self, q: &Point3<f32>) -> Vector3<f32> {
        self.rotation * (q - self.origin)
    }

    /// `α`: the angle about x that brings `T · q` into the half-plane `y = 0, z > 0`, in
    /// `(−π, π]`.
    #[inline]
    pub fn alpha(&self, q: &Point3<f32>) -> f32 {
        let v = self.transform(q);
        fast_atan2(v.y, v.z)
    }

    /// `T` as an isometry.
    fn isometry(&self) -> Isometry3<f32> {
        let r = UnitQuaternion::from_rotation_matrix(&self.rotation);
        Isometry3::from_parts(Translation3::from(r * -self.origin.coords), r)
    }
}

/// The pose `T_s⁻¹ · R_x(α) · T_m` that maps a model reference point onto a scene reference
/// point, turned by `α = α_m − α_s` about the shared normal.
pub fn pose_from_alignment(
    scene_frame: &LocalFrame,
    model_frame: &LocalFrame,
    alpha: f32,
) -> Isometry3<f32> {
    let rx = Isometry3::rotation(Vector3::x() * alpha);
    scene_frame.isometry().inverse() * rx * model_frame.isometry()
}

/// Wraps an angle into `[−π, π)`.
#[inline]
pub fn wrap_angle(a: f32) -> f32 {
    let mut a = (a + PI).rem_euclid(2.0 * PI) - PI;
    if a >= PI {
        a -= 2.0 * PI;
    }
    a
}

/// Bin of a wrapped angle in `[−π, π)` among `bins` equal bins.
#[inline]
pub fn alpha_bin(alpha: f32, bins: u32) -> u32 {
    let b = ((alpha + PI) * (bins as f32 / (2.0 * PI))) as i64;
    b.clamp(0, bins as i64 - 1) as u32
}

/// Centre angle of an α bin, in `[−π, π)`.
#[inline]
pub fn alpha_of_bin(bin: u32, bins: u32) -> f32 {
    -PI + (bin as f32 + 0.5) * (2.0 * PI / bins as f32)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Unit;

    fn oriented(p: [f32; 3], n: [f32; 3]) -> (Point3<f32>, Vector3<f32>) {
        (Point3::from(p), Vector3::from(n).normalize())
    }

    fn some_pose() -> Isometry3<f32> {
        Isometry3::from_parts(
            Translation3::new(12.0, -40.0, 730.0),
            UnitQuaternion::from_axis_angle(
                &Unit::new_normalize(Vector3::new(0.3, -0.8, 0.5)),
                2.1,
            ),
        )
    }

    #[test]
    fn feature_is_invariant_under_rigid_transform() {
        let (p1, n1) = oriented([1.0, 2.0, 3.0], [0.2, 0.9, -0.1]);
        let (p2, n2) = oriented([40.0, -10.0, 25.0], [-0.7, 0.1, 0.6]);
        let f = PointPairFeature::compute(&p1, &n1, &p2, &n2).unwrap();
        let t = some_pose();
        let g = PointPairFeature::compute(&(t * p1), &(t * n1), &(t * p2), &(t * n2)).unwrap();
        assert!((f.distance_mm - g.distance_mm).abs() < 1e-3);
        assert!((f.angle_n1_d - g.angle_n1_d).abs() < 1e-4);
        assert!((f.angle_n2_d - g.angle_n2_d).abs() < 1e-4);
        assert!((f.angle_n1_n2 - g.angle_n1_n2).abs() < 1e-4);
        // and the angles are real angles, not cosines
        let d = (p2 - p1).normalize();
        assert!((f.angle_n1_d - n1.dot(&d).acos()).abs() < 1e-4);
    }

    #[test]
    fn fast_acos_and_atan2_match_the_library() {
        for i in 0..=2000 {
            let x = -1.0 + i as f32 / 1000.0;
            assert!((fast_acos(x) - x.acos()).abs() < 7e-5, "acos({x})");
        }
        for i in 0..720 {
            let a = (i as f32 * 0.5).to_radians() - PI;
            for r in [1e-3f32, 1.0, 250.0] {
                let (y, x) = (r * a.sin(), r * a.cos());
                let d = wrap_angle(fast_atan2(y, x) - y.atan2(x)).abs();
                assert!(d < 2e-5, "atan2({y}, {x}) off by {d}");
            }
        }
        assert_eq!(fast_atan2(0.0, 0.0), 0.0);
        assert!((fast_atan2(0.0, -1.0).abs() - PI).abs() < 1e-6);
    }

    #[test]
    fn coincident_points_have_no_feature() {
        let (p, n) = oriented([1.0, 2.0, 3.0], [0.0, 0.0, 1.0]);
        assert!(PointPairFeature::compute(&p, &n, &p, &n).is_none());
    }

    #[test]
    fn pose_from_a_transformed_pair_is_that_pose() {
        let pairs = [
            (
                [1.0, 2.0, 3.0],
                [0.2, 0.9, -0.1],
                [40.0, -10.0, 25.0],
                [-0.7, 0.1, 0.6],
            ),
            (
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [0.0, 30.0, 5.0],
                [0.0, 1.0, 0.0],
            ),
            (
                [5.0, 5.0, 5.0],
                [-1.0, 0.0, 0.0],
                [5.0, -20.0, 9.0],
                [0.0, 0.0, 1.0],
            ),
            (
                [3.0, -7.0, 1.0],
                [0.0, 0.0, -1.0],
                [-13.0, 8.0, 10.0],
                [0.5, 0.5, 0.5],
            ),
        ];
        let truth = some_pose();
        for (a, na, b, nb) in pairs {
            let (m1, n1) = oriented(a, na);
            let (m2, _) = oriented(b, nb);
            let (s1, sn1, s2) = (truth * m1, truth * n1, truth * m2);
            let model_frame = LocalFrame::new(&m1, &n1);
            let scene_frame = LocalFrame::new(&s1, &sn1);
            let alpha = model_frame.alpha(&m2) - scene_frame.alpha(&s2);
            let pose = pose_from_alignment(&scene_frame, &model_frame, alpha);
            let dr = (pose.rotation.to_rotation_matrix().matrix()
                - truth.rotation.to_rotation_matrix().matrix())
            .abs()
            .max();
            let dt = (pose.translation.vector - truth.translation.vector)
                .abs()
                .max();
            assert!(dr < 1e-4, "rotation differs by {dr}");
            assert!(dt / 730.0 < 1e-4, "translation differs by {dt} mm");
        }
    }

    #[test]
    fn local_frame_puts_normal_on_x_and_point_at_origin() {
        for n in [
            [0.0, 0.0, 1.0],
            [1.0, 0.0, 0.0],
            [-1.0, 0.0, 0.0],
            [0.3, -0.4, 0.5],
        ] {
            let (p, n) = oriented([3.0, 4.0, 5.0], n);
            let f = LocalFrame::new(&p, &n);
            assert!(f.transform(&p).norm() < 1e-5);
            let rotated = f.isometry() * n;
            assert!((rotated - Vector3::x()).norm() < 1e-5, "{rotated:?}");
        }
    }

    #[test]
    fn alpha_brings_point_into_the_positive_z_half_plane() {
        let (p, n) = oriented([0.0, 0.0, 0.0], [0.3, 0.1, 0.9]);
        let f = LocalFrame::new(&p, &n);
        let q = Point3::new(10.0, -20.0, 7.0);
        let a = f.alpha(&q);
        let v = Rotation3::from_axis_angle(&Vector3::x_axis(), a) * f.transform(&q);
        assert!(v.y.abs() < 1e-4 && v.z > 0.0, "{v:?}");
    }

    #[test]
    fn exact_key_and_bins() {
        let q = Quantizer::new(100.0, 20, 15);
        assert_eq!(q.key_count(), 67_500);
        let step = PI / 15.0;
        let f = PointPairFeature {
            distance_mm: 12.5,      // bin 2 (step 5 mm), middle
            angle_n1_d: 0.5 * step, // bin 0
            angle_n2_d: 7.5 * step, // bin 7
            angle_n1_n2: PI,        // last bin
        };
        assert_eq!(q.key(&f), Some(((2 * 15) * 15 + 7) * 15 + 14));
        // distance exactly the diameter is in the last bin, beyond it in none
        let mut g = f;
        g.distance_mm = 100.0;
        assert_eq!(q.key(&g).map(|k| k / (15 * 15 * 15)), Some(19));
        g.distance_mm = 100.5;
        assert_eq!(q.key(&g), None);
    }

    #[test]
    fn neighbour_rule_follows_thirds() {
        let q = Quantizer::new(100.0, 20, 15);
        let step = PI / 15.0;
        let mut out = [0u32; MAX_KEYS];
        // All four values in the middle third: only the exact key.
        let mid = PointPairFeature {
            distance_mm: 12.5,
            angle_n1_d: 3.5 * step,
            angle_n2_d: 7.5 * step,
            angle_n1_n2: 9.5 * step,
        };
        assert_eq!(q.keys_with_neighbours(&mid, &mut out), 1);
        assert_eq!(out[0], q.key(&mid).unwrap());
        // All four near a bin border (and not at the table's ends): 2^4 keys, all distinct.
        let border = PointPairFeature {
            distance_mm: 10.5,      // lower third of bin 2 -> also bin 1
            angle_n1_d: 3.9 * step, // upper third -> also bin 4
            angle_n2_d: 7.1 * step, // lower third -> also bin 6
            angle_n1_n2: 9.8 * step,
        };
        let n = q.keys_with_neighbours(&border, &mut out);
        assert_eq!(n, 16);
        let mut keys = out[..n].to_vec();
        assert_eq!(keys[0], q.key(&border).unwrap());
        keys.sort();
        keys.dedup();
        assert_eq!(keys.len(), 16);
        let d = |k: u32| k / 3375;
        let a1 = |k: u32| (k / 225) % 15;
        assert!(keys.iter().all(|&k| d(k) == 1 || d(k) == 2));
        assert!(keys.iter().all(|&k| a1(k) == 3 || a1(k) == 4));
        // Angles clamp at 0 and pi, distance bin below 0 is dropped: no neighbours there.
        let edge = PointPairFeature {
            distance_mm: 0.5,
            angle_n1_d: 0.0,
            angle_n2_d: PI,
            angle_n1_n2: 0.1 * step,
        };
        assert_eq!(q.keys_with_neighbours(&edge, &mut out), 1);
    }

    /// Against the rule written out plainly, on features spread over the whole table and
    /// beyond it: the same keys, the exact one first, none twice.
    #[test]
    fn neighbour_keys_are_the_plain_product() {
        let q = Quantizer::new(100.0, 20, 15);
        let mut rng = crate::geometry::rng::Rng::new(5);
        let mut counts = [0usize; MAX_KEYS + 1];
        for _ in 0..20_000 {
            let f = PointPairFeature {
                distance_mm: 105.0 * rng.uniform() as f32,
                angle_n1_d: PI * rng.uniform() as f32,
                angle_n2_d: PI * rng.uniform() as f32,
                angle_n1_n2: PI * rng.uniform() as f32,
            };
            let mut out = [0u32; MAX_KEYS];
            let n = q.keys_with_neighbours(&f, &mut out);
            counts[n] += 1;
            let Some(exact) = q.key(&f) else {
                assert_eq!(n, 0, "{f:?}");
                continue;
            };
            // The plain rule: per dimension the bin and, in an outer third, the one beside it.
            let c = [
                f.distance_mm / q.distance_step_mm,
                f.angle_n1_d * 15.0 / PI,
                f.angle_n2_d * 15.0 / PI,
                f.angle_n1_n2 * 15.0 / PI,
            ];
            let bins = [20i64, 15, 15, 15];
            let mut options: Vec<Vec<i64>> = Vec::new();
            for i in 0..4 {
                let b = (c[i].floor() as i64).min(bins[i] - 1);
                let frac = c[i] - b as f32;
                let mut o = vec![b];
                if frac < 1.0 / 3.0 && b > 0 {
                    o.push(b - 1);
                } else if frac > 2.0 / 3.0 && b + 1 < bins[i] {
                    o.push(b + 1);
                }
                options.push(o);
            }
            let mut plain = Vec::new();
            for &d in &options[0] {
                for &a1 in &options[1] {
                    for &a2 in &options[2] {
                        for &a3 in &options[3] {
                            plain.push((((d * 15 + a1) * 15 + a2) * 15 + a3) as u32);
                        }
                    }
                }
            }
            assert_eq!(out[0], exact, "{f:?}");
            let mut got = out[..n].to_vec();
            got.sort();
            got.dedup();
            assert_eq!(got.len(), n, "a key twice for {f:?}");
            plain.sort();
            assert_eq!(got, plain, "{f:?}");
        }
        // Every product size turns up, and 16 keys about (2/3)^4 of the time.
        for n in [1, 2, 4, 8, 16] {
            assert!(counts[n] > 100, "{counts:?}");
        }
        assert!(counts[16] > 2_500 && counts[16] < 4_300, "{counts:?}");
    }

    #[test]
    fn alpha_wraps_and_bins() {
        assert!((wrap_angle(3.0 * PI / 2.0) + PI / 2.0).abs() < 1e-5);
        assert!((wrap_angle(-3.0 * PI / 2.0) - PI / 2.0).abs() < 1e-5);
        assert!(wrap_angle(PI) < PI && wrap_angle(PI) >= -PI);
        assert_eq!(alpha_bin(-PI, 30), 0);
        assert_eq!(alpha_bin(PI - 1e-4, 30), 29);
        assert_eq!(alpha_bin(0.01, 30), 15);
        for b in 0..30 {
            assert_eq!(alpha_bin(alpha_of_bin(b, 30), 30), b);
        }
    }

    #[test]
    fn a_batch_of_pairs_gives_each_pairs_values_to_the_bit() {
        let mut rng = crate::geometry::rng::Rng::new(11);
        let q = Quantizer::new(120.0, 20, 15);
        let (p, n) = oriented([3.0, -7.0, 640.0], [0.2, -0.4, -0.9]);
        let frame = LocalFrame::new(&p, &n);
        let mut batch = PairBatch::default();
        let mut partners = vec![(p, n)]; // the reference point itself: no feature
        for _ in 0..257 {
            partners.push(oriented(
                [
                    p.x + rng.range(-120.0, 120.0),
                    p.y + rng.range(-120.0, 120.0),
                    p.z + rng.range(-60.0, 60.0),
                ],
                [
                    rng.range(-1.0, 1.0),
                    rng.range(-1.0, 1.0),
                    rng.range(-1.0, 0.1),
                ],
            ));
        }
        for (pi, ni) in &partners {
            batch.push(pi, ni);
        }
        batch.compute(&p, &n, &frame, &q);
        assert_eq!(batch.coordinates.len(), partners.len());
        assert_eq!(batch.coordinates[0], PairBatch::COINCIDENT);
        assert_eq!(q.key_at(PairBatch::COINCIDENT), None);
        for (j, (pi, ni)) in partners.iter().enumerate().skip(1) {
            let f = PointPairFeature::compute(&p, &n, pi, ni).unwrap();
            let bits = |c: [f32; 4]| c.map(f32::to_bits);
            assert_eq!(
                bits(batch.coordinates[j]),
                bits(q.coordinates_of(&f)),
                "pair {j}"
            );
            assert_eq!(
                batch.alpha_fixed[j],
                crate::model::table::alpha_to_fixed(frame.alpha(pi)),
                "pair {j}"
            );
        }
    }
}
