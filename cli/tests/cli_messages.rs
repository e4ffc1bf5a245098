//! What the `ppf` command line says when it is given what it cannot use, and what it leaves
//! behind when it fails: refusals name the file or the flags to give, exit codes are those of
//! the tools they mirror, and scratch folders go on every way out. The demo and replay tests
//! read `../shared/data`; they run whenever the data is there, and always under `CI=true`.

mod common;

use std::path::Path;
use std::process::{Command, Output};

use common::Scratch;
use ppfd_bop::shared_test_data;
use ppfd_models::synthetic::parts::Part;

fn ppf(args: &[&str]) -> Command {
    let mut command = Command::new(env!("CARGO_BIN_EXE_ppf"));
    command.args(args);
    command
}

/// Runs the command; its output, printed for a failing test to show.
fn run(command: &mut Command) -> Output {
    let out = command.output().unwrap();
    common::show(command, &out);
    out
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

fn write_part_mesh(path: &Path) {
    std::fs::write(path, Part::ALL[0].mesh().to_ply_ascii()).unwrap();
}

/// A `PPFD_PREFIX` the daemon would refuse is a usage error that names the variable, for every
/// command that reaches the daemon, as `ppfd` refuses it; a command that reaches none does not
/// read it.
#[test]
fn a_bad_prefix_variable_is_a_usage_error_that_names_it() {
    for args in [
        &["stats"][..],
        &["models"],
        &["detect", "--camera", "k", "--objects", "1"],
        &["bench", "--camera", "k", "--objects", "1"],
        &["replay", "/nonexistent", "--camera", "k"],
    ] {
        let out = run(ppf(args).env("PPFD_PREFIX", "cell1"));
        assert_eq!(out.status.code(), Some(2), "{args:?}: a usage error");
        let text = stderr(&out);
        assert!(
            text.contains("PPFD_PREFIX: prefix name \"cell1\" must end with '_'"),
            "{args:?}: {text}"
        );
    }
    let out = run(ppf(&["score", "/nonexistent", "x.csv"]).env("PPFD_PREFIX", "cell1"));
    assert_eq!(out.status.code(), Some(1));
    assert!(!stderr(&out).contains("PPFD_PREFIX"), "{}", stderr(&out));
}

#[test]
fn detect_without_a_mode_names_both_modes() {
    for args in [&["detect"][..], &["detect", "--objects", "1"]] {
        let out = run(&mut ppf(args));
        assert_eq!(out.status.code(), Some(2), "a usage error");
        let e = stderr(&out);
        assert!(
            e.contains("--camera NAME") && e.contains("--dataset DIR --scene N --image N"),
            "{e}"
        );
    }
}

/// A flag of the other mode is a usage error (exit 2) that says what the flag is for.
#[test]
fn detect_with_a_flag_of_the_other_mode_is_a_usage_error() {
    let out = run(&mut ppf(&[
        "detect",
        "--camera",
        "k",
        "--objects",
        "8",
        "--scene",
        "2",
    ]));
    assert_eq!(out.status.code(), Some(2));
    assert!(stderr(&out).contains("--scene works on a frame of a BOP dataset"));
}

/// `ppf model info` given a mesh says how to make a model of it.
#[test]
fn model_info_on_a_mesh_points_to_model_build() {
    let scratch = Scratch::new("info-mesh");
    let mesh = scratch.join("part.ply");
    write_part_mesh(&mesh);
    let out = run(ppf(&["model", "info"]).arg(&mesh));
    assert_eq!(out.status.code(), Some(1));
    assert!(stderr(&out).contains("ppf model build"), "{}", stderr(&out));
}

/// As `ppfd` does, and as the README promises for a bad detector parameter.
#[test]
fn serve_refuses_a_bad_parameter_with_exit_code_2() {
    let prefix = format!("cf_serve_{}_", std::process::id());
    let out = run(&mut ppf(&[
        "serve",
        "--set",
        "voting.no_such_field=1",
        "--prefix",
        &prefix,
    ]));
    assert_eq!(out.status.code(), Some(2));
    assert!(stderr(&out).contains("no_such_field"));
}

/// A models folder that does not exist is a bad setting as a bad parameter is: exit code 2,
/// named, before the daemon serves.
#[test]
fn serve_refuses_a_missing_models_folder_with_exit_code_2() {
    let prefix = format!("cf_nomodels_{}_", std::process::id());
    let out = run(&mut ppf(&[
        "serve",
        "--models",
        "/nonexistent/models",
        "--prefix",
        &prefix,
    ]));
    assert_eq!(out.status.code(), Some(2));
    let e = stderr(&out);
    assert!(e.contains("model directory /nonexistent/models"), "{e}");
    assert!(String::from_utf8_lossy(&out.stdout).is_empty());
}

/// `--id 0` is refused by `ppf model build` as by `ppf models --load` (before any daemon is
/// asked), and a folder is named as one.
#[test]
fn model_build_refuses_id_0_and_a_folder() {
    let scratch = Scratch::new("build-refusals");
    let mesh = scratch.join("duck.ply");
    write_part_mesh(&mesh);
    let out_dir = scratch.join("models");
    let mesh_s = mesh.to_str().unwrap();
    let out_s = out_dir.to_str().unwrap();

    let build = run(&mut ppf(&[
        "model", "build", mesh_s, "--out", out_s, "--id", "0",
    ]));
    let load = run(&mut ppf(&[
        "models",
        "--load",
        mesh_s,
        "--id",
        "0",
        "--prefix",
        "cf_unused_",
    ]));
    for out in [&build, &load] {
        assert_eq!(out.status.code(), Some(2));
        let e = stderr(out);
        assert!(e.contains("invalid value '0' for '--id <ID>'"), "{e}");
    }
    let line = |out: &Output| stderr(out).lines().next().unwrap_or_default().to_owned();
    assert_eq!(line(&build), line(&load), "refused the same way");

    let folder = run(ppf(&["model", "build"])
        .arg(&scratch.0)
        .args(["--out", out_s]));
    assert!(!folder.status.success());
    let e = stderr(&folder);
    assert!(
        e.contains("is a directory") && e.contains("PLY mesh files") && !e.contains("malformed"),
        "{e}"
    );
    assert!(!out_dir.exists(), "nothing is built, no folder made");
}

/// The daemon's rule: the digits ending a file's name are its object id. A name without them
/// needs --id; two files of one id are refused before anything is built.
#[test]
fn model_build_takes_ids_as_the_daemon_does_and_refuses_what_has_none_or_the_same() {
    let scratch = Scratch::new("build-ids");
    for name in ["duck.ply", "obj_000001.ply", "part1.ply", "duck7.ply"] {
        write_part_mesh(&scratch.join(name));
    }
    let out_dir = scratch.join("models");
    let build = |names: &[&str]| {
        let mut command = ppf(&["model", "build"]);
        for name in names {
            command.arg(scratch.join(name));
        }
        run(command.arg("--out").arg(&out_dir))
    };

    let out = build(&["duck.ply", "obj_000001.ply"]);
    assert!(!out.status.success());
    let e = stderr(&out);
    assert!(
        e.contains("duck.ply: no object id") && e.contains("--id"),
        "{e}"
    );
    let out = build(&["part1.ply", "obj_000001.ply"]);
    assert!(!out.status.success());
    let e = stderr(&out);
    assert!(
        e.contains("part1.ply and ") && e.contains("obj_000001.ply are both object 1"),
        "{e}"
    );
    assert!(!out_dir.exists(), "a refused command builds nothing");

    let out = build(&["duck7.ply"]);
    assert!(out.status.success());
    assert!(String::from_utf8_lossy(&out.stdout).contains("duck7.ply: object 7,"));
    let info = run(ppf(&["model", "info"]).arg(out_dir.join("duck7.ppfm")));
    assert!(String::from_utf8_lossy(&info.stdout).contains("object id       7\n"));
    assert_eq!(
        ppfd::ppf_engine::object_id_of_file(Path::new("duck7.ply")),
        Some(7),
        "the daemon's id for the mesh"
    );
}

#[test]
fn a_failed_model_bench_leaves_no_scratch_folder() {
    let scratch = Scratch::new("bench");
    let bad = scratch.join("obj_000004.ply");
    std::fs::write(&bad, "ply\nformat ascii 1.0\nend_header\n").unwrap();
    let child = ppf(&["model", "bench"])
        .arg(&bad)
        .stdout(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let pid = child.id();
    let out = child.wait_with_output().unwrap();
    assert!(!out.status.success());
    let left = std::env::temp_dir().join(format!("ppf-model-bench-{pid}"));
    assert!(!left.exists(), "{} left behind", left.display());
}

/// A mesh that fails is said, and the meshes after it are measured all the same, as `ppf
/// model build` goes on past one; the run exits 1 saying how many failed.
#[test]
fn model_bench_goes_on_past_a_bad_mesh() {
    let scratch = Scratch::new("bench-goes-on");
    let bad = scratch.join("obj_000004.ply");
    std::fs::write(&bad, "ply\nformat ascii 1.0\nend_header\n").unwrap();
    let good = scratch.join("obj_000001.ply");
    std::fs::write(&good, Part::LBracket.mesh().to_ply_ascii()).unwrap();
    let out = run(ppf(&["model", "bench", "--repeat", "1"])
        .arg(&bad)
        .arg(&good));
    let (stdout, stderr) = (
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr),
    );
    assert_eq!(out.status.code(), Some(1), "{stdout}\n{stderr}");
    assert!(stdout.contains("| obj_000001 |"), "{stdout}");
    assert!(
        stderr.contains("obj_000004") && stderr.contains("1 of 2 meshes failed"),
        "{stderr}"
    );
}

/// The demo on a dataset whose mesh is not named `obj_<id>.ply`: the daemon is given it under
/// that name, and the demo's folder goes, and its daemon is stopped, when the demo fails. A fake
/// `ppfd` records the model folder it was given, then either dies before it is ready or says
/// it is ready and serves nothing (so the demo fails to connect).
#[test]
fn the_demo_names_meshes_by_object_id_and_cleans_up_when_it_fails() {
    let Some(dataset) = shared_test_data("mpabst_bop_obj19/data") else {
        return;
    };
    assert!(dataset.join("obj.ply").is_file(), "the mesh is obj.ply");
    let scratch = Scratch::new("demo");
    let fake = scratch.join("fake-ppfd.sh");
    std::fs::write(
        &fake,
        r#"#!/bin/sh
echo $$ > "$FAKE_DIR/pid"
while [ $# -gt 0 ]; do
    [ "$1" = --models ] && ls "$2" > "$FAKE_DIR/models"
    shift
done
[ "$FAKE_READY" = 1 ] || exit 3
echo "ppfd ready pid=$$ models=1"
exec sleep 120
"#,
    )
    .unwrap();
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(&fake, std::fs::Permissions::from_mode(0o755)).unwrap();
    for ready in ["0", "1"] {
        let _ = std::fs::remove_file(scratch.join("models"));
        let child = ppf(&["demo", "--dataset"])
            .arg(&dataset)
            .arg("--ppfd")
            .arg(&fake)
            .arg("--model-cache")
            .arg(scratch.join("cache"))
            .env("FAKE_DIR", &scratch.0)
            .env("FAKE_READY", ready)
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        let pid = child.id();
        let out = child.wait_with_output().unwrap();
        eprintln!("ready={ready}: {:?}\n{}", out.status, stderr(&out));
        assert!(!out.status.success());
        let expected = if ready == "1" {
            "no ppfd daemon is serving"
        } else {
            "ppfd stopped before it was ready"
        };
        assert!(stderr(&out).contains(expected), "{}", stderr(&out));
        let listed = std::fs::read_to_string(scratch.join("models")).unwrap();
        assert_eq!(listed.trim(), "obj_000019.ply");
        let work = std::env::temp_dir().join(format!("ppf-demo-{pid}"));
        assert!(!work.exists(), "{} left behind", work.display());
        let fake_pid = std::fs::read_to_string(scratch.join("pid")).unwrap();
        assert!(
            !Path::new(&format!("/proc/{}", fake_pid.trim())).exists(),
            "the fake daemon {} is still running",
            fake_pid.trim()
        );
    }
}

#[test]
fn replaying_a_scene_that_is_not_there_lists_the_scenes() {
    let Some(dataset) = shared_test_data("lmo") else {
        return;
    };
    let prefix = format!("cf_replay_{}_", std::process::id());
    let out = run(ppf(&["replay"]).arg(&dataset).args([
        "--camera",
        "cf_nowhere",
        "--scene",
        "9",
        "--prefix",
        &prefix,
    ]));
    assert!(!out.status.success());
    let e = stderr(&out);
    assert!(
        e.contains("no scene 9 in 'test'; the only scene is 2"),
        "{e}"
    );
}

/// A folder given to `ppf model info` is named as one (it read "No such device (os error 19)").
#[test]
fn model_info_on_a_folder_says_it_wants_a_model_file() {
    let scratch = Scratch::new("info-folder");
    let out = run(ppf(&["model", "info"]).arg(&scratch.0));
    assert_eq!(out.status.code(), Some(1));
    let e = stderr(&out);
    assert!(
        e.contains("is a folder") && e.contains(".ppfm") && !e.contains("os error"),
        "{e}"
    );
}

/// `--out` naming a file is refused as not a folder (it read "File exists (os error 17)"),
/// before anything is built, and the file is left as it was.
#[test]
fn model_build_into_a_file_says_out_takes_a_folder() {
    let scratch = Scratch::new("build-out-file");
    let mesh = scratch.join("obj_000001.ply");
    write_part_mesh(&mesh);
    let file = scratch.join("models");
    std::fs::write(&file, "not a folder").unwrap();
    let out = run(ppf(&["model", "build"]).arg(&mesh).arg("--out").arg(&file));
    assert_eq!(out.status.code(), Some(1));
    let e = stderr(&out);
    assert!(
        e.contains("--out") && e.contains("is a file") && e.contains("folder"),
        "{e}"
    );
    assert!(!e.contains("os error"), "{e}");
    assert_eq!(std::fs::read_to_string(&file).unwrap(), "not a folder");
}

/// As `ppf replay` does: a scene the dataset has not is refused with the scenes it has (it
/// read "no image with depth to evaluate").
#[test]
fn evaluating_a_scene_that_is_not_there_lists_the_scenes() {
    let Some(dataset) = shared_test_data("lmo") else {
        return;
    };
    let scratch = Scratch::new("eval-scene");
    let out = run(ppf(&["eval"])
        .arg(&dataset)
        .args(["--scene", "99", "--out"])
        .arg(scratch.join("results.csv"))
        .env("PPFD_CACHE", scratch.join("cache")));
    assert_eq!(out.status.code(), Some(1));
    let e = stderr(&out);
    assert!(e.contains("no scene 99; the only scene is 2"), "{e}");
    assert!(!scratch.join("cache").exists(), "nothing was built");
}

/// `--json` formats the score report and `--no-score` skips it: together a usage error, where
/// `--json` was dropped without a word.
#[test]
fn eval_refuses_json_without_a_score() {
    let out = run(&mut ppf(&["eval", "/nowhere", "--json", "--no-score"]));
    assert_eq!(out.status.code(), Some(2));
    let e = stderr(&out);
    assert!(e.contains("--json") && e.contains("--no-score"), "{e}");
}

/// `--requests` counts the requests of all clients: fewer than one each is a usage error (it
/// reported "1 requests from 4 clients", three of which sent none), before any daemon is asked.
#[test]
fn bench_refuses_fewer_requests_than_clients() {
    let prefix = format!("cf_bench_{}_", std::process::id());
    let out = run(&mut ppf(&[
        "bench",
        "--camera",
        "k",
        "--objects",
        "1",
        "--requests",
        "1",
        "--clients",
        "4",
        "--prefix",
        &prefix,
    ]));
    assert_eq!(out.status.code(), Some(2));
    let e = stderr(&out);
    assert!(
        e.contains("--requests 1 is fewer than --clients 4") && e.contains("--requests 4"),
        "{e}"
    );
}

/// `--image` picks a frame of a dataset; without `--dataset` it is a usage error, before
/// anything is built or started, rather than ignored with the generated scene shown.
#[test]
fn demo_refuses_an_image_without_a_dataset() {
    let out = run(&mut ppf(&["demo", "--image", "2", "3"]));
    assert_eq!(out.status.code(), Some(2));
    let e = stderr(&out);
    assert!(e.contains("--image") && e.contains("--dataset DIR"), "{e}");
    assert!(String::from_utf8_lossy(&out.stdout).is_empty());
}

/// A request option out of its range is a usage error before the scene is drawn or the daemon
/// started, as `ppf detect` has it.
#[test]
fn demo_refuses_a_request_option_out_of_range_before_it_starts() {
    let out = run(&mut ppf(&["demo", "--min-score", "2"]));
    assert_eq!(out.status.code(), Some(2));
    let e = stderr(&out);
    assert!(e.contains("minimum score 2 is out of range"), "{e}");
    assert!(String::from_utf8_lossy(&out.stdout).is_empty());
}

/// A daemon started by `ppf serve` in another folder, its lines read up to "ppfd ready"; stopped
/// with SIGTERM when dropped.
/// `ppf serve` under a prefix of its own, stopped and its leftovers removed on drop.
struct Serve(std::process::Child, String);

impl Serve {
    fn start(models: &Path, cache: &Path, cwd: &Path, prefix: &str) -> Serve {
        use std::io::BufRead;
        let mut child = ppf(&["serve", "--models"])
            .arg(models)
            .arg("--model-cache")
            .arg(cache)
            .args(["--prefix", prefix])
            .current_dir(cwd)
            .stdout(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        let stdout = child.stdout.take().unwrap();
        let serve = Serve(child, prefix.to_owned());
        let ready = std::io::BufReader::new(stdout)
            .lines()
            .map_while(Result::ok)
            .any(|l| l.starts_with("ppfd ready"));
        assert!(ready, "ppf serve stopped before it was ready");
        serve
    }
}

impl Drop for Serve {
    fn drop(&mut self) {
        // SAFETY: signals our own child.
        unsafe { libc::kill(self.0.id() as i32, libc::SIGTERM) };
        let _ = self.0.wait();
        let _ = ppfd_client::remove_prefix_leftovers(&self.1);
    }
}

/// The daemon runs in a folder of its own: `--load` with a relative path was looked up there.
/// The client sends the path from its own folder, and a refusal names that path.
#[test]
fn models_load_takes_a_relative_path_from_the_current_folder() {
    let scratch = Scratch::new("load-relative");
    for dir in ["models", "cache", "daemon-cwd", "meshes"] {
        std::fs::create_dir(scratch.join(dir)).unwrap();
    }
    write_part_mesh(&scratch.join("meshes/obj_000003.ply"));
    let prefix = format!("cf_load_{}_", std::process::id());
    let _daemon = Serve::start(
        &scratch.join("models"),
        &scratch.join("cache"),
        &scratch.join("daemon-cwd"),
        &prefix,
    );
    let load = |file: &str| {
        run(ppf(&["models", "--load", file, "--prefix", &prefix])
            .current_dir(scratch.join("meshes")))
    };
    let out = load("obj_000003.ply");
    assert!(out.status.success(), "{}", stderr(&out));
    assert!(String::from_utf8_lossy(&out.stdout).contains("loaded object 3"));

    let out = load("../nowhere/obj_000004.ply");
    assert_eq!(out.status.code(), Some(1));
    let e = stderr(&out);
    let named = scratch.join("meshes/../nowhere/obj_000004.ply");
    assert!(e.contains(named.to_str().unwrap()), "{e}");
}

/// The processes whose parent is `pid`.
fn children_of(pid: u32) -> Vec<u32> {
    std::fs::read_dir("/proc")
        .unwrap()
        .flatten()
        .filter_map(|e| e.file_name().to_str()?.parse::<u32>().ok())
        .filter(|child| {
            std::fs::read_to_string(format!("/proc/{child}/stat")).is_ok_and(|stat| {
                // pid (comm) state ppid ...: the comm may hold spaces, not a ')'.
                stat.rsplit_once(')')
                    .and_then(|(_, rest)| rest.split_whitespace().nth(1)?.parse::<u32>().ok())
                    == Some(pid)
            })
        })
        .collect()
}

/// Stopped with SIGTERM mid-detection, the demo stops its daemon and removes its work folder
/// before it exits (SIGTERM's default action would end the process at once and leave both
/// behind).
#[test]
fn a_demo_stopped_by_sigterm_leaves_nothing_behind() {
    use std::io::BufRead;
    let scratch = Scratch::new("demo-stop");
    let mut demo = ppf(&["demo", "--model-cache"])
        .arg(scratch.join("cache"))
        .stdout(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let pid = demo.id();
    let work = std::env::temp_dir().join(format!("ppf-demo-{pid}"));
    let mut lines = std::io::BufReader::new(demo.stdout.take().unwrap()).lines();
    let ready = lines
        .by_ref()
        .map_while(Result::ok)
        .any(|l| l.starts_with("daemon ready"));
    assert!(ready, "the demo's daemon never came up");
    let daemons = children_of(pid);
    assert_eq!(daemons.len(), 1, "one daemon: {daemons:?}");
    assert!(work.is_dir(), "the demo works in {}", work.display());
    // SAFETY: signals our own child.
    unsafe { libc::kill(pid as i32, libc::SIGTERM) };
    let status = demo.wait().unwrap();
    let daemon_left = Path::new(&format!("/proc/{}", daemons[0])).exists();
    let work_left = work.exists();
    if daemon_left {
        // SAFETY: the demo's daemon, left running by a failing demo.
        unsafe { libc::kill(daemons[0] as i32, libc::SIGKILL) };
    }
    let _ = std::fs::remove_dir_all(&work);
    assert_eq!(status.code(), Some(128 + libc::SIGTERM), "{status:?}");
    assert!(!daemon_left, "the demo's daemon {} still runs", daemons[0]);
    assert!(!work_left, "{} left behind", work.display());
    // Nor anything of its iceoryx2 prefix (its global management segment outlived every run).
    let prefix = format!("ppfd_demo_{pid}_");
    let shm: Vec<String> = std::fs::read_dir("/dev/shm")
        .map(|d| {
            d.flatten()
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| n.starts_with(&prefix))
                .collect()
        })
        .unwrap_or_default();
    assert!(shm.is_empty(), "left in /dev/shm: {shm:?}");
}

/// Stopped with SIGTERM, a looping replay drops its camera before it exits: its shared memory
/// (21 MB for the VGA frame) and its node's files go with it. They stayed: the default action
/// ended the process at once.
#[test]
fn a_replay_stopped_by_sigterm_leaves_no_shared_memory_behind() {
    use std::io::BufRead;
    let Some(dataset) = shared_test_data("lmo") else {
        return;
    };
    let prefix = format!("cf_replay_stop_{}_", std::process::id());
    let leftovers = || -> Vec<String> {
        ["/dev/shm", "/tmp/iceoryx2/nodes", "/tmp/iceoryx2/services"]
            .iter()
            .filter_map(|dir| std::fs::read_dir(dir).ok())
            .flat_map(|d| d.flatten())
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .filter(|n| n.starts_with(&prefix))
            // The prefix's global management file outlives every process of it.
            .filter(|n| !n.ends_with(".global_mgmt"))
            .collect()
    };
    let mut replay = ppf(&["replay"])
        .arg(&dataset)
        .args(["--camera", "cf_stop", "--loop", "--prefix", &prefix])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut lines = std::io::BufReader::new(replay.stdout.take().unwrap()).lines();
    let published = lines
        .by_ref()
        .map_while(Result::ok)
        .any(|l| l.starts_with("frame 1:"));
    assert!(published, "the replay never published");
    let segments = leftovers();
    assert!(
        segments.iter().any(|n| n.ends_with(".data")),
        "the replay's frame memory is not under its prefix: {segments:?}"
    );
    // SAFETY: signals our own child.
    unsafe { libc::kill(replay.id() as i32, libc::SIGTERM) };
    let out = replay.wait_with_output().unwrap();
    let left = leftovers();
    let _ = ppfd_client::remove_prefix_leftovers(&prefix);
    assert_eq!(out.status.code(), Some(128 + libc::SIGTERM), "{out:?}");
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("stopped by SIGTERM"),
        "{out:?}"
    );
    assert!(left.is_empty(), "left behind: {left:?}");
}

/// Without `--loop`, the replay stays 2 s after its last frame, at any rate: the linger starts
/// when that frame is published, not a frame period later (at 0.2 frames per second, five
/// seconds in which the frame grows older than the daemon's stale limit).
#[test]
fn a_replay_lingers_from_its_last_frame() {
    let scratch = Scratch::new("replay-linger");
    let data = scratch.join("parts");
    assert!(run(ppf(&["generate"]).arg(&data)).status.success());
    let prefix = format!("cf_linger_{}_", std::process::id());
    let started = std::time::Instant::now();
    let out = run(ppf(&["replay"]).arg(&data).args([
        "--camera",
        "cf_linger",
        "--fps",
        "0.2",
        "--prefix",
        &prefix,
    ]));
    let took = started.elapsed();
    let _ = ppfd_client::remove_prefix_leftovers(&prefix);
    assert!(out.status.success(), "{out:?}");
    assert!(
        took < std::time::Duration::from_secs_f32(4.5),
        "one frame at 0.2 fps took {took:?}: a frame period (5 s) before the 2 s linger"
    );
}

/// A camera name the protocol does not allow is a usage error (exit 2) in every command that
/// takes `--camera`, as a bad `--prefix` is, before anything connects.
#[test]
fn a_bad_camera_name_is_a_usage_error() {
    for args in [
        &["detect", "--objects", "1", "--camera"][..],
        &["bench", "--objects", "1", "--camera"][..],
        &["replay", "/nonexistent", "--camera"][..],
    ] {
        for name in ["c 6", ""] {
            let out = run(ppf(args).arg(name));
            let e = String::from_utf8_lossy(&out.stderr);
            assert_eq!(out.status.code(), Some(2), "{args:?} {name:?}: {e}");
            assert!(e.contains("--camera"), "{args:?} {name:?}: {e}");
        }
    }
}
