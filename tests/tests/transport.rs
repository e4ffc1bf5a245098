//! End-to-end tests of the transport: the real daemon (with a matching engine that only
//! answers), a camera process and client processes, each test under its own iceoryx2 prefix.

use std::path::Path;
use std::time::Duration;

use ppfd_tests::{fake_model_dir, Prefix, Proc};

const DAEMON: &str = env!("CARGO_BIN_EXE_e2e-daemon");
const CAMERA: &str = env!("CARGO_BIN_EXE_e2e-camera");
const CLIENT: &str = env!("CARGO_BIN_EXE_e2e-client");
const STARTUP: Duration = Duration::from_secs(20);

fn daemon(prefix: &Prefix, models: &Path, extra: &[&str], delay_ms: &str) -> Proc {
    let mut args = vec!["--prefix", &prefix.0, "--models", models.to_str().unwrap(), "--housekeeping-ms", "100"];
    args.extend_from_slice(extra);
    let mut d = Proc::spawn(Path::new(DAEMON), &args, &[("PPFD_TEST_ENGINE", "fake"), ("PPFD_FAKE_DELAY_MS", delay_ms)]);
    d.wait_line("ppfd ready", STARTUP);
    d
}

fn camera(prefix: &Prefix, name: &str, extra: &[&str]) -> Proc {
    let mut args = vec!["--prefix", &prefix.0, "--camera", name];
    args.extend_from_slice(extra);
    let mut c = Proc::spawn(Path::new(CAMERA), &args, &[]);
    c.wait_line("camera ready", STARTUP);
    c
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
    let mut a = client(&prefix, &["--camera", "cam0", "--objects", "1,2", "--requests", "20"]);
    let mut b = client(&prefix, &["--camera", "cam0", "--objects", "3", "--requests", "20"]);
    for (c, hyps) in [(&mut a, "2"), (&mut b, "1")] {
        let lines = results(c, Duration::from_secs(10));
        assert_eq!(lines.len(), 20);
        for l in &lines {
            let f: Vec<&str> = l.split(' ').collect();
            assert_eq!(f[0], "ok", "{l}");
            assert_eq!(f[2], hyps, "{l}");
            assert!(f[3].parse::<u64>().unwrap() > 0, "a camera frame was used: {l}");
        }
    }
    d.signal(libc::SIGTERM);
    let status = d.wait_exit(Duration::from_secs(5)).expect("daemon stops on SIGTERM");
    assert!(status.success(), "{status:?}");
}
