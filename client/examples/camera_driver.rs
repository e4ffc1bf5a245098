//! A camera driver: publishes depth frames into shared memory for the ppfd daemon.
//!
//! The depth here is synthetic (a tilted wall with a box on it) and written straight into the
//! loaned shared-memory slice, as a real driver would copy or DMA its sensor buffer there.
//!
//! ```sh
//! cargo run --release -p ppfd-client --example camera_driver -- kinect 30
//! ```

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use ppfd_client::{monotonic_now_ns, CameraPublisher, Intrinsics};

const USAGE: &str = "usage: camera_driver [CAMERA [FPS]]
  CAMERA  the name to publish as (default: kinect)
  FPS     frames per second, above 0 to 1000 (default: 30)
Ctrl-C or SIGTERM stops it; the daemon is the one of PPFD_PREFIX's prefix.";

/// Ends with the error's message (its `Display`), as a command-line tool says it: arguments
/// that do not parse with the usage and exit code 2, a failure while publishing with 1.
fn main() -> std::process::ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.iter().any(|a| a == "-h" || a == "--help") {
        println!("{USAGE}");
        return std::process::ExitCode::SUCCESS;
    }
    let (camera, fps) = match parse(&args) {
        Ok(parsed) => parsed,
        Err(e) => {
            eprintln!("error: {e}\n{USAGE}");
            return std::process::ExitCode::from(2);
        }
    };
    match run(&camera, fps, stop_on_signals()) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}

/// The camera name and the frame rate.
fn parse(args: &[String]) -> Result<(String, f64), String> {
    if args.len() > 2 {
        return Err(format!("{} arguments; it takes at most 2", args.len()));
    }
    let camera = args.first().cloned().unwrap_or_else(|| "kinect".into());
    if camera.starts_with('-') {
        return Err(format!(
            "{camera:?} is no camera name (this example takes no flags)"
        ));
    }
    let fps = match args.get(1) {
        Some(v) => v
            .parse()
            .ok()
            .filter(|f: &f64| f.is_finite() && *f > 0.0 && *f <= 1000.0)
            .ok_or_else(|| format!("frames per second: {v:?} is not a number above 0 to 1000"))?,
        None => 30.0,
    };
    Ok((camera, fps))
}

/// A flag set once SIGINT or SIGTERM arrives. The driver then returns and drops its publisher,
/// which removes the camera's shared memory; killed by the signal's default action instead, it
/// would leave the memory for the daemon's cleanup to find.
fn stop_on_signals() -> Arc<AtomicBool> {
    let stop = Arc::new(AtomicBool::new(false));
    // SAFETY: plain libc calls on a local signal set; blocked before any other thread starts,
    // so that every thread inherits the mask and only the waiting thread takes the signals.
    let set = unsafe {
        let mut set: libc::sigset_t = std::mem::zeroed();
        libc::sigemptyset(&mut set);
        libc::sigaddset(&mut set, libc::SIGINT);
        libc::sigaddset(&mut set, libc::SIGTERM);
        libc::pthread_sigmask(libc::SIG_BLOCK, &set, std::ptr::null_mut());
        set
    };
    let flag = stop.clone();
    std::thread::spawn(move || {
        let mut signal = 0;
        // SAFETY: waits for one of the signals blocked above.
        while unsafe { libc::sigwait(&set, &mut signal) } != 0 {}
        flag.store(true, Ordering::SeqCst);
    });
    stop
}

fn run(camera: &str, fps: f64, stop: Arc<AtomicBool>) -> Result<(), Box<dyn std::error::Error>> {
    let (width, height) = (640u32, 480u32);
    // No prefix: PPFD_PREFIX's, as the daemon started in the same environment takes it.
    let mut publisher = CameraPublisher::new(None, camera, 0, width, height, Intrinsics::LMO, 1.0)?;
    println!("publishing {width}x{height} depth as camera {camera:?} at {fps} fps (Ctrl-C stops)");

    let period = Duration::from_secs_f64(1.0 / fps);
    let mut next = Instant::now();
    while !stop.load(Ordering::SeqCst) {
        let capture = monotonic_now_ns();
        let t = (capture / 1_000_000) as f32 / 1000.0;
        let frame = publisher.loan()?.write_from_fn(|i| {
            let (u, v) = ((i as u32 % width) as f32, (i as u32 / width) as f32);
            let wall = 900.0 + 0.2 * u + 0.1 * v;
            let in_box =
                (250.0..390.0).contains(&(u - 40.0 * t.sin())) && (180.0..300.0).contains(&v);
            (if in_box { wall - 80.0 } else { wall }) as u16
        });
        let seq = frame.send(capture)?;
        if seq % 30 == 0 {
            println!("frame {seq}");
        }
        next += period;
        // Not a plain sleep: a daemon that subscribes between frames gets the newest at once.
        // In steps, so that a stop is seen within 50 ms at any frame rate.
        while !stop.load(Ordering::SeqCst) {
            let left = next.saturating_duration_since(Instant::now());
            if left.is_zero() {
                break;
            }
            publisher.idle(left.min(Duration::from_millis(50)))?;
        }
    }
    println!("stopped; camera {camera:?} removed");
    Ok(())
}
