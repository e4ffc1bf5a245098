//! Maximum Symmetry-aware Projection Distance (BOP's `pose_error.mspd`): the largest distance
//! between the image projections of a model vertex at the estimated and at the true pose,
//! minimised over the object's symmetries. In pixels.

use nalgebra::{Isometry3, Point3, Vector2};

use ppfd_models::geometry::camera::Intrinsics;
use ppfd_models::Pose;

fn project(k: &[f64; 4], p: &Point3<f64>) -> Vector2<f64> {
    Vector2::new(k[0] * p.x / p.z + k[2], k[1] * p.y / p.z + k[3])
}

/// MSPD of `estimate` against `truth` for a camera with `intrinsics`, over the model vertices
/// `points` with the symmetry transforms `symmetries` (at least the identity).
/// `f64::INFINITY` when `points` or `symmetries` is empty.
pub fn mspd(
    estimate: &Pose,
    truth: &Pose,
    intrinsics: &Intrinsics,
    points: &[Point3<f32>],
    symmetries: &[Isometry3<f64>],
) -> f64 {
    let k = [
        intrinsics.fx as f64,
        intrinsics.fy as f64,
        intrinsics.cx as f64,
        intrinsics.cy as f64,
    ];
    let estimate = estimate.cast::<f64>();
    let truth = truth.cast::<f64>();
    let projected: Vec<Vector2<f64>> = points
        .iter()
        .map(|p| project(&k, &(estimate * p.cast::<f64>())))
        .collect();
    symmetries
        .iter()
        .map(|symmetry| {
            let truth_sym = truth * symmetry;
            points
                .iter()
                .zip(&projected)
                .map(|(p, e)| (project(&k, &(truth_sym * p.cast::<f64>())) - e).norm_squared())
                .fold(f64::NEG_INFINITY, f64::max)
                .sqrt()
        })
        .filter(|e| !e.is_nan())
        .fold(f64::INFINITY, f64::min)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion, Vector3};

    #[test]
    fn a_sideways_shift_projects_to_f_times_shift_over_depth() {
        let k = Intrinsics::LMO;
        let points = vec![Point3::new(0.0f32, 0.0, 0.0), Point3::new(0.0, 0.0, 0.0)];
        let truth = Pose::from_parts(
            Translation3::new(0.0, 0.0, 1000.0),
            UnitQuaternion::identity(),
        );
        let estimate = Pose::from_parts(
            Translation3::new(10.0, 0.0, 1000.0),
            UnitQuaternion::identity(),
        );
        let e = mspd(&estimate, &truth, &k, &points, &[Isometry3::identity()]);
        assert!((e - k.fx as f64 * 10.0 / 1000.0).abs() < 1e-3, "{e}");
    }

    #[test]
    fn a_shift_along_the_ray_of_a_point_does_not_move_its_projection_but_a_symmetry_helps() {
        let k = Intrinsics::LMO;
        let points = vec![Point3::new(30.0f32, 0.0, 0.0), Point3::new(-30.0, 0.0, 0.0)];
        let truth = Pose::from_parts(
            Translation3::new(0.0, 0.0, 1000.0),
            UnitQuaternion::identity(),
        );
        // Swapping the two points (half turn about y) leaves the projection unchanged only with
        // the symmetry listed.
        let half_turn = Pose::rotation(Vector3::y() * std::f32::consts::PI);
        let estimate = truth * half_turn;
        let without = mspd(&estimate, &truth, &k, &points, &[Isometry3::identity()]);
        let with = mspd(
            &estimate,
            &truth,
            &k,
            &points,
            &[Isometry3::identity(), half_turn.cast()],
        );
        assert!(without > 30.0, "{without}");
        assert!(with < 1e-3, "{with}");
    }
}
