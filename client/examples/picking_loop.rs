//! A multi-object warehouse picking loop. Each cycle takes the next order (a few object ids),
//! asks the daemon for them in the camera's newest frame, picks the best-scored instance, "moves
//! the robot" there and reports the cycle time. Refusals (stale camera, unknown object) are
//! handled the way a cell controller would: skip, report, go on. The poses of the previous cycle
//! that it did not pick go with the request as hints: the daemon refines those first and votes
//! only for the objects whose hints fail, and the loop reports how many poses came from hints.
//!
//! ```sh
//! cargo run --release -p ppfd-client --example picking_loop -- kinect 20 1,5,6 8,9
//! ```
//!
//! `--timeout-ms N` anywhere among the arguments sets the detect timeout (default: the
//! library's); `--help` says the rest.

use std::time::{Duration, Instant};

use ppfd_client::protocol::MAX_HINTS_PER_REQUEST;
use ppfd_client::{checks, Client, DetectOptions, Error, PoseHint, PoseHypothesis, Status};

const USAGE: &str = "usage: picking_loop [CAMERA [CYCLES [ORDER ...]]] [--timeout-ms N]
  CAMERA         the camera to detect in (default: kinect)
  CYCLES         how many cycles to run (default: 10)
  ORDER          the object ids of one order, comma separated, from 1; the orders are taken in
                 turn (default: 1,5,6 8,9)
  --timeout-ms N the detect timeout, milliseconds above 0 (default: the library's, 3 s)
The daemon is the one of PPFD_PREFIX's prefix (default: iceoryx2's).";

/// What the loop is asked to do.
struct Args {
    camera: String,
    cycles: usize,
    orders: Vec<Vec<u32>>,
    timeout: Option<Duration>,
}

/// Ends with the error's message (its `Display`), as a command-line tool says it: arguments
/// that do not parse with the usage and exit code 2, a run that fails with 1.
fn main() -> std::process::ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.iter().any(|a| a == "-h" || a == "--help") {
        println!("{USAGE}");
        return std::process::ExitCode::SUCCESS;
    }
    let args = match parse(args) {
        Ok(parsed) => parsed,
        Err(e) => {
            eprintln!("error: {e}\n{USAGE}");
            return std::process::ExitCode::from(2);
        }
    };
    match run(args) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}

/// `--timeout-ms N` (or `=N`) anywhere; then the camera, the cycles and the orders in turn.
fn parse(args: Vec<String>) -> Result<Args, String> {
    let mut timeout = None;
    let mut positional = Vec::new();
    let mut args = args.into_iter();
    while let Some(a) = args.next() {
        let value = if a == "--timeout-ms" {
            Some(
                args.next()
                    .ok_or("--timeout-ms needs a number of milliseconds")?,
            )
        } else {
            a.strip_prefix("--timeout-ms=").map(str::to_owned)
        };
        match value {
            Some(v) => match v.parse::<u64>() {
                Ok(ms) if ms > 0 => timeout = Some(Duration::from_millis(ms)),
                _ => {
                    return Err(format!(
                        "--timeout-ms {v:?}: a number of milliseconds above 0"
                    ))
                }
            },
            None if a.starts_with('-') => return Err(format!("unknown flag {a:?}")),
            None => positional.push(a),
        }
    }
    let mut positional = positional.into_iter();
    let camera = positional.next().unwrap_or_else(|| "kinect".into());
    let cycles: usize = match positional.next() {
        Some(v) => v
            .parse()
            .map_err(|_| format!("cycles: {v:?} is not a count"))?,
        None => 10,
    };
    let orders: Vec<Vec<u32>> = positional
        .map(|o| {
            o.split(',')
                .map(|s| match s.parse::<u32>() {
                    Ok(id) if id > 0 => Ok(id),
                    _ => Err(format!(
                        "order {o:?}: {s:?} is not an object id (a whole number from 1)"
                    )),
                })
                .collect::<Result<Vec<u32>, String>>()
        })
        .collect::<Result<_, _>>()?;
    let orders = if orders.is_empty() {
        vec![vec![1, 5, 6], vec![8, 9]]
    } else {
        orders
    };
    Ok(Args {
        camera,
        cycles,
        orders,
        timeout,
    })
}

fn run(args: Args) -> Result<(), Box<dyn std::error::Error>> {
    let Args {
        camera,
        cycles,
        orders,
        timeout,
    } = args;
    let client = Client::connect()?;
    // The default timeout, 3 s, is about six times what eight objects in a cluttered VGA frame
    // take on two cores (0.52 s).
    let options = DetectOptions {
        // Each object's best pose: a second pose that passes both filters is often a partial
        // fit beside the first, and a cell would send the robot to it.
        hypotheses_per_object: 1,
        max_frame_age: Some(Duration::from_millis(500)),
        ..Default::default()
    };
    let mut options = DetectOptions {
        timeout: timeout.unwrap_or(options.timeout),
        ..options
    };
    let mut picked = 0;
    // The previous cycle's poses that passed both filters, less the one picked.
    let mut known: Vec<PoseHypothesis> = Vec::new();
    // How the cycles ended, for the summary line: refusals the cell
    // expects (a stale camera, a daemon restarting), answers that never came, and answers that
    // do not match their request (poses of objects not asked for).
    let (mut refused, mut failed, mut mismatched) = (0usize, 0usize, 0usize);
    for cycle in 0..cycles {
        let order = &orders[cycle % orders.len()];
        let start = Instant::now();
        options.hints = known
            .iter()
            .filter(|h| order.contains(&h.object_id))
            .take(MAX_HINTS_PER_REQUEST)
            .map(PoseHint::from)
            .collect();
        let found = match client.detect(&camera, order, &options) {
            Ok(found) => found,
            Err(Error::Refused {
                status: Status::CameraStale,
                value,
                ..
            }) => {
                println!(
                    "cycle {cycle}: camera stale ({:.0} ms), waiting for the driver",
                    value as f64 / 1e6
                );
                refused += 1;
                std::thread::sleep(Duration::from_millis(200));
                continue;
            }
            // Waiting out the daemon (restarting, or not yet up), or a camera that has not
            // published yet: retrying at once would spin; wait before the next cycle.
            Err(
                e @ (Error::NoDaemon { .. }
                | Error::DaemonGone
                | Error::Refused {
                    status: Status::NoFrame | Status::UnknownCamera | Status::Busy,
                    ..
                }),
            ) => {
                println!("cycle {cycle}: {e}; retrying in 0.5 s");
                refused += 1;
                std::thread::sleep(Duration::from_millis(500));
                continue;
            }
            Err(e) => {
                println!("cycle {cycle}: {e}");
                failed += 1;
                std::thread::sleep(Duration::from_millis(100));
                continue;
            }
        };
        if let Some(h) = found
            .hypotheses
            .iter()
            .find(|h| !order.contains(&h.object_id))
        {
            println!(
                "cycle {cycle}: MISMATCH: asked for {order:?}, answered object {}",
                h.object_id
            );
            mismatched += 1;
            continue;
        }
        let both = checks::CONSISTENT | checks::SILHOUETTE;
        let passed: Vec<&PoseHypothesis> = found
            .hypotheses
            .iter()
            .filter(|h| h.checks & both == both)
            .collect();
        let from_hints = passed
            .iter()
            .filter(|h| h.checks & checks::HINT != 0)
            .count();
        // The best-scored instance of any object of the order is the next pick.
        let Some(best) = passed
            .iter()
            .copied()
            .max_by(|a, b| a.score.total_cmp(&b.score))
        else {
            println!("cycle {cycle}: nothing of {order:?} in view");
            known.clear();
            continue;
        };
        // What is left in view for the next cycle: every pose but the one picked. Objects of
        // other orders keep their poses from earlier cycles.
        known.retain(|h| !order.contains(&h.object_id));
        known.extend(
            passed
                .iter()
                .filter(|h| !std::ptr::eq(**h, best))
                .copied()
                .copied(),
        );
        let pose = best.isometry();
        let t = pose.translation.vector;
        // A real cell would plan a grasp from `pose` and move the arm here.
        picked += 1;
        println!(
            "cycle {cycle}: order {order:?} -> pick object {} (score {:.2}) at ({:.0}, {:.0}, {:.0}) mm; \
             {from_hints} of {} poses from {} hints; cycle {:.1} ms (detection {:.1} ms, overhead \
             {:.3} ms, frame {} aged {:.1} ms)",
            best.object_id,
            best.score,
            t.x,
            t.y,
            t.z,
            passed.len(),
            options.hints.len(),
            start.elapsed().as_secs_f64() * 1e3,
            found.latency.daemon.detection_ns as f64 / 1e6,
            found.latency.overhead_ns() as f64 / 1e6,
            found.frame_sequence,
            found.frame_age_ns as f64 / 1e6,
        );
    }
    println!(
        "{picked} picks in {cycles} cycles; {refused} refused or waited, {failed} failed, {mismatched} mismatched"
    );
    if mismatched > 0 {
        return Err(format!("{mismatched} answers did not match their requests").into());
    }
    if cycles > 0 && failed == cycles {
        return Err("every cycle failed".into());
    }
    Ok(())
}
