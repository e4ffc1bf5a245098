//! A signal that interrupts a client's wait for its answer, such as a program's own watchdog
//! timer, only wakes the wait: the answer still comes. A test binary of its own, since the
//! handler it installs is the whole process's.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Duration;

use ppfd_client::{Client, ClientOptions, DetectOptions};
use ppfd_tests::{fake_model_dir, Prefix};

mod common;
use common::{camera, fake_daemon};

static RANG: AtomicUsize = AtomicUsize::new(0);

extern "C" fn ring(_: libc::c_int) {
    RANG.fetch_add(1, Ordering::Relaxed);
}

/// Sets `ring` as the SIGALRM handler without `SA_RESTART`, as Python's and most programs'
/// handlers are.
fn install_ring() {
    // SAFETY: installs a handler that only counts, with an empty mask.
    unsafe {
        let mut action: libc::sigaction = std::mem::zeroed();
        action.sa_sigaction = ring as extern "C" fn(libc::c_int) as usize;
        action.sa_flags = 0;
        libc::sigemptyset(&mut action.sa_mask);
        assert_eq!(
            libc::sigaction(libc::SIGALRM, &action, std::ptr::null_mut()),
            0
        );
    }
}

/// Signals `thread` (the one that waits) every `period` until `stop` is set: a timer's signal
/// goes to any thread of the process, and the test harness's main thread would take it.
fn watchdog(
    thread: libc::pthread_t,
    period: Duration,
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
) -> std::thread::JoinHandle<()> {
    std::thread::spawn(move || {
        while !stop.load(Ordering::Relaxed) {
            // SAFETY: `thread` lives until `stop` is set and this thread is joined.
            unsafe { libc::pthread_kill(thread, libc::SIGALRM) };
            std::thread::sleep(period);
        }
    })
}

#[test]
fn a_signal_during_a_request_only_wakes_the_wait() {
    let prefix = Prefix::new("signals");
    let models = fake_model_dir("signals", &[1]);
    let _daemon = fake_daemon(&prefix, &models, &[], &[("PPFD_FAKE_DELAY_MS", "500")]);
    let _camera = camera(&prefix, "cam0", &["--fps", "50"]);
    let client = Client::connect_with(&ClientOptions {
        prefix: Some(prefix.0.clone()),
        ..Default::default()
    })
    .expect("client connects");
    let options = DetectOptions {
        timeout: Duration::from_secs(20),
        ..Default::default()
    };
    // Served once without the timer: the daemon has the camera's frames.
    let deadline = std::time::Instant::now() + Duration::from_secs(10);
    while let Err(e) = client.detect("cam0", &[1], &options) {
        assert!(std::time::Instant::now() < deadline, "never served: {e}");
        std::thread::sleep(Duration::from_millis(20));
    }
    install_ring();
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    // SAFETY: the calling thread's own id.
    let me = unsafe { libc::pthread_self() };
    let ringing = watchdog(me, Duration::from_millis(20), stop.clone());
    let answer = client.detect("cam0", &[1], &options);
    stop.store(true, Ordering::Relaxed);
    ringing.join().unwrap();
    let found = answer.expect("answered despite the signals");
    assert_eq!(found.hypotheses.first().map(|h| h.object_id), Some(1));
    let rang = RANG.load(Ordering::Relaxed);
    assert!(
        rang >= 5,
        "the timer rang {rang} times during a 0.5 s detection"
    );
}
