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
