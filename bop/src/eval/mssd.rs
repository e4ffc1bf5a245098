//! Maximum Symmetry-aware Surface Distance (BOP's `pose_error.mssd`): the largest distance
//! between a model vertex at the estimated pose and the same vertex at the true pose, minimised
//! over the object's symmetries. In mm.

use nalgebra::{Isometry3, Point3};

use ppfd_models::Pose;

/// MSSD of `estimate` against `truth` over the model vertices `points`, with the symmetry
/// transforms `symmetries` (from [`super::symmetry::symmetry_transforms`]; must hold at least the
/// identity). `f64::INFINITY` when `points` or `symmetries` is empty.
pub fn mssd(
    estimate: &Pose,
    truth: &Pose,
    points: &[Point3<f32>],
    symmetries: &[Isometry3<f64>],
) -> f64 {
    let estimate = estimate.cast::<f64>();
    let truth = truth.cast::<f64>();
    let moved: Vec<Point3<f64>> = points.iter().map(|p| estimate * p.cast::<f64>()).collect();
    symmetries
        .iter()
        .map(|symmetry| {
            let truth_sym = truth * symmetry;
            points
                .iter()
                .zip(&moved)
                .map(|(p, e)| (truth_sym * p.cast::<f64>() - e).norm_squared())
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

    fn box_corners() -> Vec<Point3<f32>> {
        let mut points = Vec::new();
        for &x in &[-40.0, 40.0] {
            for &y in &[-20.0, 20.0] {
                for &z in &[-10.0, 10.0] {
                    points.push(Point3::new(x, y, z));
                }
            }
        }
        points
    }

    fn truth() -> Pose {
        Pose::from_parts(
            Translation3::new(10.0, -30.0, 800.0),
            UnitQuaternion::from_euler_angles(0.3, -0.2, 1.1),
        )
    }

    #[test]
    fn a_translation_is_its_length() {
        let estimate = Pose::from_parts(
            Translation3::from(truth().translation.vector + Vector3::new(3.0, 0.0, -4.0)),
            truth().rotation,
        );
        let e = mssd(
            &estimate,
            &truth(),
            &box_corners(),
            &[Isometry3::identity()],
        );
        assert!((e - 5.0).abs() < 1e-4, "{e}");
    }

    #[test]
    fn a_rotation_moves_the_furthest_vertex_most() {
        // Turned by 90° about the model's z: corner (40, 20, z) goes to (−20, 40, z), 60.83 mm
        // away; that is the largest displacement.
        let turn = Pose::rotation(Vector3::z() * std::f32::consts::FRAC_PI_2);
        let estimate = truth() * turn;
        let e = mssd(
            &estimate,
            &truth(),
            &box_corners(),
            &[Isometry3::identity()],
        );
        assert!(
            (e - (60f64 * 60.0 + 20.0 * 20.0).sqrt()).abs() < 1e-3,
            "{e}"
        );
    }

    #[test]
    fn a_symmetry_of_the_object_costs_nothing() {
        // The box is symmetric under a half turn about z.
        let half_turn = Pose::rotation(Vector3::z() * std::f32::consts::PI);
        let estimate = truth() * half_turn;
        let without = mssd(
            &estimate,
            &truth(),
            &box_corners(),
            &[Isometry3::identity()],
        );
        let with = mssd(
            &estimate,
            &truth(),
            &box_corners(),
            &[Isometry3::identity(), half_turn.cast::<f64>()],
        );
        assert!(without > 80.0, "{without}");
        assert!(with < 1e-3, "{with}");
    }

    #[test]
    fn nothing_to_compare_is_infinite() {
        assert_eq!(
            mssd(&truth(), &truth(), &[], &[Isometry3::identity()]),
            f64::INFINITY
        );
        assert_eq!(mssd(&truth(), &truth(), &box_corners(), &[]), f64::INFINITY);
    }
}
