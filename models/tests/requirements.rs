//! What a caller asks of the answer, on generated scenes with several instances of one part:
//! ordering by distance, the pose restriction of bin picking, the minimum score, the instance
//! distance and the region of interest, on voted poses and on poses from hints. Runs anywhere
//! (no data files).

use ppfd_models::detect::detector::{Checks, Detections, Detector, Hint, RunOptions};
use ppfd_models::detect::requirements::{Order, PixelRegion, PoseRestriction, Requirements};
use ppfd_models::geometry::mesh::Mesh;
use ppfd_models::geometry::render::bounding_sphere;
use ppfd_models::model::{ModelParams, ObjectModel};
use ppfd_models::synthetic::parts::Part;
use ppfd_models::synthetic::scene::{NoiseModel, SceneSpec, SyntheticScene};
use ppfd_models::Pose;

const PART: Part = Part::LBracket;

struct Setup {
    mesh: Mesh,
    model: ObjectModel,
    /// Three instances of the part resting on the table, with sensor noise.
    scene: SyntheticScene,
}

fn setup(seed: u64) -> Setup {
    let mesh = PART.mesh();
    let model = ObjectModel::build(&mesh, 1, PART.name(), &ModelParams::default()).unwrap();
    let scene = SceneSpec::new(seed)
        .object(1, &mesh)
        .object(1, &mesh)
        .object(1, &mesh)
        .noise(Some(NoiseModel::kinect()))
        .build()
        .unwrap();
    Setup { mesh, model, scene }
}

impl Setup {
    fn detect(&self, n: usize, requirements: Requirements) -> Detections {
        self.detect_hinted(n, requirements, Vec::new())
    }

    fn detect_hinted(&self, n: usize, requirements: Requirements, hints: Vec<Hint>) -> Detections {
        let options = RunOptions {
            hypotheses_per_object: n,
            requirements,
            hints,
            ..Default::default()
        };
        Detector::default()
            .detect(&self.scene.frame.view(), &[&self.model], &options)
            .unwrap()
    }

    /// The ground-truth instance `pose` is a correct pose of, if any.
    fn instance_of(&self, pose: &Pose) -> Option<usize> {
        let d = self.model.diameter_mm();
        self.scene.ground_truth.iter().position(|(_, truth)| {
            (pose.translation.vector - truth.translation.vector).norm() < 0.1 * d
                && pose.rotation.angle_to(&truth.rotation).to_degrees() < 15.0
        })
    }

    fn instances(&self, found: &Detections) -> Vec<Option<usize>> {
        found.objects[0]
            .hypotheses
            .iter()
            .map(|h| self.instance_of(&h.pose))
            .collect()
    }

    /// Distance of the model's centre from the camera at `pose`, mm.
    fn distance(&self, pose: &Pose) -> f32 {
        (pose * bounding_sphere(&self.mesh).0).coords.norm()
    }
}

/// Nearest first: the three instances come nearest first, and the first is the nearest of
/// the truth; best score first puts another instance first in this scene, so the order is the
/// request's doing. Nearest first goes with a minimum score, as in a cell: a partial match
/// near the camera would otherwise come before a part. The scene is one where the poses of all
/// three instances pass the filters: a pose that fails one is listed after those that pass,
/// whatever its distance, and in more than half of the generated piles of three (seeds 30–49)
/// one instance's pose fails the consistency filter. Of those left, in seeds 43, 44 and 49
/// the best scored is not the nearest.
#[test]
fn ordered_by_distance_the_nearest_instance_comes_first() {
    let s = setup(43);
    let by_score = s.detect(3, Requirements::default());
    let min_score = 0.4 * by_score.objects[0].hypotheses[0].score;
    let nearest_first = Requirements {
        order: Order::Distance,
        min_score,
        ..Default::default()
    };
    let by_distance = s.detect(3, nearest_first);
    let (score_hits, distance_hits) = (s.instances(&by_score), s.instances(&by_distance));
    eprintln!("by score {score_hits:?}, by distance {distance_hits:?}");
    let mut found: Vec<usize> = distance_hits.iter().flatten().copied().collect();
    found.sort();
    assert_eq!(found, vec![0, 1, 2], "every instance found");
    let distances: Vec<f32> = by_distance.objects[0]
        .hypotheses
        .iter()
        .map(|h| s.distance(&h.pose))
        .collect();
    assert!(distances.windows(2).all(|w| w[0] <= w[1]), "{distances:?}");
    let nearest = (0..3)
        .min_by(|&a, &b| {
            let d = |i: usize| s.distance(&s.scene.ground_truth[i].1);
            d(a).total_cmp(&d(b))
        })
        .unwrap();
    assert_eq!(distance_hits[0], Some(nearest));
    assert_ne!(
        score_hits[0],
        Some(nearest),
        "the scene must tell the orders apart"
    );

    // Asked for one, the nearest is the one, not the best scored.
    let one = s.detect(1, nearest_first);
    assert_eq!(s.instances(&one), vec![Some(nearest)]);
}

/// Bin picking: with the pose restriction around one instance's posed axis, that instance is
/// found and the others, whose axes lean too far, are not; every pose returned passes.
#[test]
fn a_pose_restriction_returns_only_poses_a_gripper_can_take() {
    let s = setup(31);
    let axis = nalgebra::Vector3::z();
    let posed = |i: usize| s.scene.ground_truth[i].1.rotation * axis;
    let unrestricted = s.instances(&s.detect(3, Requirements::default()));
    assert!(
        (0..3).all(|i| unrestricted.contains(&Some(i))),
        "{unrestricted:?}"
    );
    // The instance whose axis is farthest from the others' is the one to keep.
    let lean = |i: usize, j: usize| posed(i).angle(&posed(j)).to_degrees();
    let keep = (0..3)
        .max_by(|&a, &b| {
            let nearest_other = |i: usize| {
                (0..3)
                    .filter(|&j| j != i)
                    .map(|j| lean(i, j))
                    .fold(f32::INFINITY, f32::min)
            };
            nearest_other(a).total_cmp(&nearest_other(b))
        })
        .unwrap();
    let margin = (0..3)
        .filter(|&j| j != keep)
        .map(|j| lean(keep, j))
        .fold(f32::INFINITY, f32::min);
    assert!(
        margin > 20.0,
        "the instances' axes must differ: {margin:.0}°"
    );
    let restriction =
        PoseRestriction::new([0.0, 0.0, 1.0], posed(keep).into(), margin / 2.0).unwrap();
    let found = s.detect(
        3,
        Requirements {
            pose_restriction: Some(restriction),
            ..Default::default()
        },
    );
    let hits = s.instances(&found);
    eprintln!("kept instance {keep} within {:.0}°: {hits:?}", margin / 2.0);
    assert!(hits.contains(&Some(keep)), "{hits:?}");
    assert!(
        hits.iter().all(|h| h.is_none() || *h == Some(keep)),
        "{hits:?}"
    );
    assert!(found.objects[0]
        .hypotheses
        .iter()
        .all(|h| restriction.allows(&h.pose)));
}

/// A minimum score leaves out whatever scores below it, even where it would fill the list.
#[test]
fn a_minimum_score_leaves_out_poorer_hypotheses() {
    let s = setup(31);
    let all = s.detect(8, Requirements::default());
    let scores: Vec<f32> = all.objects[0].hypotheses.iter().map(|h| h.score).collect();
    let min_score = scores[2] + 0.5 * (scores[1] - scores[2]).max(0.0);
    assert!(scores.iter().any(|&x| x < min_score), "{scores:?}");
    let kept = s.detect(
        8,
        Requirements {
            min_score,
            ..Default::default()
        },
    );
    let kept: Vec<f32> = kept.objects[0].hypotheses.iter().map(|h| h.score).collect();
    eprintln!("scores {scores:?}; at least {min_score}: {kept:?}");
    assert!(
        !kept.is_empty() && kept.iter().all(|&x| x >= min_score),
        "{kept:?}"
    );
    assert!(kept.len() < scores.len());
}

/// The instance distance: at two diameters, no two hypotheses put the centre that close; at
/// the default a quarter, some do.
#[test]
fn the_instance_distance_sets_how_far_apart_two_instances_lie() {
    let s = setup(31);
    let d = s.model.diameter_mm();
    let closest_pair = |found: &Detections| {
        let hyps = &found.objects[0].hypotheses;
        let mut closest = f32::INFINITY;
        for (i, a) in hyps.iter().enumerate() {
            for b in &hyps[..i] {
                let c = bounding_sphere(&s.mesh).0;
                closest = closest.min((a.pose * c - b.pose * c).norm() / d);
            }
        }
        closest
    };
    let default = closest_pair(&s.detect(8, Requirements::default()));
    let wide = s.detect(
        8,
        Requirements {
            instance_distance_fraction: Some(1.5),
            ..Default::default()
        },
    );
    eprintln!(
        "closest centres: default {default:.2} D, asked for 1.5 D {:.2} D",
        closest_pair(&wide)
    );
    assert!(default < 1.5, "{default}");
    assert!(closest_pair(&wide) >= 1.5);
}

/// A region of interest around one instance: reference points come only from it, so that
/// instance is found and the others are not; a region outside the frame is refused.
#[test]
fn a_region_of_interest_limits_where_reference_points_are_taken() {
    let s = setup(31);
    let k = s.scene.frame.intrinsics;
    let (target, truth) = s.scene.ground_truth[0];
    assert_eq!(target, 1);
    let (mut u0, mut v0, mut u1, mut v1) = (i64::MAX, i64::MAX, i64::MIN, i64::MIN);
    for p in &s.mesh.positions {
        let (u, v) = k.pixel(&(truth * p));
        (u0, v0, u1, v1) = (u0.min(u), v0.min(v), u1.max(u), v1.max(v));
    }
    let region = PixelRegion {
        x: u0.max(0) as u32,
        y: v0.max(0) as u32,
        width: (u1 - u0.max(0) + 1) as u32,
        height: (v1 - v0.max(0) + 1) as u32,
    };
    let whole = s.detect(3, Requirements::default());
    let within = s.detect(
        3,
        Requirements {
            region: Some(region),
            ..Default::default()
        },
    );
    let hits = s.instances(&within);
    eprintln!(
        "region {region:?}: {hits:?}; reference points {} of {}",
        within.counts.reference_points, whole.counts.reference_points
    );
    assert!(within.counts.reference_points < whole.counts.reference_points / 2);
    assert_eq!(hits[0], Some(0));
    for other in 1..3 {
        // An instance the region does not reach is not found.
        let (_, pose) = s.scene.ground_truth[other];
        let (u, v) = k.pixel(&(pose * bounding_sphere(&s.mesh).0));
        let inside = u >= region.x as i64
            && v >= region.y as i64
            && u < (region.x + region.width) as i64
            && v < (region.y + region.height) as i64;
        if !inside {
            assert!(!hits.contains(&Some(other)), "{hits:?}");
        }
    }

    let outside = RunOptions {
        requirements: Requirements {
            region: Some(PixelRegion {
                x: 600,
                y: 0,
                width: 100,
                height: 10,
            }),
            ..Default::default()
        },
        ..Default::default()
    };
    let e = Detector::default()
        .detect(&s.scene.frame.view(), &[&s.model], &outside)
        .unwrap_err()
        .to_string();
    assert!(e.contains("outside the 640x480 frame"), "{e}");
}

/// Hints go through the same requirements as voted poses: with the three instances' true poses
/// as hints, all three come back from them nearest first when asked; a pose restriction, a
/// minimum score or a region of interest that a hinted instance does not meet leaves that
/// hint out (its object is then voted for, under the same requirements), and every pose
/// returned meets them.
#[test]
fn hinted_poses_meet_the_requirements_as_voted_ones_do() {
    let s = setup(31);
    let truths: Vec<Pose> = s.scene.ground_truth.iter().map(|g| g.1).collect();
    let hints: Vec<Hint> = truths
        .iter()
        .map(|&pose| Hint { object_id: 1, pose })
        .collect();
    let from_hints = |found: &Detections| {
        found.objects[0]
            .hypotheses
            .iter()
            .filter(|h| h.checks.has(Checks::HINT))
            .count()
    };

    let nearest_first = Requirements {
        order: Order::Distance,
        ..Default::default()
    };
    let found = s.detect_hinted(3, nearest_first, hints.clone());
    let hits = s.instances(&found);
    let distances: Vec<f32> = found.objects[0]
        .hypotheses
        .iter()
        .map(|h| s.distance(&h.pose))
        .collect();
    eprintln!("nearest first from hints: {hits:?} at {distances:?} mm");
    assert_eq!(from_hints(&found), 3, "{hits:?}");
    assert!(
        found.objects[0].clusters.is_empty(),
        "voted with every hint kept"
    );
    let mut sorted = hits.iter().flatten().copied().collect::<Vec<_>>();
    sorted.sort();
    assert_eq!(sorted, vec![0, 1, 2]);
    assert!(distances.windows(2).all(|w| w[0] <= w[1]), "{distances:?}");

    // A pose restriction around instance 0's posed axis, leaving out the others' (this seed's
    // instances lean apart, as the pose restriction test shows).
    let axis = nalgebra::Vector3::z();
    let posed = |i: usize| truths[i].rotation * axis;
    let margin = (1..3)
        .map(|j| posed(0).angle(&posed(j)).to_degrees())
        .fold(f32::INFINITY, f32::min);
    assert!(
        margin > 20.0,
        "the instances' axes must differ: {margin:.0}°"
    );
    let restriction = PoseRestriction::new([0.0, 0.0, 1.0], posed(0).into(), margin / 2.0).unwrap();
    let found = s.detect_hinted(
        3,
        Requirements {
            pose_restriction: Some(restriction),
            ..Default::default()
        },
        hints.clone(),
    );
    let hits = s.instances(&found);
    eprintln!(
        "restricted to instance 0's axis within {:.0}°: {hits:?}",
        margin / 2.0
    );
    assert_eq!(hits.first(), Some(&Some(0)), "{hits:?}");
    assert!(found.objects[0].hypotheses[0].checks.has(Checks::HINT));
    assert!(
        hits.iter().all(|h| h.is_none() || *h == Some(0)),
        "{hits:?}"
    );
    assert!(found.objects[0]
        .hypotheses
        .iter()
        .all(|h| restriction.allows(&h.pose)));

    // A minimum score between the hinted instances' scores keeps the better ones only.
    let all = s.detect_hinted(3, Requirements::default(), hints.clone());
    let mut scores: Vec<f32> = all.objects[0].hypotheses.iter().map(|h| h.score).collect();
    scores.sort_by(|a, b| b.total_cmp(a));
    let min_score = 0.5 * (scores[1] + scores[2]);
    let found = s.detect_hinted(
        3,
        Requirements {
            min_score,
            ..Default::default()
        },
        hints.clone(),
    );
    let kept: Vec<(bool, f32)> = found.objects[0]
        .hypotheses
        .iter()
        .map(|h| (h.checks.has(Checks::HINT), h.score))
        .collect();
    eprintln!("hinted scores {scores:?}; at least {min_score}: {kept:?}");
    assert!(kept.iter().all(|&(_, x)| x >= min_score), "{kept:?}");
    assert_eq!(kept.iter().filter(|k| k.0).count(), 2, "{kept:?}");

    // A region of interest around instance 0: the hints of instances with no surface in it
    // are left out.
    let k = s.scene.frame.intrinsics;
    let pixels = |pose: &Pose| -> Vec<(i64, i64)> {
        s.mesh
            .positions
            .iter()
            .map(|p| k.pixel(&(pose * p)))
            .collect()
    };
    let own = pixels(&truths[0]);
    let (u0, v0) = own
        .iter()
        .fold((i64::MAX, i64::MAX), |a, p| (a.0.min(p.0), a.1.min(p.1)));
    let (u1, v1) = own
        .iter()
        .fold((i64::MIN, i64::MIN), |a, p| (a.0.max(p.0), a.1.max(p.1)));
    let region = PixelRegion {
        x: u0.max(0) as u32,
        y: v0.max(0) as u32,
        width: (u1 - u0.max(0) + 1) as u32,
        height: (v1 - v0.max(0) + 1) as u32,
    };
    let found = s.detect_hinted(
        3,
        Requirements {
            region: Some(region),
            ..Default::default()
        },
        hints,
    );
    let hits = s.instances(&found);
    eprintln!("region {region:?} from hints: {hits:?}");
    assert!(hits.contains(&Some(0)), "{hits:?}");
    for (other, truth) in truths.iter().enumerate().skip(1) {
        let reaches = pixels(truth).iter().any(|&(u, v)| {
            u >= region.x as i64
                && v >= region.y as i64
                && u < (region.x + region.width) as i64
                && v < (region.y + region.height) as i64
        });
        if !reaches {
            assert!(!hits.contains(&Some(other)), "instance {other}: {hits:?}");
        }
    }
}
