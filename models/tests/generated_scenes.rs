//! Detection on generated scenes: generated parts at random poses, with and without sensor
//! noise and occluders. Runs anywhere (no data files).

use ppfd_models::clustering::cluster_poses;
use ppfd_models::detector::DetectParams;
use ppfd_models::model::{ModelParams, ObjectModel};
use ppfd_models::parts::Part;
use ppfd_models::scene::{prepare, PreparedScene};
use ppfd_models::synthetic::{random_pose_in_view, Rng, SyntheticScene};
use ppfd_models::voting::vote;
use ppfd_models::Pose;

fn errors(est: &Pose, gt: &Pose) -> (f32, f32) {
    (
        (est.translation.vector - gt.translation.vector).norm(),
        est.rotation.angle_to(&gt.rotation).to_degrees(),
    )
}

/// Best cluster after voting and clustering alone, for one object in one scene.
fn best_cluster(model: &ObjectModel, scene: &SyntheticScene, params: &DetectParams) -> Pose {
    let image = prepare(&scene.frame.view(), &params.scene).unwrap();
    let cloud = PreparedScene::new(
        &image.oriented_points(),
        &model.params().subsample_params(model.diameter_mm()),
    )
    .unwrap();
    let (raw, _) = vote(model, &cloud, &params.voting);
    cluster_poses(&raw, model.diameter_mm(), &params.clustering)[0].pose
}

#[test]
#[ignore = "target of the detection issue not reached yet: about 13-19 of 50 best clusters within 0.05 D and 5 deg"]
fn noise_free_single_object_at_random_poses() {
    let params = DetectParams::new();
    let mut rng = Rng::new(11);
    let mut hits = 0;
    let runs = 50;
    let models: Vec<ObjectModel> = Part::ALL
        .iter()
        .map(|p| {
            ObjectModel::build(&p.mesh(), p.object_id(), p.name(), &ModelParams::default()).unwrap()
        })
        .collect();
    for i in 0..runs {
        let part = Part::ALL[i % Part::ALL.len()];
        let model = &models[i % Part::ALL.len()];
        let d = model.diameter_mm();
        let pose = random_pose_in_view(&mut rng, d, (600.0, 1000.0));
        let scene =
            SyntheticScene::single(&part.mesh(), part.object_id(), pose, None, i as u64).unwrap();
        let best = best_cluster(model, &scene, &params);
        let (dt, dr) = errors(&best, &pose);
        if dt < 0.05 * d && dr < 5.0 {
            hits += 1;
        } else {
            eprintln!(
                "run {i} ({}): best cluster off by {dt:.1} mm, {dr:.1} deg",
                part.name()
            );
        }
    }
    eprintln!("noise-free: {hits}/{runs} best clusters within 0.05 D and 5 deg");
    assert!(hits as f32 >= 0.95 * runs as f32, "{hits}/{runs}");
}

#[test]
fn model_points_moved_by_a_pose_vote_for_that_pose() {
    let params = DetectParams::new();
    let mut rng = Rng::new(5);
    let mut hits = 0;
    for i in 0..20 {
        let part = [Part::LBracket, Part::TPipe][i % 2];
        let model =
            ObjectModel::build(&part.mesh(), 1, part.name(), &ModelParams::default()).unwrap();
        let d = model.diameter_mm();
        let pose = random_pose_in_view(&mut rng, d, (600.0, 1000.0));
        let pts = model.surface_points();
        let mut moved = ppfd_models::subsample::OrientedPoints::default();
        for (p, n) in pts.positions.iter().zip(&pts.normals) {
            moved.push(pose * p, pose * n);
        }
        let cloud = PreparedScene::new(&moved, &model.params().subsample_params(d)).unwrap();
        let (raw, _) = vote(&model, &cloud, &params.voting);
        let best = cluster_poses(&raw, d, &params.clustering)[0].pose;
        let (dt, dr) = errors(&best, &pose);
        eprintln!("{}: {dt:.1} mm {dr:.1} deg", part.name());
        if dt < 0.05 * d && dr < 5.0 {
            hits += 1;
        }
    }
    assert!(hits >= 19, "{hits}/20");
}
