//! Exclusion across objects on a generated frame: the four parts on a table with Kinect-like
//! noise, as `ppf generate --seed 4` makes it. Without exclusion, one part's best pose lies on
//! another part's surface; with it, that pose gives way to the part's own.

use ppfd_models::detect::detector::{DetectParams, Detections, Detector, RunOptions};
use ppfd_models::geometry::render::bounding_sphere;
use ppfd_models::model::ObjectModel;
use ppfd_models::synthetic::parts::Part;
use ppfd_models::synthetic::scene::{NoiseModel, SceneSpec, SyntheticScene};

fn scene() -> SyntheticScene {
    let meshes: Vec<_> = Part::ALL.iter().map(|p| (*p, p.mesh())).collect();
    let mut spec = SceneSpec::new(4).noise(Some(NoiseModel::kinect()));
    for (part, mesh) in &meshes {
        spec = spec.object(part.object_id(), mesh);
    }
    spec.build().unwrap()
}

/// Per part, how far (mm) its first answer puts the centre of its bounding sphere from where
/// the ground truth puts it: a pose on the part itself, turned by one of its symmetries or not,
/// keeps the centre within a few millimetres.
fn centre_errors(
    models: &[ObjectModel],
    scene: &SyntheticScene,
    d: &Detections,
) -> Vec<(u32, f32)> {
    models
        .iter()
        .map(|m| {
            let centre = bounding_sphere(
                &Part::ALL
                    .iter()
                    .find(|p| p.object_id() == m.object_id())
                    .unwrap()
                    .mesh(),
            )
            .0;
            let truth = scene
                .ground_truth
                .iter()
                .find(|(id, _)| *id == m.object_id())
                .unwrap()
                .1;
            let found = d
                .objects
                .iter()
                .find(|o| o.object_id == m.object_id())
                .and_then(|o| o.hypotheses.first())
                .map(|h| h.pose)
                .expect("every part gets an answer");
            (m.object_id(), ((found * centre) - (truth * centre)).norm())
        })
        .collect()
}

#[test]
fn a_pose_on_another_parts_surface_gives_way_to_the_parts_own() {
    let scene = scene();
    let models: Vec<ObjectModel> = Part::ALL.iter().map(|p| p.model().unwrap()).collect();
    let refs: Vec<&ObjectModel> = models.iter().collect();
    let frame = scene.frame.view();
    let opts = RunOptions::default();

    let mut without = DetectParams::new();
    without.exclusion.min_shared_fraction = 0.0;
    let d = Detector::new(without).detect(&frame, &refs, &opts).unwrap();
    let misplaced: Vec<(u32, f32)> = centre_errors(&models, &scene, &d)
        .into_iter()
        .filter(|&(id, e)| {
            e > 0.1
                * models
                    .iter()
                    .find(|m| m.object_id() == id)
                    .unwrap()
                    .diameter_mm()
        })
        .collect();
    assert!(
        !misplaced.is_empty(),
        "without exclusion every part was found: the frame no longer shows what the test is about"
    );

    let d = Detector::new(DetectParams::new())
        .detect(&frame, &refs, &opts)
        .unwrap();
    for (id, e) in centre_errors(&models, &scene, &d) {
        let diameter = models
            .iter()
            .find(|m| m.object_id() == id)
            .unwrap()
            .diameter_mm();
        assert!(
            e < 0.1 * diameter,
            "part {id}: its answer's centre lies {e:.0} mm from the truth (without exclusion, \
             misplaced: {misplaced:?})"
        );
    }
}
