//! `ppf replay`: act as a camera driver, publishing the depth frames of a BOP dataset.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use clap::Args;
use ppfd_bop::dataset::BopDataset;
use ppfd_client::{monotonic_now_ns, CameraPublisher, Intrinsics};
use ppfd_models::geometry::camera::OwnedDepthFrame;

use crate::common::{scenes_there, Connect};
use crate::stop;

/// Decoded frames kept in memory when looping.
const KEEP_DECODED_BYTES: usize = 1 << 30;

/// How long a replay without `--loop` keeps its last frame published before it exits.
const LINGER: Duration = Duration::from_secs(2);

/// The longest a replay idles before it looks whether SIGINT or SIGTERM has stopped it.
const STOP_CHECK: Duration = Duration::from_millis(50);

/// Without `--verbose`, the time between two summary lines.
const SUMMARY_PERIOD: Duration = Duration::from_secs(10);

#[derive(Args, Debug)]
pub struct ReplayArgs {
    /// Root of a BOP dataset (e.g. ../shared/data/lmo).
    pub dataset: PathBuf,
    /// Camera name to publish as.
    #[arg(long, value_parser = crate::common::camera_name)]
    pub camera: String,
    /// Frames per second, 0.01 to 1000.
    #[arg(long, default_value_t = 10.0, value_parser = parse_fps)]
    pub fps: f64,
    /// Start again after the last frame, until interrupted. Without it the replay stays 2 s
    /// after its last frame, so that the daemon can take it, and exits.
    #[arg(long = "loop")]
    pub repeat: bool,
    /// Dataset split folder (default: test).
    #[arg(long)]
    pub split: Option<String>,
    /// Only this scene.
    #[arg(long)]
    pub scene: Option<u32>,
    /// Print a line for every frame published (default: the first frame's line, then a summary
    /// every 10 s).
    #[arg(long)]
    pub verbose: bool,
    #[command(flatten)]
    pub connect: Connect,
}

pub fn run(args: ReplayArgs) -> Result<(), String> {
    // Killed by the default action, a replay would leave its camera's shared memory (21 MB for
    // a VGA frame) behind; stopped this way, the publisher is dropped and takes it along.
    stop::handle_stop_signals(None);
    let dataset = match &args.split {
        Some(split) => BopDataset::open_split(&args.dataset, split),
        None => BopDataset::open(&args.dataset),
    }
    .map_err(|e| e.to_string())?;
    if let Some(scene) = args.scene {
        let scenes = dataset.scene_ids();
        if !scenes.contains(&scene) {
            let within = match dataset.split() {
                Some(split) if !split.is_empty() => format!(" in '{split}'"),
                _ => String::new(),
            };
            return Err(format!(
                "{}: no scene {scene}{within}; {}",
                args.dataset.display(),
                scenes_there(&scenes)
            ));
        }
    }
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
        return Err(match args.scene {
            Some(scene) => format!(
                "{}: scene {scene} has no depth frames to replay",
                args.dataset.display()
            ),
            None => format!("{}: no depth frames to replay", args.dataset.display()),
        });
    };
    let first = dataset
        .depth_frame(first_scene, first_im)
        .map_err(|e| e.to_string())?;
    let k = first.intrinsics;
    let prefix = args.connect.prefix()?;
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
    let mut progress = Progress::new(args.verbose, next);
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
            let line = progress.published(Instant::now(), || {
                let objects: Vec<u32> = dataset
                    .ground_truth(scene, im)
                    .map(|g| g.iter().map(|p| p.obj_id).collect())
                    .unwrap_or_default();
                format!("frame {seq}: scene {scene} image {im}, objects {objects:?}")
            });
            if let Some(line) = line {
                println!("{line}");
            }
            if !args.repeat && index + 1 == images.len() {
                // The last frame: the linger below follows it at once, while it is fresh.
                break;
            }
            next += period;
            // Not a plain sleep: a daemon that subscribes meanwhile gets this frame now, not
            // the next one (at --fps 0.2, five seconds later).
            idle(&camera, next.saturating_duration_since(Instant::now()))?;
        }
        if !args.repeat {
            if let Some(line) = progress.finished(Instant::now()) {
                println!("{line}");
            }
            // A frame whose publisher is gone before the daemon has read it is lost (iceoryx2
            // unmaps the publisher's memory; the daemon logs "Lost chunk"): stay until the
            // daemon has come round to it (it reads frames at requests and at least once a
            // housekeeping period, 1 s by default), handing the last frame to a daemon that
            // subscribes meanwhile.
            idle(&camera, LINGER)?;
            return Ok(());
        }
    }
}

/// [`CameraPublisher::idle`] for `duration`, ended early (with an error naming the signal) by
/// SIGINT or SIGTERM.
fn idle(camera: &CameraPublisher, duration: Duration) -> Result<(), String> {
    let until = Instant::now() + duration;
    loop {
        stop::check()?;
        let left = until.saturating_duration_since(Instant::now());
        camera
            .idle(left.min(STOP_CHECK))
            .map_err(|e| e.to_string())?;
        if left <= STOP_CHECK {
            return stop::check();
        }
    }
}

/// What replay prints as it publishes: every frame's line with `--verbose`; else the first
/// frame's line, then a summary at most every [`SUMMARY_PERIOD`]. A looping replay runs in the
/// background of the shell that runs `ppf detect` or `ppf bench`, and a line per frame (10 to
/// 30 a second) would drown their output.
struct Progress {
    verbose: bool,
    started: Instant,
    published: u64,
    /// When the last summary was printed (or the first frame's line), and the count then.
    last_line: Option<(Instant, u64)>,
}

impl Progress {
    fn new(verbose: bool, started: Instant) -> Progress {
        Progress {
            verbose,
            started,
            published: 0,
            last_line: None,
        }
    }

    /// Counts a frame published at `now`; the line to print, if any (`frame_line` describes
    /// the frame; it is called only when its line is printed).
    fn published(&mut self, now: Instant, frame_line: impl FnOnce() -> String) -> Option<String> {
        self.published += 1;
        match self.last_line {
            _ if self.verbose => Some(frame_line()),
            None => {
                self.last_line = Some((now, self.published));
                Some(frame_line())
            }
            Some((at, count)) if now.duration_since(at) >= SUMMARY_PERIOD => {
                self.last_line = Some((now, self.published));
                let rate = (self.published - count) as f64 / now.duration_since(at).as_secs_f64();
                Some(format!(
                    "{} frames published in {:.0} s, {rate:.1} per second over the last {:.0} s",
                    self.published,
                    now.duration_since(self.started).as_secs_f64(),
                    now.duration_since(at).as_secs_f64()
                ))
            }
            Some(_) => None,
        }
    }

    /// The closing line of a replay that ends (not with `--verbose`, whose frame lines say it
    /// all): how many frames were published, over how long.
    fn finished(&self, now: Instant) -> Option<String> {
        (!self.verbose && self.published > 1).then(|| {
            format!(
                "{} frames published in {:.1} s",
                self.published,
                now.duration_since(self.started).as_secs_f64()
            )
        })
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Without --verbose: the first frame's line, then one summary per period; with it, every
    /// frame's line.
    #[test]
    fn a_replay_says_little_unless_verbose() {
        let t0 = Instant::now();
        let at = |ms: u64| t0 + Duration::from_millis(ms);
        let mut quiet = Progress::new(false, t0);
        let mut printed = Vec::new();
        // 10 fps for 25 s.
        for i in 0..250u64 {
            if let Some(line) = quiet.published(at(i * 100), || format!("frame {i}")) {
                printed.push(line);
            }
        }
        assert_eq!(printed.len(), 3, "{printed:?}");
        assert_eq!(printed[0], "frame 0");
        assert_eq!(
            printed[1],
            "101 frames published in 10 s, 10.0 per second over the last 10 s"
        );
        assert!(printed[2].starts_with("201 frames published in 20 s"));
        assert_eq!(
            quiet.finished(at(25_000)).unwrap(),
            "250 frames published in 25.0 s"
        );

        let mut verbose = Progress::new(true, t0);
        for i in 0..25u64 {
            let line = verbose.published(at(i * 100), || format!("frame {i}"));
            assert_eq!(line.unwrap(), format!("frame {i}"));
        }
        assert!(verbose.finished(at(2_500)).is_none());
    }
}
