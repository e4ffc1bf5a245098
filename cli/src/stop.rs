//! Stopping a command that leaves things behind with SIGINT or SIGTERM: `ppf demo` (a daemon
//! and a work folder) and `ppf replay` (a camera's shared memory). By default either signal
//! ends the process at once, and the daemon runs on, the folder stays and so does the camera's
//! 21 MB segment; here both are blocked and read by a thread of their own, which stops the
//! child so that the command's own way out (an error, then its cleanup) is taken.

use std::path::PathBuf;
use std::sync::atomic::{AtomicI32, Ordering};
use std::sync::Mutex;
use std::time::Duration;

/// The signal that stopped the command, 0 while none has.
static STOP_SIGNAL: AtomicI32 = AtomicI32::new(0);

/// The child process to stop on a signal. Locked while the signal is sent to it, so that the
/// command cannot reap it (and its pid be reused) in between.
static CHILD: Mutex<Option<u32>> = Mutex::new(None);

/// How long the command has after a signal to clean up by itself; then the signal's thread
/// kills the child, removes the folder and ends the process.
const GRACE: Duration = Duration::from_secs(10);

/// Takes SIGINT and SIGTERM from their default action for the rest of the process: on either,
/// the child (see [`set_child`]) is sent SIGTERM and [`stop_signal`] tells the command to end.
/// If the command has not ended within 10 s, `scratch` (if any) is removed and the process
/// ends. Call it before any thread is started (threads started later inherit the blocked
/// signals; child processes do not).
pub fn handle_stop_signals(scratch: Option<PathBuf>) {
    // SAFETY: plain libc calls on a local signal set.
    let set = unsafe {
        let mut set: libc::sigset_t = std::mem::zeroed();
        libc::sigemptyset(&mut set);
        libc::sigaddset(&mut set, libc::SIGINT);
        libc::sigaddset(&mut set, libc::SIGTERM);
        libc::pthread_sigmask(libc::SIG_BLOCK, &set, std::ptr::null_mut());
        set
    };
    std::thread::spawn(move || {
        let mut signal = 0;
        // SAFETY: waits for one of the signals blocked above.
        while unsafe { libc::sigwait(&set, &mut signal) } != 0 {}
        STOP_SIGNAL.store(signal, Ordering::SeqCst);
        signal_child(libc::SIGTERM);
        std::thread::sleep(GRACE);
        signal_child(libc::SIGKILL);
        if let Some(scratch) = scratch {
            let _ = std::fs::remove_dir_all(scratch);
        }
        std::process::exit(128 + signal);
    });
}

/// The child process a signal stops (`None` once it is gone). Clear it before reaping the
/// child.
pub fn set_child(pid: Option<u32>) {
    *CHILD.lock().unwrap_or_else(|e| e.into_inner()) = pid;
}

fn signal_child(signal: i32) {
    let child = CHILD.lock().unwrap_or_else(|e| e.into_inner());
    if let Some(pid) = *child {
        // SAFETY: signals our own child, not yet reaped (it is cleared before that).
        unsafe { libc::kill(pid as i32, signal) };
    }
}

/// The signal that stopped the command, if one has.
pub fn stop_signal() -> Option<i32> {
    match STOP_SIGNAL.load(Ordering::SeqCst) {
        0 => None,
        signal => Some(signal),
    }
}

/// An error that ends the command once a signal has stopped it.
pub fn check() -> Result<(), String> {
    match stop_signal() {
        Some(signal) => Err(format!("stopped by {}", signal_name(signal))),
        None => Ok(()),
    }
}

pub fn signal_name(signal: i32) -> &'static str {
    match signal {
        libc::SIGINT => "SIGINT",
        libc::SIGTERM => "SIGTERM",
        _ => "a signal",
    }
}
