//! Symmetric objects (METHOD.md §1.8) on generated scenes: a U-channel with a half turn and a
//! stepped shaft with any turn about its axis. Detection reports the canonical pose of the
//! object, and clustering gathers the votes of equivalent poses. Runs anywhere (no data files).

use ppfd_models::detect::clustering::cluster_poses;
use ppfd_models::detect::detector::{Checks, DetectParams, Detector, Hint, RunOptions};
use ppfd_models::detect::scene::{prepare, PreparedScene};
use ppfd_models::detect::voting::vote;
use ppfd_models::model::symmetry::Symmetry;
use ppfd_models::model::{ModelParams, ObjectModel};
use ppfd_models::synthetic::parts::SymmetricPart;
use ppfd_models::synthetic::scene::{random_pose_in_view, NoiseModel, Rng, SyntheticScene};
use ppfd_models::Pose;

fn model_of(part: SymmetricPart) -> ObjectModel {
    ObjectModel::build(
        &part.mesh(),
        part.object_id(),
        part.name(),
        &ModelParams::default(),
    )
    .unwrap()
    .with_symmetry(&part.symmetry())
    .unwrap()
}

/// Translation (mm) and rotation (degrees) between two poses, as they are.
fn errors(est: &Pose, truth: &Pose) -> (f32, f32) {
    (
        (est.translation.vector - truth.translation.vector).norm(),
        est.rotation.angle_to(&truth.rotation).to_degrees(),
    )
}

/// A pose of `part` in view that is not the canonical one of its equivalents: the canonical
/// pose of a random one, turned by the half turn or by 100° about the axis.
fn non_canonical_pose(part: SymmetricPart, symmetry: &Symmetry, rng: &mut Rng, d: f32) -> Pose {
    let canonical = symmetry.canonical(&random_pose_in_view(rng, d, (650.0, 900.0)));
    match part {
        SymmetricPart::UChannel => canonical * symmetry.discrete[0],
        SymmetricPart::SteppedShaft => canonical * symmetry.continuous.unwrap().turn(1.75),
    }
}

/// The scene shows the part at a pose that is not canonical; the detection reports the
/// canonical one, which is where the object is. Without the symmetry, the reported pose would
/// be whichever equivalent won the votes.
#[test]
fn detections_of_symmetric_parts_report_the_canonical_pose() {
    let detector = Detector::default();
    let noise = NoiseModel::kinect();
    for part in SymmetricPart::ALL {
        let model = model_of(part);
        let symmetry = model.symmetry();
        assert_eq!(symmetry, part.symmetry());
        let d = model.diameter_mm();
        let mut rng = Rng::new(part.object_id() as u64);
        for run in 0..3 {
            let shown = non_canonical_pose(part, &symmetry, &mut rng, d);
            let canonical = symmetry.canonical(&shown);
            let (dt, dr) = errors(&shown, &canonical);
            assert!(
                dr > 30.0,
                "{part:?} {run}: the scene's pose is {dr:.0}° from the canonical, {dt:.0} mm"
            );
            let scene =
                SyntheticScene::single(&part.mesh(), part.object_id(), shown, Some(&noise), run)
                    .unwrap();
            let found = detector
                .detect(&scene.frame.view(), &[&model], &RunOptions::default())
                .unwrap();
            let best = found.objects[0].hypotheses[0].pose;
            let (dt, dr) = errors(&best, &canonical);
            eprintln!("{part:?} {run}: {dt:.1} mm, {dr:.1}° from the canonical pose");
            assert!(
                dt < 0.05 * d && dr < 5.0,
                "{part:?} {run}: {dt:.1} mm, {dr:.1}° from the canonical pose"
            );
            let again = symmetry.canonical(&best);
            assert!(
                errors(&again, &best).1 < 0.01,
                "{part:?} {run}: the reported pose is not canonical"
            );
            for h in &found.objects[0].hypotheses {
                assert!(errors(&symmetry.canonical(&h.pose), &h.pose).1 < 0.01);
            }
        }
    }
}

/// On the votes of one view, clustering with the symmetry gathers the equivalent poses the
/// votes spread over: the best cluster has more votes, and is equivalent to the truth.
#[test]
fn clustering_gathers_the_votes_of_equivalent_poses() {
    let params = DetectParams::new();
    for part in SymmetricPart::ALL {
        let model = model_of(part);
        let symmetry = model.symmetry();
        let d = model.diameter_mm();
        let mut rng = Rng::new(10 + part.object_id() as u64);
        let truth = random_pose_in_view(&mut rng, d, (650.0, 900.0));
        let scene = SyntheticScene::single(&part.mesh(), part.object_id(), truth, None, 3).unwrap();
        let image = prepare(&scene.frame.view(), &params.scene).unwrap();
        let cloud = PreparedScene::new(
            &image.oriented_points(),
            &model.params().subsample_params(d),
        )
        .unwrap();
        let (raw, _) = vote(&model, &cloud, &params.voting);
        let plain = cluster_poses(&raw, d, &Symmetry::default(), &params.clustering);
        let gathered = cluster_poses(&raw, d, &symmetry, &params.clustering);
        let (dt, dr) = errors(
            &symmetry.closest_equivalent(&gathered[0].pose, &truth.rotation),
            &truth,
        );
        eprintln!(
            "{part:?}: best cluster {} votes without the symmetry, {} with ({dt:.1} mm, {dr:.1}°); \
             {} and {} clusters",
            plain[0].votes,
            gathered[0].votes,
            plain.len(),
            gathered.len()
        );
        assert!(dt < 0.05 * d && dr < 5.0, "{part:?}: {dt:.1} mm, {dr:.1}°");
        assert!(
            gathered[0].votes as f32 > 1.3 * plain[0].votes as f32,
            "{part:?}: {} votes with the symmetry, {} without",
            gathered[0].votes,
            plain[0].votes
        );
        assert!(gathered.len() < plain.len());
    }
}

/// A hint at a pose that is not canonical comes back as the canonical pose, and two hints at
/// equivalent poses are one instance: one of them is answered, and no voted pose of the same
/// instance follows it.
#[test]
fn hints_of_symmetric_parts_come_back_canonical_and_as_one_instance() {
    let detector = Detector::default();
    let noise = NoiseModel::kinect();
    for part in SymmetricPart::ALL {
        let model = model_of(part);
        let symmetry = model.symmetry();
        let d = model.diameter_mm();
        let mut rng = Rng::new(20 + part.object_id() as u64);
        let shown = non_canonical_pose(part, &symmetry, &mut rng, d);
        let canonical = symmetry.canonical(&shown);
        let scene =
            SyntheticScene::single(&part.mesh(), part.object_id(), shown, Some(&noise), 7).unwrap();
        let hint = |pose| Hint {
            object_id: part.object_id(),
            pose,
        };
        let opts = RunOptions {
            hints: vec![hint(shown), hint(canonical)],
            hypotheses_per_object: 2,
            ..RunOptions::default()
        };
        let found = detector
            .detect(&scene.frame.view(), &[&model], &opts)
            .unwrap();
        let hypotheses = &found.objects[0].hypotheses;
        let best = &hypotheses[0];
        let (dt, dr) = errors(&best.pose, &canonical);
        assert!(
            best.checks.has(Checks::HINT) && dt < 0.05 * d && dr < 5.0,
            "{part:?}: {:?}, {dt:.1} mm, {dr:.1}° from the canonical pose",
            best.checks
        );
        let both = Checks::CONSISTENT | Checks::SILHOUETTE;
        let passed = hypotheses
            .iter()
            .filter(|h| h.checks.0 & both == both)
            .count();
        assert_eq!(passed, 1, "{part:?}: {hypotheses:?}");
        for h in hypotheses {
            assert!(errors(&symmetry.canonical(&h.pose), &h.pose).1 < 0.01);
        }
    }
}
