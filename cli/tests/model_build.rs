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

fn ppf_model(args: &[&std::ffi::OsStr]) -> (std::process::Output, String, String) {
    let mut command = Command::new(env!("CARGO_BIN_EXE_ppf"));
    command.arg("model").args(args);
    let out = command.output().unwrap();
    common::show(&command, &out);
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    (out, stdout, stderr)
}

/// `--symmetry` is stored in the model and shown by `ppf model info`; without it, a mesh takes
/// the symmetries of the `models_info.json` beside it.
#[test]
fn a_symmetry_given_or_read_beside_the_mesh_is_stored_and_shown() {
    use ppfd_models::synthetic::parts::SymmetricPart;
    let scratch = Scratch::new("model-build-symmetry");
    let mesh = scratch.join("obj_000005.ply");
    std::fs::write(&mesh, SymmetricPart::UChannel.mesh().to_ply_ascii()).unwrap();
    let out = scratch.join("models");
    let model = out.join("obj_000005.ppfm");
    let os = |s: &'static str| std::ffi::OsStr::new(s);

    let (run, stdout, _) = ppf_model(&[
        os("build"),
        mesh.as_os_str(),
        os("--symmetry"),
        os("z:2"),
        os("--out"),
        out.as_os_str(),
    ]);
    assert!(run.status.success());
    assert!(stdout.contains("obj_000005.ply: symmetry: discrete, 2 poses alike\n"));
    let (run, stdout, _) = ppf_model(&[os("info"), model.as_os_str()]);
    assert!(run.status.success());
    assert!(stdout.contains("symmetry        discrete, 2 poses alike\n"));

    // The same half turn from models_info.json (BOP's row-major 4×4), and `none` to ignore it.
    std::fs::write(
        scratch.join("models_info.json"),
        r#"{"5": {"diameter": 150.7, "min_x": -45, "min_y": -55, "min_z": -25,
                  "size_x": 90, "size_y": 110, "size_z": 50,
                  "symmetries_discrete": [[-1, 0, 0, 0, 0, -1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]]}}"#,
    )
    .unwrap();
    let (run, stdout, _) =
        ppf_model(&[os("build"), mesh.as_os_str(), os("--out"), out.as_os_str()]);
    assert!(run.status.success());
    assert!(
        stdout.contains("symmetry: discrete, 2 poses alike (from ")
            && stdout.contains("models_info.json)"),
        "{stdout}"
    );
    let (run, stdout, _) = ppf_model(&[
        os("build"),
        mesh.as_os_str(),
        os("--symmetry"),
        os("none"),
        os("--out"),
        out.as_os_str(),
    ]);
    assert!(
        run.status.success() && !stdout.contains(": symmetry:"),
        "{stdout}"
    );
    let (_, stdout, _) = ppf_model(&[os("info"), model.as_os_str()]);
    assert!(stdout.contains("symmetry        none\n"), "{stdout}");
    // The model of the file's bytes records their CRC, as the daemon's cache does: the daemon
    // takes it, beside the mesh, before a model it cached of the mesh.
    use ppfd_models::model::store;
    let crc = store::source_crc(&std::fs::read(&mesh).unwrap());
    assert_eq!(store::load(&model).unwrap().source_crc(), crc);

    // A symmetry of models_info.json that the mesh does not have (a quarter turn) is left out
    // with a warning, as the daemon and `ppf eval` leave it; given with --symmetry, refused.
    std::fs::write(
        scratch.join("models_info.json"),
        r#"{"5": {"diameter": 150.7, "min_x": -45, "min_y": -55, "min_z": -25,
                  "size_x": 90, "size_y": 110, "size_z": 50,
                  "symmetries_discrete": [[0, -1, 0, 0, 1, 0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]]}}"#,
    )
    .unwrap();
    let (run, stdout, stderr) =
        ppf_model(&[os("build"), mesh.as_os_str(), os("--out"), out.as_os_str()]);
    assert!(run.status.success(), "{stderr}");
    assert!(!stdout.contains(": symmetry:"), "{stdout}");
    assert!(
        stderr.contains("obj_000005.ply: the symmetry of ")
            && stderr.contains("models_info.json is left out, the model has none")
            && stderr.contains("does not have it"),
        "{stderr}"
    );
    assert!(store::load(&model).unwrap().symmetry().is_none());
    let (run, _, stderr) = ppf_model(&[
        os("build"),
        mesh.as_os_str(),
        os("--symmetry"),
        os("z:4"),
        os("--out"),
        out.as_os_str(),
    ]);
    assert_eq!(run.status.code(), Some(1));
    assert!(stderr.contains("does not have it"), "{stderr}");
}

/// Each refusal of `--symmetry` says what was wrong, and nothing is written.
#[test]
fn a_malformed_or_false_symmetry_is_refused_saying_why() {
    let scratch = Scratch::new("model-build-symmetry-refused");
    let mesh = scratch.join("obj_000001.ply");
    std::fs::write(&mesh, Part::LBracket.mesh().to_ply_ascii()).unwrap();
    let other = scratch.join("obj_000002.ply");
    std::fs::write(&other, Part::TPipe.mesh().to_ply_ascii()).unwrap();
    let out = scratch.join("models");
    let os = std::ffi::OsStr::new;
    let usage = [
        ("z:1", "the order 1 is not 2 to 100"),
        ("z:half", "the order \"half\" is not a whole number or inf"),
        ("w:2", "the axis \"w\" is not three finite numbers"),
        ("0,0,0:inf", "the axis has zero length"),
        ("z:2@1,2", "the point \"1,2\" is not three finite numbers"),
        ("z2", "no ':' between the axis and the order"),
    ];
    for (value, why) in usage {
        let (run, _, stderr) = ppf_model(&[
            os("build"),
            mesh.as_os_str(),
            os("--symmetry"),
            os(value),
            os("--out"),
            out.as_os_str(),
        ]);
        assert_eq!(run.status.code(), Some(2), "{value}: a usage error");
        assert!(
            stderr.contains(&format!("invalid value '{value}' for '--symmetry"))
                && stderr.contains(why),
            "{value}: {stderr}"
        );
    }
    let refusals: [(&[&str], &[&std::path::Path], &str); 4] = [
        (
            &["--symmetry", "none", "--symmetry", "z:2"],
            &[&mesh],
            "--symmetry none says the object has no symmetry: give it alone",
        ),
        (
            &["--symmetry", "z:inf", "--symmetry", "x:inf"],
            &[&mesh],
            "two different continuous symmetry axes",
        ),
        (
            &["--symmetry", "z:2"],
            &[&mesh, &other],
            "--symmetry applies to a single mesh",
        ),
        // The bracket has no half turn.
        (
            &["--symmetry", "z:2"],
            &[&mesh],
            "obj_000001: symmetry: the object does not have it: discrete transform 1 (a turn \
             of 180° about (0.00, 0.00, 1.00)) moves a tenth of its surface",
        ),
    ];
    for (extra, meshes, why) in refusals {
        let mut args: Vec<&std::ffi::OsStr> = vec![os("build")];
        args.extend(meshes.iter().map(|m| m.as_os_str()));
        args.extend(extra.iter().map(|a| os(a)));
        args.extend([os("--out"), out.as_os_str()]);
        let (run, _, stderr) = ppf_model(&args);
        assert_eq!(run.status.code(), Some(1), "{extra:?}");
        assert!(stderr.contains(why), "{extra:?}: {stderr}");
    }
    assert!(!out.join("obj_000001.ppfm").exists());
}

/// A mesh in centimetres (a 100 mm part measuring 10) builds, with a warning that says the
/// scale; the same mesh scaled by 10 builds without it.
#[test]
fn a_mesh_in_centimetres_is_warned_of_with_its_scale() {
    let scratch = Scratch::new("model-build-cm");
    let mut mesh = Part::ALL[0].mesh();
    mesh.scale(0.1);
    let path = scratch.0.join("obj_000003.ply");
    std::fs::write(&path, mesh.to_ply_ascii()).unwrap();
    let out = scratch.0.join("models");
    let (run, _, stderr) = ppf_model(&[
        "build".as_ref(),
        path.as_os_str(),
        "--out".as_ref(),
        out.as_os_str(),
    ]);
    assert!(run.status.success());
    assert!(
        stderr.contains(&format!("warning: {}: the diameter is", path.display()))
            && stderr.contains("scale it by 10"),
        "{stderr}"
    );
    let (run, _, stderr) = ppf_model(&[
        "build".as_ref(),
        path.as_os_str(),
        "--scale".as_ref(),
        "10".as_ref(),
        "--out".as_ref(),
        out.as_os_str(),
    ]);
    assert!(run.status.success());
    assert!(!stderr.contains("warning"), "{stderr}");
}
