//! What `ppf` does with input that would cost it without bound or mislead it: special files are
//! refused at once (never read, never waited on), meshes that make no sense in millimetres are
//! refused with what to do, broken dataset files are reported before any work starts, and
//! flags that take numbers refuse the ones that cannot work. Every mesh, frame and dataset is
//! generated here.

mod common;

use std::path::Path;
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use common::Scratch;
use ppfd_models::geometry::mesh::Mesh;
use ppfd_models::synthetic::parts::{box_mesh, Part};

fn ppf(args: &[&str]) -> Command {
    let mut command = Command::new(env!("CARGO_BIN_EXE_ppf"));
    command.args(args);
    command
}

/// Runs the command, killing it after `limit`; its output, printed for a failing test to show.
fn run_within(command: &mut Command, limit: Duration) -> Output {
    let mut child = command
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if start.elapsed() > limit {
            let _ = child.kill();
            let _ = child.wait();
            panic!("{command:?} still ran after {limit:?}");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let out = child.wait_with_output().unwrap();
    common::show(command, &out);
    out
}

fn run(command: &mut Command) -> Output {
    run_within(command, Duration::from_secs(300))
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

fn mkfifo(path: &Path) {
    let made = Command::new("mkfifo").arg(path).status().unwrap();
    assert!(made.success(), "mkfifo {}", path.display());
}

/// A 64 × 48 depth PNG of a flat wall at 800 mm.
fn write_depth_png(path: &Path, width: u32, height: u32) {
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut encoder = png::Encoder::new(file, width, height);
    encoder.set_color(png::ColorType::Grayscale);
    encoder.set_depth(png::BitDepth::Sixteen);
    let bytes: Vec<u8> = (0..width * height)
        .flat_map(|_| 800u16.to_be_bytes())
        .collect();
    encoder
        .write_header()
        .unwrap()
        .write_image_data(&bytes)
        .unwrap();
}

const GOOD_GT: &str = r#"{"0": [{"obj_id": 1, "cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, 1], "cam_t_m2c": [0, 0, 700]}],
                         "1": [{"obj_id": 1, "cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, 1], "cam_t_m2c": [0, 0, 700]}]}"#;

/// A one-scene dataset of two 64 × 48 frames of a wall, with a generated part as object 1.
fn write_dataset(root: &Path, scene_gt: &str) {
    let scene = root.join("test/000000");
    std::fs::create_dir_all(&scene).unwrap();
    std::fs::create_dir_all(root.join("models")).unwrap();
    std::fs::write(
        root.join("camera.json"),
        r#"{"cx": 32, "cy": 24, "depth_scale": 1.0, "fx": 60, "fy": 60, "height": 48, "width": 64}"#,
    )
    .unwrap();
    std::fs::write(
        root.join("models/obj_000001.ply"),
        Part::ALL[0].mesh().to_ply_ascii(),
    )
    .unwrap();
    let k = r#"{"cam_K": [60, 0, 32, 0, 60, 24, 0, 0, 1], "depth_scale": 1.0}"#;
    std::fs::write(
        scene.join("scene_camera.json"),
        format!(r#"{{"0": {k}, "1": {k}}}"#),
    )
    .unwrap();
    std::fs::write(scene.join("scene_gt.json"), scene_gt).unwrap();
    for im in 0..2 {
        write_depth_png(&scene.join(format!("depth/{im:06}.png")), 64, 48);
    }
}

/// `ppf detect --dataset root --scene 0 --image 0`, with `cache` as the model cache.
fn detect_image_0(root: &Path, cache: &Path) -> Output {
    run(ppf(&["detect", "--dataset"])
        .arg(root)
        .args(["--scene", "0", "--image", "0"])
        .env("PPFD_CACHE", cache))
}

/// `ppf eval root --out csv`, with `cache` as the model cache.
fn eval_into(root: &Path, csv: &Path, cache: &Path) -> Output {
    run(ppf(&["eval"])
        .arg(root)
        .arg("--out")
        .arg(csv)
        .env("PPFD_CACHE", cache))
}

#[test]
fn special_files_are_refused_at_once_by_model_build_and_score() {
    let dir = Scratch::new("special-files");
    let link = dir.join("obj_000001.ply");
    std::os::unix::fs::symlink("/dev/null", &link).unwrap();
    let fifo = dir.join("obj_000002.ply");
    mkfifo(&fifo);
    let out_dir = dir.join("out");
    for mesh in [&link, &fifo] {
        let out = run_within(
            ppf(&["model", "build", mesh.to_str().unwrap(), "--out"]).arg(&out_dir),
            Duration::from_secs(30),
        );
        assert_eq!(out.status.code(), Some(1));
        assert!(text(&out.stderr).contains("not a regular file"), "{mesh:?}");
    }
    let dataset = dir.join("dataset");
    write_dataset(&dataset, GOOD_GT);
    let csv = dir.join("results.csv");
    std::os::unix::fs::symlink("/dev/null", &csv).unwrap();
    let out = run_within(
        ppf(&["score"]).arg(&dataset).arg(&csv),
        Duration::from_secs(30),
    );
    assert_eq!(out.status.code(), Some(1));
    assert!(text(&out.stderr).contains("not a regular file"));
}

#[test]
fn a_mesh_in_metres_is_refused_unless_scaled_and_the_size_is_printed_in_millimetres() {
    let dir = Scratch::new("metres");
    let mesh = dir.join("obj_000001.ply");
    std::fs::write(
        &mesh,
        box_mesh(nalgebra::Vector3::new(0.06, 0.04, 0.02)).to_ply_ascii(),
    )
    .unwrap();
    let out_dir = dir.join("out");
    let out = run(ppf(&["model", "build", mesh.to_str().unwrap(), "--out"]).arg(&out_dir));
    assert_eq!(out.status.code(), Some(1));
    let e = text(&out.stderr);
    assert!(e.contains("metres") && e.contains("--scale 1000"), "{e}");

    let out = run(ppf(&[
        "model",
        "build",
        mesh.to_str().unwrap(),
        "--scale",
        "1000",
        "--out",
    ])
    .arg(&out_dir));
    assert!(out.status.success());
    let o = text(&out.stdout);
    assert!(
        o.contains("diameter 74.8 mm, size 60.0 × 40.0 × 20.0 mm"),
        "{o}"
    );
    let out = run(ppf(&["model", "info"]).arg(out_dir.join("obj_000001.ppfm")));
    assert!(out.status.success());
    let o = text(&out.stdout);
    assert!(
        o.contains("size            60.0 × 40.0 × 20.0 mm")
            && o.contains("closed, normals outward"),
        "{o}"
    );
    let out = run(&mut ppf(&[
        "model", "build", "--scale", "0", "x.ply", "--out", "o",
    ]));
    assert_eq!(out.status.code(), Some(2));
}

#[test]
fn inward_normals_are_flipped_with_a_note_and_a_plane_is_refused() {
    let dir = Scratch::new("inward");
    let mut inward = box_mesh(nalgebra::Vector3::new(60.0, 40.0, 20.0));
    inward.flip_normals();
    let mesh = dir.join("obj_000001.ply");
    std::fs::write(&mesh, inward.to_ply_ascii()).unwrap();
    let out_dir = dir.join("out");
    let out = run(ppf(&["model", "build", mesh.to_str().unwrap(), "--out"]).arg(&out_dir));
    assert!(out.status.success());
    let o = text(&out.stdout);
    assert!(o.contains("note:") && o.contains("flipped"), "{o}");
    let out = run(ppf(&["model", "info"]).arg(out_dir.join("obj_000001.ppfm")));
    assert!(text(&out.stdout).contains("closed, normals outward"));

    let triangle = Mesh::from_triangles(
        vec![
            nalgebra::Point3::new(0.0, 0.0, 0.0),
            nalgebra::Point3::new(100.0, 0.0, 0.0),
            nalgebra::Point3::new(0.0, 100.0, 0.0),
        ],
        &[[0, 1, 2]],
    )
    .unwrap();
    let mesh = dir.join("obj_000002.ply");
    std::fs::write(&mesh, triangle.to_ply_ascii()).unwrap();
    let out = run(ppf(&["model", "build", mesh.to_str().unwrap(), "--out"]).arg(&out_dir));
    assert_eq!(out.status.code(), Some(1));
    assert!(text(&out.stderr).contains("single plane"));
}

#[test]
fn numbers_that_cannot_work_and_two_changes_at_once_are_usage_errors() {
    for args in [
        &["stats", "--timeout-ms", "0"][..],
        &["models", "--timeout-ms", "0"],
        &[
            "bench",
            "--camera",
            "c",
            "--objects",
            "1",
            "--timeout-ms",
            "0",
        ],
        &["model", "bench", "x.ply", "--repeat", "0"],
        &["models", "--load", "/x/obj_000001.ply", "--drop", "1"],
    ] {
        let out = run(&mut ppf(args));
        assert_eq!(out.status.code(), Some(2), "{args:?}");
    }
}

/// Each broken `scene_gt.json` is an error naming the file, not a frame without ground truth.
#[test]
fn a_broken_ground_truth_or_depth_image_stops_detect_before_it_detects() {
    let dir = Scratch::new("broken-gt");
    let one = |r: &str, id: &str| {
        format!(r#"{{"0": [{{"obj_id": {id}, "cam_R_m2c": {r}, "cam_t_m2c": [0, 0, 700]}}]}}"#)
    };
    let cases = [
        one("[1, 0, 0, 0, 1, 0, 0, 0]", "1"),
        one("[1, 0, 0, 0, 2, 0, 0, 0, 1]", "1"),
        one("[1, 0, 0, 0, 1, 0, 0, 0, 1]", "-1"),
        one("[1, 0, 0, 0, 1, 0, 0, 0, NaN]", "1"),
        "{\"0\": [".to_string(),
    ];
    for (i, gt) in cases.iter().enumerate() {
        let root = dir.join(&format!("d{i}"));
        write_dataset(&root, gt);
        let out = run(ppf(&["detect", "--dataset"])
            .arg(&root)
            .args(["--scene", "0", "--image", "0"]));
        assert_eq!(out.status.code(), Some(1), "{gt}");
        assert!(text(&out.stderr).contains("scene_gt.json"), "{gt}");
        assert!(!text(&out.stdout).contains("correct"), "nothing detected");
    }
    let root = dir.join("size");
    write_dataset(&root, GOOD_GT);
    write_depth_png(&root.join("test/000000/depth/000001.png"), 65, 48);
    let out = run(ppf(&["detect", "--dataset"])
        .arg(&root)
        .args(["--scene", "0", "--image", "1"]));
    assert_eq!(out.status.code(), Some(1));
    assert!(text(&out.stderr).contains("65x48, camera.json gives 64x48"));
}

/// `ppf eval` checks every image's files first: a broken second image stops it before any
/// model is built or frame detected.
#[test]
fn eval_reports_a_broken_image_before_any_work() {
    let dir = Scratch::new("eval-broken");
    let root = dir.join("dataset");
    write_dataset(&root, GOOD_GT);
    write_depth_png(&root.join("test/000000/depth/000001.png"), 64, 40);
    let cache = dir.join("cache");
    let out = eval_into(&root, &dir.join("r.csv"), &cache);
    assert_eq!(out.status.code(), Some(1));
    assert!(text(&out.stderr).contains("000001.png"));
    assert!(!cache.exists(), "no model was built");
}

/// A frame that holds no depth to detect in (every pixel 0, a sensor that dropped out) costs
/// its own targets: the image after it is detected and the run scored, and then the failure is
/// named and the exit code is 1.
#[test]
fn eval_goes_on_past_a_frame_it_cannot_detect_in() {
    let dir = Scratch::new("eval-empty-frame");
    let root = dir.join("dataset");
    write_dataset(&root, GOOD_GT);
    let depth = root.join("test/000000/depth/000000.png");
    let file = std::io::BufWriter::new(std::fs::File::create(&depth).unwrap());
    let mut encoder = png::Encoder::new(file, 64, 48);
    encoder.set_color(png::ColorType::Grayscale);
    encoder.set_depth(png::BitDepth::Sixteen);
    let zeros = vec![0u8; 64 * 48 * 2];
    encoder
        .write_header()
        .unwrap()
        .write_image_data(&zeros)
        .unwrap();
    let csv = dir.join("r.csv");
    let out = eval_into(&root, &csv, &dir.join("cache"));
    assert_eq!(out.status.code(), Some(1));
    let (o, e) = (text(&out.stdout), text(&out.stderr));
    assert!(
        o.contains("2 scored in 2 images") && o.contains("| all |"),
        "both images' targets scored: {o}"
    );
    assert!(
        e.contains("1 of 2 images failed")
            && e.contains("scene 0 image 0: ")
            && e.contains("no valid depth"),
        "{e}"
    );
    assert!(csv.exists(), "the results are written");
    // When every image fails, nothing is written: an empty results file would score as a
    // detector that found nothing.
    std::fs::remove_file(&csv).unwrap();
    std::fs::copy(&depth, root.join("test/000000/depth/000001.png")).unwrap();
    let out = eval_into(&root, &csv, &dir.join("cache"));
    assert_eq!(out.status.code(), Some(1));
    let e = text(&out.stderr);
    assert!(
        e.contains("no image could be detected in (2 failed; nothing written)"),
        "{e}"
    );
    assert!(!csv.exists(), "nothing written");
}

/// A mesh in metres is refused as it is; its model built with `--scale 1000` into the mesh's
/// own folder, as the refusal advises, is taken in its place.
#[test]
fn a_model_built_with_scale_beside_its_mesh_in_metres_is_taken() {
    let dir = Scratch::new("scaled-beside");
    let root = dir.join("dataset");
    write_dataset(&root, GOOD_GT);
    let models = root.join("models");
    let mut metres = Part::ALL[0].mesh();
    metres.scale(0.001);
    std::fs::write(models.join("obj_000001.ply"), metres.to_ply_ascii()).unwrap();
    let detect = || detect_image_0(&root, &dir.join("cache"));
    let refused = detect();
    assert_eq!(refused.status.code(), Some(1));
    let said = text(&refused.stderr);
    assert!(
        said.contains(&format!(
            "{}: invalid mesh",
            models.join("obj_000001.ply").display()
        )) && said.contains("--scale 1000"),
        "the file and the advice: {said}"
    );
    let built = run(ppf(&["model", "build"])
        .arg(models.join("obj_000001.ply"))
        .args(["--scale", "1000", "--out"])
        .arg(&models));
    assert!(built.status.success());
    let out = detect();
    assert!(out.status.success(), "the scaled model is taken");
    assert!(
        text(&out.stdout).contains("| 1 |"),
        "object 1 is detected for"
    );
}

/// A mesh in centimetres is warned of with the scale each time the dataset commands load its
/// model, the first time (built) and the next (taken from the cache).
#[test]
fn a_small_model_is_warned_of_at_each_load() {
    let dir = Scratch::new("small-model");
    let root = dir.join("dataset");
    write_dataset(&root, GOOD_GT);
    let mut centimetres = Part::ALL[0].mesh();
    centimetres.scale(0.1);
    let mesh = root.join("models/obj_000001.ply");
    std::fs::write(&mesh, centimetres.to_ply_ascii()).unwrap();
    for _ in 0..2 {
        let out = detect_image_0(&root, &dir.join("cache"));
        assert!(out.status.success());
        let e = text(&out.stderr);
        assert!(
            e.contains(&format!("warning: {}: the diameter is", mesh.display()))
                && e.contains("scale it by 10"),
            "{e}"
        );
    }
}

/// On a frame where the object is not (a wall), its row says so.
#[test]
fn an_object_without_a_hypothesis_has_a_row_in_dataset_mode() {
    let dir = Scratch::new("no-hypothesis");
    let root = dir.join("dataset");
    write_dataset(&root, GOOD_GT);
    let out = detect_image_0(&root, &dir.join("cache"));
    assert!(out.status.success());
    let o = text(&out.stdout);
    assert!(o.contains("| 1 |") && o.contains("(no hypothesis)"), "{o}");
}

/// A `models_info.json` diameter fifty times its mesh's (another unit, another object) would
/// pass poses half a metre off: `ppf eval` refuses it before detecting, and `ppf score` before
/// scoring, naming the object, both diameters and the file.
#[test]
fn a_diameter_that_is_not_the_meshs_is_refused() {
    let scratch = Scratch::new("wrong-diameter");
    let data = scratch.join("parts");
    let out = run(ppf(&["generate"]).arg(&data));
    assert!(out.status.success());
    let entries: serde_json::Map<String, serde_json::Value> = Part::ALL
        .iter()
        .map(|p| {
            let d = ppfd_models::model::sampling::diameter(&p.mesh().positions);
            let stated = if *p == Part::TPipe { 50.0 * d } else { d };
            (
                p.object_id().to_string(),
                serde_json::json!({"diameter": stated, "min_x": 0, "min_y": 0, "min_z": 0,
                                   "size_x": 1, "size_y": 1, "size_z": 1}),
            )
        })
        .collect();
    std::fs::write(
        data.join("models/models_info.json"),
        serde_json::to_vec(&entries).unwrap(),
    )
    .unwrap();
    let results = scratch.join("results.csv");
    let out = run(ppf(&["eval"]).arg(&data).arg("--out").arg(&results));
    let e = text(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{e}");
    let id = Part::TPipe.object_id();
    assert!(
        e.contains("models_info.json")
            && e.contains(&format!("object {id}: diameter"))
            && e.contains("mm across"),
        "{e}"
    );
    assert!(!results.exists(), "refused before detecting");
    std::fs::write(
        &results,
        format!("scene_id,im_id,obj_id,score,R,t,time\n0,0,{id},1,1 0 0 0 1 0 0 0 1,0 0 500,-1\n"),
    )
    .unwrap();
    let out = run(ppf(&["score"]).arg(&data).arg(&results));
    let e = text(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{e}");
    assert!(e.contains(&format!("object {id}: diameter")), "{e}");
}
