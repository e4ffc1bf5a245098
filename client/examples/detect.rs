//! One detect call: the newest frame of a camera, some objects, the poses and where the time
//! went.
//!
//! ```sh
//! cargo run --release -p ppfd-client --example detect -- kinect 1 5 6
//! ```

use ppfd_client::{Client, DetectOptions};

const USAGE: &str = "usage: detect [CAMERA [OBJECT_ID ...]]
  CAMERA     the camera whose newest frame to detect in (default: kinect)
  OBJECT_ID  object ids, from 1 (default: 1)
The daemon is the one of PPFD_PREFIX's prefix (default: iceoryx2's).";

/// Ends with the error's message (its `Display`), as a command-line tool says it: arguments
/// that do not parse with the usage and exit code 2, a failed detection with 1.
fn main() -> std::process::ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.iter().any(|a| a == "-h" || a == "--help") {
        println!("{USAGE}");
        return std::process::ExitCode::SUCCESS;
    }
    let (camera, objects) = match parse(&args) {
        Ok(parsed) => parsed,
        Err(e) => {
            eprintln!("error: {e}\n{USAGE}");
            return std::process::ExitCode::from(2);
        }
    };
    match run(&camera, &objects) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}

/// The camera and the object ids.
fn parse(args: &[String]) -> Result<(String, Vec<u32>), String> {
    let camera = args.first().cloned().unwrap_or_else(|| "kinect".into());
    if camera.starts_with('-') {
        return Err(format!(
            "{camera:?} is no camera name (this example takes no flags)"
        ));
    }
    let objects: Vec<u32> = args
        .iter()
        .skip(1)
        .map(|a| match a.parse::<u32>() {
            Ok(id) if id > 0 => Ok(id),
            _ => Err(format!("{a:?} is not an object id (a whole number from 1)")),
        })
        .collect::<Result<_, _>>()?;
    let objects = if objects.is_empty() { vec![1] } else { objects };
    Ok((camera, objects))
}

fn run(camera: &str, objects: &[u32]) -> Result<(), Box<dyn std::error::Error>> {
    let client = Client::connect()?;
    let found = client.detect(
        camera,
        objects,
        &DetectOptions {
            hypotheses_per_object: 3,
            // A cluttered frame takes seconds per object on a 2-core machine.
            timeout: std::time::Duration::from_secs(30),
            ..Default::default()
        },
    )?;
    for h in &found.hypotheses {
        let pose = h.isometry();
        let t = pose.translation.vector;
        println!(
            "object {:>3} #{}: score {:.3}, t = ({:.1}, {:.1}, {:.1}) mm, rotation {:.1} deg about {:?}",
            h.object_id,
            // From 1, as `ppf detect` counts.
            h.instance_rank + 1,
            h.score,
            t.x,
            t.y,
            t.z,
            pose.rotation.angle().to_degrees(),
            pose.rotation.axis().map(|a| [a.x, a.y, a.z])
        );
    }
    let l = &found.latency;
    println!(
        "end to end {:.2} ms = detection {:.2} ms + overhead {:.3} ms (transport {:.3} + queue {:.3} + hand-back {:.3} + return {:.3})",
        l.end_to_end_ns as f64 / 1e6,
        l.daemon.detection_ns as f64 / 1e6,
        l.overhead_ns() as f64 / 1e6,
        l.daemon.transport_ns as f64 / 1e6,
        l.daemon.queue_wait_ns as f64 / 1e6,
        l.hand_back_ns() as f64 / 1e6,
        l.response_transport_ns as f64 / 1e6,
    );
    Ok(())
}
