//! Projective ICP (Rusinkiewicz & Levoy 2001), point-to-plane (METHOD.md §3.3).
//!
//! Correspondences come from projecting each visible model surface point into the depth image
//! and taking the scene point measured at that pixel: no search. Each iteration solves the
//! linearised point-to-plane problem (a 6×6 system) over the motions its pairs constrain, and
//! rejects pairs farther apart than a distance that shrinks from iteration to iteration.

use nalgebra::{Matrix6, Translation3, UnitQuaternion, Vector3, Vector6};

use crate::detect::rescoring::{Moved, PoseMatrix};
use crate::detect::scene::SceneImage;
use crate::model::subsample::OrientedPoints;
use crate::Pose;

/// Parameters of projective ICP.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IcpParams {
    /// How many of the best re-scored poses are refined. The paper: 200. Re-scoring with
    /// silhouettes ranks the right pose near the top, and each pose kept for ICP costs a
    /// silhouette in the first re-scoring: with 30 the LM-O frame keeps its 6 of 8 and the
    /// YCB-Video frames their recall (0.933, against 0.911 with 200), see docs/METHOD.md §3.3.
    pub top_poses: usize,
    /// Iterations per pose.
    pub iterations: usize,
    /// Correspondences farther apart than this fraction of the diameter are rejected in the
    /// first iteration; the limit halves each iteration down to `final_distance_fraction`.
    pub initial_distance_fraction: f32,
    /// The smallest correspondence distance limit, a fraction of the diameter D.
    pub final_distance_fraction: f32,
    /// Pairs whose normals differ by more than this angle are rejected, degrees.
    pub max_normal_angle_deg: f32,
    /// Stop early when an update moves less than this, mm and radians.
    pub convergence_translation_mm: f32,
    /// ...and turns it less than this, radians.
    pub convergence_rotation: f32,
    /// The first `coarse_iterations` use every `coarse_stride`-th surface point only (a
    /// uniform sample, as Rusinkiewicz & Levoy advise): a pose far off needs few points to
    /// move most of the way, and the remaining iterations use them all. Converging early in
    /// the coarse phase moves on to the fine one. `coarse_stride` 1 uses every point throughout.
    pub coarse_iterations: usize,
    /// The coarse iterations' stride through the surface points; 1 uses every point.
    pub coarse_stride: usize,
    /// A motion the pairs constrain less than this fraction of the motion they constrain best
    /// (an eigenvalue of the 6×6 system against its largest, rotations counted by the arc they
    /// turn the model's farthest surface point through, so that both are in mm) is left out of
    /// the step. Point-to-plane pairs on a flat face say nothing of sliding along it or turning
    /// about its normal; solved anyway, those motions follow the sensor's noise (a face laid in
    /// a noisy table top slid up to 10 mm and turned up to 6.5° with every motion solved, 2.8 mm
    /// and 0.4° with 10⁻³: docs/METHOD.md §3.3). 0 keeps every motion the pairs constrain at
    /// all.
    pub min_constraint_ratio: f32,
}

impl Default for IcpParams {
    fn default() -> Self {
        Self {
            top_poses: 30,
            iterations: 8,
            initial_distance_fraction: 0.1,
            final_distance_fraction: 0.02,
            max_normal_angle_deg: 60.0,
            convergence_translation_mm: 0.05,
            convergence_rotation: 1e-4,
            coarse_iterations: 4,
            coarse_stride: 4,
            min_constraint_ratio: 1e-3,
        }
    }
}

impl IcpParams {
    /// How far one run can move any surface point of a model of `diameter_mm` from where it
    /// starts, mm: no step moves a point farther than that iteration's pair distance limit,
    /// which halves from the initial limit down to the final one.
    pub fn max_travel_mm(&self, diameter_mm: f32) -> f32 {
        let mut limit = self.initial_distance_fraction * diameter_mm;
        let floor = self.final_distance_fraction * diameter_mm;
        let mut travel = 0.0;
        for _ in 0..self.iterations {
            travel += limit;
            limit = (limit * 0.5).max(floor);
        }
        travel
    }
}

/// An iteration with fewer correspondences than this solves nothing (six unknowns).
pub const MIN_CORRESPONDENCES: u32 = 6;

/// What one ICP run did.
#[derive(Clone, Copy, Debug, Default)]
pub struct IcpResult {
    /// The refined pose, model to camera (mm).
    pub pose: Pose,
    /// Correspondences used in the last iteration.
    pub correspondences: u32,
    /// Root mean square point-to-plane distance in the last iteration, mm.
    pub rms_mm: f32,
    /// Iterations run, at most [`IcpParams::iterations`].
    pub iterations: u32,
}

impl IcpResult {
    /// The residual of the last iteration, mm, for a run with `params` on a model of diameter
    /// `diameter_mm`; when it had too few correspondences to trust a root mean square, the
    /// final pair distance limit, the farthest a pair may lie apart.
    pub fn residual_mm(&self, params: &IcpParams, diameter_mm: f32) -> f32 {
        if self.correspondences >= MIN_CORRESPONDENCES && self.rms_mm.is_finite() {
            self.rms_mm
        } else {
            params.final_distance_fraction * diameter_mm
        }
    }
}

/// The mean of the surface points (the origin for an empty surface).
fn surface_centroid(surface: &OrientedPoints) -> nalgebra::Point3<f32> {
    let n = surface.positions.len().max(1) as f32;
    let sum = surface
        .positions
        .iter()
        .fold(Vector3::zeros(), |acc, p| acc + p.coords);
    nalgebra::Point3::from(sum / n)
}

/// The least-squares solution `(ω, δt)` of `ata · x = atb` over the motions the pairs
/// constrain: in coordinates where a rotation counts by the arc it turns a point `radius` mm
/// from the centre through, the eigenvectors of `ata` whose eigenvalues are at least
/// `min_ratio` of the largest (and above 0). `None` when the pairs constrain no motion.
fn constrained_step(
    ata: &Matrix6<f64>,
    atb: &Vector6<f64>,
    radius: f32,
    min_ratio: f32,
) -> Option<Vector6<f64>> {
    let r = f64::from(radius.max(f32::MIN_POSITIVE));
    // x = S y with S = diag(1/r, 1/r, 1/r, 1, 1, 1): the system in y is Sᵀ ata S y = Sᵀ atb.
    let scale = Vector6::new(1.0 / r, 1.0 / r, 1.0 / r, 1.0, 1.0, 1.0);
    let scaled = Matrix6::from_fn(|i, j| ata[(i, j)] * scale[i] * scale[j]);
    let rhs = atb.component_mul(&scale);
    let eigen = scaled.symmetric_eigen();
    let largest = eigen.eigenvalues.max();
    if !(largest > 0.0 && largest.is_finite()) {
        return None;
    }
    let floor = (f64::from(min_ratio) * largest).max(f64::MIN_POSITIVE);
    let mut y = Vector6::zeros();
    for (i, &value) in eigen.eigenvalues.iter().enumerate() {
        if value >= floor {
            let v = eigen.eigenvectors.column(i);
            y += v * (v.dot(&rhs) / value);
        }
    }
    Some(y.component_mul(&scale))
}

/// Refines `pose` of the model `surface` against `scene`.
pub fn refine(
    surface: &OrientedPoints,
    pose: &Pose,
    scene: &SceneImage,
    diameter_mm: f32,
    params: &IcpParams,
) -> IcpResult {
    let k = &scene.intrinsics;
    let cos_max = params.max_normal_angle_deg.to_radians().cos();
    let mut pose = *pose;
    let mut result = IcpResult {
        pose,
        ..Default::default()
    };
    let mut max_d = params.initial_distance_fraction * diameter_mm;
    let min_d = params.final_distance_fraction * diameter_mm;
    let coarse_until = params.coarse_iterations.min(params.iterations);
    let centroid = surface_centroid(surface);
    let radius = surface
        .positions
        .iter()
        .map(|p| (p - centroid).norm())
        .fold(0.0f32, f32::max);
    let mut it = 0;
    while it < params.iterations {
        let coarse = it < coarse_until;
        let stride = if coarse {
            params.coarse_stride.max(1)
        } else {
            1
        };
        let mut ata = Matrix6::<f64>::zeros();
        let mut atb = Vector6::<f64>::zeros();
        let mut count = 0u32;
        let mut sq = 0f64;
        let moved = PoseMatrix::new(&pose);
        // The small rotation turns about the model's centre, not the camera's origin. To first
        // order both are the same motion, but about the origin every finite turn comes with a
        // lever of a metre and a translation that only cancels it linearly: poses 15° off slid
        // away by up to 0.6 m instead of converging (`icp_converges_from_poses_turned_far`).
        let centre = pose * centroid;
        Moved::each(&moved, k, surface, stride, |m, lane| {
            if !m.facing[lane] {
                return;
            }
            let Some((q, qn)) = scene.at(m.u[lane] as i64, m.v[lane] as i64) else {
                return;
            };
            let (pc, nc) = (m.point(lane), m.normal(lane));
            let d = pc - q;
            if d.norm_squared() > max_d * max_d || qn.dot(&nc) < cos_max {
                return;
            }
            // r = ((p − c) × n)·ω + n·δt + (p − q)·n, linear in the small motion (ω, δt).
            let c = (pc - centre).cross(&qn);
            let row = Vector6::new(
                c.x as f64,
                c.y as f64,
                c.z as f64,
                qn.x as f64,
                qn.y as f64,
                qn.z as f64,
            );
            let r = d.dot(&qn) as f64;
            ata += row * row.transpose();
            atb -= row * r;
            sq += r * r;
            count += 1;
        });
        result.correspondences = count;
        result.iterations += 1;
        it += 1;
        if count < MIN_CORRESPONDENCES {
            if coarse {
                it = coarse_until; // too few in the sample: try with every point
                continue;
            }
            break;
        }
        result.rms_mm = (sq / count as f64).sqrt() as f32;
        let Some(x) = constrained_step(&ata, &atb, radius, params.min_constraint_ratio) else {
            break;
        };
        let mut omega = Vector3::new(x[0] as f32, x[1] as f32, x[2] as f32);
        let mut dt = Vector3::new(x[3] as f32, x[4] as f32, x[5] as f32);
        // No surface point moves farther in one step than its pair was allowed to lie apart:
        // where the pairs barely constrain a motion (a cylinder's axis, say), noise must not
        // throw the pose away. The step is shortened, its direction kept.
        let reach = dt.norm() + omega.norm() * radius;
        if reach > max_d {
            let s = max_d / reach;
            (omega, dt) = (omega * s, dt * s);
        }
        // x ↦ R(ω)(x − c) + c + δt
        let rotation = UnitQuaternion::from_scaled_axis(omega);
        let update = Pose::from_parts(
            Translation3::from(centre.coords + dt - rotation * centre.coords),
            rotation,
        );
        pose = update * pose;
        result.pose = pose;
        max_d = (max_d * 0.5).max(min_d);
        if dt.norm() < params.convergence_translation_mm
            && omega.norm() < params.convergence_rotation
        {
            if coarse {
                it = coarse_until;
                continue;
            }
            break;
        }
    }
    result
}
