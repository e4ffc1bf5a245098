//! A camera driver for the end-to-end tests: publishes VGA frames of a flat wall (`--size WxH`
//! for another size), one frame of a
//! BOP dataset (`--bop <root> --scene <id> --image <id>`), or the generated scene of the generated
//! parts (`--parts-seed <seed>`, Kinect-like noise unless `--noise none`), at `--fps`, `--frames`
//! times (0: until killed), then stays alive without publishing (a camera that stopped; a
//! daemon that subscribes then still gets the last frame). `--stamp-ahead-ms MS` stamps frames
//! MS milliseconds ahead of the monotonic clock (a driver stamping another clock), `--stamp zero`
//! stamps them 0 (no capture time). Prints `scene
//! <checksum>` for a generated scene (`ppfd_tests::depth_checksum`, hex), `camera ready` when its
//! service exists, `frame <seq>` per frame and `camera stopped` after the last.

use std::io::Write;
use std::time::{Duration, Instant};

use ppfd_client::{monotonic_now_ns, CameraPublisher, Intrinsics};

fn arg(args: &[String], name: &str) -> Option<String> {
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1))
        .cloned()
}

/// The flags this driver knows; each takes a value.
const FLAGS: &[&str] = &[
    "--prefix",
    "--camera",
    "--fps",
    "--frames",
    "--parts-seed",
    "--noise",
    "--bop",
    "--scene",
    "--image",
    "--stamp-ahead-ms",
    "--stamp",
    "--size",
];

/// Stops with a usage line at an unknown flag (a typo would otherwise publish on the default
/// prefix) or a flag without its value.
fn check(args: &[String]) {
    for pair in args[1..].chunks(2) {
        if !FLAGS.contains(&pair[0].as_str()) || pair.len() < 2 {
            eprintln!(
                "e2e-camera: unknown flag or missing value at {:?}; flags, each with a value: {}",
                pair[0],
                FLAGS.join(" ")
            );
            std::process::exit(2);
        }
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    check(&args);
    let prefix = arg(&args, "--prefix");
    let camera = arg(&args, "--camera").unwrap_or_else(|| "cam0".into());
    let fps: f64 = arg(&args, "--fps")
        .and_then(|v| v.parse().ok())
        .unwrap_or(30.0);
    let frames: u64 = arg(&args, "--frames")
        .and_then(|v| v.parse().ok())
        .unwrap_or(0);
    let mut out = std::io::stdout().lock();
    let generated = arg(&args, "--parts-seed").map(|seed| {
        let seed: u64 = seed.parse().expect("--parts-seed takes a number");
        let noisy = arg(&args, "--noise").as_deref() != Some("none");
        let scene = ppfd_tests::parts_scene(seed, noisy);
        writeln!(
            out,
            "scene {:016x}",
            ppfd_tests::depth_checksum(&scene.frame.depth)
        )
        .unwrap();
        scene.frame
    });
    let loaded = generated.or_else(|| {
        arg(&args, "--bop").map(|root| {
            let scene: u32 = arg(&args, "--scene")
                .and_then(|v| v.parse().ok())
                .unwrap_or(0);
            let image: u32 = arg(&args, "--image")
                .and_then(|v| v.parse().ok())
                .unwrap_or(0);
            let dataset = ppfd_bop::dataset::BopDataset::open(&root).expect("BOP dataset");
            dataset.depth_frame(scene, image).expect("depth frame")
        })
    });
    let (width, height, intrinsics, scale, depth) = match loaded {
        Some(f) => {
            let k = f.intrinsics;
            let k = Intrinsics {
                fx: k.fx,
                fy: k.fy,
                cx: k.cx,
                cy: k.cy,
            };
            (f.width, f.height, k, f.depth_scale_mm, f.depth)
        }
        None => {
            let (w, h) = arg(&args, "--size")
                .and_then(|s| {
                    let (w, h) = s.split_once('x')?;
                    Some((w.parse::<u32>().ok()?, h.parse::<u32>().ok()?))
                })
                .unwrap_or((640, 480));
            let wall = vec![800u16; w as usize * h as usize];
            (w, h, Intrinsics::LMO, 1.0f32, wall)
        }
    };
    // A driver whose clock is not the daemon's (wall-clock time, say): its frames are stamped
    // this far ahead.
    let stamp_ahead_ns: u64 = arg(&args, "--stamp-ahead-ms")
        .map(|s| {
            s.parse::<u64>()
                .expect("--stamp-ahead-ms takes whole milliseconds")
                * 1_000_000
        })
        .unwrap_or(0);
    let unstamped = match arg(&args, "--stamp").as_deref() {
        None => false,
        Some("zero") => true,
        Some(other) => panic!("--stamp takes zero, not {other:?}"),
    };
    let mut publisher = CameraPublisher::new(
        prefix.as_deref(),
        &camera,
        7,
        width,
        height,
        intrinsics,
        scale,
    )
    .unwrap_or_else(|e| {
        // A refusal (another driver publishes under the name) is an answer, not a crash.
        eprintln!("e2e-camera: camera {camera:?}: {e}");
        std::process::exit(1);
    });
    writeln!(out, "camera ready").unwrap();
    out.flush().unwrap();
    let period = Duration::from_secs_f64(1.0 / fps.max(0.1));
    let mut next = Instant::now();
    let mut sent = 0;
    while frames == 0 || sent < frames {
        let seq = publisher
            .loan()
            .and_then(|frame| frame.write_from_slice(&depth))
            .and_then(|frame| {
                let stamp = if unstamped {
                    0
                } else {
                    monotonic_now_ns() + stamp_ahead_ns
                };
                frame.send(stamp)
            })
            .expect("publish");
        sent += 1;
        writeln!(out, "frame {seq}").unwrap();
        out.flush().unwrap();
        next += period;
        publisher
            .idle(next.saturating_duration_since(Instant::now()))
            .expect("idle");
    }
    writeln!(out, "camera stopped").unwrap();
    out.flush().unwrap();
    // Reachable while stopped: a daemon that subscribes now still gets the last frame.
    loop {
        publisher.idle(Duration::from_secs(3600)).expect("idle");
    }
}
