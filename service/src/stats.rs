//! Daemon statistics: counters and HDR latency histograms, read by the `Statistics` control
//! command.

use std::time::Instant;

use hdrhistogram::Histogram;
use ppfd_protocol::control::{DaemonStats, LatencySummary};

/// Counters and latency histograms since the daemon started.
pub struct Stats {
    started: Instant,
    /// Detect requests taken off the port; these counters are those of [`DaemonStats`].
    pub requests_received: u64,
    /// Detect requests answered `Ok`.
    pub requests_served: u64,
    /// Detect requests refused with an error status.
    pub requests_refused: u64,
    /// Of the refused, detect requests whose deadline passed while they were queued.
    pub requests_expired: u64,
    /// Requests whose answer did not reach their client.
    pub requests_abandoned: u64,
    /// Camera frames taken off the camera ports.
    pub frames_received: u64,
    total: Latencies,
    overhead: Latencies,
    detection: Latencies,
}

/// One latency's samples: their histogram, and the largest exactly. The histogram's own
/// maximum and percentiles are the tops of its buckets (three significant digits), above the
/// samples they stand for.
struct Latencies {
    histogram: Histogram<u64>,
    max_ns: u64,
}

impl Latencies {
    fn new() -> Latencies {
        Latencies {
            // 1 ns .. 1 h at 3 significant digits; values are recorded in ns and clamped.
            histogram: Histogram::new_with_bounds(1, 3_600_000_000_000, 3)
                .expect("valid histogram bounds"),
            max_ns: 0,
        }
    }

    fn record(&mut self, ns: u64) {
        self.histogram.saturating_record(ns.max(1));
        self.max_ns = self.max_ns.max(ns);
    }

    /// The percentiles at most the largest sample: a bucket's top can lie above it.
    fn summary(&self) -> LatencySummary {
        let h = &self.histogram;
        if h.is_empty() {
            return LatencySummary::default();
        }
        let at = |q| h.value_at_quantile(q).min(self.max_ns);
        LatencySummary {
            count: h.len(),
            p50_ns: at(0.50),
            p90_ns: at(0.90),
            p99_ns: at(0.99),
            max_ns: self.max_ns,
        }
    }
}

impl Default for Stats {
    fn default() -> Self {
        Stats {
            started: Instant::now(),
            requests_received: 0,
            requests_served: 0,
            requests_refused: 0,
            requests_expired: 0,
            requests_abandoned: 0,
            frames_received: 0,
            total: Latencies::new(),
            overhead: Latencies::new(),
            detection: Latencies::new(),
        }
    }
}

impl Stats {
    /// Records a served request.
    pub fn record_served(&mut self, total_ns: u64, overhead_ns: u64, detection_ns: u64) {
        self.requests_served += 1;
        self.total.record(total_ns);
        self.overhead.record(overhead_ns);
        self.detection.record(detection_ns);
    }

    /// The wire form; the caller fills what the statistics do not know (models, queue).
    pub fn snapshot(&self) -> DaemonStats {
        DaemonStats {
            uptime_ns: self.started.elapsed().as_nanos() as u64,
            requests_received: self.requests_received,
            requests_served: self.requests_served,
            requests_refused: self.requests_refused,
            requests_expired: self.requests_expired,
            requests_abandoned: self.requests_abandoned,
            frames_received: self.frames_received,
            resident_bytes: resident_bytes(),
            total: self.total.summary(),
            overhead: self.overhead.summary(),
            detection: self.detection.summary(),
            ..DaemonStats::default()
        }
    }
}

/// Resident set size of this process, bytes (0 where `/proc` is not available).
pub fn resident_bytes() -> u64 {
    let Ok(statm) = std::fs::read_to_string("/proc/self/statm") else {
        return 0;
    };
    let pages: u64 = statm
        .split_whitespace()
        .nth(1)
        .and_then(|v| v.parse().ok())
        .unwrap_or(0);
    // SAFETY: sysconf has no preconditions.
    let page = unsafe { libc::sysconf(libc::_SC_PAGESIZE) };
    pages * page.max(0) as u64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_follow_the_recorded_samples() {
        let mut s = Stats::default();
        for i in 1..=100u64 {
            s.record_served(i * 1000, i * 10, i * 990);
        }
        let snap = s.snapshot();
        assert_eq!(snap.requests_served, 100);
        assert_eq!(snap.total.count, 100);
        assert!(
            (49_000..=51_000).contains(&snap.total.p50_ns),
            "{:?}",
            snap.total
        );
        assert!(
            (98_000..=100_100).contains(&snap.total.p99_ns),
            "{:?}",
            snap.total
        );
        assert!(snap.total.max_ns >= 100_000);
        assert!(snap.resident_bytes > 0);
    }

    /// The maximum is the largest sample, not its bucket's top, and no percentile lies above
    /// it: one request of 310 230 ns reads 310 230 ns, where the histogram's bucket ends at
    /// 310 271 ns.
    #[test]
    fn the_maximum_is_the_largest_sample() {
        let mut s = Stats::default();
        s.record_served(310_230, 5, 7);
        let t = s.snapshot().total;
        assert_eq!(t.max_ns, 310_230);
        assert_eq!((t.p50_ns, t.p90_ns, t.p99_ns), (310_230, 310_230, 310_230));
        s.record_served(54_166_333, 5, 7);
        let t = s.snapshot().total;
        assert_eq!(t.max_ns, 54_166_333);
        assert!(t.p50_ns <= t.max_ns && t.p99_ns <= t.max_ns, "{t:?}");
    }
}
