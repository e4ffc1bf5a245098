//! `ppf model build` run as a script runs it (output not a terminal, so no progress bar): each
//! mesh says what became of it, and a failure says why.

mod common;

use std::process::Command;

use common::Scratch;
use ppfd_models::synthetic::parts::Part;

#[test]
fn each_mesh_reports_its_model_or_why_it_failed_without_a_terminal() {
    let scratch = Scratch::new("model-build");
    let good = scratch.0.join("obj_000003.ply");
    std::fs::write(&good, Part::ALL[0].mesh().to_ply_ascii()).unwrap();
    let bad = scratch.0.join("obj_000004.ply");
    std::fs::write(
        &bad,
        "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nend_header\n1\n2\n",
    )
    .unwrap();
    let out = scratch.0.join("models");

    let run = Command::new(env!("CARGO_BIN_EXE_ppf"))
        .args(["model", "build"])
        .arg(&good)
        .arg(&bad)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&run.stdout);
    let stderr = String::from_utf8_lossy(&run.stderr);
    eprintln!("stdout:\n{stdout}\nstderr:\n{stderr}");

    assert!(!run.status.success(), "a failed mesh must fail the command");
    // The good mesh is built, saved, and says so.
    assert!(out.join("obj_000003.ppfm").is_file());
    assert!(
        stdout.contains("obj_000003.ply: object 3,") && stdout.contains("table entries"),
        "no line for the built model"
    );
    // The bad one names itself and the reason, then the summary.
    let reason = stderr
        .lines()
        .find(|l| l.contains("obj_000004.ply"))
        .expect("no line for the failed mesh");
    assert!(
        reason.contains("malformed PLY") && reason.contains("'y'"),
        "{reason}"
    );
    assert!(stderr.contains("1 of 2 meshes failed"));
    assert!(!out.join("obj_000004.ppfm").exists());
}

/// Output into a pipe whose reader has gone (`ppf model info … | head -1`): the command ends
/// quietly, as other command-line tools do, instead of panicking on the next print.
#[test]
fn a_closed_output_pipe_ends_the_command_quietly() {
    use std::os::unix::process::ExitStatusExt;
    let scratch = Scratch::new("closed-pipe");
    let mesh = scratch.0.join("obj_000003.ply");
    std::fs::write(&mesh, Part::ALL[0].mesh().to_ply_ascii()).unwrap();
    let built = Command::new(env!("CARGO_BIN_EXE_ppf"))
        .args(["model", "build"])
        .arg(&mesh)
        .arg("--out")
        .arg(&scratch.0)
        .output()
        .unwrap();
    assert!(built.status.success(), "{built:?}");

    // The reader is closed before the command starts: its first print meets a broken pipe.
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    let run = Command::new(env!("CARGO_BIN_EXE_ppf"))
        .args(["model", "info"])
        .arg(scratch.0.join("obj_000003.ppfm"))
        .stdout(writer)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert_eq!(
        run.status.signal(),
        Some(13),
        "ended by SIGPIPE: {:?}",
        run.status
    );
}

/// A model file of another object is not overwritten: the mesh `obj_000003.ply` built as
/// object 8 (`--id 8`) is saved as `obj_000003.ppfm`, and building the mesh again as object 3
/// is refused, naming the file and both ids, with the object-8 model left as it was.
#[test]
fn a_model_of_another_object_is_not_overwritten() {
    let scratch = Scratch::new("model-build-other");
    let mesh = scratch.0.join("obj_000003.ply");
    std::fs::write(&mesh, Part::ALL[0].mesh().to_ply_ascii()).unwrap();
    let out = scratch.0.join("models");
    let build = |extra: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_ppf"))
            .args(["model", "build"])
            .arg(&mesh)
            .args(extra)
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap()
    };
    assert!(build(&["--id", "8"]).status.success());
    let saved = out.join("obj_000003.ppfm");
    let before = std::fs::read(&saved).unwrap();

    let again = build(&[]);
    let stderr = String::from_utf8_lossy(&again.stderr);
    assert!(!again.status.success(), "{stderr}");
    assert!(
        stderr.contains("obj_000003.ppfm holds the model of object 8")
            && stderr.contains("is object 3: not overwritten"),
        "{stderr}"
    );
    assert_eq!(
        std::fs::read(&saved).unwrap(),
        before,
        "the object-8 model changed"
    );
    // The same object again is rebuilt in place.
    assert!(build(&["--id", "8"]).status.success());
}
