//! Detection on generated scenes: generated parts at random poses, with and without sensor
//! noise and occluders. Runs anywhere (no data files).

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use ppfd_models::detect::clustering::cluster_poses;
use ppfd_models::detect::detector::DetectParams;
use ppfd_models::detect::scene::{prepare, PreparedScene};
use ppfd_models::detect::voting::vote;
use ppfd_models::geometry::mesh::Mesh;
use ppfd_models::geometry::render::bounding_sphere;
use ppfd_models::model::{ModelParams, ObjectModel};
use ppfd_models::synthetic::parts::Part;
use ppfd_models::synthetic::scene::{
    random_pose_in_view, NoiseModel, Occluder, Placement, Rng, SceneSpec, SyntheticScene,
};
use ppfd_models::Pose;

fn errors(est: &Pose, gt: &Pose) -> (f32, f32) {
    (
        (est.translation.vector - gt.translation.vector).norm(),
        est.rotation.angle_to(&gt.rotation).to_degrees(),
    )
}

/// Best cluster after voting and clustering alone, for one object in one scene, and how many
/// reference points voted.
fn best_cluster(model: &ObjectModel, scene: &SyntheticScene, params: &DetectParams) -> (Pose, u32) {
    let image = prepare(&scene.frame.view(), &params.scene).unwrap();
    let cloud = PreparedScene::new(
        &image.oriented_points(),
        &model.params().subsample_params(model.diameter_mm()),
    )
    .unwrap();
    let (raw, counts) = vote(model, &cloud, &params.voting);
    let best = cluster_poses(
        &raw,
        model.diameter_mm(),
        &model.symmetry(),
        &params.clustering,
    )[0]
    .pose;
    (best, counts.reference_points)
}

/// One model of each generated part.
fn part_models() -> Vec<ObjectModel> {
    Part::ALL
        .iter()
        .map(|p| {
            ObjectModel::build(&p.mesh(), p.object_id(), p.name(), &ModelParams::default()).unwrap()
        })
        .collect()
}

/// `runs` scenes made by `scene_of(run, part, model, pose)` for poses drawn from `seed`, parts
/// in turn; returns how many best clusters lie within 0.05 D and 5° of the truth.
fn best_cluster_hits(
    runs: usize,
    seed: u64,
    scene_of: impl Fn(usize, Part, &ObjectModel, Pose) -> SyntheticScene,
) -> usize {
    best_cluster_hits_with(&DetectParams::new(), &part_models(), runs, seed, scene_of).0
}

/// [`best_cluster_hits`] with the given parameters and models; also returns the reference
/// points of all runs together.
fn best_cluster_hits_with(
    params: &DetectParams,
    models: &[ObjectModel],
    runs: usize,
    seed: u64,
    scene_of: impl Fn(usize, Part, &ObjectModel, Pose) -> SyntheticScene,
) -> (usize, u64) {
    let mut rng = Rng::new(seed);
    let mut hits = 0;
    let mut references = 0u64;
    for i in 0..runs {
        let part = Part::ALL[i % Part::ALL.len()];
        let model = &models[i % Part::ALL.len()];
        let d = model.diameter_mm();
        let pose = random_pose_in_view(&mut rng, d, (600.0, 1000.0));
        let scene = scene_of(i, part, model, pose);
        let (best, reference_points) = best_cluster(model, &scene, params);
        references += reference_points as u64;
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
    (hits, references)
}

#[test]
fn noise_free_single_object_at_random_poses() {
    let runs = 50;
    let hits = best_cluster_hits(runs, 11, |i, part, _, pose| {
        SyntheticScene::single(&part.mesh(), part.object_id(), pose, None, i as u64).unwrap()
    });
    eprintln!("noise-free: {hits}/{runs} best clusters within 0.05 D and 5 deg");
    assert!(hits as f32 >= 0.95 * runs as f32, "{hits}/{runs}");
}

/// `mesh` as a CAD export without normals would give it: one vertex per position, shared by
/// the faces on both sides of every edge, normals left to be taken from the faces.
fn welded_without_normals(mesh: &Mesh) -> Mesh {
    let mut index_of = std::collections::HashMap::new();
    let mut positions = Vec::new();
    let remap: Vec<u32> = mesh
        .positions
        .iter()
        .map(|p| {
            *index_of
                .entry([p.x, p.y, p.z].map(f32::to_bits))
                .or_insert_with(|| {
                    positions.push(*p);
                    positions.len() as u32 - 1
                })
        })
        .collect();
    let faces: Vec<[u32; 3]> = mesh
        .faces
        .iter()
        .map(|f| f.map(|v| remap[v as usize]))
        .collect();
    Mesh::from_triangles(positions, &faces).unwrap()
}

/// The parts' meshes welded and stripped of normals, as CAD tools often export them, make models
/// that find the parts as well as the meshes with their own normals do (noise-free, the 50
/// views of `noise_free_single_object_at_random_poses`). Normals blended across the parts'
/// sharp edges (models of format version 3) missed 27 of the 50.
#[test]
fn parts_exported_without_normals_are_found_as_well() {
    let models: Vec<ObjectModel> = Part::ALL
        .iter()
        .map(|p| {
            let mesh = welded_without_normals(&p.mesh());
            ObjectModel::build(&mesh, p.object_id(), p.name(), &ModelParams::default()).unwrap()
        })
        .collect();
    let runs = 50;
    let (hits, _) = best_cluster_hits_with(
        &DetectParams::new(),
        &models,
        runs,
        11,
        |i, part, _, pose| {
            SyntheticScene::single(&part.mesh(), part.object_id(), pose, None, i as u64).unwrap()
        },
    );
    eprintln!("meshes without normals: {hits}/{runs} best clusters within 0.05 D and 5 deg");
    assert!(hits as f32 >= 0.95 * runs as f32, "{hits}/{runs}");
}

/// `mesh` at `pose` in front of the camera (no table), with Kinect-like noise and two round
/// bars across the view between it and the camera, one upright left of its centre, one level
/// above it: together they hide some 10–35 % of it.
fn occluded_scene(mesh: &Mesh, object_id: u32, pose: Pose, seed: u64) -> SyntheticScene {
    let (centre, radius) = bounding_sphere(mesh);
    let c = pose * centre;
    let z = c.z - radius - 80.0;
    let scale = z / c.z;
    let at = |dx: f32, dy: f32| Translation3::new((c.x + dx) * scale, (c.y + dy) * scale, z);
    let bar_radius = 0.2 * radius * scale;
    let length = 3.0 * radius * scale;
    let upright = Occluder::Cylinder {
        radius_mm: bar_radius,
        height_mm: length,
        pose: Isometry3::from_parts(
            at(-0.75 * radius, 0.0),
            UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f32::consts::FRAC_PI_2),
        ),
    };
    let level = Occluder::Cylinder {
        radius_mm: bar_radius,
        height_mm: length,
        pose: Isometry3::from_parts(
            at(0.0, 0.75 * radius),
            UnitQuaternion::from_axis_angle(&Vector3::y_axis(), std::f32::consts::FRAC_PI_2),
        ),
    };
    SceneSpec::new(seed)
        .table(false)
        .camera(Isometry3::identity())
        .object_with(object_id, mesh, Placement::At(pose))
        .noise(Some(NoiseModel::kinect()))
        .occluder(upright)
        .occluder(level)
        .build()
        .unwrap()
}

/// The detection issue's target: 85 % of the best clusters within 0.05 D and 5°. Measured: 35
/// of 40 with reference points spread evenly (33 with every second point). Over seeds 12–15
/// (160 runs) it is 134 (84 %; 130 with every second point): the rotation about a part's
/// near-symmetry axis is the weak spot (most misses are the toothed disc, by 5–9°, about half
/// its 15° tooth pitch).
#[test]
fn noisy_single_object_behind_two_occluders() {
    let runs = 40;
    let visible = std::cell::RefCell::new(Vec::new());
    let hits = best_cluster_hits(runs, 12, |i, part, _, pose| {
        let scene = occluded_scene(&part.mesh(), part.object_id(), pose, i as u64);
        visible.borrow_mut().push(scene.visible_fraction[0]);
        scene
    });
    let visible = visible.into_inner();
    let mean_visible = visible.iter().sum::<f32>() / visible.len() as f32;
    eprintln!(
        "noise and two occluders: {hits}/{runs} best clusters within 0.05 D and 5 deg \
         (mean visible fraction {mean_visible:.2})"
    );
    assert!(
        mean_visible < 0.9,
        "the occluders hide too little: {mean_visible}"
    );
    assert!(hits as f32 >= 0.85 * runs as f32, "{hits}/{runs}");
}

/// Reference points spread one per cube of 0.1 D (the default) find more of voting's best
/// clusters than every second subsampled point does, with at most a tenth more reference
/// points, over three sets of generated views: noise-free (seed 11, 50 runs), noise and two
/// occluders (seeds 12–15, 160 runs), noise-free again (seed 21, 200 runs). Prints the table in
/// `VotingParams::reference_step`'s documentation.
#[test]
fn evenly_spread_reference_points_find_more_best_clusters_than_every_second_point() {
    let models = part_models();
    let spread = DetectParams::new();
    assert!(spread.voting.reference_spacing_fraction > 0.0 && spread.voting.reference_step == 1);
    let mut strided = DetectParams::new();
    strided.voting.reference_spacing_fraction = 0.0;
    strided.voting.reference_step = 2;
    let measure = |params: &DetectParams| {
        let free = best_cluster_hits_with(params, &models, 50, 11, |i, part, _, pose| {
            SyntheticScene::single(&part.mesh(), part.object_id(), pose, None, i as u64).unwrap()
        });
        let noisy = (12..16u64).map(|seed| {
            best_cluster_hits_with(params, &models, 40, seed, |i, part, _, pose| {
                occluded_scene(&part.mesh(), part.object_id(), pose, i as u64)
            })
        });
        let noisy = noisy.fold((0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
        let more = best_cluster_hits_with(params, &models, 200, 21, |i, part, _, pose| {
            let seed = 1000 + i as u64;
            SyntheticScene::single(&part.mesh(), part.object_id(), pose, None, seed).unwrap()
        });
        let references = free.1 + noisy.1 + more.1;
        ([free.0, noisy.0, more.0], references)
    };
    let (spread_hits, spread_refs) = measure(&spread);
    let (strided_hits, strided_refs) = measure(&strided);
    eprintln!("| selection | noise-free | noisy | noise-free (200) | reference points |");
    for (name, h, r) in [
        ("cubes of 0.1 D", spread_hits, spread_refs),
        ("every 2nd point", strided_hits, strided_refs),
    ] {
        eprintln!("| {name} | {} | {} | {} | {r} |", h[0], h[1], h[2]);
    }
    let total = |h: [usize; 3]| h.iter().sum::<usize>();
    assert!(
        total(spread_hits) > total(strided_hits),
        "{spread_hits:?} against {strided_hits:?}"
    );
    assert!(
        spread_refs * 10 <= strided_refs * 11,
        "{spread_refs} reference points against {strided_refs}"
    );
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
        let mut moved = ppfd_models::model::subsample::OrientedPoints::default();
        for (p, n) in pts.positions.iter().zip(&pts.normals) {
            moved.push(pose * p, pose * n);
        }
        let cloud = PreparedScene::new(&moved, &model.params().subsample_params(d)).unwrap();
        let (raw, _) = vote(&model, &cloud, &params.voting);
        let best = cluster_poses(&raw, d, &model.symmetry(), &params.clustering)[0].pose;
        let (dt, dr) = errors(&best, &pose);
        eprintln!("{}: {dt:.1} mm {dr:.1} deg", part.name());
        if dt < 0.05 * d && dr < 5.0 {
            hits += 1;
        }
    }
    assert!(hits >= 19, "{hits}/20");
}

/// The angle bracket's model, and the oriented points of a generated view of it on the table,
/// with the default parameters that prepared them.
fn bracket_on_table() -> (
    ObjectModel,
    ppfd_models::model::subsample::OrientedPoints,
    DetectParams,
) {
    let part = Part::LBracket;
    let mesh = part.mesh();
    let model = ObjectModel::build(&mesh, 1, part.name(), &ModelParams::default()).unwrap();
    let scene = SceneSpec::new(3)
        .object(1, &mesh)
        .camera_distance_mm(700.0, 800.0)
        .build()
        .unwrap();
    let params = DetectParams::new();
    let image = prepare(&scene.frame.view(), &params.scene).unwrap();
    (model, image.oriented_points(), params)
}

/// Points on the table cannot be model points: they pair with no reference point, and voting
/// gives exactly what it gives on the scene without them.
#[test]
fn table_points_are_no_partners() {
    use ppfd_models::detect::plane::SupportingPlane;
    use ppfd_models::detect::voting::{vote_from, Selection};
    use ppfd_models::model::subsample::OrientedPoints;
    let (model, points, params) = bracket_on_table();
    let d = model.diameter_mm();
    let planes = SupportingPlane::find_all(&points, &params.plane);
    assert!(!planes.is_empty(), "no table found");
    let cloud = PreparedScene::new(&points, &model.params().subsample_params(d)).unwrap();
    let selection = Selection::new(&cloud, &params.voting, &planes, d);
    let on_table = selection.excluded.iter().filter(|&&b| b).count();
    assert!(
        on_table > cloud.points.len() / 4,
        "{on_table} of {} points on the table",
        cloud.points.len()
    );
    assert!(selection.references.iter().all(|&r| !selection.excluded[r]));

    let (without, counts) = vote_from(&model, &cloud, &selection, &params.voting);

    // The same scene with the table's points taken out, the same reference points.
    let mut kept = OrientedPoints::default();
    for i in 0..cloud.points.len() {
        if !selection.excluded[i] {
            kept.push(cloud.points.positions[i], cloud.points.normals[i]);
        }
    }
    // A leaf far below the points' spacing keeps every point as it is (in another order).
    let bare = PreparedScene::new(
        &kept,
        &ppfd_models::model::subsample::SubsampleParams {
            leaf_mm: 1e-3,
            cluster_angle: 1e-3,
            neighbour_filtering: false,
        },
    )
    .unwrap();
    assert_eq!(bare.points.len(), kept.len());
    let bits = |p: &nalgebra::Point3<f32>| p.coords.map(f32::to_bits);
    let index: std::collections::HashMap<_, usize> = bare
        .points
        .positions
        .iter()
        .enumerate()
        .map(|(i, p)| (bits(p), i))
        .collect();
    let bare_selection = Selection {
        references: selection
            .references
            .iter()
            .map(|&r| index[&bits(&cloud.points.positions[r])])
            .collect(),
        excluded: vec![false; kept.len()],
    };
    // (The hypotheses themselves may differ at bin borders: subsampling renormalises normals.)
    let (_, expected_counts) = vote_from(&model, &bare, &bare_selection, &params.voting);
    assert_eq!(counts.pairs, expected_counts.pairs);
    assert_eq!(counts.votes, expected_counts.votes);
    assert!(!without.is_empty());
}

/// The detector's cloud holds only the points its object may vote with: the whole cloud's points
/// that no plane excludes, in their order, and voting on it forms the same pairs and casts the
/// same votes from the same reference points.
#[test]
fn a_cloud_leaves_out_the_points_no_object_votes_with() {
    use ppfd_models::detect::plane::SupportingPlane;
    use ppfd_models::detect::voting::{vote_from, Selection};
    let (model, points, params) = bracket_on_table();
    let d = model.diameter_mm();
    let planes = SupportingPlane::find_all(&points, &params.plane);
    assert!(!planes.is_empty(), "no table found");
    let (clouds, cloud_of) = params.prepare_clouds(&points, &planes, &[&model]).unwrap();
    assert_eq!(cloud_of, [0]);
    let trimmed = &clouds[0];
    let (groups, _) = params.scene_clouds(&[&model]);
    let in_front = SupportingPlane::drop_hidden(&points, &planes, d).unwrap_or(points);
    let whole = PreparedScene::new(&in_front, &groups[0]).unwrap();

    let all = Selection::new(&whole, &params.voting, &planes, d);
    let kept: Vec<usize> = (0..whole.points.len())
        .filter(|&i| !all.excluded[i])
        .collect();
    assert!(
        kept.len() < whole.points.len() * 3 / 4,
        "{} of {} kept",
        kept.len(),
        whole.points.len()
    );
    let positions: Vec<_> = kept.iter().map(|&i| whole.points.positions[i]).collect();
    assert_eq!(trimmed.points.positions, positions);

    let selection = Selection::new(trimmed, &params.voting, &planes, d);
    assert!(selection.excluded.iter().all(|&e| !e));
    let references: Vec<usize> = all
        .references
        .iter()
        .map(|&r| kept.binary_search(&r).unwrap())
        .collect();
    assert_eq!(selection.references, references);
    let (_, on_whole) = vote_from(&model, &whole, &all, &params.voting);
    let (_, on_trimmed) = vote_from(&model, trimmed, &selection, &params.voting);
    assert_eq!(on_trimmed.pairs, on_whole.pairs);
    assert_eq!(on_trimmed.votes, on_whole.votes);
}

/// What lies behind the table (a copy of the part 300 mm below its surface, as on a shelf
/// beyond its edge) gives no reference points and no partners; with `plane.exclude_behind` off
/// it does.
#[test]
fn points_behind_the_table_are_neither_references_nor_partners() {
    use ppfd_models::detect::plane::{PlaneParams, SupportingPlane};
    use ppfd_models::detect::voting::Selection;
    let (model, seen, params) = bracket_on_table();
    let d = model.diameter_mm();
    let table = SupportingPlane::find(&seen, &params.plane).expect("no table found");
    // The scene, and a copy of what stands on the table moved 300 mm behind it.
    let mut points = seen.clone();
    for (p, n) in seen.positions.iter().zip(&seen.normals) {
        if table.distance(p) > 10.0 {
            points.push(p - table.normal * 300.0, *n);
        }
    }
    let copies = points.len() - seen.len();
    assert!(copies > 100, "{copies} points on the part");
    let cloud = PreparedScene::new(&points, &model.params().subsample_params(d)).unwrap();
    let behind = |i: usize| table.distance(&cloud.points.positions[i]) < -100.0;
    let select = |plane: &PlaneParams| {
        let planes = SupportingPlane::find_all(&points, plane);
        Selection::new(&cloud, &params.voting, &planes, d)
    };

    let selection = select(&params.plane);
    let hidden = (0..cloud.points.len()).filter(|&i| behind(i)).count();
    assert!(hidden > 20, "{hidden} subsampled points behind the table");
    assert!((0..cloud.points.len())
        .filter(|&i| behind(i))
        .all(|i| selection.excluded[i]));
    assert!(selection.references.iter().all(|&r| !behind(r)));
    assert!(!selection.references.is_empty());

    let kept = select(&PlaneParams {
        exclude_behind: false,
        ..params.plane
    });
    let behind_references = kept.references.iter().filter(|&&r| behind(r)).count();
    assert!(behind_references > 5, "{behind_references}");
}

/// Multi-instance output: two instances of one part on the table are the two best hypotheses,
/// and a lone part's further hypotheses are never that part again (non-maximum suppression by
/// `DetectParams::nms_distance_fraction`).
#[test]
fn instances_of_a_part_are_told_apart_and_duplicates_suppressed() {
    use ppfd_models::detect::detector::{Detector, RunOptions};
    let detector = Detector::new(DetectParams::new());
    let options = |n| RunOptions {
        hypotheses_per_object: n,
        ..Default::default()
    };
    let mut report = String::new();
    for part in [Part::LBracket, Part::TPipe] {
        let (mesh, id) = (part.mesh(), part.object_id());
        let model = ObjectModel::build(&mesh, id, part.name(), &ModelParams::default()).unwrap();
        let d = model.diameter_mm();
        let correct = |est: &Pose, truth: &Pose| {
            let (dt, dr) = errors(est, truth);
            dt < 0.1 * d && dr < 15.0
        };
        let centre = bounding_sphere(&mesh).0;

        let pair = SceneSpec::new(21)
            .object(id, &mesh)
            .object(id, &mesh)
            .noise(Some(NoiseModel::kinect()))
            .build()
            .unwrap();
        let found = detector
            .detect(&pair.frame.view(), &[&model], &options(2))
            .unwrap();
        let best: Vec<Pose> = found.objects[0].hypotheses.iter().map(|h| h.pose).collect();
        for (i, (_, truth)) in pair.ground_truth.iter().enumerate() {
            let hit = best.iter().position(|h| correct(h, truth));
            report += &format!(
                "{}: instance {i} ({:.0} % visible) is hypothesis {hit:?} of {}\n",
                part.name(),
                100.0 * pair.visible_fraction[i],
                best.len()
            );
            assert!(hit.is_some(), "{report}");
        }

        let lone = SceneSpec::new(22)
            .object(id, &mesh)
            .noise(Some(NoiseModel::kinect()))
            .build()
            .unwrap();
        let found = detector
            .detect(&lone.frame.view(), &[&model], &options(5))
            .unwrap();
        let hyps = &found.objects[0].hypotheses;
        assert!(correct(&hyps[0].pose, &lone.ground_truth[0].1), "{report}");
        let apart: Vec<f32> = hyps[1..]
            .iter()
            .map(|h| (h.pose * centre - hyps[0].pose * centre).norm() / d)
            .collect();
        report += &format!(
            "{}: alone, hypotheses 2-{} put its centre {apart:.2?} D from the first's\n",
            part.name(),
            hyps.len()
        );
        // No duplicate of the one instance: no later hypothesis is a correct pose of it, and
        // none puts its centre within a fifth of the diameter of the first's.
        assert!(
            hyps[1..]
                .iter()
                .all(|h| !correct(&h.pose, &lone.ground_truth[0].1)),
            "{report}"
        );
        assert!(apart.iter().all(|&a| a >= 0.2), "{report}");
    }
    eprintln!("{report}");
}
