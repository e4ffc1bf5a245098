//! What the end-to-end tests share: the package's binaries and how a test starts the daemon
//! with the transport-only engine and a camera. Each test file uses a part of it.
#![allow(dead_code)]

use std::path::Path;
use std::time::Duration;

use ppfd_tests::{Prefix, Proc};

/// `ppfd` with the test engines (`PPFD_TEST_ENGINE`).
pub const DAEMON: &str = env!("CARGO_BIN_EXE_e2e-daemon");
/// A camera driver publishing generated frames.
pub const CAMERA: &str = env!("CARGO_BIN_EXE_e2e-camera");
/// A client that prints each answer as a line.
pub const CLIENT: &str = env!("CARGO_BIN_EXE_e2e-client");
/// How long a daemon or camera may take to say it is ready.
pub const STARTUP: Duration = Duration::from_secs(20);

/// The daemon with the transport-only engine under `prefix`, serving the fake models of
/// `models` and housekeeping every 100 ms, with `extra` flags and `env` added to its
/// environment; not waited for.
pub fn spawn_fake_daemon(
    prefix: &Prefix,
    models: &Path,
    extra: &[&str],
    env: &[(&str, &str)],
) -> Proc {
    let mut args = vec![
        "--prefix",
        &prefix.0,
        "--models",
        models.to_str().unwrap(),
        "--housekeeping-ms",
        "100",
    ];
    args.extend_from_slice(extra);
    let mut envs = vec![("PPFD_TEST_ENGINE", "fake")];
    envs.extend_from_slice(env);
    Proc::spawn(Path::new(DAEMON), &args, &envs)
}

/// [`spawn_fake_daemon`], once it says it is ready.
pub fn fake_daemon(prefix: &Prefix, models: &Path, extra: &[&str], env: &[(&str, &str)]) -> Proc {
    let mut d = spawn_fake_daemon(prefix, models, extra, env);
    d.wait_line("ppfd ready", STARTUP);
    d
}

/// A camera `name` under `prefix` with `extra` flags (`--fps`); not waited for.
pub fn spawn_camera(prefix: &Prefix, name: &str, extra: &[&str]) -> Proc {
    let mut args = vec!["--prefix", &prefix.0, "--camera", name];
    args.extend_from_slice(extra);
    Proc::spawn(Path::new(CAMERA), &args, &[])
}

/// [`spawn_camera`], once it says it is ready.
pub fn camera(prefix: &Prefix, name: &str, extra: &[&str]) -> Proc {
    let mut c = spawn_camera(prefix, name, extra);
    c.wait_line("camera ready", STARTUP);
    c
}
