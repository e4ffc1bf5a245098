//! `CLOCK_MONOTONIC`, the one clock of the protocol: every timestamp on the wire is nanoseconds of
//! it, so instants taken in different processes on the same machine compare directly.

use std::time::{Duration, Instant};

/// Now, `CLOCK_MONOTONIC`, nanoseconds.
pub fn monotonic_now_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec; CLOCK_MONOTONIC always exists on Linux.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    debug_assert_eq!(rc, 0);
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

/// The `Instant` of a `CLOCK_MONOTONIC` timestamp (for deadlines handed to library code that
/// takes an `Instant`). Timestamps in the past map to now, those beyond what an `Instant` holds
/// to a century from now.
pub fn instant_of(monotonic_ns: u64) -> Instant {
    let now_ns = monotonic_now_ns();
    instant_after(Duration::from_nanos(monotonic_ns.saturating_sub(now_ns)))
}

/// Now plus `wait`, or a century from now for a wait beyond what an `Instant` holds
/// (`Duration::MAX` for "no limit").
pub fn instant_after(wait: Duration) -> Instant {
    let now = Instant::now();
    now.checked_add(wait)
        .unwrap_or_else(|| now + Duration::from_secs(100 * 365 * 24 * 3600))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn monotonic_clock_advances_with_std_instant() {
        // Each std reading is bracketed by two of ours, so the comparison needs no tolerance
        // for the scheduler: it holds however long the thread is held up between reads.
        let a1 = monotonic_now_ns();
        let t = Instant::now();
        let a2 = monotonic_now_ns();
        std::thread::sleep(Duration::from_millis(5));
        let b1 = monotonic_now_ns();
        let elapsed = t.elapsed().as_nanos() as u64;
        let b2 = monotonic_now_ns();
        assert!(b1 > a2);
        assert!(
            (b1 - a2..=b2 - a1).contains(&elapsed),
            "std's {elapsed} ns against ours {}..={} ns",
            b1 - a2,
            b2 - a1
        );
    }

    #[test]
    fn instants_of_future_timestamps_lie_ahead() {
        assert!(instant_of(u64::MAX) > Instant::now() + Duration::from_secs(3600));
        let d = instant_of(monotonic_now_ns() + 5_000_000_000);
        let ahead = d.saturating_duration_since(Instant::now());
        // The margin is for a thread held up between the two readings.
        assert!(
            ahead > Duration::from_secs(4) && ahead <= Duration::from_secs(5),
            "{ahead:?}"
        );
        assert!(instant_of(0) <= Instant::now());
    }
}
