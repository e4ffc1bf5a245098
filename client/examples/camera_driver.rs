//! A camera driver: publishes depth frames into shared memory for the ppfd daemon.
//!
//! The depth here is synthetic (a tilted wall with a box on it) and written straight into the
//! loaned shared-memory slice, as a real driver would copy or DMA its sensor buffer there.
//!
//! ```sh
//! cargo run --release -p ppfd-client --example camera_driver -- kinect 30
//! ```

use std::time::{Duration, Instant};

use ppfd_client::{monotonic_now_ns, CameraPublisher, Intrinsics};

/// Ends with the error's message (its `Display`), as a command-line tool says it.
fn main() -> std::process::ExitCode {
    match run() {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}

fn run() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let camera = args.next().unwrap_or_else(|| "kinect".into());
    let fps: f64 = match args.next() {
        Some(v) => v
            .parse()
            .ok()
            .filter(|f: &f64| f.is_finite() && *f > 0.0 && *f <= 1000.0)
            .ok_or_else(|| format!("frames per second: {v:?} is not a number above 0 to 1000"))?,
        None => 30.0,
    };
    let (width, height) = (640u32, 480u32);
    // No prefix: PPFD_PREFIX's, as the daemon started in the same environment takes it.
    let mut publisher =
        CameraPublisher::new(None, &camera, 0, width, height, Intrinsics::LMO, 1.0)?;
    println!("publishing {width}x{height} depth as camera {camera:?} at {fps} fps (Ctrl-C stops)");

    let period = Duration::from_secs_f64(1.0 / fps);
    let mut next = Instant::now();
    loop {
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
        publisher.idle(next.saturating_duration_since(Instant::now()))?;
    }
}
