//! `ppf replay`: act as a camera driver, publishing the depth frames of a BOP dataset.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use clap::Args;
use ppfd_client::{monotonic_now_ns, CameraPublisher, Intrinsics};
use ppfd_models::bop::BopDataset;
use ppfd_models::camera::OwnedDepthFrame;

use crate::common::Connect;

/// Decoded frames kept in memory when looping.
const KEEP_DECODED_BYTES: usize = 1 << 30;

#[derive(Args, Debug)]
pub struct ReplayArgs {
    /// Root of a BOP dataset (e.g. ../shared/data/lmo).
    pub dataset: PathBuf,
    /// Camera name to publish as.
    #[arg(long)]
    pub camera: String,
    /// Frames per second, 0.01 to 1000.
    #[arg(long, default_value_t = 10.0, value_parser = parse_fps)]
    pub fps: f64,
    /// Start again after the last frame, until interrupted.
    #[arg(long = "loop")]
    pub repeat: bool,
    /// Dataset split folder (default: test).
    #[arg(long)]
    pub split: Option<String>,
    /// Only this scene.
    #[arg(long)]
    pub scene: Option<u32>,
    #[command(flatten)]
    pub connect: Connect,
}

pub fn run(args: ReplayArgs) -> Result<(), String> {
    let dataset = match &args.split {
        Some(split) => BopDataset::open_split(&args.dataset, split),
        None => BopDataset::open(&args.dataset),
    }
    .map_err(|e| e.to_string())?;
    let mut images = Vec::new();
    for scene in dataset.scene_ids() {
        if args.scene.is_some_and(|s| s != scene) {
            continue;
        }
        for im in dataset.image_ids(scene).map_err(|e| e.to_string())? {
            if dataset.has_depth(scene, im) {
                images.push((scene, im));
            }
        }
    }
    let Some(&(first_scene, first_im)) = images.first() else {
        return Err(format!(
            "{}: no depth frames to replay",
            args.dataset.display()
        ));
    };
    let first = dataset
        .depth_frame(first_scene, first_im)
        .map_err(|e| e.to_string())?;
    let k = first.intrinsics;
    let prefix = args
        .connect
        .prefix
        .clone()
        .or_else(ppfd_client::prefix_from_env);
    let mut camera = CameraPublisher::new(
        prefix.as_deref(),
        &args.camera,
        0,
        first.width,
        first.height,
        Intrinsics {
            fx: k.fx,
            fy: k.fy,
            cx: k.cx,
            cy: k.cy,
        },
        first.depth_scale_mm,
    )
    .map_err(|e| e.to_string())?;
    eprintln!(
        "replaying {} frames of {} as camera {:?} at {} fps{}",
        images.len(),
        args.dataset.display(),
        args.camera,
        args.fps,
        if args.repeat { ", looping" } else { "" }
    );
    let period = Duration::from_secs_f64(1.0 / args.fps);
    // When looping, frames are decoded once and kept (up to a memory budget): a camera driver
    // only copies a frame into shared memory, so the replayed camera should not spend ~1.5 ms
    // of CPU decoding a PNG per frame beside the daemon it feeds.
    let mut decoded: Vec<Option<OwnedDepthFrame>> = (0..images.len()).map(|_| None).collect();
    let mut kept_bytes = 0usize;
    decoded[0] = Some(first.clone());
    let mut next = Instant::now();
    loop {
        for (index, &(scene, im)) in images.iter().enumerate() {
            let read;
            let frame = match &decoded[index] {
                Some(frame) => frame,
                None => {
                    read = dataset.depth_frame(scene, im).map_err(|e| e.to_string())?;
                    let bytes = read.depth.len() * 2;
                    if args.repeat && kept_bytes + bytes <= KEEP_DECODED_BYTES {
                        kept_bytes += bytes;
                        decoded[index] = Some(read.clone());
                    }
                    &read
                }
            };
            if (frame.width, frame.height) != (first.width, first.height) {
                return Err(format!(
                    "scene {scene} image {im} is {}x{}, the camera publishes {}x{}",
                    frame.width, frame.height, first.width, first.height
                ));
            }
            let mut ready = camera
                .loan()
                .map_err(|e| e.to_string())?
                .write_from_slice(&frame.depth)
                .map_err(|e| e.to_string())?;
            let k = frame.intrinsics;
            let h = ready.header_mut();
            h.intrinsics = Intrinsics {
                fx: k.fx,
                fy: k.fy,
                cx: k.cx,
                cy: k.cy,
            };
            h.depth_scale_mm = frame.depth_scale_mm;
            let seq = ready.send(monotonic_now_ns()).map_err(|e| e.to_string())?;
            let objects: Vec<u32> = dataset
                .ground_truth(scene, im)
                .map(|g| g.iter().map(|p| p.obj_id).collect())
                .unwrap_or_default();
            println!("frame {seq}: scene {scene} image {im}, objects {objects:?}");
            next += period;
            std::thread::sleep(next.saturating_duration_since(Instant::now()));
        }
        if !args.repeat {
            return Ok(());
        }
    }
}

/// A frame rate from 0.01 to 1000 frames per second (NaN and infinity refused).
fn parse_fps(text: &str) -> Result<f64, String> {
    let fps: f64 = text.parse().map_err(|e| format!("{text:?}: {e}"))?;
    if (0.01..=1000.0).contains(&fps) {
        Ok(fps)
    } else {
        Err(format!("{fps} fps: give 0.01 to 1000"))
    }
}
