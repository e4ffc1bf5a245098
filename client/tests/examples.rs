//! The examples as a user runs them: `--help` says how, arguments that do not parse are a
//! usage error (exit 2) before anything connects, and the camera driver stopped with SIGTERM
//! removes its camera's shared memory. They are built with the tests (`cargo test` builds a
//! package's examples), beside them in the target folder.

use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// The example `name`, built by this `cargo test` run.
fn example(name: &str) -> PathBuf {
    let exe = std::env::current_exe().expect("the test's path");
    // target/<profile>/deps/examples-<hash> → target/<profile>/examples/<name>
    let path = exe
        .parent()
        .and_then(|deps| deps.parent())
        .expect("the target folder")
        .join("examples")
        .join(name);
    assert!(path.is_file(), "{} is not built", path.display());
    path
}

/// Runs `command` to its end, killing it after 20 s: an example that takes an argument for
/// a camera to publish or ask for would run on, and fail here, not hold the test run.
fn output_within(command: &mut Command) -> std::process::Output {
    let mut child = command
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let started = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if started.elapsed() > Duration::from_secs(20) {
            let _ = child.kill();
            let out = child.wait_with_output().unwrap();
            panic!("{command:?} still ran after 20 s: {out:?}");
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    child.wait_with_output().unwrap()
}

#[test]
fn help_and_bad_arguments_are_said_with_the_usage() {
    for (name, bad) in [
        ("detect", &["cam", "0"][..]),
        ("picking_loop", &["cam", "2", "1,0"][..]),
        ("picking_loop", &["cam", "--timeout-ms", "0"][..]),
        ("camera_driver", &["cam", "0"][..]),
    ] {
        let prefix = format!("exargs{}_", std::process::id());
        let help = output_within(
            Command::new(example(name))
                .arg("--help")
                .env("PPFD_PREFIX", &prefix),
        );
        let text = String::from_utf8_lossy(&help.stdout);
        assert!(help.status.success(), "{name} --help: {help:?}");
        assert!(text.starts_with(&format!("usage: {name}")), "{text}");
        // Under a prefix of no daemon: nothing here may reach a real one.
        let out = output_within(
            Command::new(example(name))
                .args(bad)
                .env("PPFD_PREFIX", &prefix),
        );
        let e = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{name} {bad:?}: {e}");
        assert!(e.starts_with("error: ") && e.contains("usage:"), "{e}");
    }
    let _ = ppfd_client::remove_prefix_leftovers(&format!("exargs{}_", std::process::id()));
}

#[test]
fn the_camera_driver_stopped_by_sigterm_removes_its_camera() {
    let prefix = format!("exdrv{}_", std::process::id());
    let mut driver = Command::new(example("camera_driver"))
        .args(["excam", "50"])
        .env("PPFD_PREFIX", &prefix)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let ours = || -> Vec<String> {
        std::fs::read_dir("/dev/shm")
            .map(|d| {
                d.flatten()
                    .map(|e| e.file_name().to_string_lossy().into_owned())
                    .filter(|n| n.starts_with(&prefix) && !n.ends_with(".global_mgmt"))
                    .collect()
            })
            .unwrap_or_default()
    };
    let started = Instant::now();
    while ours().is_empty() {
        assert!(
            started.elapsed() < Duration::from_secs(20),
            "the driver made no shared memory"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    // SAFETY: signals our own child.
    unsafe { libc::kill(driver.id() as i32, libc::SIGTERM) };
    let stopped = Instant::now();
    while driver.try_wait().unwrap().is_none() {
        if stopped.elapsed() > Duration::from_secs(10) {
            let _ = driver.kill();
            panic!("the driver did not stop on SIGTERM");
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    let out = driver.wait_with_output().unwrap();
    let left = ours();
    let _ = ppfd_client::remove_prefix_leftovers(&prefix);
    assert!(out.status.success(), "{out:?}");
    assert!(
        String::from_utf8_lossy(&out.stdout).contains("stopped"),
        "{out:?}"
    );
    assert!(left.is_empty(), "left in /dev/shm: {left:?}");
}
