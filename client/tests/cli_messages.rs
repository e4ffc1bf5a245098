//! What the `ppf` command line says when it is given what it cannot use, and what it leaves
//! behind when it fails: refusals name the file or the flags to give, exit codes are those of
//! the tools they mirror, and scratch folders go on every way out. The demo and replay tests
//! read `../shared/data`; they run whenever the data is there, and always under `CI=true`.
#![cfg(feature = "cli")]

mod common;

use common::{shared_data, Scratch};

use std::path::Path;
use std::process::{Command, Output};

use ppfd_models::parts::Part;

fn ppf(args: &[&str]) -> Command {
    let mut command = Command::new(env!("CARGO_BIN_EXE_ppf"));
    command.args(args);
    command
}

/// Runs the command; its output, printed for a failing test to show.
fn run(command: &mut Command) -> Output {
    let out = command.output().unwrap();
    eprintln!(
        "{command:?}: {:?}\nstdout:\n{}\nstderr:\n{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

fn write_part_mesh(path: &Path) {
    std::fs::write(path, Part::ALL[0].mesh().to_ply_ascii()).unwrap();
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

/// The demo on a dataset whose mesh is not named `obj_<id>.ply`: the daemon is given it under
/// that name, and the demo's folder goes, and its daemon is stopped, when the demo fails. A fake
/// `ppfd` records the model folder it was given, then either dies before it is ready or says
/// it is ready and serves nothing (so the demo fails to connect).
#[test]
fn the_demo_names_meshes_by_object_id_and_cleans_up_when_it_fails() {
    let Some(dataset) = shared_data("mpabst_bop_obj19/data") else {
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
    let Some(dataset) = common::lmo() else { return };
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
