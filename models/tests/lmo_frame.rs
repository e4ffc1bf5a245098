//! Detection on the real LM-O frame (scene 2, image 3: eight objects on a cluttered table, a
//! Kinect v1 depth image) read from `../shared/data/lmo`. Runs whenever the data is there, and
//! must run in CI (`CI=true`); elsewhere it is skipped, with a message, when the data is absent.
//!
//! A pose counts as correct within 0.1 D and 15° of the ground truth, the smaller error over
//! the object's discrete symmetries (the eggbox and the glue have one each).

use std::path::PathBuf;

use ppfd_bop::dataset::{BopDataset, GtPose};
use ppfd_bop::eval::csv::EstimateRow;
use ppfd_bop::eval::score::{score_results, ScoreOptions};
use ppfd_bop::shared_test_data;
use ppfd_models::detect::detector::{
    Checks, DetectParams, Detections, Detector, Hint, ObjectDetections, RunOptions,
};
use ppfd_models::geometry::mesh::Mesh;
use ppfd_models::model::{ModelParams, ObjectModel};
use ppfd_models::Pose;

const SCENE: u32 = 2;
const IMAGE: u32 = 3;

/// Translation (mm) and rotation (degrees) errors of `est`, the smallest over `symmetries`
/// (identity included).
fn errors(est: &Pose, truth: &Pose, symmetries: &[Pose]) -> (f32, f32) {
    std::iter::once(Pose::identity())
        .chain(symmetries.iter().copied())
        .map(|s| {
            let t = truth * s;
            (
                (est.translation.vector - t.translation.vector).norm(),
                est.rotation.angle_to(&t.rotation).to_degrees(),
            )
        })
        .min_by(|a, b| (a.0 + a.1).total_cmp(&(b.0 + b.1)))
        .unwrap()
}

/// How many of the frame's objects have a correct pose among their 10 best clusters, and how
/// many a correct best pose.
struct Outcome {
    clusters_ok: usize,
    final_ok: usize,
    objects: usize,
    /// Per object, the pairs formed and the votes cast.
    work: Vec<(u32, u64, u64)>,
    /// The points of the subsampled clouds the objects voted on, summed over objects.
    cloud_points: u32,
    /// The objects whose hypotheses differ from those of a detection of that object alone.
    differ_alone: Vec<u32>,
}

/// The frame's dataset, ground truth, and the models of its objects (default parameters).
fn open_frame(dir: &PathBuf) -> (BopDataset, Vec<GtPose>, Vec<ObjectModel>) {
    let dataset = BopDataset::open(dir).unwrap();
    let truth = dataset.ground_truth(SCENE, IMAGE).unwrap().to_vec();
    let models: Vec<ObjectModel> = truth
        .iter()
        .map(|g| {
            let mesh = Mesh::from_ply_file(dataset.model_path(g.obj_id).unwrap()).unwrap();
            ObjectModel::build(&mesh, g.obj_id, "lmo", &ModelParams::default()).unwrap()
        })
        .collect();
    (dataset, truth, models)
}

/// Detects the frame's objects with the default parameters and prints the error table.
fn detect_frame(dir: &PathBuf) -> Outcome {
    let (dataset, truth, models) = open_frame(dir);
    let visible = dataset.ground_truth_info(SCENE, IMAGE).unwrap().to_vec();
    let frame = dataset.depth_frame(SCENE, IMAGE).unwrap();
    let params = DetectParams::new();
    let clusters_kept = params.clusters_kept;
    let refs: Vec<&ObjectModel> = models.iter().collect();
    let detector = Detector::new(params);
    let opts = RunOptions {
        hypotheses_per_object: 1,
        ..Default::default()
    };
    let det: Detections = detector.detect(&frame.view(), &refs, &opts).unwrap();
    // The objects run side by side; each must come out as it does alone. Three objects keep
    // the test short: the largest, the smallest and one between.
    let mut differ_alone = Vec::new();
    for i in [0, 3, 6] {
        let alone = detector.detect(&frame.view(), &refs[i..=i], &opts).unwrap();
        let poses = |d: &ObjectDetections| -> Vec<(Pose, u32, u32)> {
            d.hypotheses
                .iter()
                .map(|h| (h.pose, h.votes, h.checks.0))
                .collect()
        };
        if poses(&alone.objects[0]) != poses(&det.objects[i]) {
            differ_alone.push(det.objects[i].object_id);
        }
    }
    assert!(clusters_kept >= 10);
    // Each object's own counts, in request order, add up to the frame's.
    assert_eq!(det.per_object_counts.len(), models.len());
    let sum = |f: fn(&ppfd_models::detect::detector::Counts) -> u64| -> u64 {
        det.per_object_counts.iter().map(f).sum()
    };
    assert_eq!(
        sum(|c| c.reference_points as u64),
        det.counts.reference_points as u64
    );
    assert_eq!(sum(|c| c.pairs), det.counts.pairs);
    assert_eq!(sum(|c| c.votes), det.counts.votes);
    assert_eq!(sum(|c| c.hypotheses as u64), det.counts.hypotheses as u64);
    for c in &det.per_object_counts {
        // An object's cloud is the frame's points subsampled with its leaf.
        assert!(c.scene_points > 0 && c.scene_points < det.counts.scene_points);
        assert!(c.reference_points > 0 && c.reference_points <= c.scene_points);
        assert!(c.votes > c.pairs, "{c:?}");
    }

    println!(
        "| object | D (mm) | visible | correct cluster rank (of 10) | best pose t err (mm) | R err (°) | correct |"
    );
    println!("|---:|---:|---:|---:|---:|---:|---|");
    let mut outcome = Outcome {
        clusters_ok: 0,
        final_ok: 0,
        objects: truth.len(),
        work: det
            .objects
            .iter()
            .zip(&det.per_object_counts)
            .map(|(o, c)| (o.object_id, c.pairs, c.votes))
            .collect(),
        cloud_points: det.per_object_counts.iter().map(|c| c.scene_points).sum(),
        differ_alone,
    };
    for ((g, info), (o, model)) in truth
        .iter()
        .zip(&visible)
        .zip(det.objects.iter().zip(&models))
    {
        assert_eq!(o.object_id, g.obj_id);
        let d = model.diameter_mm();
        let symmetries = dataset
            .model_info(g.obj_id)
            .map(|i| i.symmetries_discrete.clone())
            .unwrap_or_default();
        let correct = |p: &Pose| {
            let (dt, dr) = errors(p, &g.pose, &symmetries);
            dt < 0.1 * d && dr < 15.0
        };
        let cluster_rank = o.clusters.iter().take(10).position(|(p, _)| correct(p));
        let best = o.hypotheses.first().map(|h| h.pose);
        let (dt, dr) = best.map_or((f32::NAN, f32::NAN), |p| errors(&p, &g.pose, &symmetries));
        let final_ok = best.is_some_and(|p| correct(&p));
        outcome.clusters_ok += cluster_rank.is_some() as usize;
        outcome.final_ok += final_ok as usize;
        println!(
            "| {} | {d:.0} | {:.2} | {} | {dt:.1} | {dr:.1} | {} |",
            g.obj_id,
            info.visib_fract,
            cluster_rank.map_or("-".to_string(), |r| (r + 1).to_string()),
            if final_ok { "yes" } else { "no" },
        );
    }
    let t = &det.timings;
    println!(
        "{} of {} with a correct pose among the 10 best clusters; best pose correct for {}; \
         voting {:.0} ms, clustering {:.0} ms, total {:.0} ms",
        outcome.clusters_ok,
        outcome.objects,
        outcome.final_ok,
        t.voting.as_secs_f64() * 1e3,
        t.clustering.as_secs_f64() * 1e3,
        t.total().as_secs_f64() * 1e3,
    );
    outcome
}

/// What the detector reaches on this frame: five objects found by voting alone and six best
/// poses after re-scoring, ICP and the filters. The ape (20 % visible) and the eggbox (half
/// hidden) get no cluster near the truth. The glue is a toss-up: one or two of its reference
/// points propose its pose, which ranks about 150th by votes and wins after re-scoring and ICP;
/// every further cut of the voting work measured (partners within 0.9 D, a narrower neighbour
/// rule, capped keys, coarser reference cubes, a finer or coarser scene leaf) lost it.
///
/// The work is bounded too, on counts (the same every run, unlike times): with the scene
/// sampled as finely as the model (a leaf of 0.05 D) the ape formed 3.44 M pairs and cast
/// 294 M votes, the duck 3.04 M and 349 M; with the scene's leaf of 0.1 D no object forms
/// more than 0.6 M pairs or casts more than 70 M votes. The clouds hold only what their objects
/// may vote with: 21 254 points in the eight, against 45 973 subsampled from the whole frame
/// and 30 721 from the points in front of the table.
#[test]
fn lmo_frame_objects_are_found() {
    let Some(dir) = shared_test_data("lmo") else {
        return;
    };
    let o = detect_frame(&dir);
    assert_eq!(o.objects, 8);
    assert!(
        o.differ_alone.is_empty(),
        "objects {:?} come out otherwise than when detected alone",
        o.differ_alone
    );
    assert!(
        o.clusters_ok >= 5,
        "{} of 8 in the best clusters",
        o.clusters_ok
    );
    assert!(o.final_ok >= 6, "{} of 8 best poses correct", o.final_ok);
    for &(id, pairs, votes) in &o.work {
        assert!(
            pairs <= 1_000_000 && votes <= 100_000_000,
            "object {id}: {pairs} pairs and {votes} votes, at most 1 M and 100 M expected"
        );
    }
    let (pairs, votes) = o
        .work
        .iter()
        .fold((0, 0), |(p, v), &(_, pi, vi)| (p + pi, v + vi));
    assert!(
        pairs <= 4_000_000 && votes <= 400_000_000,
        "{pairs} pairs and {votes} votes in all, at most 4 M and 400 M expected"
    );
    assert!(
        o.cloud_points <= 25_000,
        "{} points in the objects' clouds, at most 25 000 expected",
        o.cloud_points
    );
}

/// The detection issues' targets on this frame: a correct pose among the 10 best clusters for
/// at least 6 of the 8 objects, and (as a proxy for the VSD criterion) the best pose correct for
/// at least 7.
#[test]
#[ignore = "targets not reached: 5 of 8 among the 10 best clusters (the glue and the eggbox rank far below the 10th by votes), 6 of 8 best poses (refined from their true poses, the ape and the egg box still score below the poses that win: docs/BENCHMARKS.md)"]
fn lmo_frame_reaches_the_issue_targets() {
    let Some(dir) = shared_test_data("lmo") else {
        return;
    };
    let o = detect_frame(&dir);
    assert!(
        o.clusters_ok >= 6,
        "{} of 8 in the best clusters",
        o.clusters_ok
    );
    assert!(o.final_ok >= 7, "{} of 8 best poses correct", o.final_ok);
}

/// With the ground truth as hints, every object of the frame comes back from its hint alone,
/// nothing is voted for, and by the BOP 2018 VSD (θ 0.3) at least 7 of the 8 poses are
/// correct, the egg box's among them. Its true pose shows 11 of its 200 outline pixels where an
/// edge is expected (all on edges) and meets the table along 62 more: the silhouette filter
/// passes it because the box rises out of the surface its outline meets (docs/METHOD.md §3.4),
/// where the floor over the whole outline in view failed it. (ICP takes the ape, a fifth of it
/// in view, 11 mm and 13° off its hint.)
#[test]
fn every_true_pose_of_the_frame_comes_back_from_its_hint() {
    let Some(dir) = shared_test_data("lmo") else {
        return;
    };
    let (dataset, truth, models) = open_frame(&dir);
    let frame = dataset.depth_frame(SCENE, IMAGE).unwrap();
    let refs: Vec<&ObjectModel> = models.iter().collect();
    let opts = RunOptions {
        hypotheses_per_object: 1,
        hints: truth
            .iter()
            .map(|g| Hint {
                object_id: g.obj_id,
                pose: g.pose,
            })
            .collect(),
        ..Default::default()
    };
    let det = Detector::new(DetectParams::new())
        .detect(&frame.view(), &refs, &opts)
        .unwrap();
    assert_eq!(det.counts.reference_points, 0, "something was voted for");
    assert_eq!(
        det.objects.len(),
        truth.len(),
        "an object did not come back"
    );
    let mut rows = Vec::new();
    for (g, o) in truth.iter().zip(&det.objects) {
        assert_eq!(o.object_id, g.obj_id);
        let h = o.hypotheses.first().expect("a pose");
        assert!(
            h.checks.has(Checks::HINT),
            "object {}: {:?}",
            g.obj_id,
            h.checks
        );
        rows.push(EstimateRow {
            scene_id: SCENE,
            im_id: IMAGE,
            obj_id: o.object_id,
            score: h.score,
            pose: h.pose,
            time_s: det.elapsed.as_secs_f32(),
        });
    }
    let report = score_results(&dataset, &rows, &ScoreOptions::default()).unwrap();
    let correct: Vec<u32> = report
        .objects
        .iter()
        .filter(|o| o.recall_bop18[0] == 1.0)
        .filter_map(|o| o.obj_id)
        .collect();
    println!("correct by VSD from their hints: {correct:?}");
    assert!(correct.len() >= 7, "correct: {correct:?}");
    assert!(correct.contains(&10), "the egg box: correct {correct:?}");
}
