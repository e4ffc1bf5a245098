//! View-dependent re-scoring (METHOD.md §3.2): how well the part of the model that the camera
//! would see at a pose fits the scene.
//!
//! Each surface point of the model is moved into the camera by the pose. Only points whose
//! normal faces the camera can be seen. Each one is projected into the depth image and compared
//! with the depth measured there:
//!
//! - within the tolerance: an **inlier**, the scene supports the model there;
//! - the scene well in front: the point is **occluded** (by clutter or another object) and says
//!   nothing either way;
//! - the scene well behind: the sensor **sees through** the model, which cannot be if the pose
//!   were right (the non-consistent-points filter uses this);
//! - no depth there: unknown.
//!
//! The fit of a pose is its number of inliers divided by the model's surface point count: the
//! fraction of the whole model surface that the scene confirms. Its support is the fraction of
//! the points that should be seen (measured and not occluded) that the scene confirms: a pose
//! placed partly behind other surfaces can collect as many inliers as the true one, but leaves
//! more of what it shows unconfirmed. Its score is the fit times the support (to the power
//! `support_weight`) times the agreement of its outline with the scene's depth edges ([`with_silhouettes`]) raised to
//! `silhouette_weight`: a model laid flat on a table or a wall fits that plane as well as the
//! true pose fits the object, but only the true pose has its outline on depth edges. On the
//! LM-O frame this lifts the glue's true pose from rank 264 to 5 among the 500 re-scored
//! clusters, and the driller's from 33 to 1.

use nalgebra::{Matrix3, Point3, Vector3};
use rayon::prelude::*;

use crate::detect::scene::SceneImage;
use crate::detect::silhouette::{Fit, OutlineCounts};
use crate::geometry::camera::Intrinsics;
use crate::geometry::grid::cell_of;
use crate::model::subsample::OrientedPoints;
use crate::Pose;

/// Parameters of re-scoring.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RescoringParams {
    /// How many of the best pose clusters are re-scored. The paper: 500.
    pub top_clusters: usize,
    /// A visible point is an inlier within this depth difference, as a fraction of the
    /// diameter. Before ICP, poses are off by up to half an α bin (6°) over a lever of D/2,
    /// about 0.05 D.
    pub tolerance_fraction: f32,
    /// After ICP, poses are scored again with this tighter tolerance (fraction of the
    /// diameter)...
    pub refined_tolerance_fraction: f32,
    /// ...but never tighter than this, mm: sensor noise at 1–1.5 m is a few millimetres.
    pub min_tolerance_mm: f32,
    /// ...and with normals within this angle, degrees.
    pub max_normal_angle_deg: f32,
    /// The scene counts as in front of (occluding) or behind (seen through) a model point only
    /// beyond this depth difference, as a fraction of the diameter, and at least
    /// `min_conflict_mm`: small misalignments at the outline must not read as contradictions.
    pub conflict_fraction: f32,
    /// The least conflict distance, mm (see `conflict_fraction`).
    pub min_conflict_mm: f32,
    /// Exponent of the support (inliers over the visible points, see [`Fit::support`]) in the
    /// score; 0 scores by the fit alone. With the residual below, 1.5 against 1: ycbv-real-dev's
    /// AR 0.644 against 0.616, the recalls of the four data sets as they were (METHOD.md §3.2).
    pub support_weight: f32,
    /// Exponent of the silhouette agreement in the score; 0 scores by the fit alone.
    pub silhouette_weight: f32,
    /// The silhouette agreement divides by at least this fraction of the whole outline, hidden
    /// parts included (see [`crate::detect::silhouette::OutlineCounts::fraction_of_at_least`]).
    pub min_visible_outline: f32,
    /// Silhouettes are rendered from a copy of the model's mesh with vertices merged on a grid
    /// of this fraction of the diameter: the outline moves by less than a cell, and the copy has
    /// fewer triangles the larger the cell. Measured (release): 0.025, 0.04 and 0.05
    /// give the same recall on the LM-O frame (VSD 0.750, AR 0.654) and synth-lmo-dev (0.931);
    /// re-scoring on a synth-lmo-dev frame takes 0.69–0.74 of 0.025's time at 0.04 and
    /// 0.63–0.66 at 0.05. 0.04 takes most of the gain for a smaller shift of the outline.
    pub silhouette_mesh_cell_fraction: f32,
    /// Before the full re-scoring, every cluster is scored on every `prescore_stride`-th
    /// surface point alone, and only the `prescore_keep` best go on to the full fit and the
    /// silhouettes (a keep of 0 or a stride of 1: every cluster does). A sparse fit ranks
    /// the clusters nearly as the full one does, for a quarter of its cost; but the silhouette
    /// still lifts a right pose from far down: on the LM-O frame the glue's is kept with 200
    /// and lost with 100. With the refined scores of METHOD.md §3.3, 250 is the fewest that
    /// give the four data sets what every cluster's full fit gives (synth-lmo-dev 0.954, 0.949
    /// with 200 and 225), for about 4 % more time on the LM-O frame (docs/METHOD.md §3.2).
    pub prescore_stride: usize,
    /// How many clusters the sparse fit passes on (see `prescore_stride`); 0 passes every one.
    pub prescore_keep: usize,
    /// Before ICP, outlines wider than this many pixels are drawn at a coarser scale (0:
    /// as [`crate::detect::filters::FilterParams::max_outline_px`] says for after ICP). A pose
    /// out of voting is off by up to half an α bin, so a finer outline adds little to its
    /// ranking: 40 keeps the LM-O frame's, synth-lmo-dev's and the YCB-Video frames' recall
    /// and takes re-scoring from about 260 to 180 ms on the LM-O frame; 24 loses a target of
    /// synth-lmo-dev (docs/METHOD.md §3.2).
    pub coarse_outline_px: u32,
    /// After ICP, of one object's refined poses the one with the smallest residual (ICP's root
    /// mean square point-to-plane distance, mm) keeps its score, and each other's score is
    /// multiplied by `((residual_scale_mm + r₀) / (residual_scale_mm + r))^residual_weight`,
    /// `r₀` the smallest residual and `r` its own: of poses that fit as much of the scene, the
    /// one that fits it more tightly wins. A right pose's residual is the sensor's noise; a
    /// model fitted to something it only resembles (a distractor box or cylinder, another
    /// object) leaves more. Weight 0 leaves the scores as re-scoring gives them (METHOD.md
    /// §3.3).
    pub residual_scale_mm: f32,
    /// The exponent of the residual factor (see `residual_scale_mm`); 0 turns it off.
    pub residual_weight: f32,
}

impl RescoringParams {
    /// The inlier tolerance before ICP for an object of diameter `diameter_mm`, mm.
    pub fn tolerance_mm(&self, diameter_mm: f32) -> f32 {
        (self.tolerance_fraction * diameter_mm).max(self.min_tolerance_mm)
    }

    /// The outline width before ICP: `coarse_outline_px`, or `after_icp_px` when that is 0.
    pub fn coarse_outline(&self, after_icp_px: u32) -> u32 {
        match self.coarse_outline_px {
            0 => after_icp_px,
            px => px,
        }
    }

    /// The depth difference beyond which the scene occludes or is seen through, mm.
    pub fn conflict_mm(&self, diameter_mm: f32) -> f32 {
        (self.conflict_fraction * diameter_mm).max(self.min_conflict_mm)
    }

    /// The inlier tolerance after ICP, mm.
    pub fn refined_tolerance_mm(&self, diameter_mm: f32) -> f32 {
        (self.refined_tolerance_fraction * diameter_mm).max(self.min_tolerance_mm)
    }
}

impl Default for RescoringParams {
    fn default() -> Self {
        Self {
            top_clusters: 500,
            tolerance_fraction: 0.05,
            refined_tolerance_fraction: 0.03,
            min_tolerance_mm: 4.0,
            max_normal_angle_deg: 45.0,
            conflict_fraction: 0.1,
            min_conflict_mm: 15.0,
            support_weight: 1.5,
            silhouette_weight: 1.5,
            min_visible_outline: 0.5,
            silhouette_mesh_cell_fraction: 0.04,
            prescore_stride: 4,
            prescore_keep: 250,
            coarse_outline_px: 40,
            residual_scale_mm: 0.5,
            residual_weight: 2.0,
        }
    }
}

/// The score of a fit before the silhouette: the fraction of the model surface confirmed, times
/// the support to the power `support_weight`.
fn fit_and_support(fit: &Fit, surface_points: usize, params: &RescoringParams) -> f32 {
    fit.inliers as f32 / surface_points.max(1) as f32 * fit.support().powf(params.support_weight)
}

/// A pose as a rotation matrix and a translation: moving a point costs a matrix product rather
/// than a quaternion rotation, which matters in loops over thousands of points per pose.
#[derive(Clone, Copy, Debug)]
pub struct PoseMatrix {
    /// The rotation, as a 3 × 3 matrix.
    pub rotation: Matrix3<f32>,
    /// The translation, mm.
    pub translation: Vector3<f32>,
}

impl PoseMatrix {
    /// `pose` as a matrix and a translation.
    pub fn new(pose: &Pose) -> PoseMatrix {
        PoseMatrix {
            rotation: *pose.rotation.to_rotation_matrix().matrix(),
            translation: pose.translation.vector,
        }
    }
}

/// A model point moved into the camera by `pose`, if its normal faces the camera: its camera
/// position, camera normal and the pixel it projects to (not checked against the image size).
#[inline]
pub fn facing_projection(
    pose: &PoseMatrix,
    p: &Point3<f32>,
    n: &Vector3<f32>,
    k: &Intrinsics,
) -> Option<(Point3<f32>, Vector3<f32>, i64, i64)> {
    let mut m = Moved::default();
    m.one(pose, k, p, n);
    m.facing[0].then(|| (m.point(0), m.normal(0), m.u[0] as i64, m.v[0] as i64))
}

/// How the scene judges one surface point at its pixel (see [`judge_point`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Judgement {
    /// No depth there.
    Unmeasured,
    /// The scene lies more than the conflict distance in front: something hides the point.
    Occluded,
    /// The scene lies more than the conflict distance behind: the sensor sees through it.
    SeeThrough,
    /// Neither, but farther than the tolerance, or with the normals too far apart.
    Missed,
    /// Within the tolerance, with the normals within the angle: the scene confirms the point.
    Inlier,
}

/// The model point `(p, n)` at `pose` against `scene`: `None` when its normal faces away from
/// the camera or it projects outside the image; otherwise its pixel and the scene's judgement,
/// with inlier tolerance `tolerance_mm`, conflict distance `conflict_mm` and normals within
/// the angle whose cosine is `cos_max`. What [`fit`] counts and an exclusion claim
/// ([`crate::detect::exclusion::Claim`]) collects. Always inlined: [`fit`] calls it for every
/// surface point of hundreds of poses, and as a call re-scoring on the LM-O frame took about
/// 7 % longer (`RAYON_NUM_THREADS=1 ppf profile`, alternately three times).
#[inline(always)]
pub fn judge_point(
    pose: &PoseMatrix,
    p: &Point3<f32>,
    n: &Vector3<f32>,
    scene: &SceneImage,
    tolerance_mm: f32,
    conflict_mm: f32,
    cos_max: f32,
) -> Option<(Judgement, i64, i64)> {
    let (pc, nc, u, v) = facing_projection(pose, p, n, &scene.intrinsics)?;
    if u < 0 || v < 0 || u >= scene.width as i64 || v >= scene.height as i64 {
        return None;
    }
    let Some(z) = scene.depth(u, v) else {
        return Some((Judgement::Unmeasured, u, v));
    };
    let dz = z - pc.z;
    let judgement = if dz < -conflict_mm {
        Judgement::Occluded
    } else if dz > conflict_mm {
        Judgement::SeeThrough
    } else if dz.abs() > tolerance_mm {
        Judgement::Missed
    } else if scene.at(u, v).is_some_and(|(_, sn)| sn.dot(&nc) >= cos_max) {
        Judgement::Inlier
    } else {
        Judgement::Missed
    };
    Some((judgement, u, v))
}

/// Measures the fit of `surface` (model coordinates) at `pose` against `scene`: the tally of
/// [`judge_point`] over its points.
///
/// Counted without branches but one: the points' judgements follow the scene's noise, so as
/// branches they are often mispredicted; counted as flags, re-scoring takes about 7 % less
/// (docs/METHOD.md §3.2). Every point reads a depth (pixel 0 for one that faces away or falls
/// outside the image, not counted); only a point within the tolerance reads the scene's normal.
/// Points are moved and projected four at a time (`Moved::four`), with the same operations
/// in the same order as one at a time, so to the bit. `fit_counts_what_judge_point_judges`
/// checks the tally.
pub fn fit(
    surface: &OrientedPoints,
    pose: &Pose,
    scene: &SceneImage,
    tolerance_mm: f32,
    conflict_mm: f32,
    max_normal_angle_deg: f32,
) -> Fit {
    let cos_max = max_normal_angle_deg.to_radians().cos();
    let pose = PoseMatrix::new(pose);
    let k = &scene.intrinsics;
    let depths = scene.depths();
    let (width, height) = (scene.width as i64, scene.height as i64);
    let mut f = Fit::default();
    let mut tally = |m: &Moved, lane: usize| {
        let (u, v) = (m.u[lane] as i64, m.v[lane] as i64);
        let inside = m.facing[lane] & (u >= 0) & (v >= 0) & (u < width) & (v < height);
        let pixel = if inside { (v * width + u) as usize } else { 0 };
        let z = depths[pixel];
        let measured = inside & z.is_finite();
        let dz = z - m.z[lane];
        let occluded = measured & (dz < -conflict_mm);
        let see_through = measured & (dz > conflict_mm);
        let close = measured & !occluded & !see_through & (dz.abs() <= tolerance_mm);
        f.facing += u32::from(inside);
        f.measured += u32::from(measured);
        f.occluded += u32::from(occluded);
        f.see_through += u32::from(see_through);
        if close {
            // A pixel without a normal holds NaN, and the comparison fails: missed.
            f.inliers += u32::from(scene.normals[pixel].dot(&m.normal(lane)) >= cos_max);
        }
    };
    Moved::each(&pose, k, surface, 1, |m, lane| tally(m, lane));
    f
}

/// Up to four model points moved into the camera by a pose: whether each faces the camera, the
/// pixel it projects to (rounded half away from zero, as [`Intrinsics::pixel`]; garbage for
/// one that does not face the camera), its depth and its normal in the camera.
#[derive(Default)]
pub(crate) struct Moved {
    pub facing: [bool; 4],
    pub u: [i32; 4],
    pub v: [i32; 4],
    pub x: [f32; 4],
    pub y: [f32; 4],
    pub z: [f32; 4],
    pub nx: [f32; 4],
    pub ny: [f32; 4],
    pub nz: [f32; 4],
}

impl Moved {
    /// Every `stride`-th point of `surface` moved by `pose`, four at a time: calls
    /// `visit(moved, lane)` for each point in order.
    #[inline]
    pub fn each(
        pose: &PoseMatrix,
        k: &Intrinsics,
        surface: &OrientedPoints,
        stride: usize,
        mut visit: impl FnMut(&Moved, usize),
    ) {
        let (positions, normals) = (&surface.positions[..], &surface.normals[..]);
        let stride = stride.max(1);
        let mut m = Moved::default();
        let mut i = 0;
        if stride == 1 {
            while i + 4 <= positions.len() {
                m.four(pose, k, &positions[i..i + 4], &normals[i..i + 4]);
                for lane in 0..4 {
                    visit(&m, lane);
                }
                i += 4;
            }
        } else {
            while i + 3 * stride < positions.len() {
                let p: [Point3<f32>; 4] = std::array::from_fn(|j| positions[i + j * stride]);
                let n: [Vector3<f32>; 4] = std::array::from_fn(|j| normals[i + j * stride]);
                m.four(pose, k, &p, &n);
                for lane in 0..4 {
                    visit(&m, lane);
                }
                i += 4 * stride;
            }
        }
        while i < positions.len() {
            m.one(pose, k, &positions[i], &normals[i]);
            visit(&m, 0);
            i += stride;
        }
    }

    /// The camera position of lane `lane`.
    #[inline]
    pub fn point(&self, lane: usize) -> Point3<f32> {
        Point3::new(self.x[lane], self.y[lane], self.z[lane])
    }

    /// The camera normal of lane `lane`.
    #[inline]
    pub fn normal(&self, lane: usize) -> Vector3<f32> {
        Vector3::new(self.nx[lane], self.ny[lane], self.nz[lane])
    }

    /// One point, into lane 0 (what [`facing_projection`] reads). A pixel beyond the `i32`
    /// range is `i32::MIN`, outside the image as the four-point path leaves it.
    #[inline]
    fn one(&mut self, pose: &PoseMatrix, k: &Intrinsics, p: &Point3<f32>, n: &Vector3<f32>) {
        let pc = Point3::from(pose.rotation * p.coords + pose.translation);
        let nc: Vector3<f32> = pose.rotation * n;
        self.facing[0] = pc.z > 0.0 && nc.dot(&pc.coords) < 0.0;
        let (u, v) = k.pixel(&pc);
        let narrow = |x: i64| i32::try_from(x).unwrap_or(i32::MIN);
        (self.u[0], self.v[0]) = (narrow(u), narrow(v));
        (self.x[0], self.y[0], self.z[0]) = (pc.x, pc.y, pc.z);
        (self.nx[0], self.ny[0], self.nz[0]) = (nc.x, nc.y, nc.z);
    }

    /// Four points side by side (see `geometry::four`); nalgebra's dot product of 3-vectors
    /// sums `(a + b) + c`, as this does, so each lane comes out as [`Moved::one`] gives it.
    #[inline]
    fn four(&mut self, pose: &PoseMatrix, k: &Intrinsics, p: &[Point3<f32>], n: &[Vector3<f32>]) {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: SSE2 is part of x86-64; the loads read the four given points, the stores
        // write this value's arrays of four.
        unsafe {
            use crate::geometry::four::{lanes_of, moved, rounded};
            use std::arch::x86_64::*;
            let (r, t) = (&pose.rotation, &pose.translation);
            let [cx, cy, cz] = moved(r, Some(t), lanes_of(|i| p[i].coords));
            let [nx, ny, nz] = moved(r, None, lanes_of(|i| n[i]));
            let dot = _mm_add_ps(
                _mm_add_ps(_mm_mul_ps(nx, cx), _mm_mul_ps(ny, cy)),
                _mm_mul_ps(nz, cz),
            );
            let zero = _mm_setzero_ps();
            let facing =
                _mm_movemask_ps(_mm_and_ps(_mm_cmpgt_ps(cz, zero), _mm_cmplt_ps(dot, zero)));
            let s = _mm_set1_ps;
            let u = _mm_add_ps(_mm_div_ps(_mm_mul_ps(s(k.fx), cx), cz), s(k.cx));
            let v = _mm_add_ps(_mm_div_ps(_mm_mul_ps(s(k.fy), cy), cz), s(k.cy));
            _mm_storeu_si128(self.u.as_mut_ptr() as *mut __m128i, rounded(u));
            _mm_storeu_si128(self.v.as_mut_ptr() as *mut __m128i, rounded(v));
            _mm_storeu_ps(self.x.as_mut_ptr(), cx);
            _mm_storeu_ps(self.y.as_mut_ptr(), cy);
            _mm_storeu_ps(self.z.as_mut_ptr(), cz);
            _mm_storeu_ps(self.nx.as_mut_ptr(), nx);
            _mm_storeu_ps(self.ny.as_mut_ptr(), ny);
            _mm_storeu_ps(self.nz.as_mut_ptr(), nz);
            self.facing = std::array::from_fn(|i| facing >> i & 1 == 1);
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            let mut one = Moved::default();
            for i in 0..4 {
                one.one(pose, k, &p[i], &n[i]);
                self.facing[i] = one.facing[0];
                (self.u[i], self.v[i]) = (one.u[0], one.v[0]);
                (self.x[i], self.y[i], self.z[i]) = (one.x[0], one.y[0], one.z[0]);
                (self.nx[i], self.ny[i], self.nz[i]) = (one.nx[0], one.ny[0], one.nz[0]);
            }
        }
    }
}

/// A pose with its re-scoring result.
#[derive(Clone, Copy, Debug)]
pub struct Scored {
    /// The pose, model to camera (mm).
    pub pose: Pose,
    /// The votes it came with: its cluster's, 0 for a hint.
    pub votes: u32,
    /// How its visible surface meets the scene, at the tolerance it was scored with.
    pub fit: Fit,
    /// `fit.inliers / surface point count`.
    pub fit_score: f32,
    /// `fit_score` times the support to the power `support_weight`.
    pub support_score: f32,
    /// How the outline meets the scene's depth edges, once measured; re-scoring reads it with
    /// [`OutlineCounts::fraction_of_at_least`], the silhouette filter with
    /// [`OutlineCounts::fraction_in_view_of_at_least`].
    pub outline: Option<OutlineCounts>,
    /// What poses are ranked by: `support_score`, times the silhouette agreement (to the power
    /// `silhouette_weight`) once that is measured.
    pub score: f32,
}

/// Re-scores `poses` (with their votes) with inlier tolerance `tolerance` (mm) and sorts them by score, best first (ties: more
/// votes first).
pub fn rescore(
    poses: &[(Pose, u32)],
    surface: &OrientedPoints,
    scene: &SceneImage,
    tolerance: f32,
    conflict_mm: f32,
    params: &RescoringParams,
) -> Vec<Scored> {
    let angle = params.max_normal_angle_deg;
    rescore_with(poses, surface.len(), params, |_, pose| {
        fit(surface, pose, scene, tolerance, conflict_mm, angle)
    })
}

/// [`rescore`] with the fit of pose `i` of `poses` given by `count(i, pose)`, over a surface of
/// `points` points.
fn rescore_with(
    poses: &[(Pose, u32)],
    points: usize,
    params: &RescoringParams,
    count: impl Fn(usize, &Pose) -> Fit + Sync,
) -> Vec<Scored> {
    let total = points.max(1) as f32;
    let mut scored: Vec<Scored> = poses
        .par_iter()
        .enumerate()
        .map(|(i, &(pose, votes))| {
            let fit = count(i, &pose);
            let fit_score = fit.inliers as f32 / total;
            let score = fit_and_support(&fit, points, params);
            Scored {
                pose,
                votes,
                fit,
                fit_score,
                support_score: score,
                outline: None,
                score,
            }
        })
        .collect();
    scored.sort_by(|a, b| b.score.total_cmp(&a.score).then(b.votes.cmp(&a.votes)));
    scored
}

/// The model's surface points as re-scoring counts them with [`fit`]: every
/// `prescore_stride`-th of them in the model's order for the sparse fit ([`prescreen`]), and the
/// rest; the full fit counts both, and adds the rest to a sparse fit already counted. Each set
/// is reordered along a Z-order curve over cubes of a fiftieth of the diameter. A fit counts
/// points, so its result does not depend on their order; in this one consecutive points project
/// to nearby pixels, and the scene's depth and normals are read from the cache rather than from
/// memory. On the LM-O frame, one core, re-scoring takes about a tenth less than in the
/// sampling's order (docs/BENCHMARKS.md, "Where the time goes").
#[derive(Clone, Debug)]
pub struct FitPoints {
    /// Every `prescore_stride`-th surface point, in Z order: what the sparse fit counts.
    pub sparse: OrientedPoints,
    /// The other surface points, in Z order.
    pub rest: OrientedPoints,
}

impl FitPoints {
    /// The points of `surface` for an object of diameter `diameter_mm`, with the sparse set of
    /// [`RescoringParams::prescore_stride`].
    pub fn new(surface: &OrientedPoints, params: &RescoringParams, diameter_mm: f32) -> FitPoints {
        let stride = params.prescore_stride.max(1);
        let inverse = 50.0 / diameter_mm.max(f32::MIN_POSITIVE);
        let (sparse, rest): (Vec<usize>, Vec<usize>) =
            (0..surface.len()).partition(|i| i % stride == 0);
        FitPoints {
            sparse: in_z_order(surface, sparse, inverse),
            rest: in_z_order(surface, rest, inverse),
        }
    }

    /// How many points the full fit counts.
    pub fn len(&self) -> usize {
        self.sparse.len() + self.rest.len()
    }

    /// Whether there is no point to count.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The fit of every point at `pose` ([`fit`] over the sparse points and the rest).
    pub fn fit(
        &self,
        pose: &Pose,
        scene: &SceneImage,
        tolerance_mm: f32,
        conflict_mm: f32,
        max_normal_angle_deg: f32,
    ) -> Fit {
        let count = |points| {
            fit(
                points,
                pose,
                scene,
                tolerance_mm,
                conflict_mm,
                max_normal_angle_deg,
            )
        };
        count(&self.sparse) + count(&self.rest)
    }
}

/// The points `chosen` of `points`, sorted by the Z-order (Morton) code of their cube of side
/// `1 / inverse_cell` (ties keep their order).
fn in_z_order(
    points: &OrientedPoints,
    mut chosen: Vec<usize>,
    inverse_cell: f32,
) -> OrientedPoints {
    // Ten bits per axis, the cube's index spread to every third bit.
    let spread = |c: i32| -> u64 {
        let mut x = (c.clamp(-512, 511) + 512) as u64;
        x = (x | (x << 16)) & 0x0300_00ff;
        x = (x | (x << 8)) & 0x0300_f00f;
        x = (x | (x << 4)) & 0x030c_30c3;
        (x | (x << 2)) & 0x0924_9249
    };
    let code = |p: &Point3<f32>| {
        let (x, y, z) = cell_of(p, inverse_cell);
        spread(x) | (spread(y) << 1) | (spread(z) << 2)
    };
    chosen.sort_by_cached_key(|&i| code(&points.positions[i]));
    OrientedPoints {
        positions: chosen.iter().map(|&i| points.positions[i]).collect(),
        normals: chosen.iter().map(|&i| points.normals[i]).collect(),
    }
}

/// The poses worth the full re-scoring: all of `poses` unless `params.prescore_keep` is set
/// and smaller, else the `prescore_keep` best by [`rescore`] on the sparse points (see
/// [`RescoringParams::prescore_stride`]), best first, with each one's fit on the sparse points
/// (for [`score_poses`], which then counts only the rest).
pub fn prescreen(
    poses: &[(Pose, u32)],
    points: &FitPoints,
    scene: &SceneImage,
    tolerance: f32,
    conflict_mm: f32,
    params: &RescoringParams,
) -> (Vec<(Pose, u32)>, Option<Vec<Fit>>) {
    let keep = params.prescore_keep;
    if keep == 0 || poses.len() <= keep || params.prescore_stride <= 1 {
        return (poses.to_vec(), None);
    }
    let mut ranked = rescore(poses, &points.sparse, scene, tolerance, conflict_mm, params);
    ranked.truncate(keep);
    let fits = ranked.iter().map(|s| s.fit).collect();
    (
        ranked.into_iter().map(|s| (s.pose, s.votes)).collect(),
        Some(fits),
    )
}

/// All of `poses`, best first by [`rescore`] on `sparse` ([`FitPoints::sparse`]): the order
/// [`prescreen`] cuts.
pub fn sparse_ranking(
    poses: &[(Pose, u32)],
    sparse: &OrientedPoints,
    scene: &SceneImage,
    tolerance: f32,
    conflict_mm: f32,
    params: &RescoringParams,
) -> Vec<(Pose, u32)> {
    rescore(poses, sparse, scene, tolerance, conflict_mm, params)
        .into_iter()
        .map(|s| (s.pose, s.votes))
        .collect()
}

/// What a silhouette is measured with: the model's mesh (a simplified copy, see
/// [`RescoringParams::silhouette_mesh_cell_fraction`]), its bounding sphere in model
/// coordinates, the scene's depth edges, and the width in pixels beyond which an outline is
/// drawn at a coarser scale (0: never).
pub struct Outline<'a> {
    /// The simplified mesh the outline is drawn from.
    pub mesh: &'a crate::geometry::mesh::Mesh,
    /// The mesh's bounding sphere: centre (model coordinates) and radius, mm.
    pub sphere: &'a (Point3<f32>, f32),
    /// The scene's depth edges.
    pub edges: &'a crate::detect::silhouette::EdgeMap,
    /// The width, pixels, beyond which an outline is drawn at a coarser scale; 0 never.
    pub max_outline_px: u32,
}

/// The whole re-scoring of `poses`: [`rescore`] on all of `points` with inlier tolerance
/// `tolerance` (mm), then, when `params.silhouette_weight` is positive, [`with_silhouettes`]
/// keeping the best `keep`. Best first. `sparse_fits`, when given, holds each pose's fit on
/// `points.sparse` with the same tolerances (as [`prescreen`] gives it): only the rest is
/// counted, the same counts with a quarter less work.
#[allow(clippy::too_many_arguments)]
pub fn score_poses(
    poses: &[(Pose, u32)],
    points: &FitPoints,
    sparse_fits: Option<&[Fit]>,
    scene: &SceneImage,
    tolerance: f32,
    conflict_mm: f32,
    params: &RescoringParams,
    outline: &Outline,
    keep: usize,
) -> Vec<Scored> {
    let angle = params.max_normal_angle_deg;
    let mut scored = rescore_with(poses, points.len(), params, |i, pose| match sparse_fits {
        Some(known) => known[i] + fit(&points.rest, pose, scene, tolerance, conflict_mm, angle),
        None => points.fit(pose, scene, tolerance, conflict_mm, angle),
    });
    if params.silhouette_weight > 0.0 {
        with_silhouettes(&mut scored, outline, scene, conflict_mm, params, keep);
    }
    scored
}

/// The re-scoring of refined poses, each with its votes and ICP's residual (mm): [`score_poses`]
/// over them all, then [`with_residuals`]. Best first.
#[allow(clippy::too_many_arguments)]
pub fn score_refined(
    refined: &[(Pose, u32, f32)],
    points: &FitPoints,
    scene: &SceneImage,
    tolerance: f32,
    conflict_mm: f32,
    params: &RescoringParams,
    outline: &Outline,
) -> Vec<Scored> {
    let poses: Vec<(Pose, u32)> = refined
        .iter()
        .map(|&(pose, votes, _)| (pose, votes))
        .collect();
    let mut scored = score_poses(
        &poses,
        points,
        None,
        scene,
        tolerance,
        conflict_mm,
        params,
        outline,
        poses.len(),
    );
    // A refined pose is found by its value: each scored pose is a copy of one of them (equal
    // poses had equal residuals).
    with_residuals(
        &mut scored,
        |pose| {
            refined
                .iter()
                .find(|r| r.0 == *pose)
                .map_or(f32::INFINITY, |r| r.2)
        },
        params,
    );
    scored
}

/// Folds ICP's residuals into the scores of refined poses, as
/// [`RescoringParams::residual_weight`] says, and sorts them best first (ties: more votes
/// first). `residual_of(pose)` is the residual of the refinement that gave `pose`, mm.
pub fn with_residuals(
    scored: &mut [Scored],
    residual_of: impl Fn(&Pose) -> f32,
    params: &RescoringParams,
) {
    if params.residual_weight <= 0.0 || scored.is_empty() {
        return;
    }
    let s = params.residual_scale_mm;
    let residuals: Vec<f32> = scored.iter().map(|x| residual_of(&x.pose)).collect();
    let tightest = residuals.iter().copied().fold(f32::INFINITY, f32::min);
    for (x, r) in scored.iter_mut().zip(&residuals) {
        x.score *= ((s + tightest) / (s + r)).powf(params.residual_weight);
    }
    scored.sort_by(|a, b| b.score.total_cmp(&a.score).then(b.votes.cmp(&a.votes)));
}

/// Measures the silhouette agreement of the poses in `scored` (rendering the outline's mesh
/// against the scene's depth edges), folds it into the score with exponent
/// `params.silhouette_weight`, sorts best first (ties: more votes first) and keeps the `keep`
/// best. A pose whose outline is nowhere visible gets agreement 0.
///
/// The agreement is at most 1, so a pose's score can only fall from its `support_score`.
/// Poses are measured in order of `support_score`, a batch at a time, and measuring stops once
/// the next pose's `support_score` is below the `keep`-th best score found: the poses left
/// could not enter the best `keep`, which are exactly those measuring every pose would give.
pub fn with_silhouettes(
    scored: &mut Vec<Scored>,
    outline: &Outline,
    scene: &SceneImage,
    occlusion_tolerance_mm: f32,
    params: &RescoringParams,
    keep: usize,
) {
    let weight = params.silhouette_weight;
    scored.sort_by(|a, b| {
        b.support_score
            .total_cmp(&a.support_score)
            .then(b.votes.cmp(&a.votes))
    });
    let batch = 4 * rayon::current_num_threads().max(1);
    let mut measured = 0;
    let mut best: Vec<f32> = Vec::new(); // scores found so far, best first, at most `keep`
    while measured < scored.len() {
        if best.len() >= keep && keep > 0 && scored[measured].support_score < best[keep - 1] {
            break;
        }
        let end = (measured + batch).min(scored.len());
        scored[measured..end].par_iter_mut().for_each_init(
            crate::geometry::render::Renderer::new,
            |renderer, s| {
                let counts = crate::detect::silhouette::outline_counts(
                    renderer,
                    outline.mesh,
                    outline.sphere,
                    &s.pose,
                    scene,
                    outline.edges,
                    outline.max_outline_px,
                    occlusion_tolerance_mm,
                )
                .unwrap_or_default();
                let f = counts
                    .fraction_of_at_least(params.min_visible_outline)
                    .unwrap_or(0.0);
                s.outline = Some(counts);
                s.score = s.support_score * f.powf(weight);
            },
        );
        for s in &scored[measured..end] {
            let at = best.partition_point(|&b| b >= s.score);
            best.insert(at, s.score);
        }
        best.truncate(keep.max(1));
        measured = end;
    }
    scored.truncate(measured);
    scored.sort_by(|a, b| b.score.total_cmp(&a.score).then(b.votes.cmp(&a.votes)));
    scored.truncate(keep);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::detect::filters::FilterParams;

    /// Of refined poses, the tightest fit keeps its score and the others lose by how much
    /// looser they fit: of two equal scores the smaller residual ranks first, a pose far ahead
    /// stays ahead of a slightly tighter one, and weight 0 changes nothing.
    #[test]
    fn residuals_rank_the_tighter_of_equal_fits_first() {
        let scored = |x: f32, score: f32, votes: u32| Scored {
            pose: Pose::from_parts(
                nalgebra::Translation3::new(x, 0.0, 800.0),
                nalgebra::UnitQuaternion::identity(),
            ),
            votes,
            fit: Fit::default(),
            fit_score: score,
            support_score: score,
            outline: None,
            score,
        };
        // Residuals by pose: x = 0 → 1.0 mm, x = 1 → 0.5 mm, x = 2 → 0.6 mm.
        let residual = |p: &Pose| [1.0, 0.5, 0.6][p.translation.vector.x as usize];
        let params = RescoringParams::default();
        let (s, k) = (params.residual_scale_mm, params.residual_weight);
        let mut poses = vec![
            scored(0.0, 0.2, 50),
            scored(1.0, 0.2, 10),
            scored(2.0, 0.5, 5),
        ];
        with_residuals(&mut poses, residual, &params);
        let order: Vec<f32> = poses.iter().map(|p| p.pose.translation.vector.x).collect();
        assert_eq!(order, [2.0, 1.0, 0.0]);
        // The tightest (0.5 mm) keeps its score; the others are scaled from it.
        assert_eq!(poses[1].score, 0.2);
        let scale = |r: f32| ((s + 0.5) / (s + r)).powf(k);
        assert!((poses[0].score - 0.5 * scale(0.6)).abs() < 1e-6);
        assert!((poses[2].score - 0.2 * scale(1.0)).abs() < 1e-6);
        assert!(poses[2].score < 0.2 && poses[0].score < 0.5);

        let off = RescoringParams {
            residual_weight: 0.0,
            ..params
        };
        let mut same = vec![scored(0.0, 0.2, 50), scored(1.0, 0.2, 10)];
        with_residuals(&mut same, residual, &off);
        assert_eq!(same[0].score, 0.2);
        assert_eq!(same[0].votes, 50);
    }
    use crate::detect::scene::{prepare, SceneParams};
    use crate::detect::silhouette::EdgeMap;
    use crate::geometry::render::bounding_sphere;
    use crate::geometry::rng::Rng;
    use crate::geometry::simplify::simplified_mesh;
    use crate::model::ObjectModel;
    use crate::synthetic::parts::Part;
    use crate::synthetic::scene::SceneSpec;
    use nalgebra::{Translation3, UnitQuaternion};

    /// The L-bracket's model, a generated scene of it on a table (prepared), and its true pose
    /// there.
    fn bracket_on_table() -> (ObjectModel, SceneImage, Pose) {
        let part = Part::LBracket;
        let model = part.model().unwrap();
        let generated = SceneSpec::new(3)
            .object(part.object_id(), &part.mesh())
            .build()
            .unwrap();
        let truth = generated.ground_truth[0].1;
        let scene = prepare(&generated.frame.view(), &SceneParams::default()).unwrap();
        (model, scene, truth)
    }

    /// Four points moved side by side come out as each moved alone, to the bit: what keeps
    /// the fit's counts those of [`judge_point`] at every tolerance's edge.
    #[test]
    fn moving_four_points_is_moving_each_alone() {
        let mut rng = Rng::new(21);
        let mut r = || (rng.uniform() as f32 - 0.5) * 2.0;
        let k = Intrinsics::LMO;
        let mut lanes_compared = 0;
        for _ in 0..300 {
            let turn = nalgebra::UnitQuaternion::from_euler_angles(3.0 * r(), 3.0 * r(), 3.0 * r());
            let pose = PoseMatrix::new(&Pose::from_parts(
                Translation3::new(300.0 * r(), 300.0 * r(), 900.0 + 500.0 * r()),
                turn,
            ));
            let p: Vec<Point3<f32>> = (0..4)
                .map(|_| Point3::new(80.0 * r(), 80.0 * r(), 80.0 * r()))
                .collect();
            let n: Vec<Vector3<f32>> = (0..4)
                .map(|_| Vector3::new(r(), r(), r()).normalize())
                .collect();
            let mut four = Moved::default();
            four.four(&pose, &k, &p, &n);
            for i in 0..4 {
                let mut one = Moved::default();
                one.one(&pose, &k, &p[i], &n[i]);
                let bits = |m: &Moved, l: usize| {
                    [m.x[l], m.y[l], m.z[l], m.nx[l], m.ny[l], m.nz[l]].map(f32::to_bits)
                };
                assert_eq!(bits(&four, i), bits(&one, 0));
                assert_eq!(four.facing[i], one.facing[0]);
                if one.facing[0] {
                    assert_eq!((four.u[i], four.v[i]), (one.u[0], one.v[0]));
                }
                lanes_compared += 1;
            }
        }
        assert_eq!(lanes_compared, 1200);
    }

    /// [`Moved::each`] visits every `stride`-th point once, in order, as moving each alone
    /// gives it, whatever the surface's length.
    #[test]
    fn each_visits_every_strided_point_in_order() {
        let mut rng = Rng::new(4);
        let mut r = || (rng.uniform() as f32 - 0.5) * 2.0;
        let k = Intrinsics::LMO;
        let pose = PoseMatrix::new(&Pose::from_parts(
            Translation3::new(10.0, -20.0, 800.0),
            nalgebra::UnitQuaternion::from_euler_angles(0.5, -1.0, 2.0),
        ));
        let all = OrientedPoints {
            positions: (0..23)
                .map(|_| Point3::new(50.0 * r(), 50.0 * r(), 50.0 * r()))
                .collect(),
            normals: (0..23)
                .map(|_| Vector3::new(r(), r(), r()).normalize())
                .collect(),
        };
        for len in [0, 1, 4, 5, 16, 22, 23] {
            let surface = OrientedPoints {
                positions: all.positions[..len].to_vec(),
                normals: all.normals[..len].to_vec(),
            };
            for stride in 1..=5 {
                let mut visited = Vec::new();
                Moved::each(&pose, &k, &surface, stride, |m, lane| {
                    visited.push((m.point(lane), m.normal(lane), m.facing[lane]));
                });
                let expected: Vec<_> = (0..len)
                    .step_by(stride)
                    .map(|i| {
                        let mut one = Moved::default();
                        one.one(&pose, &k, &surface.positions[i], &surface.normals[i]);
                        (one.point(0), one.normal(0), one.facing[0])
                    })
                    .collect();
                assert_eq!(visited, expected, "{len} points, stride {stride}");
            }
        }
    }

    #[test]
    fn support_is_confirmed_over_visible() {
        let f = Fit {
            facing: 100,
            measured: 90,
            inliers: 40,
            occluded: 10,
            see_through: 5,
        };
        assert_eq!(f.visible(), 80);
        assert!((f.support() - 0.5).abs() < 1e-6);
        assert_eq!(Fit::default().support(), 0.0);
        // The same inliers with more of the pose left unconfirmed score lower.
        let params = RescoringParams::default();
        let looser = Fit { measured: 130, ..f };
        assert!(fit_and_support(&looser, 1000, &params) < fit_and_support(&f, 1000, &params));
        let fit_only = RescoringParams {
            support_weight: 0.0,
            ..params
        };
        assert_eq!(
            fit_and_support(&looser, 1000, &fit_only),
            fit_and_support(&f, 1000, &fit_only)
        );
    }

    /// Re-scoring counts the points in Z order; the counts are those of the model's order, and
    /// the sparse set holds the same points as every `prescore_stride`-th of the model's.
    /// The fit is the tally of each point's judgement, on poses that see the part well, that
    /// put it partly outside the image, behind the table, in front of it, turned away, and
    /// behind the camera: every kind of judgement occurs.
    #[test]
    fn fit_counts_what_judge_point_judges() {
        let part = Part::LBracket;
        let model = part.model().unwrap();
        let mut generated = SceneSpec::new(3)
            .object(part.object_id(), &part.mesh())
            .build()
            .unwrap();
        let truth = generated.ground_truth[0].1;
        // Every third row without depth: points the sensor did not measure.
        let width = generated.frame.width as usize;
        for (i, z) in generated.frame.depth.iter_mut().enumerate() {
            if (i / width).is_multiple_of(3) {
                *z = 0;
            }
        }
        let scene = prepare(&generated.frame.view(), &SceneParams::default()).unwrap();
        let d = model.diameter_mm();
        let params = RescoringParams::default();
        let surface = model.surface_points();
        let (tol, conflict) = (params.tolerance_mm(d), params.conflict_mm(d));
        let cos_max = params.max_normal_angle_deg.to_radians().cos();
        let turn = nalgebra::UnitQuaternion::from_euler_angles(0.4, 2.5, -0.3);
        let poses = [
            truth,
            Translation3::new(0.03 * d, -0.02 * d, 0.01 * d) * truth,
            Translation3::new(0.0, 0.0, 2.0 * d) * truth,
            Translation3::new(0.0, 0.0, -0.5 * d) * truth,
            Translation3::new(-truth.translation.x - 350.0, 0.0, 0.0) * truth,
            truth * turn,
            Translation3::new(0.0, 0.0, -2.0 * truth.translation.z) * truth,
        ];
        // Poses scattered about the truth as well, and surfaces of every length modulo four
        // (points are moved four at a time, the last few one at a time).
        let mut rng = Rng::new(8);
        let mut poses = poses.to_vec();
        for _ in 0..40 {
            let mut r = || (rng.uniform() as f32 - 0.5) * 2.0;
            let turn = nalgebra::UnitQuaternion::from_euler_angles(0.3 * r(), 0.3 * r(), 0.3 * r());
            let shift = Translation3::new(0.2 * d * r(), 0.2 * d * r(), 0.2 * d * r());
            poses.push(shift * truth * turn);
        }
        let n = surface.len();
        let cut = |m: usize| OrientedPoints {
            positions: surface.positions[..m].to_vec(),
            normals: surface.normals[..m].to_vec(),
        };
        let surfaces = [cut(n), cut(n - 1), cut(n - 2), cut(n - 3), cut(3)];
        let mut seen = [0u32; 5];
        for (pose, surface) in poses
            .iter()
            .flat_map(|pose| surfaces.iter().map(move |s| (*pose, s)))
        {
            let matrix = PoseMatrix::new(&pose);
            let mut tally = Fit::default();
            for (p, n) in surface.positions.iter().zip(&surface.normals) {
                let Some((j, _, _)) = judge_point(&matrix, p, n, &scene, tol, conflict, cos_max)
                else {
                    continue;
                };
                tally.facing += 1;
                tally.measured += u32::from(j != Judgement::Unmeasured);
                tally.occluded += u32::from(j == Judgement::Occluded);
                tally.see_through += u32::from(j == Judgement::SeeThrough);
                tally.inliers += u32::from(j == Judgement::Inlier);
                seen[match j {
                    Judgement::Unmeasured => 0,
                    Judgement::Occluded => 1,
                    Judgement::SeeThrough => 2,
                    Judgement::Missed => 3,
                    Judgement::Inlier => 4,
                }] += 1;
            }
            assert_eq!(
                fit(surface, &pose, &scene, tol, conflict, 45.0),
                tally,
                "{pose:?}, {} points",
                surface.len()
            );
        }
        assert!(seen.iter().all(|&c| c > 0), "judgements seen: {seen:?}");
    }

    /// The full re-scoring of the poses the sparse fit keeps counts only the rest of the
    /// points on top of each one's sparse fit, and gives what counting every point gives.
    #[test]
    fn the_full_fit_adds_the_rest_to_the_sparse_one() {
        let (model, scene, truth) = bracket_on_table();
        let d = model.diameter_mm();
        let params = RescoringParams {
            prescore_keep: 4,
            silhouette_weight: 0.0,
            ..Default::default()
        };
        let points = FitPoints::new(&model.surface_points(), &params, d);
        let poses: Vec<(Pose, u32)> = (0..9)
            .map(|i| {
                let dx = (i as f32 - 4.0) * 0.02 * d;
                (Translation3::new(dx, 0.01 * d, 0.0) * truth, 10 + i)
            })
            .collect();
        let (tol, conflict) = (params.tolerance_mm(d), params.conflict_mm(d));
        let (kept, sparse_fits) = prescreen(&poses, &points, &scene, tol, conflict, &params);
        let sparse_fits = sparse_fits.expect("the sparse fit cuts 9 poses to 4");
        assert_eq!(kept.len(), 4);
        let edges = EdgeMap::new(&scene, &FilterParams::default());
        let mesh = model.render_mesh();
        let sphere = bounding_sphere(&mesh);
        let outline = Outline {
            mesh: &mesh,
            sphere: &sphere,
            edges: &edges,
            max_outline_px: 0,
        };
        let score = |known: Option<&[Fit]>| {
            score_poses(
                &kept, &points, known, &scene, tol, conflict, &params, &outline, 4,
            )
        };
        let (added, counted) = (score(Some(&sparse_fits)), score(None));
        assert!(counted[0].fit.inliers > 0);
        for (a, c) in added.iter().zip(&counted) {
            assert_eq!(a.fit, c.fit);
            assert_eq!(a.fit, points.fit(&a.pose, &scene, tol, conflict, 45.0));
        }
    }

    #[test]
    fn fit_points_count_as_the_model_order_does() {
        let (model, scene, truth) = bracket_on_table();
        let d = model.diameter_mm();
        let params = RescoringParams::default();
        let surface = model.surface_points();
        let points = FitPoints::new(&surface, &params, d);
        assert_eq!(points.len(), surface.len());
        let key = |p: &Point3<f32>| [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()];
        let sorted = |ps: &mut dyn Iterator<Item = Point3<f32>>| {
            let mut v: Vec<[u32; 3]> = ps.map(|p| key(&p)).collect();
            v.sort();
            v
        };
        assert_eq!(
            sorted(
                &mut points
                    .sparse
                    .positions
                    .iter()
                    .chain(&points.rest.positions)
                    .copied()
            ),
            sorted(&mut surface.positions.iter().copied())
        );
        let every = OrientedPoints {
            positions: surface
                .positions
                .iter()
                .step_by(params.prescore_stride)
                .copied()
                .collect(),
            normals: surface
                .normals
                .iter()
                .step_by(params.prescore_stride)
                .copied()
                .collect(),
        };
        assert_eq!(
            sorted(&mut points.sparse.positions.iter().copied()),
            sorted(&mut every.positions.iter().copied())
        );
        assert_ne!(
            points.sparse.positions, every.positions,
            "the order is changed"
        );
        let (tol, conflict) = (params.tolerance_mm(d), params.conflict_mm(d));
        let shifted = Translation3::new(0.02 * d, 0.0, 0.0) * truth;
        for pose in [truth, shifted] {
            let model_order = fit(&surface, &pose, &scene, tol, conflict, 45.0);
            assert!(model_order.inliers > 0);
            assert_eq!(points.fit(&pose, &scene, tol, conflict, 45.0), model_order);
            assert_eq!(
                fit(&points.sparse, &pose, &scene, tol, conflict, 45.0),
                fit(&every, &pose, &scene, tol, conflict, 45.0)
            );
        }
    }

    #[test]
    fn bounded_silhouettes_keep_the_same_best_poses() {
        let (model, scene, truth) = bracket_on_table();
        let d = model.diameter_mm();
        // Poses around the truth, from close to far off.
        let mut rng = Rng::new(11);
        let poses: Vec<(Pose, u32)> = (0..300)
            .map(|i| {
                let spread = (i % 30) as f32 / 30.0;
                let axis = nalgebra::Unit::new_normalize(nalgebra::Vector3::new(
                    rng.normal() as f32,
                    rng.normal() as f32,
                    rng.normal() as f32,
                ));
                let turn = UnitQuaternion::from_axis_angle(&axis, spread * 0.6);
                let shift = Translation3::new(
                    rng.range(-1.0, 1.0) * spread * 0.2 * d,
                    rng.range(-1.0, 1.0) * spread * 0.2 * d,
                    rng.range(-1.0, 1.0) * spread * 0.2 * d,
                );
                (shift * truth * turn, 300 - i as u32)
            })
            .collect();
        let params = RescoringParams::default();
        let surface = model.surface_points();
        let edges = EdgeMap::new(&scene, &FilterParams::default());
        let silhouettes = simplified_mesh(&model.render_mesh(), 0.025 * d);
        let sphere = bounding_sphere(&silhouettes);
        let conflict = params.conflict_mm(d);
        let scored = rescore(
            &poses,
            &surface,
            &scene,
            params.tolerance_mm(d),
            conflict,
            &params,
        );
        let outline = Outline {
            mesh: &silhouettes,
            sphere: &sphere,
            edges: &edges,
            max_outline_px: FilterParams::default().max_outline_px,
        };
        let mut every = scored.clone();
        let all = every.len();
        with_silhouettes(&mut every, &outline, &scene, conflict, &params, all);
        assert_eq!(every.len(), all);
        assert!(every.iter().all(|s| s.outline.is_some()));
        for keep in [1, 10, 50] {
            let mut bounded = scored.clone();
            with_silhouettes(&mut bounded, &outline, &scene, conflict, &params, keep);
            assert_eq!(bounded.len(), keep);
            let a: Vec<f32> = bounded.iter().map(|s| s.score).collect();
            let b: Vec<f32> = every[..keep].iter().map(|s| s.score).collect();
            assert_eq!(a, b, "best {keep}");
        }
        // The best pose is near the truth, and with silhouettes folded in it scores at most
        // its support score.
        assert!((every[0].pose.translation.vector - truth.translation.vector).norm() < 0.05 * d);
        assert!(every.iter().all(|s| s.score <= s.support_score));
    }
}
