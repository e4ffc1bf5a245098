//! `ppf demo --overlay`: the picture it writes shows each part's outline where the part lies
//! (no data files needed).

mod common;

use std::process::Command;

use common::{Scratch, ServedPart};
use ppfd_models::geometry::render::render_depth;
use ppfd_models::synthetic::parts::Part;
use ppfd_models::synthetic::scene::{NoiseModel, SceneSpec};

/// Colours of the outlines (`cli/src/overlay.rs`): a pose that passed both filters, one that
/// failed one.
const POSE_COLOURS: [[u8; 3]; 2] = [[40, 230, 40], [255, 230, 0]];

fn read_rgb(path: &std::path::Path) -> (u32, u32, Vec<u8>) {
    let mut decoder =
        png::Decoder::new(std::io::BufReader::new(std::fs::File::open(path).unwrap()));
    decoder.set_transformations(png::Transformations::IDENTITY);
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgb);
    assert_eq!(info.bit_depth, png::BitDepth::Eight);
    (info.width, info.height, buf)
}

/// A part's silhouette at `pose` and the outline pixels of the picture near it (within two
/// pixels: a detected pose lies a few millimetres off the truth), and those near none of
/// `masks`.
fn outline_pixels(
    (w, h, rgb): &(u32, u32, Vec<u8>),
    masks: &[ppfd_models::geometry::render::DepthImage],
) -> (Vec<usize>, usize, usize) {
    let is_pose = |u: u32, v: u32| {
        let i = 3 * (v * w + u) as usize;
        POSE_COLOURS.iter().any(|c| rgb[i..i + 3] == *c)
    };
    let mut per_part = vec![0usize; masks.len()];
    let (mut on, mut off) = (0usize, 0usize);
    for v in 0..*h {
        for u in 0..*w {
            if !is_pose(u, v) {
                continue;
            }
            let near = |m: &ppfd_models::geometry::render::DepthImage| {
                (-2i64..=2).any(|dv| {
                    (-2i64..=2).any(|du| {
                        let (x, y) = (u as i64 + du, v as i64 + dv);
                        x >= 0 && y >= 0 && m.get(x as u32, y as u32).is_some()
                    })
                })
            };
            let mut hit = false;
            for (i, m) in masks.iter().enumerate() {
                if near(m) {
                    per_part[i] += 1;
                    hit = true;
                }
            }
            if hit {
                on += 1;
            } else {
                off += 1;
            }
        }
    }
    (per_part, on, off)
}

/// The demo's scene (seed 1, the four generated parts with Kinect-like noise): each part's
/// silhouette at its true pose holds pose outline pixels, and nearly all of them lie on some
/// part's silhouette.
#[test]
fn the_demo_overlay_outlines_each_part_where_it_lies() {
    let scratch = Scratch::new("overlay");
    let png_path = scratch.join("demo.png");
    let out = Command::new(env!("CARGO_BIN_EXE_ppf"))
        .args(["demo", "--overlay"])
        .arg(&png_path)
        .arg("--model-cache")
        .arg(scratch.join("cache"))
        .output()
        .unwrap();
    eprintln!(
        "{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(out.status.success());
    let (w, h, rgb) = read_rgb(&png_path);
    assert_eq!((w, h), (640, 480));

    let meshes: Vec<_> = Part::ALL.iter().map(|p| p.mesh()).collect();
    let mut spec = SceneSpec::new(1).noise(Some(NoiseModel::kinect()));
    for (part, mesh) in Part::ALL.iter().zip(&meshes) {
        spec = spec.object(part.object_id(), mesh);
    }
    let scene = spec.build().unwrap();
    let k = scene.frame.intrinsics;
    let masks: Vec<_> = scene
        .ground_truth
        .iter()
        .zip(&meshes)
        .map(|((_, pose), mesh)| render_depth(mesh, pose, &k, w, h).unwrap())
        .collect();
    let (per_part, on, off) = outline_pixels(&(w, h, rgb), &masks);
    eprintln!("outline pixels per part {per_part:?}; on a part {on}, elsewhere {off}");
    assert!(per_part.iter().all(|&n| n > 100), "{per_part:?}");
    assert!(
        off * 20 < on,
        "{off} outline pixels off the parts, {on} on them"
    );
}

/// `ppf detect --camera --overlay`: a daemon (`ppf serve`) over a part's model, this test
/// publishing the part's scene as a camera at 50 frames per second; the picture, drawn over
/// the frame the detection used (not a later one: the camera's queue holds two frames, fewer
/// than a detection lasts) from the models folder's mesh, outlines the part where it lies.
#[test]
fn the_camera_overlay_outlines_the_part_on_the_cameras_frame() {
    let scratch = Scratch::new("camera-overlay");
    let mut served = ServedPart::start(&scratch, "overlay", Part::TPipe, 5);
    let png_path = scratch.join("camera.png");
    let mut detect = Command::new(env!("CARGO_BIN_EXE_ppf"))
        .args([
            "detect",
            "--prefix",
            &served.prefix,
            "--camera",
            "cam",
            "--objects",
        ])
        .arg(served.part.object_id().to_string())
        .arg("--overlay")
        .arg(&png_path)
        .arg("--models")
        .arg(&served.models)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // The command asks before the camera's first frame: it waits for that frame rather than
    // being refused. Then publish until the command has its answer: both the daemon and the
    // command read frames.
    std::thread::sleep(std::time::Duration::from_millis(400));
    assert!(
        detect.try_wait().unwrap().is_none(),
        "ppf detect gave up before the camera's first frame"
    );
    let out = served.publish_every_until_done(std::time::Duration::from_millis(20), detect);
    let status = out.status;
    eprintln!(
        "{status:?}\n{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    let (f, mesh, scene) = (&served.scene.frame, &served.mesh, &served.scene);
    let k = f.intrinsics;
    assert!(status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("overlay written") && !stderr.contains("the overlay shows frame"),
        "{stderr}"
    );
    let picture = read_rgb(&png_path);
    let mask = render_depth(mesh, &scene.ground_truth[0].1, &k, f.width, f.height).unwrap();
    let (per_part, on, off) = outline_pixels(&picture, &[mask]);
    eprintln!("outline pixels on the part {per_part:?}, elsewhere {off}");
    assert!(
        on > 100 && off * 20 < on,
        "{on} on the part, {off} elsewhere"
    );
}

/// `ppf detect --camera --overlay` with `--models` holding another object's mesh under the
/// served part's id: the answer is printed, and the picture is refused, naming both diameters,
/// rather than outlining another object where the part was found.
#[test]
fn a_mesh_other_than_the_daemons_is_refused_after_the_answer() {
    let scratch = Scratch::new("camera-overlay-other");
    let mut served = ServedPart::start(&scratch, "overlay_other", Part::TPipe, 5);
    let served_diameter = ppfd_models::model::sampling::diameter(&served.mesh.positions);
    let other = Part::ALL
        .into_iter()
        .map(|p| p.mesh())
        .find(|m| {
            let d = ppfd_models::model::sampling::diameter(&m.positions);
            (d - served_diameter).abs() > 0.2 * served_diameter
        })
        .expect("a part of another size");
    let wrong = scratch.join("wrong-models");
    std::fs::create_dir_all(&wrong).unwrap();
    let id = served.part.object_id();
    std::fs::write(wrong.join(format!("obj_{id:06}.ply")), other.to_ply_ascii()).unwrap();
    let png_path = scratch.join("other.png");
    let detect = Command::new(env!("CARGO_BIN_EXE_ppf"))
        .args(["detect", "--prefix", &served.prefix, "--camera", "cam"])
        .args(["--objects", &id.to_string()])
        .arg("--overlay")
        .arg(&png_path)
        .arg("--models")
        .arg(&wrong)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let out = served.publish_every_until_done(std::time::Duration::from_millis(20), detect);
    let (stdout, stderr) = (
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr),
    );
    assert_eq!(out.status.code(), Some(1), "{stdout}\n{stderr}");
    assert!(
        stdout.contains("scene points"),
        "the answer is printed: {stdout}"
    );
    assert!(
        stderr.contains("mm across") && stderr.contains("no overlay written"),
        "{stderr}"
    );
    assert!(!png_path.exists());
}

/// An overlay path the picture cannot go to (not a PNG, in a folder that is not there) is
/// refused before the detection, in both modes; a colour image that does not read leaves the
/// picture on the depth, with a note, instead of losing the detection.
#[test]
fn overlay_paths_are_checked_first_and_a_broken_colour_image_falls_back_to_depth() {
    let scratch = Scratch::new("overlay-paths");
    let data = scratch.join("parts");
    let generate = Command::new(env!("CARGO_BIN_EXE_ppf"))
        .arg("generate")
        .arg(&data)
        .output()
        .unwrap();
    assert!(generate.status.success());
    let detect = |overlay: &std::path::Path| {
        Command::new(env!("CARGO_BIN_EXE_ppf"))
            .args(["detect", "--dataset"])
            .arg(&data)
            .args([
                "--scene",
                "0",
                "--image",
                "0",
                "--objects",
                "4",
                "--overlay",
            ])
            .arg(overlay)
            .output()
            .unwrap()
    };
    for (path, says) in [
        (scratch.join("picture.jpg"), "ending in .png"),
        (scratch.join("missing/picture.png"), "cannot write there"),
    ] {
        let out = detect(&path);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{stderr}");
        assert!(stderr.contains(says), "{stderr}");
        assert!(
            out.stdout.is_empty(),
            "refused before detecting: {}",
            String::from_utf8_lossy(&out.stdout)
        );
    }
    let camera = Command::new(env!("CARGO_BIN_EXE_ppf"))
        .args([
            "detect",
            "--camera",
            "cam",
            "--objects",
            "4",
            "--prefix",
            "ovpath_",
        ])
        .arg("--overlay")
        .arg(scratch.join("picture.jpg"))
        .arg("--models")
        .arg(data.join("models"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&camera.stderr);
    assert_eq!(camera.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("ending in .png"), "{stderr}");
    // A colour image cut short: the picture is drawn on the depth.
    let rgb = data.join("test/000000/rgb/000000.png");
    std::fs::create_dir_all(rgb.parent().unwrap()).unwrap();
    let mut png = Vec::new();
    {
        let mut encoder = png::Encoder::new(&mut png, 640, 480);
        encoder.set_color(png::ColorType::Rgb);
        let mut writer = encoder.write_header().unwrap();
        writer
            .write_image_data(&vec![128u8; 640 * 480 * 3])
            .unwrap();
    }
    std::fs::write(&rgb, &png[..png.len() / 3]).unwrap();
    let picture = scratch.join("depth.png");
    let out = detect(&picture);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("drawn on the depth instead"), "{stderr}");
    assert_eq!(read_rgb(&picture).0, 640);
}
