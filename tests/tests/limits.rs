//! What one model load may cost the daemon, end to end with the real engine: four clients
//! asking at once to build models of a large generated mesh are served one build at a time, so
//! the daemon's peak memory stays under a stated bound instead of four builds' worth.

use std::path::Path;
use std::time::Duration;

use nalgebra::Point3;
use ppfd_models::geometry::mesh::Mesh;
use ppfd_tests::{Prefix, Proc, WorkDir};

mod common;
use common::DAEMON;

/// The daemon builds no model at start here, but a loaded CI machine starts slowly.
const STARTUP: Duration = Duration::from_secs(60);

/// Latitude and longitude steps of the generated sphere: 2 × 500 × 500 = 500 000 faces, a
/// quarter of the largest mesh a model is built from.
const RINGS: u32 = 500;
const SEGMENTS: u32 = 500;

/// A closed sphere of radius 50 mm with `2 × RINGS × SEGMENTS` triangles, the poles fanned.
fn sphere() -> Mesh {
    let r = 50.0f32;
    let mut positions = vec![Point3::new(0.0, 0.0, r)];
    for i in 1..RINGS {
        let theta = std::f32::consts::PI * i as f32 / RINGS as f32;
        for j in 0..SEGMENTS {
            let phi = std::f32::consts::TAU * j as f32 / SEGMENTS as f32;
            positions.push(Point3::new(
                r * theta.sin() * phi.cos(),
                r * theta.sin() * phi.sin(),
                r * theta.cos(),
            ));
        }
    }
    positions.push(Point3::new(0.0, 0.0, -r));
    let south = positions.len() as u32 - 1;
    let at = |ring: u32, j: u32| 1 + (ring - 1) * SEGMENTS + j % SEGMENTS;
    let mut faces = Vec::new();
    for j in 0..SEGMENTS {
        faces.push([0, at(1, j), at(1, j + 1)]);
        faces.push([south, at(RINGS - 1, j + 1), at(RINGS - 1, j)]);
    }
    for ring in 1..RINGS - 1 {
        for j in 0..SEGMENTS {
            let (a, b) = (at(ring, j), at(ring, j + 1));
            let (c, d) = (at(ring + 1, j), at(ring + 1, j + 1));
            faces.push([a, c, d]);
            faces.push([a, d, b]);
        }
    }
    Mesh::from_triangles(positions, &faces).unwrap()
}

/// The peak resident memory of process `pid` so far (`VmHWM`), bytes.
fn peak_rss(pid: u32) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    let line = status
        .lines()
        .find(|l| l.starts_with("VmHWM:"))
        .expect("VmHWM");
    let kb: u64 = line.split_whitespace().nth(1).unwrap().parse().unwrap();
    kb * 1024
}

/// The bound on the daemon's peak above idle: one build of the sphere at a time, and the four
/// models (11 MB each) it keeps, stay under it; the four builds at once go about a third
/// beyond it.
const BOUND_ABOVE_IDLE: u64 = 180 << 20;

#[test]
fn four_loads_at_once_are_built_one_at_a_time_within_the_memory_bound() {
    let work = WorkDir::new("four-loads");
    let (models, cache) = (work.join("models"), work.join("cache"));
    std::fs::create_dir_all(&models).unwrap();
    let ply = sphere().to_ply_ascii();
    let meshes: Vec<_> = (11..15)
        .map(|id| {
            let path = models.join(format!("obj_{id:06}.ply"));
            std::fs::write(&path, &ply).unwrap();
            path
        })
        .collect();
    drop(ply);
    let prefix = Prefix::new("four-loads");
    let empty = work.join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    let mut daemon = Proc::spawn(
        Path::new(DAEMON),
        &[
            "--prefix",
            &prefix.0,
            "--models",
            empty.to_str().unwrap(),
            "--model-cache",
            cache.to_str().unwrap(),
        ],
        &[],
    );
    daemon.wait_line("ppfd ready", STARTUP);
    let idle = peak_rss(daemon.child.id());
    let loads: Vec<_> = meshes
        .iter()
        .map(|mesh| {
            let (prefix, mesh) = (prefix.0.clone(), mesh.clone());
            std::thread::spawn(move || {
                let options = ppfd_client::ClientOptions {
                    prefix: Some(prefix),
                    control_timeout: Duration::from_secs(600),
                    ..Default::default()
                };
                let client = ppfd_client::Client::connect_with(&options).unwrap();
                client.load_model(mesh.to_str().unwrap(), 0)
            })
        })
        .collect();
    for load in loads {
        let info = load.join().unwrap().expect("loaded");
        assert!((info.diameter_mm - 100.0).abs() < 0.5, "{info:?}");
    }
    let peak = peak_rss(daemon.child.id());
    eprintln!(
        "daemon peak {} MB, {} MB above idle",
        peak >> 20,
        (peak - idle) >> 20
    );
    assert!(
        peak - idle < BOUND_ABOVE_IDLE,
        "four loads took the daemon {} MB above idle, the bound is {} MB",
        (peak - idle) >> 20,
        BOUND_ABOVE_IDLE >> 20
    );
}
