//! One detect call: the newest frame of a camera, some objects, the poses and where the time
//! went.
//!
//! ```sh
//! cargo run --release -p ppfd-client --example detect -- kinect 1 5 6
//! ```

use ppfd_client::{Client, DetectOptions};

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
    let objects: Vec<u32> = args
        .map(|a| a.parse().map_err(|_| format!("{a:?} is not an object id")))
        .collect::<Result<_, _>>()?;
    let objects = if objects.is_empty() { vec![1] } else { objects };

    let client = Client::connect()?;
    let found = client.detect(
        &camera,
        &objects,
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
            h.instance_rank,
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
        "end to end {:.2} ms = detection {:.2} ms + overhead {:.3} ms (transport {:.3} + queue {:.3} + return {:.3})",
        l.end_to_end_ns as f64 / 1e6,
        l.daemon.detection_ns as f64 / 1e6,
        l.overhead_ns() as f64 / 1e6,
        l.daemon.transport_ns as f64 / 1e6,
        l.daemon.queue_wait_ns as f64 / 1e6,
        l.response_transport_ns as f64 / 1e6,
    );
    Ok(())
}
