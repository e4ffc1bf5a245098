//! `ppf eval` refuses a results file it cannot write before it detects anything, and leaves the
//! file as it was when it fails before the first image (a run over a
//! dataset takes minutes to hours). Reads `../shared/data/lmo`; runs whenever the data is there,
//! and always under `CI=true`.

use std::path::PathBuf;
use std::process::Command;

use ppfd_bop::shared_test_data;

#[test]
fn an_unwritable_results_file_is_refused_before_any_detection() {
    let Some(dataset) = shared_test_data("lmo") else {
        return;
    };
    let out = std::env::temp_dir()
        .join(format!("ppf-eval-missing-{}", std::process::id()))
        .join("results.csv");
    let cache = std::env::temp_dir().join(format!("ppf-eval-cache-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&cache);
    let run = Command::new(env!("CARGO_BIN_EXE_ppf"))
        .arg("eval")
        .arg(&dataset)
        .arg("--out")
        .arg(&out)
        // A cache of the test's own, which nothing may be written to.
        .env("PPFD_CACHE", &cache)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(!run.status.success());
    assert!(
        stderr.contains("results.csv") && stderr.contains("No such file"),
        "{stderr}"
    );
    assert!(
        !stderr.contains("estimates"),
        "nothing was detected: {stderr}"
    );
    let built = std::fs::read_dir(&cache).map_or(0, |d| d.count());
    let _ = std::fs::remove_dir_all(&cache);
    assert_eq!(built, 0, "no model was built before the refusal");
}

/// A run that fails before its first image (here: an object the dataset has no model of) leaves
/// no results file behind, and an existing one as it was.
#[test]
fn a_run_that_fails_before_any_image_leaves_the_results_file_as_it_was() {
    let Some(dataset) = shared_test_data("lmo") else {
        return;
    };
    let dir = std::env::temp_dir().join(format!("ppf-eval-early-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let eval = |out: &PathBuf, extra: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_ppf"))
            .arg("eval")
            .arg(&dataset)
            .arg("--out")
            .arg(out)
            .args(extra)
            .env("PPFD_CACHE", dir.join("cache"))
            .output()
            .unwrap()
    };
    let fresh = dir.join("fresh.csv");
    let run = eval(&fresh, &["--objects", "999"]);
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(!run.status.success());
    assert!(stderr.contains("999"), "{stderr}");
    assert!(!fresh.exists(), "an empty results file was left behind");

    let kept = dir.join("kept.csv");
    let before = "scene_id,im_id,obj_id,score,R,t,time\n2,3,8,0.5,1 0 0 0 1 0 0 0 1,0 0 1000,1.0\n";
    std::fs::write(&kept, before).unwrap();
    let run = eval(&kept, &["--objects", "999"]);
    assert!(!run.status.success());
    assert_eq!(std::fs::read_to_string(&kept).unwrap(), before);

    // Zero hypotheses per object is refused by name, before anything else.
    let run = eval(&kept, &["--hypotheses", "0"]);
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(!run.status.success());
    assert!(stderr.contains("--hypotheses"), "{stderr}");
    assert_eq!(std::fs::read_to_string(&kept).unwrap(), before);
    let _ = std::fs::remove_dir_all(&dir);
}

/// `--scene` scores the scene it evaluated against that scene's targets, not the whole
/// dataset's (the other scenes' targets counted as misses). Reads `../shared/data/ycbv-real-dev`
/// (scene 0: 5 images, 15 targets; scene 2: 5 images, 30).
#[test]
fn one_scene_is_scored_against_its_own_targets() {
    let Some(dataset) = shared_test_data("ycbv-real-dev") else {
        return;
    };
    let dir = std::env::temp_dir().join(format!("ppf-eval-scene-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let run = Command::new(env!("CARGO_BIN_EXE_ppf"))
        .arg("eval")
        .arg(&dataset)
        .args(["--scene", "0", "--objects", "8", "--out"])
        .arg(dir.join("scene0.csv"))
        .env("PPFD_CACHE", dir.join("cache"))
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&run.stdout);
    let _ = std::fs::remove_dir_all(&dir);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    assert!(
        stdout.contains(": 15 scored in 5 images, none skipped"),
        "{stdout}"
    );
}

/// An object the ground truth names but `models_info.json` does not list is detected too, not
/// left out without a word; and since scoring needs its entry, a scored run says so before any
/// detection. A copy of the LM-O frame's dataset (links to its files) with object 12's entry
/// taken out of `models_info.json`.
#[test]
fn an_object_missing_from_models_info_is_detected_and_named_before_scoring() {
    let Some(dataset) = shared_test_data("lmo") else {
        return;
    };
    let dir = std::env::temp_dir().join(format!("ppf-eval-noinfo-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let copy = dir.join("lmo");
    std::fs::create_dir_all(copy.join("models")).unwrap();
    for entry in std::fs::read_dir(&dataset).unwrap() {
        let path = entry.unwrap().path();
        if path.file_name().unwrap() != "models" {
            std::os::unix::fs::symlink(&path, copy.join(path.file_name().unwrap())).unwrap();
        }
    }
    for entry in std::fs::read_dir(dataset.join("models")).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap();
        if name == "models_info.json" {
            let mut info: serde_json::Map<String, serde_json::Value> =
                serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
            assert!(info.remove("12").is_some());
            let text = serde_json::to_string(&info).unwrap();
            std::fs::write(copy.join("models").join(name), text).unwrap();
        } else {
            std::os::unix::fs::symlink(&path, copy.join("models").join(name)).unwrap();
        }
    }
    let eval = |out: &str, extra: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_ppf"))
            .arg("eval")
            .arg(&copy)
            .arg("--out")
            .arg(dir.join(out))
            .args(extra)
            .env("PPFD_CACHE", dir.join("cache"))
            .output()
            .unwrap()
    };
    let scored = eval("scored.csv", &[]);
    let stderr = String::from_utf8_lossy(&scored.stderr);
    assert!(!scored.status.success());
    assert!(stderr.contains("no entry for object 12"), "{stderr}");
    assert!(
        !stderr.contains("estimates"),
        "nothing was detected: {stderr}"
    );

    let run = eval("detected.csv", &["--no-score"]);
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success(), "{stderr}");
    let rows = std::fs::read_to_string(dir.join("detected.csv")).unwrap();
    let objects: std::collections::BTreeSet<&str> = rows
        .lines()
        .skip(1)
        .map(|line| line.split(',').nth(2).unwrap())
        .collect();
    let _ = std::fs::remove_dir_all(&dir);
    assert_eq!(objects.len(), 8, "{objects:?}");
    assert!(objects.contains("12"), "{objects:?}");
}

/// A run stopped on the way (Ctrl-C) leaves no empty results file, which `ppf score` would
/// take for a detector that found nothing. Reads `../shared/data/synth-lmo-dev` (40 images,
/// several seconds), stopped after one.
#[test]
fn a_run_stopped_on_the_way_leaves_no_empty_results_file() {
    let Some(dataset) = shared_test_data("synth-lmo-dev") else {
        return;
    };
    let dir = std::env::temp_dir().join(format!("ppf-eval-stopped-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let out = dir.join("results.csv");
    let mut child = Command::new(env!("CARGO_BIN_EXE_ppf"))
        .arg("eval")
        .arg(&dataset)
        .arg("--out")
        .arg(&out)
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    std::thread::sleep(std::time::Duration::from_secs(1));
    // SAFETY: signals our own child, not yet reaped.
    unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
    let status = child.wait().unwrap();
    let left = out.exists();
    let _ = std::fs::remove_dir_all(&dir);
    assert!(
        !status.success(),
        "the run ended before it was stopped: {status:?}"
    );
    assert!(!left, "an empty results file was left behind");
}
