//! `ppf demo --overlay`: the picture it writes shows each part's outline where the part lies
//! (no data files needed).

mod common;

use std::process::Command;

use common::Scratch;
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
    let is_pose = |u: u32, v: u32| {
        let i = 3 * (v * w + u) as usize;
        POSE_COLOURS.iter().any(|c| rgb[i..i + 3] == *c)
    };
    let mut per_part = vec![0usize; masks.len()];
    let (mut on, mut off) = (0usize, 0usize);
    for v in 0..h {
        for u in 0..w {
            if !is_pose(u, v) {
                continue;
            }
            // Within two pixels of a silhouette: the detected pose is a few mm off the truth.
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
    eprintln!("outline pixels per part {per_part:?}; on a part {on}, elsewhere {off}");
    assert!(per_part.iter().all(|&n| n > 100), "{per_part:?}");
    assert!(
        off * 20 < on,
        "{off} outline pixels off the parts, {on} on them"
    );
}
