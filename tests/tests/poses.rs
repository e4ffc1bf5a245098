//! End to end with the real engine: poses through the whole path (camera process → shared memory
//! → daemon → detect responses) against the ground truth, each test under its own iceoryx2 prefix.
//!
//! - The generated scene (no data files): the daemon maps the models of the generated parts, a
//!   camera process publishes the scene `ppf demo --seed <seed>` shows (all four parts on a
//!   table, Kinect-like noise), and two client processes ask for overlapping sets of parts; every
//!   best pose must be near the truth.
//! - An LM-O object (`../shared/data/synth-lmo-dev`; runs whenever it is there, and must find it
//!   under `CI=true`): the daemon builds the model from the object's PLY mesh itself (its mesh →
//!   model → cache path, which the generated test skips by handing it model files) and finds it
//!   in a frame rendered by another tool.

use std::path::{Path, PathBuf};
use std::time::Duration;

use ppfd_bop::dataset::BopDataset;
use ppfd_models::synthetic::parts::Part;
use ppfd_models::Pose;
use ppfd_tests::{
    depth_checksum, part_model, parts_scene, write_part_models, Prefix, Proc, WorkDir,
};

mod common;
use common::{spawn_camera, CLIENT, DAEMON, STARTUP};

/// Detections are slow next to transport; a loaded CI machine gets plenty.
const DETECTION: Duration = Duration::from_secs(600);

/// A correct pose: translation within this fraction of the object's diameter…
const MAX_TRANSLATION_OF_DIAMETER: f32 = 0.1;
/// …and rotation within this angle (the generated parts have no symmetry to allow for).
const MAX_ROTATION_DEG: f32 = 15.0;

/// Seed of the generated scene: `ppf demo`'s default, so that the test and the README's main
/// command show the same scene.
const SEED: u64 = 1;

/// A daemon with the PPF engine over `models`, models built from meshes cached in `cache`,
/// with `extra` flags.
fn start_daemon(prefix: &Prefix, models: &Path, cache: &Path, extra: &[&str]) -> Proc {
    let mut args = vec![
        "--prefix",
        &prefix.0,
        "--models",
        models.to_str().unwrap(),
        "--model-cache",
        cache.to_str().unwrap(),
        "--housekeeping-ms",
        "100",
        "--max-frame-age-ms",
        "5000",
    ];
    args.extend(extra);
    let mut d = Proc::spawn(Path::new(DAEMON), &args, &[]);
    d.wait_line("ppfd ready", DETECTION);
    d
}

fn errors(est: &Pose, truth: &Pose) -> (f32, f32) {
    (
        (est.translation.vector - truth.translation.vector).norm(),
        est.rotation.angle_to(&truth.rotation).to_degrees(),
    )
}

/// A client process's best pose of one object, from its `pose` lines.
struct Answer {
    client: &'static str,
    object_id: u32,
    score: f32,
    pose: Pose,
    frame: u64,
}

/// Reads a client process's answer up to `done`: its best pose per object.
fn client_answers(c: &mut Proc, name: &'static str) -> Vec<Answer> {
    c.wait_line("client ready", STARTUP);
    let mut frame = 0;
    let mut answers: Vec<Answer> = Vec::new();
    loop {
        let line = c.wait_line("", DETECTION);
        let f: Vec<&str> = line.split(' ').collect();
        match f[0] {
            "done" => return answers,
            "ok" => frame = f[3].parse().unwrap(),
            "pose" => {
                let n: Vec<f32> = f[3..].iter().map(|v| v.parse().unwrap()).collect();
                assert_eq!(n.len(), 13, "client {name}: {line}");
                let h = ppfd_client::PoseHypothesis {
                    rotation: n[1..10].try_into().unwrap(),
                    translation_mm: n[10..13].try_into().unwrap(),
                    ..Default::default()
                };
                let answer = Answer {
                    client: name,
                    object_id: f[1].parse().unwrap(),
                    score: n[0],
                    pose: h.isometry(),
                    frame,
                };
                match answers.iter_mut().find(|a| a.object_id == answer.object_id) {
                    Some(a) if a.score < answer.score => *a = answer,
                    Some(_) => {}
                    None => answers.push(answer),
                }
            }
            _ => panic!("client {name} was refused: {line}"),
        }
    }
}

/// A camera process publishing the generated scene of `seed` (`ppf demo --seed`) as `parts`,
/// with Kinect-like noise when `noisy`.
fn parts_camera(prefix: &Prefix, seed: u64, noisy: bool) -> Proc {
    let seed = seed.to_string();
    let mut args = vec!["--fps", "5", "--parts-seed", &seed];
    if !noisy {
        args.extend(["--noise", "none"]);
    }
    spawn_camera(prefix, "parts", &args)
}

/// A client process asking camera `parts` for `objects` (`a,b`), with `extra` flags.
fn parts_client(prefix: &Prefix, objects: &str, extra: &[&str]) -> Proc {
    let mut args = vec![
        "--prefix",
        &prefix.0,
        "--camera",
        "parts",
        "--objects",
        objects,
        "--wait-frame-ms",
        "20000",
        "--timeout-ms",
        "600000",
    ];
    args.extend(extra);
    Proc::spawn(Path::new(CLIENT), &args, &[])
}

/// The generated scene of `seed` through the whole path: client A asks for parts 1, 2, 3 and
/// client B, at the same time, for parts 3 and 4; every best pose must be within the tolerances.
fn generated_scene_through_the_whole_path(test: &str, seed: u64, noisy: bool) {
    let scene = parts_scene(seed, noisy);
    let prefix = Prefix::new(test);
    let work = WorkDir::new(test);
    let diameters = write_part_models(&work.join("models"));
    let _daemon = start_daemon(&prefix, &work.join("models"), &work.join("cache"), &[]);
    // The model files overwritten in place while the daemon holds their models (a redeploy by
    // `cp`): the daemon holds copies, so this changes nothing (a map of the files themselves
    // would take it down with SIGBUS at the first detection).
    for entry in std::fs::read_dir(work.join("models")).unwrap() {
        std::fs::write(entry.unwrap().path(), b"overwritten").unwrap();
    }

    let mut cam = parts_camera(&prefix, seed, noisy);
    let published = cam.wait_line("scene ", STARTUP);
    let expected = format!("scene {:016x}", depth_checksum(&scene.frame.depth));
    assert_eq!(
        published, expected,
        "the camera process generated another frame than the test's"
    );
    cam.wait_line("camera ready", STARTUP);

    let client = |objects: &str| parts_client(&prefix, objects, &["--hypotheses", "1", "--poses"]);
    let requests: [(&'static str, &[u32]); 2] = [("A", &[1, 2, 3]), ("B", &[3, 4])];
    let mut procs: Vec<Proc> = requests
        .iter()
        .map(|(_, ids)| {
            let ids: Vec<String> = ids.iter().map(u32::to_string).collect();
            client(&ids.join(","))
        })
        .collect();
    let answers: Vec<Vec<Answer>> = procs
        .iter_mut()
        .zip(&requests)
        .map(|(p, (name, _))| client_answers(p, name))
        .collect();

    let mut table = format!(
        "generated scene, seed {seed}{}: best pose per requested part \
         (correct: dt <= {MAX_TRANSLATION_OF_DIAMETER} D and dR <= {MAX_ROTATION_DEG} deg)\n\
         {:<6} {:>3} {:<16} {:>7} {:>6} {:>8} {:>7} {:>8} {:>6} {:>6}  verdict\n",
        if noisy {
            ", Kinect-like noise"
        } else {
            ", no noise"
        },
        "client",
        "id",
        "part",
        "visible",
        "D mm",
        "dt mm",
        "dt/D",
        "dR deg",
        "score",
        "frame",
    );
    let (mut wrong, mut asked) = (0, 0);
    for ((name, ids), answers) in requests.iter().zip(&answers) {
        for &id in *ids {
            asked += 1;
            let index = scene
                .ground_truth
                .iter()
                .position(|g| g.0 == id)
                .expect("the part is in the scene");
            let part = Part::from_object_id(id).unwrap();
            let d = diameters[Part::ALL.iter().position(|p| *p == part).unwrap()];
            let visible = scene.visible_fraction[index];
            let head = format!(
                "{name:<6} {id:>3} {:<16} {visible:>7.2} {d:>6.0}",
                part.name()
            );
            match answers.iter().find(|a| a.object_id == id) {
                Some(a) => {
                    let (dt, dr) = errors(&a.pose, &scene.ground_truth[index].1);
                    let ok = dt <= MAX_TRANSLATION_OF_DIAMETER * d && dr <= MAX_ROTATION_DEG;
                    wrong += usize::from(!ok);
                    table += &format!(
                        "{head} {dt:>8.1} {:>7.3} {dr:>8.1} {:>6.3} {:>6}  {}\n",
                        dt / d,
                        a.score,
                        a.frame,
                        if ok { "ok" } else { "WRONG" },
                    );
                    assert_eq!(a.client, *name);
                }
                None => {
                    wrong += 1;
                    table += &format!("{head}  no hypothesis  WRONG\n");
                }
            }
        }
        assert!(
            answers.iter().all(|a| ids.contains(&a.object_id)),
            "client {name} got poses of objects it did not ask for"
        );
    }
    eprintln!("{table}");
    assert!(wrong == 0, "{wrong} of {asked} poses wrong\n{table}");
}

#[test]
fn generated_scene_poses_through_the_whole_path_match_the_ground_truth() {
    generated_scene_through_the_whole_path("gen_poses", SEED, true);
}

/// Hints through the daemon: of the generated scene's parts 1, 2 and 3, the first two hinted at
/// their true poses come back from their hints (check bit `HINT`) without voting for them, and
/// part 3, hinted 0.8 of its diameter off, fails its hint and is found by voting. Hints below
/// the request's minimum score fail. A hint with a NaN, or one for an object not asked for, is
/// refused with what is wrong, and the daemon serves on.
/// The generated scene served: a daemon over the parts' models, a camera publishing the scene,
/// and a client, under a prefix of their own.
struct PartsServed {
    scene: ppfd_models::synthetic::scene::SyntheticScene,
    diameters: Vec<f32>,
    client: ppfd_client::Client,
    _camera: Proc,
    _daemon: Proc,
    _work: WorkDir,
    _prefix: Prefix,
}

impl PartsServed {
    fn start(test: &str) -> PartsServed {
        let scene = parts_scene(SEED, true);
        let prefix = Prefix::new(test);
        let work = WorkDir::new(test);
        let diameters = write_part_models(&work.join("models"));
        let daemon = start_daemon(&prefix, &work.join("models"), &work.join("cache"), &[]);
        let mut camera = parts_camera(&prefix, SEED, true);
        camera.wait_line("camera ready", STARTUP);
        let client = ppfd_client::Client::connect_with(&ppfd_client::ClientOptions {
            prefix: Some(prefix.0.clone()),
            ..Default::default()
        })
        .unwrap();
        PartsServed {
            scene,
            diameters,
            client,
            _camera: camera,
            _daemon: daemon,
            _work: work,
            _prefix: prefix,
        }
    }
}

/// `pose` of object `id` as the wire carries it.
fn hint(id: u32, pose: Pose) -> ppfd_client::PoseHint {
    ppfd_client::PoseHint::from_isometry(id, &pose)
}

#[test]
fn hinted_parts_come_back_from_their_hints_and_a_wrong_hint_from_voting() {
    use ppfd_client::checks;
    let served = PartsServed::start("gen_hints");
    let (scene, diameters, client) = (&served.scene, &served.diameters, &served.client);
    let options = ppfd_client::DetectOptions {
        timeout: DETECTION,
        ..Default::default()
    };
    let truth = |id: u32| scene.ground_truth.iter().find(|g| g.0 == id).unwrap().1;
    let d3 = diameters[2];
    let mut off = truth(3);
    off.translation.vector.x += 0.8 * d3;
    let hinted = ppfd_client::DetectOptions {
        hints: vec![hint(1, truth(1)), hint(2, truth(2)), hint(3, off)],
        ..options.clone()
    };
    let found = loop {
        match client.detect("parts", &[1, 2, 3], &hinted) {
            Err(ppfd_client::Error::Refused {
                status: ppfd_client::Status::NoFrame | ppfd_client::Status::UnknownCamera,
                ..
            }) => std::thread::sleep(Duration::from_millis(50)),
            answer => break answer.expect("detections"),
        }
    };
    let mut report = String::new();
    for (id, d) in [(1, diameters[0]), (2, diameters[1]), (3, d3)] {
        let best = found
            .best(id)
            .unwrap_or_else(|| panic!("no pose of part {id}"));
        let (dt, dr) = errors(&best.isometry(), &truth(id));
        report += &format!(
            "part {id}: checks {:#b}, {dt:.1} mm, {dr:.1} deg\n",
            best.checks
        );
        let from_hint = best.checks & checks::HINT != 0;
        assert_eq!(from_hint, id != 3, "{report}");
        assert!(
            dt <= MAX_TRANSLATION_OF_DIAMETER * d && dr <= MAX_ROTATION_DEG,
            "{report}"
        );
    }
    // Only part 3 voted: fewer reference points than the three parts voting.
    let voted = client.detect("parts", &[1, 2, 3], &options).unwrap();
    assert!(
        0 < found.counts.reference_points
            && found.counts.reference_points < voted.counts.reference_points,
        "{report}{:?} {:?}",
        found.counts,
        voted.counts
    );
    // The request's minimum score holds for hints too: above what parts 1 and 2 scored from
    // their hints, their hints fail, and voting returns nothing below it either.
    let best_hinted = [1, 2]
        .map(|id| found.best(id).unwrap().score)
        .into_iter()
        .fold(0f32, f32::max);
    let min_score = (best_hinted + 0.01).min(1.0);
    let demanding = ppfd_client::DetectOptions {
        requirements: ppfd_client::Requirements {
            min_score,
            ..Default::default()
        },
        hints: hinted.hints[..2].to_vec(),
        ..options.clone()
    };
    let strict = client.detect("parts", &[1, 2], &demanding).unwrap();
    report += &format!(
        "at least {min_score}: {:?}\n",
        strict
            .hypotheses
            .iter()
            .map(|h| (h.object_id, h.checks, h.score))
            .collect::<Vec<_>>()
    );
    assert!(
        strict
            .hypotheses
            .iter()
            .all(|h| h.checks & checks::HINT == 0 && h.score >= min_score),
        "{report}"
    );
    assert!(strict.counts.reference_points > 0, "{report}");
    eprintln!("{report}");

    let refusal = |header: &ppfd_client::protocol::detect::DetectRequestHeader| match client
        .send_raw(header, &[], DETECTION)
    {
        Err(ppfd_client::Error::Refused {
            status, message, ..
        }) => (status, message),
        other => panic!("expected a refusal, got {other:?}"),
    };
    let mut header = ppfd_client::protocol::detect::DetectRequestHeader {
        camera_name: ppfd_client::protocol::text::encode_name("camera", "parts").unwrap(),
        ..Default::default()
    };
    header.set_objects(&[1, 2]).unwrap();
    header.hints[0] = hint(1, truth(1));
    header.hints[0].translation_mm[0] = f32::NAN;
    header.hint_count = 1;
    let (status, message) = refusal(&header);
    assert_eq!(status, ppfd_client::Status::InvalidRequest);
    assert!(
        message.starts_with("hint 0 for object 1 is not a pose"),
        "{message}"
    );
    header.hints[0] = hint(4, truth(4));
    let (_, message) = refusal(&header);
    assert_eq!(
        message,
        "hint 0 is for object 4, which the request does not ask for"
    );
    assert!(client.detect("parts", &[1], &options).is_ok());
}

#[test]
fn lmo_object_built_from_its_mesh_by_the_daemon_is_found_through_the_whole_path() {
    let Some(root) = ppfd_bop::shared_test_data("synth-lmo-dev") else {
        return;
    };
    let dataset = BopDataset::open(&root).unwrap();
    let (scene, image) = (dataset.scene_ids()[0], 0);
    let image = dataset
        .image_ids(scene)
        .unwrap()
        .first()
        .copied()
        .unwrap_or(image);
    let truth = dataset.ground_truth(scene, image).unwrap().to_vec();
    let info = dataset.ground_truth_info(scene, image).unwrap().to_vec();
    // The well visible objects: a depth-only method cannot be asked to find a sliver.
    let wanted: Vec<(u32, Pose, f32)> = truth
        .iter()
        .zip(&info)
        .filter(|(_, i)| i.visib_fract >= 0.6)
        .map(|(g, _)| {
            (
                g.obj_id,
                g.pose,
                dataset.model_info(g.obj_id).unwrap().diameter_mm,
            )
        })
        .take(1)
        .collect();
    assert!(
        !wanted.is_empty(),
        "scene {scene} image {image} has no well visible object"
    );

    let prefix = Prefix::new("lmo_poses");
    let work = WorkDir::new("lmo-poses");
    let models = work.join("models");
    std::fs::create_dir_all(&models).unwrap();
    for (id, _, _) in &wanted {
        let mesh = std::fs::canonicalize(dataset.model_path(*id).unwrap()).unwrap();
        std::os::unix::fs::symlink(&mesh, models.join(mesh.file_name().unwrap())).unwrap();
    }
    let _daemon = start_daemon(&prefix, &models, &work.join("cache"), &[]);
    let (scene_s, image_s) = (scene.to_string(), image.to_string());
    let mut cam = spawn_camera(
        &prefix,
        "synth",
        &[
            "--fps",
            "5",
            "--bop",
            root.to_str().unwrap(),
            "--scene",
            &scene_s,
            "--image",
            &image_s,
        ],
    );
    cam.wait_line("camera ready", STARTUP);
    cam.wait_line("frame 2", STARTUP);

    let ids: Vec<u32> = wanted.iter().map(|w| w.0).collect();
    let client = ppfd_client::Client::connect_with(&ppfd_client::ClientOptions {
        prefix: Some(prefix.0.clone()),
        ..Default::default()
    })
    .unwrap();
    let options = ppfd_client::DetectOptions {
        hypotheses_per_object: 3,
        timeout: DETECTION,
        ..Default::default()
    };
    let found = client.detect("synth", &ids, &options).expect("detections");
    eprintln!("latency: {:?}", found.latency);
    for (id, truth, diameter) in &wanted {
        let best = found
            .best(*id)
            .unwrap_or_else(|| panic!("no hypothesis for object {id}"));
        // Against the equivalent of the pose closest to the truth, under the object's symmetries
        // in `models_info.json`.
        let symmetry = dataset.symmetry(*id).unwrap();
        let pose = symmetry.closest_equivalent(&best.isometry(), &truth.rotation);
        let (dt, dr) = errors(&pose, truth);
        eprintln!(
            "object {id}: dt {dt:.1} mm, dR {dr:.1} deg, score {:.3}",
            best.score
        );
        assert!(
            dt < MAX_TRANSLATION_OF_DIAMETER * diameter && dr < MAX_ROTATION_DEG,
            "object {id}: off by {dt:.1} mm (diameter {diameter:.0}) and {dr:.1}°"
        );
    }
    assert!(
        found.latency.daemon.detection_ns > 0
            && found.latency.end_to_end_ns >= found.latency.daemon.detection_ns
    );
    assert!(
        found.counts.scene_points > 0 && found.counts.pairs > 0,
        "{:?}",
        found.counts
    );
}

/// Detector parameters given to the daemon (`--set`, or the configuration file's `[detector]`
/// table) are the ones its engine detects with: with every fourth candidate a reference point,
/// the daemon reports as many reference points as the detector run in this process with that
/// setting, and fewer than with every second.
#[test]
fn detector_parameters_given_to_the_daemon_are_the_ones_it_detects_with() {
    use ppfd_models::detect::detector::{DetectParams, Detector, RunOptions};
    let test = "daemon_params";
    let scene = parts_scene(SEED, true);
    let part = Part::ALL[0];
    let model = part_model(part);
    let reference_points = |step: &str| {
        let mut params = DetectParams::new();
        params.set("voting.reference_step", step).unwrap();
        let found = Detector::new(params)
            .detect(&scene.frame.view(), &[&model], &RunOptions::default())
            .unwrap();
        found.counts.reference_points
    };
    let (every_second, every_fourth) = (reference_points("2"), reference_points("4"));

    let prefix = Prefix::new(test);
    let work = WorkDir::new(test);
    write_part_models(&work.join("models"));
    let config = work.join("ppfd.toml");
    // The file asks for every third point; the flag, which comes after it, for every fourth.
    std::fs::write(&config, "[detector]\nvoting.reference_step = 3\n").unwrap();
    let _daemon = start_daemon(
        &prefix,
        &work.join("models"),
        &work.join("cache"),
        &[
            "--config",
            config.to_str().unwrap(),
            "--set",
            "voting.reference_step=4",
        ],
    );
    let mut cam = parts_camera(&prefix, SEED, true);
    cam.wait_line("camera ready", STARTUP);
    let mut client = parts_client(&prefix, &part.object_id().to_string(), &[]);
    client.wait_line("client ready", STARTUP);
    let ok = client.wait_line("", DETECTION);
    let fields: Vec<&str> = ok.split(' ').collect();
    assert_eq!(fields[0], "ok", "{ok}");
    let served: u32 = fields[4].parse().unwrap();
    eprintln!(
        "reference points: daemon {served}; this process, every 4th point {every_fourth}, \
         every 2nd {every_second}"
    );
    assert_eq!(served, every_fourth);
    assert!(every_fourth < every_second);
    // The daemon says which parameters it runs with: the flag's value, which won.
    let (_, detector) = ppfd_client::Client::connect_with(&ppfd_client::ClientOptions {
        prefix: Some(prefix.0.clone()),
        ..Default::default()
    })
    .unwrap()
    .statistics()
    .expect("statistics");
    assert_eq!(detector, "detector: voting.reference_step=4");
}

/// A daemon given a detector parameter it does not know, or a bad value, says which and does
/// not start.
#[test]
fn the_daemon_refuses_unknown_detector_parameters_at_start() {
    let prefix = Prefix::new("daemon_bad_params");
    for (flag, said) in [
        ("voting.reference_steps=4", "voting.reference_steps"),
        ("filters.min_silhouette_fraction=NaN", "finite"),
    ] {
        let out = std::process::Command::new(DAEMON)
            .args(["--prefix", &prefix.0, "--set", flag])
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{flag}: {stderr}");
        assert!(stderr.contains(said), "{flag}: {stderr}");
        assert!(
            !String::from_utf8_lossy(&out.stdout).contains("ppfd ready"),
            "{flag}"
        );
    }
}

/// A mesh of the models folder that does not load (one in metres) is counted in the ready line,
/// and a request for its object is told why, beside the ids that are loaded.
#[test]
fn a_request_for_an_object_whose_mesh_did_not_load_is_told_why() {
    let prefix = Prefix::new("failed_mesh");
    let work = WorkDir::new("failed-mesh");
    let (models, cache) = (work.join("models"), work.join("cache"));
    std::fs::create_dir_all(&models).unwrap();
    let part = Part::ALL[0];
    let good = models.join(format!("obj_{:06}.ply", part.object_id()));
    std::fs::write(&good, part.mesh().to_ply_ascii()).unwrap();
    let mut metres = Part::ALL[1].mesh();
    metres.scale(0.001);
    let broken = models.join("obj_000007.ply");
    std::fs::write(&broken, metres.to_ply_ascii()).unwrap();
    let mut daemon = Proc::spawn(
        Path::new(DAEMON),
        &["--prefix", &prefix.0, "--models", models.to_str().unwrap()],
        &[("PPFD_CACHE", cache.to_str().unwrap())],
    );
    let ready = daemon.wait_line("ppfd ready", DETECTION);
    assert!(ready.contains("models=1 failed=1"), "{ready}");
    let mut camera = spawn_camera(&prefix, "cam0", &["--fps", "20"]);
    camera.wait_line("camera ready", STARTUP);
    let client = ppfd_client::Client::connect_with(&ppfd_client::ClientOptions {
        prefix: Some(prefix.0.clone()),
        ..Default::default()
    })
    .unwrap();
    match client.detect("cam0", &[part.object_id(), 7], &plain_options()) {
        Err(ppfd_client::Error::Refused {
            status, message, ..
        }) => {
            assert_eq!(status, ppfd_client::Status::UnknownObject, "{message}");
            assert!(
                message.starts_with(&format!(
                    "unknown object id 7: loaded are {}; {} did not load: ",
                    part.object_id(),
                    broken.display()
                )) && message.contains("metres"),
                "{message}"
            );
        }
        other => panic!("expected a refusal, got {other:?}"),
    }
}

/// A load refused at run time is logged whole, where its answer is cut to fit: a loading
/// script's journal says why.
#[test]
fn a_refused_load_is_logged_whole() {
    use std::io::BufRead;
    let prefix = Prefix::new("load_log");
    let work = WorkDir::new("load-log");
    let models = work.join("models");
    std::fs::create_dir_all(&models).unwrap();
    let deep = work.join("l".repeat(150));
    std::fs::create_dir_all(&deep).unwrap();
    let garbage = deep.join("obj_000040.ply");
    std::fs::write(&garbage, "x".repeat(600)).unwrap();
    let log = work.join("ppfd.log");
    let mut daemon = std::process::Command::new(DAEMON)
        .args(["--prefix", &prefix.0, "--models", models.to_str().unwrap()])
        .env("PPFD_CACHE", work.join("cache"))
        .stdout(std::process::Stdio::piped())
        .stderr(std::fs::File::create(&log).unwrap())
        .spawn()
        .unwrap();
    let mut lines = std::io::BufReader::new(daemon.stdout.take().unwrap()).lines();
    assert!(
        lines.any(|l| l.is_ok_and(|l| l.starts_with("ppfd ready"))),
        "the daemon did not start"
    );
    let client = ppfd_client::Client::connect_with(&ppfd_client::ClientOptions {
        prefix: Some(prefix.0.clone()),
        ..Default::default()
    })
    .unwrap();
    let answered = match client.load_model(garbage.to_str().unwrap(), 0) {
        Err(ppfd_client::Error::Refused { message, .. }) => message,
        other => panic!("expected a refusal, got {other:?}"),
    };
    drop(client);
    // SAFETY: a signal to the child this test started.
    unsafe { libc::kill(daemon.id() as i32, libc::SIGTERM) };
    daemon.wait().unwrap();
    let logged = std::fs::read_to_string(&log).unwrap();
    let line = logged
        .lines()
        .find(|l| l.contains("control request refused"))
        .unwrap_or_else(|| panic!("no refusal logged: {logged}"));
    assert!(answered.ends_with('…'), "the answer is cut: {answered}");
    let whole = answered.trim_end_matches('…');
    assert!(
        line.contains(whole) && line.len() > line.find(whole).unwrap() + whole.len() + 20,
        "the log has the whole reason: {line}\nanswered: {answered}"
    );
}

/// A daemon without `--model-cache` saves the models it builds from meshes in the user's cache
/// (`$PPFD_CACHE` here), not beside the meshes: a dataset's folder may be read-only (then every
/// start rebuilt every model) or shared, and a daemon running as root wrote into it anyway. The
/// second start takes the saved model as it is.
#[test]
fn models_built_from_meshes_are_cached_outside_the_models_folder() {
    let prefix = Prefix::new("default_cache");
    let work = WorkDir::new("default-cache");
    let (models, cache) = (work.join("models"), work.join("cache"));
    std::fs::create_dir_all(&models).unwrap();
    let part = Part::ALL[0];
    let mesh_file = models.join(format!("{}_{:06}.ply", part.name(), part.object_id()));
    std::fs::write(&mesh_file, part.mesh().to_ply_ascii()).unwrap();
    let cache_s = cache.to_str().unwrap().to_owned();
    let start = || {
        let mut d = Proc::spawn(
            Path::new(DAEMON),
            &["--prefix", &prefix.0, "--models", models.to_str().unwrap()],
            &[("PPFD_CACHE", cache_s.as_str())],
        );
        d.wait_line("ppfd ready", DETECTION);
        let client = ppfd_client::Client::connect_with(&ppfd_client::ClientOptions {
            prefix: Some(prefix.0.clone()),
            ..Default::default()
        })
        .unwrap();
        let listed = client.models().expect("models listed");
        assert_eq!(
            listed.iter().map(|m| m.object_id).collect::<Vec<_>>(),
            [part.object_id()]
        );
        d
    };
    let list = |dir: &Path| -> Vec<PathBuf> {
        let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
            .map(|r| r.map(|e| e.unwrap().path()).collect())
            .unwrap_or_default();
        v.sort();
        v
    };
    let daemon = start();
    drop(daemon);
    assert_eq!(
        list(&models),
        std::slice::from_ref(&mesh_file),
        "nothing beside the mesh"
    );
    let cached = list(&cache);
    assert_eq!(cached.len(), 1, "{cached:?}");
    assert_eq!(cached[0].extension().unwrap(), "ppfm");
    let built = std::fs::metadata(&cached[0]).unwrap().modified().unwrap();
    let daemon = start();
    drop(daemon);
    assert_eq!(list(&cache), cached);
    assert_eq!(
        std::fs::metadata(&cached[0]).unwrap().modified().unwrap(),
        built,
        "the second start rebuilt the model"
    );
    assert_eq!(list(&models), [mesh_file]);
}

/// What a request asks of the answer, end to end with the real engine: each value out of its
/// range is refused with a message naming it and its range (sent raw, past the client's own
/// check, which refuses them before sending), a region outside the camera's frame is refused
/// by the engine, the daemon keeps serving, and a request for the parts nearest first above a
/// minimum score gets them so.
#[test]
fn request_requirements_are_checked_by_the_daemon_and_served() {
    use ppfd_client::protocol::detect::DetectRequestHeader;
    use ppfd_client::protocol::text;
    use ppfd_client::{checks, order, DetectOptions, Requirements, Status};
    let test = "requirements";
    let prefix = Prefix::new(test);
    let work = WorkDir::new(test);
    let diameters = write_part_models(&work.join("models"));
    let _daemon = start_daemon(&prefix, &work.join("models"), &work.join("cache"), &[]);
    let mut cam = parts_camera(&prefix, SEED, true);
    cam.wait_line("camera ready", STARTUP);
    let client = ppfd_client::Client::connect_with(&ppfd_client::ClientOptions {
        prefix: Some(prefix.0.clone()),
        ..Default::default()
    })
    .unwrap();
    let part = Part::ALL[0];
    let mut good = DetectRequestHeader {
        camera_name: text::encode_name("camera", "parts").unwrap(),
        ..Default::default()
    };
    good.set_objects(&[part.object_id()]).unwrap();
    let refused = |change: &dyn Fn(&mut Requirements)| {
        let mut header = good;
        change(&mut header.requirements);
        let mut options = DetectOptions {
            timeout: DETECTION,
            ..Default::default()
        };
        change(&mut options.requirements);
        // The client library refuses it before sending…
        match client.detect("parts", &[part.object_id()], &options) {
            Err(ppfd_client::Error::Protocol(_)) => {}
            other => panic!("the client sent a bad request: {other:?}"),
        }
        // …and the daemon, sent raw.
        match client.send_raw(&header, &[], DETECTION) {
            Err(ppfd_client::Error::Refused {
                status, message, ..
            }) => {
                assert_eq!(status, Status::InvalidRequest, "{message}");
                message
            }
            other => panic!("expected a refusal, got {other:?}"),
        }
    };
    let m = refused(&|r| r.min_score = 1.5);
    assert!(
        m.contains("minimum score 1.5") && m.contains("0 to 1"),
        "{m}"
    );
    let m = refused(&|r| r.instance_distance_fraction = 3.0);
    assert!(
        m.contains("instance distance 3") && m.contains("at most 2"),
        "{m}"
    );
    let m = refused(&|r| r.order = 9);
    assert!(m.contains("order 9"), "{m}");
    let m = refused(&|r| r.region_of_interest.width = 50);
    assert!(m.contains("region of interest 50x0"), "{m}");
    let m = refused(&|r| r.pose_restriction.max_angle_deg = 270.0);
    assert!(m.contains("270 degrees") && m.contains("0 to 180"), "{m}");
    let m = refused(&|r| {
        r.pose_restriction.max_angle_deg = 30.0;
        r.pose_restriction.camera_direction = [0.0, f32::NAN, 0.0];
    });
    assert!(m.contains("camera direction"), "{m}");

    // In range, but outside the camera's 640 × 480 frame: only the frame tells.
    let mut outside = good;
    outside.requirements.region_of_interest = ppfd_client::RegionOfInterest {
        x: 600,
        y: 0,
        width: 100,
        height: 10,
    };
    // The camera's first frame may not have reached the daemon yet.
    let answer = loop {
        match client.send_raw(&outside, &[], DETECTION) {
            Err(ppfd_client::Error::Refused {
                status: Status::NoFrame | Status::UnknownCamera,
                ..
            }) => std::thread::sleep(Duration::from_millis(50)),
            answer => break answer,
        }
    };
    match answer {
        Err(ppfd_client::Error::Refused {
            status, message, ..
        }) => {
            assert_eq!(status, Status::InvalidRequest, "{message}");
            assert!(message.contains("outside the 640x480 frame"), "{message}");
        }
        other => panic!("expected a refusal, got {other:?}"),
    }

    let ids: Vec<u32> = Part::ALL.iter().map(|p| p.object_id()).collect();
    let mut options = DetectOptions {
        hypotheses_per_object: 4,
        timeout: DETECTION,
        ..Default::default()
    };
    let plain = client.detect("parts", &ids, &options).expect("served");
    let mut scores: Vec<f32> = plain.hypotheses.iter().map(|h| h.score).collect();
    scores.sort_by(f32::total_cmp);
    // Just above the lowest score: that pose goes, and enough stay to have an order.
    let min_score = (scores[0] + scores[1]) / 2.0;
    assert!(scores[0] < min_score && min_score < scores[1], "{scores:?}");
    options.requirements = Requirements {
        min_score,
        order: order::DISTANCE,
        ..Default::default()
    };
    let found = client.detect("parts", &ids, &options).expect("served");
    assert!(!found.hypotheses.is_empty());
    // The daemon orders by the distance of the model's bounding-sphere centre; a part's origin is
    // its bounding-box centre, which lies within a few millimetres of it.
    let distance = |h: &ppfd_client::PoseHypothesis| {
        let t = h.translation_mm;
        (t[0] * t[0] + t[1] * t[1] + t[2] * t[2]).sqrt()
    };
    let tiers = |h: &ppfd_client::PoseHypothesis| {
        (h.checks & (checks::CONSISTENT | checks::SILHOUETTE)).count_ones()
    };
    let mut ordered = 0;
    for (&id, &diameter) in ids.iter().zip(&diameters) {
        let poses: Vec<_> = found.of(id).collect();
        assert!(poses.iter().all(|h| h.score >= min_score), "{poses:?}");
        // Nearest first among the poses that passed as many filters; those that passed fewer
        // come after, as with the best score first.
        for pair in poses.windows(2) {
            if tiers(pair[0]) == tiers(pair[1]) {
                assert!(
                    distance(pair[0]) <= distance(pair[1]) + 0.02 * diameter,
                    "object {id}: {pair:?}"
                );
                ordered += 1;
            }
        }
    }
    assert!(ordered > 0, "no two poses of one object to order");
}

/// A diagnosing request through the daemon: per object with a pose, the stages one by one
/// against it. Parts 1 and 2 against their true poses are found, with a line per stage; part 3
/// against a pose where it is not is lost at a stage; an object without a pose is not
/// diagnosed. A request with hints as well is refused by the client, and one with the flag
/// but no pose by the daemon.
#[test]
fn a_diagnosis_through_the_daemon_says_where_each_object_is_lost() {
    let served = PartsServed::start("gen_diagnose");
    let (scene, diameters, client) = (&served.scene, &served.diameters, &served.client);
    let truth = |id: u32| scene.ground_truth.iter().find(|g| g.0 == id).unwrap().1;
    let mut away = truth(3);
    away.translation.vector.z += 3.0 * diameters[2];
    let options = ppfd_client::DetectOptions {
        timeout: DETECTION,
        diagnose: vec![hint(1, truth(1)), hint(2, truth(2)), hint(3, away)],
        ..Default::default()
    };
    let found = loop {
        match client.detect("parts", &[1, 2, 3, 4], &options) {
            Err(ppfd_client::Error::Refused {
                status: ppfd_client::Status::NoFrame | ppfd_client::Status::UnknownCamera,
                ..
            }) => std::thread::sleep(Duration::from_millis(50)),
            answer => break answer.expect("detections"),
        }
    };
    let text = found.diagnosis.clone();
    eprintln!("{text}");
    let lines: Vec<&str> = text.lines().collect();
    let section = |id: u32| -> Vec<&str> {
        let head = format!("object {id}:");
        let Some(start) = lines.iter().position(|l| l.starts_with(&head)) else {
            return Vec::new();
        };
        lines[start..]
            .iter()
            .enumerate()
            .take_while(|(i, l)| *i == 0 || l.starts_with("  "))
            .map(|(_, l)| *l)
            .collect()
    };
    for id in [1, 2] {
        let s = section(id);
        assert_eq!(
            s.first(),
            Some(&format!("object {id}: found").as_str()),
            "{text}"
        );
        for stage in [
            "voting",
            "clustering",
            "re-scoring",
            "ICP",
            "filters",
            "result",
        ] {
            assert!(
                s.iter().any(|l| l.trim_start().starts_with(stage)),
                "no {stage} line for part {id}:\n{text}"
            );
        }
    }
    let s3 = section(3);
    assert!(
        s3.first()
            .is_some_and(|l| l.starts_with("object 3: lost at ")),
        "{text}"
    );
    assert!(section(4).is_empty(), "{text}");
    // The detection itself ran from scratch and answered every object.
    for id in [1, 2, 3, 4] {
        assert!(found.best(id).is_some(), "no pose of part {id}");
    }
    let plain = client.detect("parts", &[1], &plain_options()).unwrap();
    assert_eq!(plain.diagnosis, "");

    let both = ppfd_client::DetectOptions {
        hints: vec![hint(1, truth(1))],
        ..options.clone()
    };
    match client.detect("parts", &[1, 2, 3], &both) {
        Err(ppfd_client::Error::Protocol(e)) => assert!(
            e.to_string()
                .contains("cannot both carry hints and ask for a diagnosis"),
            "{e}"
        ),
        other => panic!("expected the client to refuse, got {other:?}"),
    }
    let mut header = ppfd_client::protocol::detect::DetectRequestHeader {
        camera_name: ppfd_client::protocol::text::encode_name("camera", "parts").unwrap(),
        flags: ppfd_client::protocol::detect::flags::DIAGNOSE,
        ..Default::default()
    };
    header.set_objects(&[1]).unwrap();
    match client.send_raw(&header, &[], DETECTION) {
        Err(ppfd_client::Error::Refused {
            status, message, ..
        }) => {
            assert_eq!(status, ppfd_client::Status::InvalidRequest);
            assert!(message.contains("no pose to diagnose against"), "{message}");
        }
        other => panic!("expected a refusal, got {other:?}"),
    }
    assert!(client.detect("parts", &[1], &plain_options()).is_ok());
}

fn plain_options() -> ppfd_client::DetectOptions {
    ppfd_client::DetectOptions {
        timeout: DETECTION,
        ..Default::default()
    }
}
