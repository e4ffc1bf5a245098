//! The service with several clients at once: two clients asking back to back for different
//! objects are served in turn, neither waiting behind a run of the other's requests, with one
//! detection at a time and with two.

use std::sync::{Arc, Barrier};
use std::time::{Duration, Instant};

use ppfd_client::{Client, ClientOptions, DetectOptions};
use ppfd_tests::{fake_model_dir, Prefix, Proc};

mod common;
use common::{camera, fake_daemon};

/// How long the stand-in engine takes per detection.
/// Long beside the scheduler's noise on a busy host, which the queue waits are compared with.
const DETECTION: Duration = Duration::from_millis(100);
const REQUESTS: usize = 20;

/// Per request of one client: when its answer came (since the start) and its queue wait.
type Served = Vec<(Duration, Duration)>;

/// A daemon with the stand-in engine, taking `detection` per detection of objects 1 and 2,
/// started with `args` besides its prefix and models, and a camera `cam0` publishing at 50 fps
/// under the same prefix; both running, the daemon subscribed.
fn fake_cell(prefix: &Prefix, name: &str, detection: Duration, args: &[&str]) -> (Proc, Proc) {
    let models = fake_model_dir(name, &[1, 2]);
    let delay = detection.as_millis().to_string();
    let daemon = fake_daemon(prefix, &models, args, &[("PPFD_FAKE_DELAY_MS", &delay)]);
    let cam = camera(prefix, "cam0", &["--fps", "50"]);
    std::thread::sleep(Duration::from_millis(300));
    (daemon, cam)
}

fn two_clients(parallel_detections: &str) -> (Served, Served) {
    let prefix = Prefix::new("load");
    let (_daemon, _cam) = fake_cell(
        &prefix,
        "load",
        DETECTION,
        &[
            "--parallel-detections",
            parallel_detections,
            "--workers",
            "2",
        ],
    );

    let start = Arc::new(Barrier::new(2));
    let t0 = Instant::now();
    let run = |object: u32| {
        let (prefix, start) = (prefix.0.clone(), start.clone());
        std::thread::spawn(move || -> Served {
            let client = Client::connect_with(&ClientOptions {
                prefix: Some(prefix),
                ..Default::default()
            })
            .expect("connected");
            let opts = DetectOptions::default();
            client.detect("cam0", &[object], &opts).expect("warm-up");
            start.wait();
            (0..REQUESTS)
                .map(|_| {
                    let d = client.detect("cam0", &[object], &opts).expect("served");
                    assert!(d.hypotheses.iter().all(|h| h.object_id == object));
                    (
                        t0.elapsed(),
                        Duration::from_nanos(d.latency.daemon.queue_wait_ns),
                    )
                })
                .collect()
        })
    };
    let (a, b) = (run(1), run(2));
    (a.join().unwrap(), b.join().unwrap())
}

/// Neither client's requests wait behind more than one detection of the other's, and each
/// client's answers are spread over the whole run, not bunched after the other's.
fn assert_served_in_turn(a: &Served, b: &Served, parallel: &str) {
    assert_eq!((a.len(), b.len()), (REQUESTS, REQUESTS));
    for (name, own) in [("a", a), ("b", b)] {
        let worst = own.iter().map(|s| s.1).max().unwrap();
        assert!(
            worst < 3 * DETECTION,
            "client {name} waited {worst:?} in the queue (parallel detections {parallel}); one detection is {DETECTION:?}"
        );
    }
    // When either client has its last answer, the other has most of its own.
    for (first, other) in [(a, b), (b, a)] {
        let done = first.last().unwrap().0;
        let other_done = other.iter().filter(|s| s.0 <= done).count();
        assert!(
            other_done >= REQUESTS - 3,
            "when one client had all {REQUESTS} answers the other had {other_done} (parallel detections {parallel})"
        );
    }
}

#[test]
fn two_clients_are_served_in_turn_one_detection_at_a_time() {
    let (a, b) = two_clients("1");
    assert_served_in_turn(&a, &b, "1");
}

#[test]
fn two_clients_are_served_in_turn_two_detections_at_a_time() {
    let (a, b) = two_clients("2");
    assert_served_in_turn(&a, &b, "2");
}

/// With more detections at once than workers, a job handed to the workers can wait for one:
/// the statistics count it as queued, not running, and its frame's age and the stale limit
/// count from when it starts. One worker, two detections at once, each 400 ms, a limit of
/// 250 ms: of two requests sent together, the one that waits for the worker finds its frame
/// (captured before the wait) stale when it starts.
#[test]
fn a_detection_waiting_for_a_worker_is_queued_and_judged_when_it_starts() {
    const SLOW: Duration = Duration::from_millis(400);
    let prefix = Prefix::new("poolwait");
    let (_daemon, _cam) = fake_cell(
        &prefix,
        "poolwait",
        SLOW,
        &[
            "--workers",
            "1",
            "--parallel-detections",
            "2",
            "--max-frame-age-ms",
            "250",
        ],
    );

    let connect = |prefix: &str| {
        Client::connect_with(&ClientOptions {
            prefix: Some(prefix.to_owned()),
            ..Default::default()
        })
        .expect("connected")
    };
    let start = Arc::new(Barrier::new(3));
    // A client is not `Send`: each thread connects its own.
    let ask = || {
        let (start, prefix) = (start.clone(), prefix.0.clone());
        std::thread::spawn(move || {
            let client = connect(&prefix);
            start.wait();
            client
                .detect("cam0", &[1], &DetectOptions::default())
                .map(|d| d.frame_age_ns)
        })
    };
    let (a, b) = (ask(), ask());
    let watcher = connect(&prefix.0);
    start.wait();
    std::thread::sleep(SLOW / 4);
    let (stats, _) = watcher.statistics().expect("statistics");
    assert_eq!(
        (stats.in_flight, stats.queued),
        (1, 1),
        "one detection runs on the one worker, the other waits for it"
    );
    let answers = [a.join().unwrap(), b.join().unwrap()];
    let served: Vec<_> = answers.iter().filter_map(|r| r.as_ref().ok()).collect();
    assert_eq!(served.len(), 1, "{answers:?}");
    assert!(
        *served[0] < 250_000_000,
        "served with a frame {} ms old",
        served[0] / 1_000_000
    );
    let refused = answers.iter().find_map(|r| r.as_ref().err()).unwrap();
    match refused {
        ppfd_client::Error::Refused { status, value, .. } => {
            assert_eq!(*status, ppfd_client::Status::CameraStale);
            // Its frame may be one that arrived after the first detection started: older than
            // the limit, not necessarily than the first detection.
            assert!(*value > 250_000_000, "{refused}");
        }
        other => panic!("{other}"),
    }
}
