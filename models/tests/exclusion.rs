//! Exclusion across objects on a generated frame: the four parts on a table with Kinect-like
//! noise, as `ppf generate --seed 4` makes it. Without exclusion (and without the fit's residual,
//! which alone also sets it right), one part's best pose lies on another part's surface; with
//! it, that pose gives way to the part's own.

use nalgebra::Point3;
use ppfd_models::detect::detector::{DetectParams, Detections, Detector, RunOptions};
use ppfd_models::geometry::render::bounding_sphere;
use ppfd_models::model::ObjectModel;
use ppfd_models::synthetic::parts::Part;
use ppfd_models::synthetic::scene::{NoiseModel, SyntheticScene};

/// A part's model with the centre of its mesh's bounding sphere.
struct Known {
    model: ObjectModel,
    centre: Point3<f32>,
}

/// Per part: its id, how far (mm) its first answer puts the centre of its bounding sphere from
/// where the ground truth puts it, and a tenth of its diameter. A pose on the part itself,
/// turned by one of its symmetries or not, keeps the centre within a few millimetres.
fn centre_errors(parts: &[Known], scene: &SyntheticScene, d: &Detections) -> Vec<(u32, f32, f32)> {
    parts
        .iter()
        .map(|k| {
            let id = k.model.object_id();
            let truth = scene.truth_of(id).unwrap();
            let found = d
                .objects
                .iter()
                .find(|o| o.object_id == id)
                .and_then(|o| o.hypotheses.first())
                .expect("every part gets an answer")
                .pose;
            let error = ((found * k.centre) - (truth * k.centre)).norm();
            (id, error, 0.1 * k.model.diameter_mm())
        })
        .collect()
}

#[test]
fn a_pose_on_another_parts_surface_gives_way_to_the_parts_own() {
    let scene = SyntheticScene::of_every_part(4, Some(NoiseModel::kinect())).unwrap();
    let parts: Vec<Known> = Part::ALL
        .iter()
        .map(|part| Known {
            model: part.model().unwrap(),
            centre: bounding_sphere(&part.mesh()).0,
        })
        .collect();
    let refs: Vec<&ObjectModel> = parts.iter().map(|k| &k.model).collect();
    let frame = scene.frame.view();
    let opts = RunOptions::default();

    // The fit's residual (METHOD.md §3.3) alone already puts this frame's misplaced part
    // right; without it, the frame shows what exclusion does.
    let mut base = DetectParams::new();
    base.rescoring.residual_weight = 0.0;
    let mut without = base.clone();
    without.exclusion.min_shared_fraction = 0.0;
    let d = Detector::new(without).detect(&frame, &refs, &opts).unwrap();
    let misplaced: Vec<(u32, f32, f32)> = centre_errors(&parts, &scene, &d)
        .into_iter()
        .filter(|&(_, error, bound)| error > bound)
        .collect();
    assert!(
        !misplaced.is_empty(),
        "without exclusion every part was found: the frame no longer shows what the test is about"
    );

    for (what, params) in [("exclusion", base), ("the defaults", DetectParams::new())] {
        let d = Detector::new(params).detect(&frame, &refs, &opts).unwrap();
        for (id, error, bound) in centre_errors(&parts, &scene, &d) {
            assert!(
                error < bound,
                "with {what}, part {id}: its answer's centre lies {error:.0} mm from the truth \
                 (without exclusion, misplaced: {misplaced:?})"
            );
        }
    }
}
