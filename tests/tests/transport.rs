//! End-to-end tests of the transport: the real daemon (with a matching engine that only
//! answers), a camera process and client processes, each test under its own iceoryx2 prefix.

use std::path::Path;
use std::time::Duration;

use ppfd_client::protocol::control::RECENT_WINDOW_NS;
use ppfd_tests::{fake_model_dir, Prefix, Proc};

mod common;
use common::{camera, fake_daemon, spawn_fake_daemon, CAMERA, CLIENT, DAEMON, STARTUP};

fn daemon(prefix: &Prefix, models: &Path, extra: &[&str], delay_ms: &str) -> Proc {
    fake_daemon(prefix, models, extra, &[("PPFD_FAKE_DELAY_MS", delay_ms)])
}

/// How many files the process `pid` (a daemon) has open.
fn open_files_of(pid: u32) -> usize {
    std::fs::read_dir(format!("/proc/{pid}/fd"))
        .expect("the daemon runs")
        .count()
}

fn client(prefix: &Prefix, args: &[&str]) -> Proc {
    let mut all = vec!["--prefix", &prefix.0];
    all.extend_from_slice(args);
    Proc::spawn(Path::new(CLIENT), &all, &[])
}

/// Reads a client's result lines up to `done`.
fn results(c: &mut Proc, timeout: Duration) -> Vec<String> {
    c.wait_line("client ready", STARTUP);
    let mut lines = Vec::new();
    loop {
        let line = c.wait_line("", timeout);
        if line == "done" {
            return lines;
        }
        lines.push(line);
    }
}

#[test]
fn two_clients_are_served_from_a_camera_and_the_daemon_stops_cleanly() {
    let prefix = Prefix::new("serve");
    let models = fake_model_dir("serve", &[1, 2, 3]);
    let mut d = daemon(&prefix, &models, &[], "2");
    let _cam = camera(&prefix, "cam0", &["--fps", "50"]);
    std::thread::sleep(Duration::from_millis(300));
    let mut a = client(
        &prefix,
        &["--camera", "cam0", "--objects", "1,2", "--requests", "20"],
    );
    let mut b = client(
        &prefix,
        &["--camera", "cam0", "--objects", "3", "--requests", "20"],
    );
    for (c, hyps) in [(&mut a, "2"), (&mut b, "1")] {
        let lines = results(c, Duration::from_secs(10));
        assert_eq!(lines.len(), 20);
        for l in &lines {
            let f: Vec<&str> = l.split(' ').collect();
            assert_eq!(f[0], "ok", "{l}");
            assert_eq!(f[2], hyps, "{l}");
            assert!(
                f[3].parse::<u64>().unwrap() > 0,
                "a camera frame was used: {l}"
            );
        }
    }
    d.signal(libc::SIGTERM);
    let status = d
        .wait_exit(Duration::from_secs(5))
        .expect("daemon stops on SIGTERM");
    assert!(status.success(), "{status:?}");
}

fn connect(prefix: &Prefix) -> ppfd_client::Client {
    let options = ppfd_client::ClientOptions {
        prefix: Some(prefix.0.clone()),
        inline_frame_capacity: 640 * 480,
        ..Default::default()
    };
    ppfd_client::Client::connect_with(&options).expect("client connects")
}

fn refusal(r: ppfd_client::Result<ppfd_client::Detections>) -> (ppfd_client::Status, u64, String) {
    match r {
        Err(ppfd_client::Error::Refused {
            status,
            value,
            message,
        }) => (status, value, message),
        other => panic!("expected a refusal, got {other:?}"),
    }
}

/// Two files of one object id at start: the first loaded (here by name) is kept and the other
/// is reported, rather than the later file silently replacing the earlier one. A file of
/// object id 0 is not loaded.
#[test]
fn a_second_model_file_with_a_loaded_id_is_refused_at_start() {
    let prefix = Prefix::new("dupid");
    let models = fake_model_dir("dupid", &[1, 2]);
    // `dup.fake` sorts before `obj_000001.fake`.
    std::fs::write(models.join("dup.fake"), "1 dup\n").unwrap();
    // Object id 0 is no id.
    std::fs::write(models.join("obj_000000.fake"), "0 nought\n").unwrap();
    let _d = daemon(&prefix, &models, &[], "0");
    let client = connect(&prefix);
    let listed = client.models().expect("models listed");
    let names: Vec<(u32, String)> = listed
        .iter()
        .map(|m| (m.object_id, m.name().to_string()))
        .collect();
    assert_eq!(names, [(1, "dup".to_string()), (2, "part2".to_string())]);
    // The statistics keep saying that files failed, long after the log's lines about them.
    let stats = client.stats().expect("statistics");
    assert_eq!(
        (
            stats.startup_files,
            stats.startup_files_done,
            stats.startup_files_failed
        ),
        (4, 4, 2),
        "{stats:?}"
    );
}

/// The daemon takes its prefix from `PPFD_PREFIX` as the clients do: the variable set for both
/// brings them together without a flag.
#[test]
fn the_daemon_takes_its_prefix_from_the_clients_variable() {
    let prefix = Prefix::new("envprefix");
    let models = fake_model_dir("envprefix", &[1]);
    let mut d = Proc::spawn(
        Path::new(DAEMON),
        &["--models", models.to_str().unwrap()],
        &[("PPFD_TEST_ENGINE", "fake"), ("PPFD_PREFIX", &prefix.0)],
    );
    d.wait_line("ppfd ready", STARTUP);
    let listed = connect(&prefix).models().expect("served under PPFD_PREFIX");
    assert_eq!(listed.len(), 1);
    // A client under another prefix is told which one it looked under.
    let other = Prefix::new("envprefix_other");
    match connect(&other).models() {
        Err(e @ ppfd_client::Error::NoDaemon { .. }) => {
            assert!(e.to_string().contains(&format!("{:?}", other.0)), "{e}")
        }
        r => panic!("expected NoDaemon, got {r:?}"),
    }
}

/// A camera whose driver has died is stale with the reason: its driver, not the age limit.
#[test]
fn a_camera_whose_driver_died_is_stale_saying_so() {
    use ppfd_client::{DetectOptions, Status};
    let prefix = Prefix::new("driverless");
    let models = fake_model_dir("driverless", &[1]);
    let _d = daemon(&prefix, &models, &["--max-frame-age-ms", "500"], "0");
    let cam = camera(&prefix, "cam0", &["--fps", "50"]);
    std::thread::sleep(Duration::from_millis(300));
    let client = connect(&prefix);
    let opts = DetectOptions::default();
    client
        .detect("cam0", &[1], &opts)
        .expect("a frame of the running driver served");
    drop(cam);
    // Beyond the age limit and a housekeeping round (100 ms), which lets go of a dead driver.
    std::thread::sleep(Duration::from_millis(1200));
    let (status, _, message) = refusal(client.detect("cam0", &[1], &opts));
    assert_eq!(status, Status::CameraStale, "{message}");
    assert!(
        message.contains("no driver publishes on it any more: restart its driver"),
        "{message}"
    );
}

#[test]
fn a_camera_that_stops_is_reported_stale_with_the_age_of_its_last_frame() {
    use ppfd_client::{DetectOptions, Status};
    let prefix = Prefix::new("stale");
    let models = fake_model_dir("stale", &[1]);
    let _d = daemon(&prefix, &models, &["--max-frame-age-ms", "1000"], "0");
    let mut cam = camera(&prefix, "cam0", &["--fps", "50", "--frames", "5"]);
    cam.wait_line("camera stopped", STARTUP);
    let client = connect(&prefix);
    let opts = DetectOptions::default();
    // Fresh enough right after the last frame (the limit is 1 s; generous for a loaded machine).
    client
        .detect("cam0", &[1], &opts)
        .expect("fresh frame served");
    std::thread::sleep(Duration::from_millis(1500));
    let (status, age_ns, message) = refusal(client.detect("cam0", &[1], &opts));
    assert_eq!(status, Status::CameraStale, "{message}");
    assert!(
        (1_500_000_000..10_000_000_000).contains(&age_ns),
        "age {age_ns} ns: {message}"
    );
    assert!(message.contains("ms old"), "{message}");
    // A request may accept older frames.
    let lenient = DetectOptions {
        max_frame_age: Some(Duration::from_secs(60)),
        ..opts
    };
    client
        .detect("cam0", &[1], &lenient)
        .expect("served with a larger age limit");
}

/// A driver that publishes one frame and then waits (`e2e-camera --frames 1`, `ppf replay`
/// without `--loop`), started before the daemon: the daemon gets that frame. The camera keeps
/// its newest frame for a late subscriber, but iceoryx2 hands it over only when the publisher
/// looks for subscribers: the driver waits with `CameraPublisher::idle`, since one that slept
/// would never look, and every request would be refused "camera has published no frame yet".
#[test]
fn a_frame_published_before_the_daemon_started_is_served() {
    let prefix = Prefix::new("early");
    let models = fake_model_dir("early", &[1]);
    let mut cam = camera(&prefix, "cam0", &["--frames", "1"]);
    cam.wait_line("camera stopped", STARTUP);
    let _d = daemon(&prefix, &models, &[], "0");
    let client = connect(&prefix);
    // The frame is as old as the daemon's start: this request takes it at any age.
    let opts = ppfd_client::DetectOptions {
        max_frame_age: Some(Duration::from_secs(600)),
        ..Default::default()
    };
    // The daemon subscribes when it finds the camera (at start, or within a housekeeping
    // round, 100 ms here); until then a request is refused "unknown camera" or "no frame yet".
    let deadline = std::time::Instant::now() + Duration::from_secs(5);
    let found = loop {
        match client.detect("cam0", &[1], &opts) {
            Ok(found) => break found,
            Err(e) if std::time::Instant::now() < deadline => {
                eprintln!("not yet: {e}");
                std::thread::sleep(Duration::from_millis(50));
            }
            Err(e) => panic!("the frame published before the daemon started never came: {e}"),
        }
    };
    assert_eq!(found.frame_sequence, 1, "the driver's only frame");
    assert!(
        (found.hypotheses[0].translation_mm[2] - 800.0).abs() < 1e-3,
        "its depth was read"
    );
}

/// A camera has one live driver: a second is refused by name while the first runs (the two would
/// interleave their frames, and detections would switch to whichever sent last), instead of
/// with iceoryx2's "ExceedsMaxSupportedPublishers" or not at all; once the first has died, a
/// driver that replaces it is let in.
#[test]
fn a_second_live_driver_of_a_camera_is_told_another_driver_publishes_under_its_name() {
    let prefix = Prefix::new("taken");
    let mut first = camera(&prefix, "cam0", &["--fps", "50"]);
    let driver = |name: &str| {
        ppfd_client::CameraPublisher::new(
            Some(&prefix.0),
            name,
            7,
            640,
            480,
            ppfd_client::Intrinsics::LMO,
            1.0,
        )
    };
    match driver("cam0") {
        Err(e @ ppfd_client::Error::CameraTaken { .. }) => {
            let text = e.to_string();
            assert!(
                text.contains("\"cam0\"") && text.contains("another driver already publishes"),
                "{text}"
            );
        }
        Err(e) => panic!("refused, but not as a camera with a driver: {e}"),
        Ok(_) => panic!("a second live driver of one camera was accepted"),
    }
    // Killed, the first driver leaves its publisher behind (iceoryx2 cleans it up when the next
    // node is made); its replacement takes the camera.
    first.signal(libc::SIGKILL);
    first
        .wait_exit(Duration::from_secs(5))
        .expect("driver died");
    let replacement = driver("cam0").expect("a driver replacing a dead one");
    // ... and is then the camera's live driver: a driver in another process is refused ...
    let mut other = Proc::spawn(
        Path::new(CAMERA),
        &["--prefix", &prefix.0, "--camera", "cam0"],
        &[],
    );
    let status = other.wait_exit(Duration::from_secs(10));
    assert!(
        status.is_some_and(|s| !s.success()),
        "a driver in another process was let in: {status:?}"
    );
    // ... while this process may make its publisher anew before dropping the old one.
    let again = driver("cam0").expect("one process making its publisher anew");
    drop(replacement);
    drop(again);
    // Another name is free.
    driver("cam1").expect("a driver under another name");
}

/// Detects on `camera` until served (a camera just started may not have published since the
/// daemon subscribed); panics after 10 s with the last refusal.
fn served_from(client: &ppfd_client::Client, camera: &str) {
    let deadline = std::time::Instant::now() + Duration::from_secs(10);
    loop {
        match client.detect(camera, &[1], &ppfd_client::DetectOptions::default()) {
            Ok(_) => return,
            Err(e) => assert!(std::time::Instant::now() < deadline, "{camera}: {e}"),
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// A camera without a driver for `--forget-camera-after-ms` is forgotten, and found again when a
/// driver publishes under its name. Otherwise a driver that names its camera anew on each run
/// (by process id, say) would leave one subscription behind per name, each keeping about three
/// files and half a megabyte of the dead driver's shared memory (measured: 332 files after 100
/// names).
#[test]
fn cameras_whose_driver_is_gone_are_forgotten_and_found_again() {
    use ppfd_client::Status;
    let prefix = Prefix::new("forget");
    let models = fake_model_dir("forget", &[1]);
    let d = daemon(&prefix, &models, &["--forget-camera-after-ms", "300"], "0");
    let pid = d.child.id();
    let open_files = || open_files_of(pid);
    let client = connect(&prefix);
    let unknown = || {
        let (status, _, message) =
            refusal(client.detect("run0", &[1], &ppfd_client::DetectOptions::default()));
        assert_eq!(status, Status::UnknownCamera, "{message}");
    };
    // Also opens the client's channels, so that the files counted next include them.
    unknown();
    client.stats().expect("statistics");
    let files_before = open_files();
    let runs = 20;
    for run in 0..runs {
        let name = format!("run{run}");
        let mut cam = camera(&prefix, &name, &["--fps", "50"]);
        served_from(&client, &name);
        cam.signal(libc::SIGKILL);
        cam.wait_exit(Duration::from_secs(5)).expect("driver died");
    }
    let deadline = std::time::Instant::now() + Duration::from_secs(20);
    let mut stats = client.stats().expect("statistics");
    while stats.cameras > 0 {
        assert!(
            std::time::Instant::now() < deadline,
            "cameras still subscribed 20 s after their drivers died: {stats:?}"
        );
        std::thread::sleep(Duration::from_millis(50));
        stats = client.stats().expect("statistics");
    }
    // What iceoryx2 keeps of a dead driver goes once the housekeeper has cleaned up after it.
    let mut files_after = open_files();
    while files_after > files_before + 3 && std::time::Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(50));
        files_after = open_files();
    }
    eprintln!(
        "{runs} drivers gone; daemon's open files {files_before} before, {files_after} after"
    );
    assert!(
        files_after <= files_before + 3,
        "{files_before} files open before, {files_after} after"
    );
    unknown();
    // A driver back under a forgotten name is picked up again.
    let _cam = camera(&prefix, "run0", &["--fps", "50"]);
    served_from(&client, "run0");
    assert_eq!(client.stats().expect("statistics").cameras, 1);
}

#[test]
fn malformed_requests_are_refused_each_with_its_error_and_the_daemon_keeps_serving() {
    use ppfd_client::protocol::detect::{flags, DetectRequestHeader};
    use ppfd_client::protocol::{text, PROTOCOL_VERSION};
    use ppfd_client::{DetectOptions, FrameHeader, Intrinsics, Status};
    let prefix = Prefix::new("malformed");
    let models = fake_model_dir("malformed", &[1, 2]);
    let _d = daemon(&prefix, &models, &[], "0");
    let _cam = camera(&prefix, "cam0", &["--fps", "50"]);
    std::thread::sleep(Duration::from_millis(300));
    let client = connect(&prefix);
    let opts = DetectOptions::default();
    let t = Duration::from_secs(5);

    let (status, value, message) = refusal(client.detect("cam0", &[1, 99], &opts));
    assert_eq!((status, value), (Status::UnknownObject, 99), "{message}");

    let (status, _, message) = refusal(client.detect("nocam", &[1], &opts));
    assert_eq!(status, Status::UnknownCamera, "{message}");

    let good = DetectRequestHeader {
        camera_name: text::encode_name("camera", "cam0").unwrap(),
        object_count: 1,
        object_ids: {
            let mut ids = [0; 32];
            ids[0] = 1;
            ids
        },
        ..Default::default()
    };
    let mut empty = good;
    empty.object_count = 0;
    let (status, _, message) = refusal(client.send_raw(&empty, &[], t));
    assert_eq!(status, Status::EmptyObjectList, "{message}");

    let mut version = good;
    version.protocol_version = PROTOCOL_VERSION + 1;
    let (status, value, message) = refusal(client.send_raw(&version, &[], t));
    assert_eq!(
        (status, value),
        (Status::ProtocolVersion, PROTOCOL_VERSION as u64),
        "{message}"
    );

    let frame = FrameHeader {
        width: 640,
        height: 480,
        intrinsics: Intrinsics::LMO,
        ..Default::default()
    };
    let mut inline = good;
    inline.flags = flags::INLINE_FRAME;
    inline.inline_frame = frame;
    let depth = vec![800u16; 640 * 480];
    let (status, _, message) = refusal(client.send_raw(&inline, &depth[..1000], t));
    assert_eq!(status, Status::InvalidFrame, "{message}");
    assert!(
        message.contains("307200") && message.contains("1000"),
        "{message}"
    );

    // Zero, NaN, or finite but no lens's focal length (one the detector would blame on the
    // depth); a principal point far outside the frame (poses would come out ~10³⁰ mm away).
    let bad_focal = [0.0, f32::NAN, 1.0e30, f32::MIN_POSITIVE].map(|fx| Intrinsics {
        fx,
        ..Intrinsics::LMO
    });
    let bad_centre = [1.0e30, -1000.0].map(|cx| Intrinsics {
        cx,
        ..Intrinsics::LMO
    });
    for bad in bad_focal.into_iter().chain(bad_centre) {
        let mut k = inline;
        k.inline_frame.intrinsics = bad;
        let (status, _, message) = refusal(client.send_raw(&k, &depth, t));
        assert_eq!(status, Status::InvalidIntrinsics, "{bad:?}: {message}");
    }

    // Stamped with wall-clock time instead of the monotonic clock: decades ahead, so its age
    // would read 0 and no frame would ever be stale.
    let wall_clock_ns = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_nanos() as u64;
    let mut ahead = inline;
    ahead.inline_frame.capture_time_ns = wall_clock_ns;
    let (status, _, message) = refusal(client.send_raw(&ahead, &depth, t));
    assert_eq!(status, Status::InvalidFrame, "{message}");
    assert!(
        message.contains("CLOCK_MONOTONIC") && message.contains("days ahead"),
        "{message}"
    );
    let _ahead_cam = camera(
        &prefix,
        "ahead",
        &["--fps", "50", "--stamp-ahead-ms", "3600000"],
    );
    // A device clock's offset gone wrong by half a second: its frames would read as that much
    // younger, and a camera stopped that long ago as live.
    let _skewed_cam = camera(
        &prefix,
        "skewed",
        &["--fps", "50", "--stamp-ahead-ms", "500"],
    );
    // No capture time: its age would read as the machine's uptime.
    let _unstamped_cam = camera(&prefix, "unstamped", &["--fps", "50", "--stamp", "zero"]);
    std::thread::sleep(Duration::from_millis(300));
    let (status, _, message) = refusal(client.detect("ahead", &[1], &opts));
    assert_eq!(status, Status::InvalidFrame, "{message}");
    assert!(message.contains("1.0 h ahead"), "{message}");
    let (status, _, message) = refusal(client.detect("skewed", &[1], &opts));
    assert_eq!(status, Status::InvalidFrame, "{message}");
    // Less the newest frame's age when the daemon looked, which a busy host stretches.
    let ahead_ms: f32 = message
        .split(" ms ahead")
        .next()
        .and_then(|m| m.rsplit(' ').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no lead in milliseconds: {message}"));
    assert!(ahead_ms > 100.0 && ahead_ms <= 500.0, "{message}");
    assert!(
        message.contains("(at most 100 ms)") && !message.ends_with('…'),
        "{message}"
    );
    let (status, _, message) = refusal(client.detect("unstamped", &[1], &opts));
    assert_eq!(status, Status::InvalidFrame, "{message}");
    assert!(
        message.contains("unstamped (capture_time_ns 0)") && message.ends_with("inline frames"),
        "{message}"
    );

    // Still serving, from the camera and inline.
    let found = client
        .detect("cam0", &[1, 2], &opts)
        .expect("camera request served");
    assert_eq!(found.hypotheses.len(), 2);
    let found = client
        .detect_inline(&frame, &depth, &[2], &opts)
        .expect("inline request served");
    assert_eq!(found.hypotheses[0].object_id, 2);
    assert!(
        (found.hypotheses[0].translation_mm[2] - 800.0).abs() < 1e-3,
        "the daemon read the inline depth"
    );
    // A worker answers its client before it reports to the daemon's statistics: the last
    // detection counts once nothing runs any more.
    let stats = settled_stats(&client);
    assert!(
        stats.requests_refused >= 11 && stats.requests_served >= 2,
        "{stats:?}"
    );
    // The last minute's latencies hold the detections just served, and no more than all.
    assert!(
        stats.recent_total.count >= 1
            && stats.recent_total.count <= stats.total.count
            && stats.recent_detection.max_ns <= stats.detection.max_ns
            && stats.recent_window_ns <= stats.uptime_ns.min(RECENT_WINDOW_NS),
        "{stats:?}"
    );
}

/// The daemon's statistics once nothing is queued or running (panics after 30 s).
fn settled_stats(client: &ppfd_client::Client) -> ppfd_client::DaemonStats {
    let deadline = std::time::Instant::now() + Duration::from_secs(30);
    loop {
        let stats = client.stats().expect("the daemon still answers");
        if stats.queued == 0 && stats.in_flight == 0 {
            return stats;
        }
        assert!(std::time::Instant::now() < deadline, "{stats:?}");
        std::thread::sleep(Duration::from_millis(10));
    }
}

#[test]
fn a_client_killed_mid_request_does_not_stall_the_next_one() {
    let prefix = Prefix::new("killed");
    let models = fake_model_dir("killed", &[1]);
    let _d = daemon(&prefix, &models, &[], "300");
    let _cam = camera(&prefix, "cam0", &["--fps", "50"]);
    std::thread::sleep(Duration::from_millis(300));
    let mut victim = client(
        &prefix,
        &["--camera", "cam0", "--objects", "1", "--requests", "3"],
    );
    victim.wait_line("client ready", STARTUP);
    std::thread::sleep(Duration::from_millis(100));
    victim.signal(libc::SIGKILL);
    victim
        .wait_exit(Duration::from_secs(5))
        .expect("victim died");

    let client = connect(&prefix);
    let started = std::time::Instant::now();
    let found = client
        .detect("cam0", &[1], &ppfd_client::DetectOptions::default())
        .expect("next client served");
    assert_eq!(found.hypotheses.len(), 1);
    // At most the victim's running detection (300 ms) stands before ours.
    assert!(
        started.elapsed() < Duration::from_millis(3000),
        "{:?}",
        started.elapsed()
    );
    let mut other = client_proc_served(&prefix);
    assert!(other.iter_mut().all(|l| l.starts_with("ok")), "{other:?}");
}

/// A client killed while its detection runs: the daemon cancels the detection, so the request
/// behind it waits about a housekeeping round, not the rest of the dead client's detection
/// (here 4 s).
#[test]
fn a_detection_whose_client_died_is_cancelled() {
    let prefix = Prefix::new("cancel");
    let models = fake_model_dir("cancel", &[1]);
    let _d = daemon(&prefix, &models, &["--parallel-detections", "1"], "4000");
    let _cam = camera(&prefix, "cam0", &["--fps", "50"]);
    std::thread::sleep(Duration::from_millis(300));
    let mut victim = client(&prefix, &["--camera", "cam0", "--objects", "1"]);
    victim.wait_line("client ready", STARTUP);
    std::thread::sleep(Duration::from_millis(300)); // its detection runs
    victim.signal(libc::SIGKILL);
    victim
        .wait_exit(Duration::from_secs(5))
        .expect("victim died");
    let client = connect(&prefix);
    // Its own detection takes the fake engine's 4 s, beyond the client's default timeout.
    let opts = ppfd_client::DetectOptions {
        timeout: Duration::from_secs(10),
        ..Default::default()
    };
    let found = client
        .detect("cam0", &[1], &opts)
        .expect("next client served");
    let waited = Duration::from_nanos(found.latency.daemon.queue_wait_ns);
    eprintln!("the next request waited {waited:?} in the queue");
    assert!(
        waited < Duration::from_millis(2000),
        "the next request waited {waited:?} behind a dead client's detection"
    );
}

/// While the daemon holds a request of a client that died, iceoryx2 keeps the connection to
/// that client (its shared memory mapped, file descriptors open), and it panics once more than
/// its buffer of such connections (128) pile up: held for ever, requests of dead clients would
/// let the 129th client killed mid-request take the daemon down.
#[test]
fn clients_killed_mid_request_by_the_hundred_leave_the_daemon_serving() {
    let prefix = Prefix::new("killings");
    let models = fake_model_dir("killings", &[1]);
    let d = daemon(&prefix, &models, &[], "300");
    let _cam = camera(&prefix, "cam0", &["--fps", "50"]);
    std::thread::sleep(Duration::from_millis(300));
    let observer = connect(&prefix);
    let pid = d.child.id();
    let open_files = || open_files_of(pid);
    let files_before = open_files();
    let wanted = 140; // more than iceoryx2's 128
    let mut batches = 0;
    let mut stats = observer.stats().expect("statistics");
    while stats.requests_abandoned < wanted {
        batches += 1;
        assert!(batches <= 20, "too few requests abandoned: {stats:?}");
        // 20 clients, each sends a request (most wait in the queue behind the 300 ms
        // detection) and is killed.
        let mut victims: Vec<Proc> = (0..20)
            .map(|_| client(&prefix, &["--camera", "cam0", "--objects", "1"]))
            .collect();
        for v in &mut victims {
            v.wait_line("client ready", STARTUP);
        }
        std::thread::sleep(Duration::from_millis(50));
        for v in &mut victims {
            v.signal(libc::SIGKILL);
            v.wait_exit(Duration::from_secs(5)).expect("victim died");
        }
        // Until the daemon has let go of the batch.
        stats = settled_stats(&observer);
    }
    let found = observer
        .detect("cam0", &[1], &ppfd_client::DetectOptions::default())
        .expect("a live client is served");
    assert_eq!(found.hypotheses.len(), 1);
    // The dead clients' connections are let go: the files that stay open are the live
    // client's, not about three per dead client (or one per batch of dead clients' requests
    // released at once).
    std::thread::sleep(Duration::from_millis(300)); // a few housekeeping rounds
    let files_after = open_files();
    eprintln!(
        "{} requests abandoned in {batches} batches; daemon's open files {files_before} before, {files_after} after",
        stats.requests_abandoned
    );
    assert!(
        files_after <= files_before + 15,
        "{files_before} files open before, {files_after} after"
    );
}

fn client_proc_served(prefix: &Prefix) -> Vec<String> {
    let mut c = client(
        prefix,
        &["--camera", "cam0", "--objects", "1", "--requests", "2"],
    );
    results(&mut c, Duration::from_secs(10))
}

/// A daemon killed under a request and restarted at once (as systemd's `Restart=` does): the
/// new daemon removes the dead one's ports as it starts, which lets go of the request before the
/// client's periodic check sees the death. The client says the daemon died, not that a live
/// daemon let go of the request.
#[test]
fn a_daemon_restarted_at_once_under_a_request_is_reported_gone() {
    let prefix = Prefix::new("restarted");
    let models = fake_model_dir("restarted", &[1]);
    let d = daemon(&prefix, &models, &[], "20000");
    let _cam = camera(&prefix, "cam0", &["--fps", "50"]);
    std::thread::sleep(Duration::from_millis(300));
    let client = connect(&prefix);
    let models_dir = models.to_path_buf();
    let prefix_name = prefix.0.clone();
    let restarter = std::thread::spawn(move || {
        std::thread::sleep(Duration::from_millis(300));
        let mut d = d;
        d.signal(libc::SIGKILL);
        d.wait_exit(Duration::from_secs(5)).expect("daemon killed");
        let again = Prefix(prefix_name);
        let new = spawn_fake_daemon(&again, &models_dir, &[], &[("PPFD_FAKE_DELAY_MS", "0")]);
        // The prefix's files belong to the test's own `Prefix`.
        std::mem::forget(again);
        new
    });
    let opts = ppfd_client::DetectOptions {
        timeout: Duration::from_secs(60),
        ..Default::default()
    };
    let result = client.detect("cam0", &[1], &opts);
    let _new = restarter.join().unwrap();
    assert!(
        matches!(result, Err(ppfd_client::Error::DaemonGone)),
        "{result:?}"
    );
}

/// A daemon killed while it works on a request never answers it: the client learns so at once
/// instead of waiting its whole timeout (here 60 s) for an answer that cannot come.
#[test]
fn a_client_learns_at_once_that_the_daemon_died_under_its_request() {
    let prefix = Prefix::new("died");
    let models = fake_model_dir("died", &[1]);
    let d = daemon(&prefix, &models, &[], "20000");
    let _cam = camera(&prefix, "cam0", &["--fps", "50"]);
    std::thread::sleep(Duration::from_millis(300));
    let client = connect(&prefix);
    let killer = std::thread::spawn(move || {
        std::thread::sleep(Duration::from_millis(500));
        d.signal(libc::SIGKILL);
        d
    });
    let started = std::time::Instant::now();
    let opts = ppfd_client::DetectOptions {
        timeout: Duration::from_secs(60),
        ..Default::default()
    };
    let result = client.detect("cam0", &[1], &opts);
    let waited = started.elapsed();
    eprintln!("the client returned {waited:?} after sending, the daemon killed at 0.5 s");
    let mut d = killer.join().unwrap();
    d.wait_exit(Duration::from_secs(5)).expect("daemon killed");
    assert!(
        matches!(result, Err(ppfd_client::Error::DaemonGone)),
        "{result:?} after {waited:?}"
    );
    // Killed after 0.5 s; the client looks every 0.25 s.
    assert!(
        waited < Duration::from_secs(5),
        "the client waited {waited:?}"
    );
}

#[test]
fn clients_reconnect_to_a_restarted_daemon() {
    let prefix = Prefix::new("restart");
    let models = fake_model_dir("restart", &[1]);
    let mut d = daemon(&prefix, &models, &[], "0");
    let _cam = camera(&prefix, "cam0", &["--fps", "50"]);
    std::thread::sleep(Duration::from_millis(300));
    let client = connect(&prefix);
    let opts = ppfd_client::DetectOptions {
        timeout: Duration::from_millis(2000),
        ..Default::default()
    };
    client
        .detect("cam0", &[1], &opts)
        .expect("served before the crash");
    // A timeout longer than any clock holds: the deadline sent saturates instead of wrapping
    // round into the past (the daemon refused it as "deadline exceeded").
    let forever = ppfd_client::DetectOptions {
        timeout: Duration::MAX,
        ..Default::default()
    };
    client
        .detect("cam0", &[1], &forever)
        .expect("served without a deadline");

    d.signal(libc::SIGKILL);
    d.wait_exit(Duration::from_secs(5)).expect("daemon killed");
    assert!(
        client.detect("cam0", &[1], &opts).is_err(),
        "no daemon, no answer"
    );

    // The new daemon removes what the dead one left and serves the same client again.
    let _d2 = daemon(&prefix, &models, &[], "0");
    let deadline = std::time::Instant::now() + Duration::from_secs(30);
    loop {
        match client.detect("cam0", &[1], &opts) {
            Ok(found) => {
                assert_eq!(found.hypotheses.len(), 1);
                break;
            }
            Err(e) if std::time::Instant::now() < deadline => {
                eprintln!("not yet: {e}");
                std::thread::sleep(Duration::from_millis(100));
            }
            Err(e) => panic!("the client never got through to the restarted daemon: {e}"),
        }
    }
}

#[test]
fn the_engine_reads_depth_in_place_in_shared_memory() {
    // The engine refuses any frame whose values do not lie in one /dev/shm mapping of the
    // daemon: a copy anywhere between the camera's (or client's) write and the engine's read
    // would put them on the heap.
    let prefix = Prefix::new("inplace");
    let models = fake_model_dir("inplace", &[1]);
    let _d = fake_daemon(&prefix, &models, &[], &[("PPFD_FAKE_CHECK_SHM", "1")]);
    let _cam = camera(&prefix, "cam0", &["--fps", "50"]);
    std::thread::sleep(Duration::from_millis(300));
    let client = connect(&prefix);
    let opts = ppfd_client::DetectOptions::default();
    let found = client
        .detect("cam0", &[1], &opts)
        .expect("camera frame read in place");
    assert!((found.hypotheses[0].translation_mm[2] - 800.0).abs() < 1e-3);
    let frame = ppfd_client::FrameHeader {
        width: 640,
        height: 480,
        intrinsics: ppfd_client::Intrinsics::LMO,
        ..Default::default()
    };
    let depth = vec![650u16; 640 * 480];
    let found = client
        .detect_inline(&frame, &depth, &[1], &opts)
        .expect("inline frame read in place");
    assert!((found.hypotheses[0].translation_mm[2] - 650.0).abs() < 1e-3);
}

/// A client beyond the most a daemon serves at once is told so, and one can connect again once
/// another has gone (it read "ExceedsMaxSupportedClients").
#[test]
fn a_client_beyond_the_most_the_daemon_serves_is_told_so() {
    let prefix = Prefix::new("maxclients");
    let models = fake_model_dir("maxclients", &[1]);
    let _d = daemon(&prefix, &models, &[], "0");
    let mut clients: Vec<ppfd_client::Client> = (0
        ..ppfd_client::protocol::services::limits::MAX_CLIENTS)
        .map(|_| connect(&prefix))
        .collect();
    let options = ppfd_client::ClientOptions {
        prefix: Some(prefix.0.clone()),
        ..Default::default()
    };
    match ppfd_client::Client::connect_with(&options) {
        Err(e @ ppfd_client::Error::TooManyClients { max: 32, .. }) => assert!(
            e.to_string()
                .contains("32 clients are connected to the daemon, the most it serves"),
            "{e}"
        ),
        other => panic!(
            "a client beyond the limit: {:?}",
            other.map(|_| "connected")
        ),
    }
    // The operator's tools connect without a detect port, and are served all the same, up to
    // the control service's own limit.
    let limits = ppfd_client::protocol::services::limits::MAX_CONTROL_CLIENTS;
    let control_only = ppfd_client::ClientOptions {
        detects: false,
        ..options.clone()
    };
    let mut tools: Vec<ppfd_client::Client> = (clients.len()..limits)
        .map(|_| ppfd_client::Client::connect_with(&control_only).expect("a tool connects"))
        .collect();
    tools[0].statistics().expect("statistics served to a tool");
    assert!(matches!(
        tools[0].detect("cam0", &[1], &ppfd_client::DetectOptions::default()),
        Err(ppfd_client::Error::ControlOnly)
    ));
    match ppfd_client::Client::connect_with(&control_only) {
        Err(ppfd_client::Error::TooManyClients { max, .. }) => assert_eq!(max, limits),
        other => panic!("a tool beyond the limit: {:?}", other.map(|_| "connected")),
    }
    tools.pop();
    clients.pop();
    let again = ppfd_client::Client::connect_with(&options).expect("a client connects again");
    again.models().expect("and is served");
}

/// A daemon holding more models than a listing carries lists the 256 of lowest id and says how
/// many it holds, rather than cutting the listing short without a word.
#[test]
fn a_listing_of_more_models_than_it_carries_says_how_many_are_loaded() {
    let prefix = Prefix::new("manymodels");
    let ids: Vec<u32> = (1..=300).collect();
    let models = fake_model_dir("manymodels", &ids);
    let _d = daemon(&prefix, &models, &[], "0");
    let listing = connect(&prefix).model_listing().expect("models listed");
    let listed: Vec<u32> = listing.models.iter().map(|m| m.object_id).collect();
    assert_eq!(listed, (1..=256).collect::<Vec<u32>>());
    assert_eq!(listing.loaded, 300);
    assert!(listing.is_partial());
}

#[test]
fn models_are_listed_loaded_and_dropped_at_run_time() {
    use ppfd_client::Status;
    let prefix = Prefix::new("control");
    let models = fake_model_dir("control", &[1, 2]);
    let _d = daemon(&prefix, &models, &[], "0");
    let _cam = camera(&prefix, "cam0", &["--fps", "50"]);
    std::thread::sleep(Duration::from_millis(300));
    let client = connect(&prefix);
    let ids = |c: &ppfd_client::Client| {
        c.models()
            .unwrap()
            .iter()
            .map(|m| m.object_id)
            .collect::<Vec<_>>()
    };
    assert_eq!(ids(&client), vec![1, 2]);
    let listing = client.model_listing().unwrap();
    assert_eq!((listing.loaded, listing.is_partial()), (2, false));

    let extra = models.join("extra.fake");
    std::fs::write(&extra, "7 bolt\n").unwrap();
    let loaded = client
        .load_model(extra.to_str().unwrap(), 0)
        .expect("model loaded");
    assert_eq!((loaded.object_id, loaded.name().as_ref()), (7, "bolt"));
    assert_eq!(ids(&client), vec![1, 2, 7]);
    let opts = ppfd_client::DetectOptions::default();
    client
        .detect("cam0", &[7], &opts)
        .expect("the new model is served");

    client.drop_model(2).expect("model dropped");
    assert_eq!(ids(&client), vec![1, 7]);
    let (status, value, _) = refusal(client.detect("cam0", &[2], &opts));
    assert_eq!((status, value), (Status::UnknownObject, 2));

    // A missing file is named as missing, also when its name carries no object id.
    for missing in ["/nonexistent/x.fake", "/nonexistent/obj_000007.ply"] {
        match client.load_model(missing, 0) {
            Err(ppfd_client::Error::Refused {
                status, message, ..
            }) => {
                assert_eq!(status, Status::ModelError);
                assert_eq!(message, format!("{missing}: no such file"));
            }
            other => panic!("{other:?}"),
        }
    }
    match client.load_model(models.to_str().unwrap(), 0) {
        Err(ppfd_client::Error::Refused { message, .. }) => {
            assert!(message.contains("is a folder"), "{message}");
        }
        other => panic!("{other:?}"),
    }
    // A relative path would name a file from the daemon's working directory, not the caller's.
    match client.load_model("extra.fake", 0) {
        Err(ppfd_client::Error::Refused {
            status, message, ..
        }) => {
            assert_eq!(status, Status::InvalidRequest);
            assert!(message.contains("relative path"), "{message}");
        }
        other => panic!("{other:?}"),
    }
    // A FIFO is refused at once: reading it would wait for a writer that never comes.
    let fifo = models.join("pipe.fake");
    let made = std::process::Command::new("mkfifo").arg(&fifo).status();
    assert!(made.is_ok_and(|s| s.success()), "mkfifo");
    match client.load_model(fifo.to_str().unwrap(), 0) {
        Err(ppfd_client::Error::Refused { message, .. }) => {
            assert!(message.contains("not a regular file"), "{message}");
        }
        other => panic!("{other:?}"),
    }
    std::fs::remove_file(&fifo).unwrap();
    // Object id 0 is refused, as `ppf model build` refuses it.
    let zero = models.join("obj_000000.fake");
    std::fs::write(&zero, "0 nought\n").unwrap();
    match client.load_model(zero.to_str().unwrap(), 0) {
        Err(ppfd_client::Error::Refused {
            status, message, ..
        }) => {
            assert_eq!(status, Status::ModelError);
            assert!(message.contains("ids start at 1"), "{message}");
        }
        other => panic!("{other:?}"),
    }
    // The refusal carries the unknown id as a detect refusal does.
    assert!(matches!(
        client.drop_model(99),
        Err(ppfd_client::Error::Refused {
            status: Status::UnknownObject,
            value: 99,
            ..
        })
    ));
    let stats = client.stats().unwrap();
    assert_eq!(stats.models_loaded, 2);
    assert!(stats.cameras >= 1 && stats.frames_received > 0, "{stats:?}");
}

/// A 48-megapixel camera frame (8000 × 6000) is refused before any detection starts, with the
/// limit named; so is an inline frame above the daemon's own limit. The daemon serves on.
#[test]
fn frames_beyond_the_pixel_limit_are_refused_naming_the_limit() {
    use ppfd_client::{DetectOptions, FrameHeader, Intrinsics, Status};
    let prefix = Prefix::new("bigframe");
    let models = fake_model_dir("bigframe", &[1]);
    let mut d = daemon(&prefix, &models, &[], "0");
    let mut huge = camera(&prefix, "huge", &["--fps", "2", "--size", "8000x6000"]);
    let _vga = camera(&prefix, "vga", &["--fps", "50"]);
    // A 48-megapixel frame takes a while to make on a loaded host: wait for the second, which
    // comes after the daemon's housekeeping has found the camera and subscribed.
    huge.wait_line("frame 2", STARTUP);
    let client = connect(&prefix);
    let opts = DetectOptions::default();
    let (status, _, message) = refusal(client.detect("huge", &[1], &opts));
    assert_eq!(status, Status::InvalidFrame, "{message}");
    assert!(
        message.contains("8000x6000")
            && message.contains(&ppfd_client::protocol::DEFAULT_MAX_FRAME_PIXELS.to_string())
            && message.contains("--max-frame-pixels"),
        "{message}"
    );
    client
        .detect("vga", &[1], &opts)
        .expect("a VGA frame is served");
    d.signal(libc::SIGTERM);
    d.wait_exit(Duration::from_secs(10));

    // The limit is the daemon's setting: below VGA, a VGA inline frame is refused.
    let prefix = Prefix::new("smallframes");
    let _d = daemon(&prefix, &models, &["--max-frame-pixels", "300000"], "0");
    let client = connect(&prefix);
    let frame = FrameHeader {
        width: 640,
        height: 480,
        intrinsics: Intrinsics::LMO,
        ..Default::default()
    };
    let depth = vec![800u16; 640 * 480];
    let (status, _, message) = refusal(client.detect_inline(&frame, &depth, &[1], &opts));
    assert_eq!(status, Status::InvalidFrame, "{message}");
    assert!(message.contains("limit of 300000"), "{message}");
}

/// A request beyond a full queue is refused "busy", naming the setting that holds more.
#[test]
fn a_request_beyond_a_full_queue_is_refused_naming_the_capacity() {
    let prefix = Prefix::new("busy");
    let models = fake_model_dir("busy", &[1]);
    let _d = daemon(&prefix, &models, &["--queue-capacity", "1"], "800");
    let _cam = camera(&prefix, "cam0", &["--fps", "50"]);
    std::thread::sleep(Duration::from_millis(300));
    let answers: Vec<_> = (0..4)
        .map(|_| {
            let prefix = prefix.0.clone();
            std::thread::spawn(move || {
                let client = ppfd_client::Client::connect_with(&ppfd_client::ClientOptions {
                    prefix: Some(prefix),
                    ..Default::default()
                })
                .expect("client connects");
                let options = ppfd_client::DetectOptions {
                    timeout: Duration::from_secs(20),
                    ..Default::default()
                };
                client.detect("cam0", &[1], &options)
            })
        })
        .collect::<Vec<_>>()
        .into_iter()
        .map(|t| t.join().unwrap())
        .collect();
    let busy: Vec<String> = answers
        .iter()
        .filter_map(|a| match a {
            Err(ppfd_client::Error::Refused {
                status: ppfd_client::Status::Busy,
                message,
                ..
            }) => Some(message.clone()),
            _ => None,
        })
        .collect();
    assert!(!busy.is_empty(), "{answers:?}");
    for m in &busy {
        assert!(
            m.contains("the most the queue holds") && m.contains("--queue-capacity"),
            "{m}"
        );
    }
}
