//! `ppf detect --diagnose` on the real LM-O frame: per object, the scene's points on it and how
//! many of its reference points propose a correct pose, consistent with each other and with the
//! rank the object's right pose reaches. Reads `../shared/data/lmo`; runs whenever the data is
//! there, and always under `CI=true`.

mod common;

use std::path::Path;
use std::process::{Command, Output};

use common::{Scratch, ServedPart};
use ppfd_models::synthetic::parts::Part;

use ppfd_bop::shared_test_data;

/// `ppf detect --dataset <dataset> --scene 2 --image 3 --diagnose --objects <objects>`, building
/// models into `cache`.
fn diagnose(dataset: &Path, objects: &str, cache: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_ppf"))
        .args(["detect", "--dataset"])
        .arg(dataset)
        .args(["--scene", "2", "--image", "3", "--diagnose", "--objects"])
        .arg(objects)
        .env("PPFD_CACHE", cache)
        .output()
        .unwrap()
}

#[test]
fn diagnose_counts_the_reference_points_that_propose_the_right_pose() {
    let Some(dataset) = shared_test_data("lmo") else {
        return;
    };
    let cache = std::env::temp_dir().join(format!("ppf-diagnose-cache-{}", std::process::id()));
    // The driller and the glue are found; the ape is lost at voting.
    let run = diagnose(&dataset, "8,11,1", &cache);
    let _ = std::fs::remove_dir_all(&cache);
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(
        run.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let header: Vec<&str> = stdout
        .lines()
        .find(|l| l.starts_with("| object"))
        .expect("a table")
        .split('|')
        .map(str::trim)
        .collect();
    let column = |name: &str| {
        header
            .iter()
            .position(|h| *h == name)
            .unwrap_or_else(|| panic!("no column {name:?} in {header:?}"))
    };
    let (object, on_object, normal_error, references, lost_at) = (
        column("object"),
        column("on object"),
        column("normal error (median °)"),
        column("reference points on object"),
        column("lost at"),
    );
    let rows: Vec<Vec<&str>> = stdout
        .lines()
        .filter(|l| l.starts_with("| ") && !l.starts_with("| object"))
        .map(|l| l.split('|').map(str::trim).collect())
        .collect();
    assert_eq!(rows.len(), 3, "{stdout}");
    for row in &rows {
        let n = |c: usize| row[c].parse::<f64>().unwrap_or_else(|_| panic!("{row:?}"));
        // Every reference point on the object is one of the cloud's points on it.
        assert!(n(references) <= n(on_object), "{row:?}");
        assert!(n(references) > 0.0, "{row:?}");
        // Normals against the side of the model facing the camera: a median beyond 45° would
        // mean they are compared with the wrong surface.
        assert!(n(normal_error) < 45.0, "{row:?}");
        // The object's stage lines, below its heading.
        let heading = match row[lost_at] {
            "found" => format!("object {}: found", row[object]),
            stage => format!("object {}: lost at {stage}", row[object]),
        };
        let stages: Vec<&str> = stdout
            .lines()
            .skip_while(|l| *l != heading)
            .skip(1)
            .take_while(|l| l.starts_with("  "))
            .map(str::trim_start)
            .collect();
        let stage = |name: &str| {
            stages
                .iter()
                .find(|l| l.split_whitespace().next() == Some(name))
                .copied()
                .unwrap_or_else(|| panic!("no {name} line for object {}: {stdout}", row[object]))
        };
        // The voting line counts the reference points proposing a pose near the target: only
        // reference points on the object can.
        let voting = stage("voting");
        let proposing: f64 = match voting.split_whitespace().nth(1) {
            Some("none") => 0.0,
            w => w
                .and_then(|w| w.parse().ok())
                .unwrap_or_else(|| panic!("{voting}")),
        };
        assert!(proposing <= n(references), "{voting} / {row:?}");
        // An object lost at voting is told by how much: where the target stands among the
        // reference points' peaks, or that it is among none of them.
        if row[object] == "1" {
            assert_eq!(row[lost_at], "voting", "{stdout}");
        }
        if row[lost_at] == "voting" {
            assert!(
                voting.contains("the nearest it comes is a reference point's")
                    || voting.contains("nor is it among the 32 highest peaks"),
                "{voting}"
            );
        }
        // The driller's pose ranks first on this frame: some reference point proposed it, and
        // ICP keeps it first.
        if row[object] == "8" {
            assert_eq!(row[lost_at], "found", "{stdout}");
            assert!(proposing > 0.0, "{voting}");
            let icp: Vec<&str> = stage("ICP").split_whitespace().take(3).collect();
            assert_eq!(icp, ["ICP", "ranks", "1"], "{stdout}");
        }
    }
}

/// An object the frame's ground truth does not hold is refused by name, before any model is
/// built (the diagnosis judges every stage against the truth).
#[test]
fn diagnose_refuses_an_object_without_ground_truth_before_building_models() {
    let Some(dataset) = shared_test_data("lmo") else {
        return;
    };
    let cache = std::env::temp_dir().join(format!("ppf-diagnose-none-{}", std::process::id()));
    // Object 2 has no model file in LM-O either: without the check, the run fails on that
    // instead, after building the driller's model.
    let run = diagnose(&dataset, "8,2", &cache);
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(!run.status.success());
    assert!(
        stderr.contains("object 2 has no ground truth in scene 2 image 3"),
        "{stderr}"
    );
    assert!(!cache.exists(), "no model was built before the refusal");
}

/// `ppf detect --camera … --diagnose-against POSES.JSON --json`: the daemon diagnoses against
/// the poses of the file that are of the objects asked for, and the JSON carries its lines; a
/// file without such a pose is refused before anything is sent.
#[test]
fn a_camera_detection_is_diagnosed_against_the_poses_of_a_file() {
    let scratch = Scratch::new("camera-diagnosis");
    let mut served = ServedPart::start(&scratch, "diagnosis", Part::LBracket, 3);
    let id = served.part.object_id();
    let truth = served.scene.ground_truth[0].1;
    let r = truth.rotation.to_rotation_matrix();
    let m = r.matrix();
    let t = truth.translation.vector;
    let pose = |object_id: u32| {
        format!(
            r#"{{"object_id": {object_id}, "rotation": [{}], "translation_mm": [{}, {}, {}]}}"#,
            (0..3)
                .flat_map(|i| (0..3).map(move |j| (i, j)))
                .map(|(i, j)| m[(i, j)].to_string())
                .collect::<Vec<_>>()
                .join(", "),
            t.x,
            t.y,
            t.z
        )
    };
    // The file holds the part's pose and one of an object the request does not ask for.
    let poses = scratch.join("believed.json");
    std::fs::write(&poses, format!("[{}, {}]", pose(id), pose(id + 40))).unwrap();
    let prefix = served.prefix.clone();
    let detect = |file: &Path| {
        Command::new(env!("CARGO_BIN_EXE_ppf"))
            .args(["detect", "--prefix", &prefix, "--camera", "cam", "--json"])
            .args(["--timeout-ms", "60000", "--objects"])
            .arg(id.to_string())
            .arg("--diagnose-against")
            .arg(file)
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap()
    };
    let out = served.publish_until_done(detect(&poses));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let answer: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    // The latency's parts close: overhead = transport + queue wait + hand-back + response
    // transport, and end to end = detection + overhead.
    let ns = |key: &str| {
        answer["latency"][key]
            .as_u64()
            .unwrap_or_else(|| panic!("no {key} in {stdout}"))
    };
    assert_eq!(
        ns("overhead_ns"),
        ns("transport_ns") + ns("queue_wait_ns") + ns("hand_back_ns") + ns("response_transport_ns")
    );
    assert_eq!(ns("end_to_end_ns"), ns("detection_ns") + ns("overhead_ns"));
    let lines: Vec<&str> = answer["diagnosis"]
        .as_array()
        .unwrap_or_else(|| panic!("no diagnosis in {stdout}"))
        .iter()
        .map(|l| l.as_str().unwrap())
        .collect();
    assert_eq!(
        lines.first(),
        Some(&format!("object {id}: found").as_str()),
        "{stdout}"
    );
    for stage in ["voting", "clustering", "ICP", "filters", "result"] {
        assert!(
            lines.iter().any(|l| l.trim_start().starts_with(stage)),
            "no {stage} line: {stdout}"
        );
    }
    assert!(!lines
        .iter()
        .any(|l| l.contains(&format!("object {}", id + 40))));

    let others = scratch.join("others.json");
    std::fs::write(&others, format!("[{}]", pose(id + 40))).unwrap();
    let out = served.publish_until_done(detect(&others));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(stderr.contains("nothing to diagnose against"), "{stderr}");
}
