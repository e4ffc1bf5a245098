//! Daemon statistics: counters and HDR latency histograms, read by the `Statistics` control
//! command.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use hdrhistogram::Histogram;
use ppfd_protocol::control::{DaemonStats, LatencySummary, RECENT_SAMPLES, RECENT_WINDOW_NS};

/// Counters and latency histograms since the daemon started, and the latencies of the last
/// minute.
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
    recent: Recent,
}

/// The served requests of the last [`RECENT_WINDOW_NS`], at most [`RECENT_SAMPLES`] of them:
/// their times and latencies exactly (a minute of requests is small; the percentiles need no
/// buckets).
struct Recent {
    /// (served at, total, overhead, detection), oldest first.
    samples: VecDeque<(Instant, [u64; 3])>,
    /// When the newest sample let go to stay within [`RECENT_SAMPLES`] was served: the window
    /// begins after it.
    cut: Option<Instant>,
}

impl Recent {
    fn window() -> Duration {
        Duration::from_nanos(RECENT_WINDOW_NS)
    }

    fn record(&mut self, at: Instant, latencies: [u64; 3]) {
        self.forget_before(at);
        if self.samples.len() == RECENT_SAMPLES {
            self.cut = self.samples.pop_front().map(|(t, _)| t);
        }
        self.samples.push_back((at, latencies));
    }

    fn forget_before(&mut self, now: Instant) {
        let Some(start) = now.checked_sub(Self::window()) else {
            return;
        };
        while self.samples.front().is_some_and(|&(t, _)| t <= start) {
            self.samples.pop_front();
        }
    }

    /// The window's length ending at `now`, and the three summaries over it.
    fn summaries(&mut self, now: Instant, started: Instant) -> (u64, [LatencySummary; 3]) {
        self.forget_before(now);
        let begins = [now.checked_sub(Self::window()), Some(started), self.cut]
            .into_iter()
            .flatten()
            .max()
            .unwrap_or(started);
        let window_ns = now.saturating_duration_since(begins).as_nanos() as u64;
        let summary = |i: usize| {
            let mut values: Vec<u64> = self.samples.iter().map(|(_, l)| l[i]).collect();
            LatencySummary::of(&mut values)
        };
        (window_ns, [summary(0), summary(1), summary(2)])
    }
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
            recent: Recent {
                samples: VecDeque::new(),
                cut: None,
            },
        }
    }
}

impl Stats {
    /// Records a served request.
    pub fn record_served(&mut self, total_ns: u64, overhead_ns: u64, detection_ns: u64) {
        self.record_served_at(Instant::now(), total_ns, overhead_ns, detection_ns);
    }

    fn record_served_at(
        &mut self,
        at: Instant,
        total_ns: u64,
        overhead_ns: u64,
        detection_ns: u64,
    ) {
        self.requests_served += 1;
        self.total.record(total_ns);
        self.overhead.record(overhead_ns);
        self.detection.record(detection_ns);
        self.recent
            .record(at, [total_ns, overhead_ns, detection_ns]);
    }

    /// The wire form without the last minute's latencies ([`Stats::add_recent`]); the caller
    /// fills what the statistics do not know (models, queue).
    pub fn snapshot(&self) -> DaemonStats {
        self.snapshot_at(Instant::now())
    }

    /// Adds the last minute's latencies to `stats`, a [`Stats::snapshot`]: linear in the
    /// requests served in that minute, so only for the statistics' own answer.
    pub fn add_recent(&mut self, stats: &mut DaemonStats) {
        self.add_recent_at(Instant::now(), stats);
    }

    fn snapshot_at(&self, now: Instant) -> DaemonStats {
        DaemonStats {
            uptime_ns: now.saturating_duration_since(self.started).as_nanos() as u64,
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

    fn add_recent_at(&mut self, now: Instant, stats: &mut DaemonStats) {
        let (window_ns, [total, overhead, detection]) = self.recent.summaries(now, self.started);
        // The window ends when the uptime does.
        stats.uptime_ns = now.saturating_duration_since(self.started).as_nanos() as u64;
        stats.recent_window_ns = window_ns;
        stats.recent_total = total;
        stats.recent_overhead = overhead;
        stats.recent_detection = detection;
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

    /// The statistics' answer at `now`, its counters read a moment before, as the daemon does.
    fn full(s: &mut Stats, now: Instant) -> DaemonStats {
        let mut stats = s.snapshot_at(now - Duration::from_millis(1));
        s.add_recent_at(now, &mut stats);
        stats
    }

    /// A slow minute shows in the recent latencies while the lifetime ones still show the
    /// fast hours before it; a minute later it is gone from the recent ones.
    #[test]
    fn the_recent_latencies_are_those_of_the_last_minute() {
        let mut s = Stats::default();
        assert_eq!(
            s.snapshot().recent_window_ns,
            0,
            "only the statistics' answer has them"
        );
        let t0 = s.started;
        let minutes = |m: u64| t0 + Duration::from_secs(60 * m);
        for i in 0..1000u64 {
            s.record_served_at(minutes(0) + Duration::from_millis(i), 10_000, 1_000, 9_000);
        }
        let young = full(&mut s, minutes(0) + Duration::from_secs(30));
        assert_eq!(
            young.recent_window_ns, 30_000_000_000,
            "no older than the daemon"
        );
        assert_eq!(young.recent_total.count, 1000);
        for i in 0..10u64 {
            s.record_served_at(minutes(5) + Duration::from_secs(i), 900_000, 1_000, 899_000);
        }
        let slow = full(&mut s, minutes(5) + Duration::from_secs(30));
        assert_eq!(slow.recent_window_ns, RECENT_WINDOW_NS);
        assert_eq!(slow.recent_total.count, 10);
        assert_eq!(slow.recent_total.p50_ns, 900_000);
        assert_eq!(slow.recent_detection.max_ns, 899_000);
        assert_eq!(slow.total.count, 1010);
        assert!(slow.total.p90_ns <= 10_010, "{:?}", slow.total);
        let later = full(&mut s, minutes(7));
        assert_eq!(later.recent_total, LatencySummary::default());
        assert_eq!(later.total.count, 1010);
    }

    /// At more than [`RECENT_SAMPLES`] requests a minute the oldest are let go and the window
    /// says how far back the rest reach.
    #[test]
    fn the_recent_window_is_bounded_in_requests() {
        let mut s = Stats::default();
        let t0 = s.started + Duration::from_secs(600);
        let n = RECENT_SAMPLES as u64 + 500;
        for i in 0..n {
            s.record_served_at(t0 + Duration::from_micros(100 * i), i + 1, 1, i);
        }
        let now = t0 + Duration::from_micros(100 * n);
        let snap = full(&mut s, now);
        assert_eq!(snap.recent_total.count, RECENT_SAMPLES as u64);
        assert_eq!(snap.recent_total.max_ns, n);
        // The newest let go is request 500 (0-based 499), served 49.9 ms after t0.
        let reach = now - (t0 + Duration::from_micros(100 * 499));
        assert_eq!(snap.recent_window_ns, reach.as_nanos() as u64);
        assert_eq!(snap.total.count, n);
    }
}
