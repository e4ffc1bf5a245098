//! The symmetry transformations of an object, as the BOP toolkit's
//! `misc.get_symmetry_transformations` lists them for MSSD and MSPD.

use nalgebra::{Isometry3, Translation3, UnitQuaternion};

use crate::dataset::ModelInfo;

/// BOP's `max_sym_disc_step`: a continuous symmetry is sampled so that the model point furthest
/// from the axis moves by at most this fraction of the diameter between samples.
pub const MAX_SYM_DISC_STEP: f64 = 0.01;

/// The transforms (model to model, mm) that leave the object's appearance unchanged: the identity,
/// each discrete symmetry of `models_info.json`, and each continuous symmetry sampled in
/// `⌈π / max_sym_disc_step⌉` equal steps over the full turn; with both kinds, every continuous
/// sample composed with every discrete one (`R_cont·R_disc`).
///
/// One departure from older toolkit versions, which skipped the zero angle of a continuous
/// symmetry (so the identity was missing from the set): the zero angle is included, as in the
/// current toolkit, so a perfect estimate has error 0.
pub fn symmetry_transforms(info: &ModelInfo, max_sym_disc_step: f64) -> Vec<Isometry3<f64>> {
    let mut discrete = vec![Isometry3::identity()];
    discrete.extend(info.symmetries_discrete.iter().map(|s| s.cast::<f64>()));

    let mut continuous = Vec::new();
    for symmetry in &info.symmetries_continuous {
        let axis = symmetry.axis.cast::<f64>();
        let offset = symmetry.offset_mm.cast::<f64>();
        let steps = (std::f64::consts::PI / max_sym_disc_step).ceil().max(1.0) as usize;
        let step = 2.0 * std::f64::consts::PI / steps as f64;
        for i in 0..steps {
            let rotation = UnitQuaternion::from_axis_angle(&axis, i as f64 * step);
            // Rotation about the axis through `offset`: t = offset − R·offset.
            let t = offset.coords - rotation * offset.coords;
            continuous.push(Isometry3::from_parts(Translation3::from(t), rotation));
        }
    }
    if continuous.is_empty() {
        return discrete;
    }
    discrete
        .iter()
        .flat_map(|d| continuous.iter().map(move |c| c * d))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::ContinuousSymmetry;
    use nalgebra::{Point3, Unit, Vector3};
    use ppfd_models::Pose;

    fn info(discrete: Vec<Pose>, continuous: Vec<ContinuousSymmetry>) -> ModelInfo {
        ModelInfo {
            diameter_mm: 100.0,
            min_mm: Point3::new(-50.0, -50.0, -50.0),
            size_mm: Vector3::new(100.0, 100.0, 100.0),
            symmetries_discrete: discrete,
            symmetries_continuous: continuous,
        }
    }

    #[test]
    fn no_symmetry_is_the_identity_alone() {
        let t = symmetry_transforms(&info(vec![], vec![]), MAX_SYM_DISC_STEP);
        assert_eq!(t, vec![Isometry3::identity()]);
    }

    #[test]
    fn discrete_symmetries_follow_the_identity() {
        let flip = Pose::rotation(Vector3::z() * std::f32::consts::PI);
        let t = symmetry_transforms(&info(vec![flip], vec![]), MAX_SYM_DISC_STEP);
        assert_eq!(t.len(), 2);
        assert_eq!(t[0], Isometry3::identity());
        assert!((t[1].rotation.angle() - std::f64::consts::PI).abs() < 1e-6);
    }

    #[test]
    fn continuous_symmetry_is_sampled_at_bop_resolution_about_its_offset_axis() {
        let axis = ContinuousSymmetry {
            axis: Unit::new_normalize(Vector3::new(0.0, 0.0, 2.0)),
            offset_mm: Point3::new(10.0, 0.0, 0.0),
        };
        let flip = Pose::rotation(Vector3::x() * std::f32::consts::PI);
        let t = symmetry_transforms(&info(vec![flip], vec![axis]), MAX_SYM_DISC_STEP);
        // ⌈π / 0.01⌉ = 315 angles, times (identity + one discrete).
        assert_eq!(t.len(), 2 * 315);
        assert!(t[0].rotation.angle() < 1e-12 && t[0].translation.vector.norm() < 1e-12);
        let step = 2.0 * std::f64::consts::PI / 315.0;
        assert!((t[1].rotation.angle() - step).abs() < 1e-9);
        // Points on the axis stay put.
        let on_axis = nalgebra::Point3::new(10.0, 0.0, 7.0);
        for s in &t[..315] {
            assert!((s * on_axis - on_axis).norm() < 1e-9);
        }
    }
}
