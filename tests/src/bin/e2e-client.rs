//! A robot process for the end-to-end tests: `--requests N` detect calls on `--camera` for
//! `--objects a,b` (`--hypotheses K` each), `--pause-ms` apart. Prints `client ready`, then per
//! request `ok <request id> <hypotheses> <frame sequence> <reference points>` or
//! `err <status code> <value> <message>` (`err transport 0 <message>` when the request never got
//! an answer from the daemon), then `done`. With `--poses`, every `ok` line is followed by one line per hypothesis:
//! `pose <object id> <rank> <score> <r00> <r01> … <r22> <tx> <ty> <tz>` (row-major rotation,
//! translation in mm, model → camera). With `--wait-frame-ms T`, a request refused because the
//! camera is not known yet or has no frame yet is retried for up to T ms.

use std::io::Write;
use std::time::{Duration, Instant};

use ppfd_client::{Client, ClientOptions, DetectOptions, Error, Status};

fn arg(args: &[String], name: &str) -> Option<String> {
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1))
        .cloned()
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let options = ClientOptions {
        prefix: arg(&args, "--prefix"),
        ..Default::default()
    };
    let camera = arg(&args, "--camera").unwrap_or_else(|| "cam0".into());
    let objects: Vec<u32> = arg(&args, "--objects")
        .unwrap_or_else(|| "1".into())
        .split(',')
        .filter_map(|s| s.parse().ok())
        .collect();
    let requests: u64 = arg(&args, "--requests")
        .and_then(|v| v.parse().ok())
        .unwrap_or(1);
    let pause = Duration::from_millis(
        arg(&args, "--pause-ms")
            .and_then(|v| v.parse().ok())
            .unwrap_or(0),
    );
    let timeout = Duration::from_millis(
        arg(&args, "--timeout-ms")
            .and_then(|v| v.parse().ok())
            .unwrap_or(5000),
    );
    let hypotheses: u32 = arg(&args, "--hypotheses")
        .and_then(|v| v.parse().ok())
        .unwrap_or(1);
    let poses = args.iter().any(|a| a == "--poses");
    let wait_frame = Duration::from_millis(
        arg(&args, "--wait-frame-ms")
            .and_then(|v| v.parse().ok())
            .unwrap_or(0),
    );
    let client = Client::connect_with(&options).expect("connect");
    let mut out = std::io::stdout().lock();
    writeln!(out, "client ready").unwrap();
    out.flush().unwrap();
    let detect = DetectOptions {
        timeout,
        hypotheses_per_object: hypotheses,
        ..Default::default()
    };
    for _ in 0..requests {
        let first_try = Instant::now();
        let answer = loop {
            match client.detect(&camera, &objects, &detect) {
                Err(Error::Refused {
                    status: Status::UnknownCamera | Status::NoFrame,
                    ..
                }) if first_try.elapsed() < wait_frame => {
                    std::thread::sleep(Duration::from_millis(50))
                }
                answer => break answer,
            }
        };
        match answer {
            Ok(d) => {
                writeln!(
                    out,
                    "ok {} {} {} {}",
                    d.request_id,
                    d.hypotheses.len(),
                    d.frame_sequence,
                    d.counts.reference_points
                )
                .unwrap();
                if poses {
                    for h in &d.hypotheses {
                        let numbers: Vec<String> = h
                            .rotation
                            .iter()
                            .chain(&h.translation_mm)
                            .map(|v| v.to_string())
                            .collect();
                        writeln!(
                            out,
                            "pose {} {} {} {}",
                            h.object_id,
                            h.instance_rank,
                            h.score,
                            numbers.join(" ")
                        )
                        .unwrap();
                    }
                }
            }
            Err(Error::Refused {
                status,
                value,
                message,
            }) => writeln!(out, "err {} {value} {message}", status.code()).unwrap(),
            Err(e) => writeln!(out, "err transport 0 {e}").unwrap(),
        }
        out.flush().unwrap();
        std::thread::sleep(pause);
    }
    writeln!(out, "done").unwrap();
    out.flush().unwrap();
}
