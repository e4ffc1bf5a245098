//! Control requests on `ppfd/control`: list the loaded models, load or drop a model at run time,
//! read the daemon's statistics. The request is a fixed [`ControlRequest`]; the response carries a
//! [`ControlResponseHeader`] and a `[ModelInfo]` payload (the model list, or the model just
//! loaded; empty otherwise).

use iceoryx2::prelude::ZeroCopySend;

use crate::{text, MESSAGE_BYTES, MODEL_NAME_BYTES, PATH_BYTES, PROTOCOL_VERSION};

/// What a [`ControlRequest`] asks for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u32)]
pub enum ControlCommand {
    /// List the loaded models.
    ListModels = 1,
    /// Load a model file (`.ppfm`) given by `path`, or build one from a PLY file (then
    /// `object_id` is the id to give it); replaces a loaded model of the same id.
    LoadModel = 2,
    /// Drop the model with `object_id`.
    DropModel = 3,
    /// Read the daemon's statistics.
    Statistics = 4,
}

impl ControlCommand {
    /// The command of a wire code.
    pub fn from_code(code: u32) -> Option<ControlCommand> {
        Some(match code {
            1 => ControlCommand::ListModels,
            2 => ControlCommand::LoadModel,
            3 => ControlCommand::DropModel,
            4 => ControlCommand::Statistics,
            _ => return None,
        })
    }
}

/// A control request (the request payload of `ppfd/control`).
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("ppfd::ControlRequest")]
#[repr(C)]
pub struct ControlRequest {
    /// [`PROTOCOL_VERSION`] of the client.
    pub protocol_version: u32,
    /// A [`ControlCommand`] code.
    pub command: u32,
    /// Chosen by the client; echoed in the response.
    pub request_id: u64,
    /// As [`crate::detect::DetectRequestHeader::reply_token`].
    pub reply_token: u64,
    /// Object id for `LoadModel` (the id to give a model built from a PLY file; for a `.ppfm`
    /// file, checked against the file's: 0 takes what the file gives) and `DropModel`.
    pub object_id: u32,
    /// Zero.
    pub reserved: u32,
    /// File path for `LoadModel`, NUL-padded UTF-8, as the daemon sees the file system.
    pub path: [u8; PATH_BYTES],
}

impl Default for ControlRequest {
    fn default() -> Self {
        ControlRequest {
            protocol_version: PROTOCOL_VERSION,
            command: 0,
            request_id: 0,
            reply_token: 0,
            object_id: 0,
            reserved: 0,
            path: [0; PATH_BYTES],
        }
    }
}

impl ControlRequest {
    /// The path as text.
    pub fn path(&self) -> std::borrow::Cow<'_, str> {
        text::decode(&self.path)
    }
}

/// Percentiles of one latency measure, nanoseconds: over the daemon's lifetime
/// ([`DaemonStats::total`] and its kin) or its last minute ([`DaemonStats::recent_total`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, ZeroCopySend)]
#[type_name("ppfd::LatencySummary")]
#[repr(C)]
pub struct LatencySummary {
    /// Number of samples.
    pub count: u64,
    /// Median, ns.
    pub p50_ns: u64,
    /// 90th percentile, ns.
    pub p90_ns: u64,
    /// 99th percentile, ns.
    pub p99_ns: u64,
    /// Largest sample, ns.
    pub max_ns: u64,
}

/// Daemon statistics: counters and latencies since it started, and the latencies of the last
/// [`RECENT_WINDOW_NS`] (a daemon that runs for weeks keeps its first days in the lifetime
/// percentiles; the recent ones show a change within a minute).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, ZeroCopySend)]
#[type_name("ppfd::DaemonStats")]
#[repr(C)]
pub struct DaemonStats {
    /// Time since start, ns.
    pub uptime_ns: u64,
    /// Detect requests taken off the port.
    pub requests_received: u64,
    /// Detect requests answered `Ok`.
    pub requests_served: u64,
    /// Detect requests refused (any status but `Ok`, including deadline and busy).
    pub requests_refused: u64,
    /// Of the refused: deadline passed while queued.
    pub requests_expired: u64,
    /// Requests whose answer did not reach their client: it went away before the answer, or
    /// the answer could not be sent (the daemon's log says why).
    pub requests_abandoned: u64,
    /// Camera frames taken off the camera ports (at the housekeeping tick and before each
    /// detection); a frame a newer one replaced before then is not counted.
    pub frames_received: u64,
    /// Cameras the daemon subscribes to now (those without a driver for a while are
    /// forgotten).
    pub cameras: u64,
    /// Models loaded.
    pub models_loaded: u64,
    /// Bytes of all loaded models (mapped or in memory).
    pub model_bytes: u64,
    /// Resident set size of the daemon process, bytes.
    pub resident_bytes: u64,
    /// Detections running on a worker now.
    pub in_flight: u64,
    /// Requests waiting for a worker now: in the daemon's queue, or handed to the workers
    /// while all are busy (with more detections at once than workers).
    pub queued: u64,
    /// Model files in the models folder the daemon loads at start (0 without one).
    pub startup_files: u64,
    /// Of those, the files loaded or failed so far: fewer than `startup_files` while the
    /// loading runs, and detections wait until it is done.
    pub startup_files_done: u64,
    /// Of those, the files that failed to load (the daemon's log names each).
    pub startup_files_failed: u64,
    /// `LoadModel` requests being served now (they run one at a time, beside detections).
    pub model_loads_running: u64,
    /// `LoadModel` requests waiting for the one running.
    pub model_loads_waiting: u64,
    /// Client send → response sent, over served requests.
    pub total: LatencySummary,
    /// Transport + queue wait (the daemon's overhead), over served requests.
    pub overhead: LatencySummary,
    /// Detection wall time, over served requests.
    pub detection: LatencySummary,
    /// The span the `recent_*` summaries cover, ending at this response: [`RECENT_WINDOW_NS`],
    /// less while the daemon is younger, or when it served more than [`RECENT_SAMPLES`]
    /// requests in that time (the oldest are let go). Zero, as the summaries, in the answers to
    /// other commands than `Statistics`.
    pub recent_window_ns: u64,
    /// `total` over the requests served within `recent_window_ns`.
    pub recent_total: LatencySummary,
    /// `overhead` over the requests served within `recent_window_ns`.
    pub recent_overhead: LatencySummary,
    /// `detection` over the requests served within `recent_window_ns`.
    pub recent_detection: LatencySummary,
}

/// How far back the recent latencies of [`DaemonStats`] look, ns (one minute).
pub const RECENT_WINDOW_NS: u64 = 60_000_000_000;
/// The most served requests the recent latencies of [`DaemonStats`] hold.
pub const RECENT_SAMPLES: usize = 100_000;

impl LatencySummary {
    /// The summary of `samples`, in any order (they are reordered), its percentiles by nearest
    /// rank ([`nearest_rank`]). Selection, not a sort: linear in the samples.
    pub fn of(samples: &mut [u64]) -> LatencySummary {
        let n = samples.len();
        if n == 0 {
            return LatencySummary::default();
        }
        let index = |q: f64| ((q * n as f64).ceil() as usize).clamp(1, n) - 1;
        let (i50, i90, i99) = (index(0.50), index(0.90), index(0.99));
        // Each selection leaves the smaller samples before its index: the next looks only there.
        let p99_ns = *samples.select_nth_unstable(i99).1;
        let p90_ns = *samples[..=i99].select_nth_unstable(i90).1;
        let p50_ns = *samples[..=i90].select_nth_unstable(i50).1;
        LatencySummary {
            count: n as u64,
            p50_ns,
            p90_ns,
            p99_ns,
            max_ns: samples.iter().copied().max().unwrap_or(0),
        }
    }
}

/// The `q`-quantile of samples sorted in ascending order by nearest rank: the smallest sample
/// with at least a fraction `q` of the samples at or below it (0 without samples).
pub fn nearest_rank(sorted: &[u64], q: f64) -> u64 {
    if sorted.is_empty() {
        return 0;
    }
    let rank = (q.clamp(0.0, 1.0) * sorted.len() as f64).ceil() as usize;
    sorted[rank.clamp(1, sorted.len()) - 1]
}

/// The user header of a control response.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("ppfd::ControlResponseHeader")]
#[repr(C)]
pub struct ControlResponseHeader {
    /// [`PROTOCOL_VERSION`] of the daemon.
    pub protocol_version: u32,
    /// A [`crate::detect::Status`] code.
    pub status: u32,
    /// The request's id.
    pub request_id: u64,
    /// Statistics: every answer carries the counters and lifetime latencies; the last minute's
    /// (`recent_*`) are worked out for `Statistics` only, and zero in other answers.
    pub stats: DaemonStats,
    /// Human-readable detail of a refusal, or for `Statistics` the detector parameters the
    /// daemon runs with; NUL-padded UTF-8.
    pub message: [u8; MESSAGE_BYTES],
}

impl Default for ControlResponseHeader {
    fn default() -> Self {
        ControlResponseHeader {
            protocol_version: PROTOCOL_VERSION,
            status: 0,
            request_id: 0,
            stats: DaemonStats::default(),
            message: [0; MESSAGE_BYTES],
        }
    }
}

impl ControlResponseHeader {
    /// The message as text.
    pub fn message(&self) -> std::borrow::Cow<'_, str> {
        text::decode(&self.message)
    }
}

/// One loaded model (an element of the control response payload).
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("ppfd::ModelInfo")]
#[repr(C)]
pub struct ModelInfo {
    /// Object id detect requests use.
    pub object_id: u32,
    /// Oriented model points after subsampling.
    pub point_count: u32,
    /// Entries of the point pair lookup table.
    pub table_entries: u64,
    /// Bytes of the model in memory.
    pub byte_size: u64,
    /// Object diameter, millimetres.
    pub diameter_mm: f32,
    /// Transforms other than the identity that map the object onto itself (its discrete
    /// symmetries; at most `u16::MAX` counted). Poses are reported as the one of each set of
    /// equivalent poses nearest the model's frame (METHOD.md §1.8).
    pub discrete_symmetries: u16,
    /// 1 if any turn about an axis maps the object onto itself (a continuous symmetry), else 0.
    pub continuous_symmetry: u16,
    /// Object name, NUL-padded UTF-8.
    pub name: [u8; MODEL_NAME_BYTES],
}

impl Default for ModelInfo {
    fn default() -> Self {
        ModelInfo {
            object_id: 0,
            point_count: 0,
            table_entries: 0,
            byte_size: 0,
            diameter_mm: 0.0,
            discrete_symmetries: 0,
            continuous_symmetry: 0,
            name: [0; MODEL_NAME_BYTES],
        }
    }
}

impl ModelInfo {
    /// The name as text.
    pub fn name(&self) -> std::borrow::Cow<'_, str> {
        text::decode(&self.name)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::mem::{offset_of, size_of};

    #[test]
    fn layouts_are_fixed() {
        assert_eq!(size_of::<ControlRequest>(), 288);
        assert_eq!(size_of::<LatencySummary>(), 40);
        assert_eq!(size_of::<DaemonStats>(), 19 * 8 + 6 * 40);
        assert_eq!(size_of::<ControlResponseHeader>(), 16 + 392 + 512);
        assert_eq!(offset_of!(ControlResponseHeader, protocol_version), 0);
        assert_eq!(size_of::<ModelInfo>(), 80);
    }

    #[test]
    fn commands_round_trip() {
        for c in [
            ControlCommand::ListModels,
            ControlCommand::LoadModel,
            ControlCommand::DropModel,
            ControlCommand::Statistics,
        ] {
            assert_eq!(ControlCommand::from_code(c as u32), Some(c));
        }
        assert_eq!(ControlCommand::from_code(0), None);
    }

    #[test]
    fn summaries_take_the_nearest_rank() {
        assert_eq!(nearest_rank(&[], 0.5), 0);
        assert_eq!(nearest_rank(&[7], 0.99), 7);
        let mut shuffled: Vec<u64> = (1..=200).map(|i| (i * 73) % 200 + 1).collect();
        let s = LatencySummary::of(&mut shuffled);
        assert_eq!(
            (s.count, s.p50_ns, s.p90_ns, s.p99_ns, s.max_ns),
            (200, 100, 180, 198, 200)
        );
        assert_eq!(LatencySummary::of(&mut []), LatencySummary::default());
        // Selection agrees with the sorted samples' ranks, duplicates and all.
        let mut x = 12345u64;
        for n in [1usize, 2, 3, 10, 99, 100, 101, 1000] {
            let mut samples: Vec<u64> = (0..n)
                .map(|_| {
                    x = x
                        .wrapping_mul(6364136223846793005)
                        .wrapping_add(1442695040888963407);
                    (x >> 40) % 50
                })
                .collect();
            let mut sorted = samples.clone();
            sorted.sort_unstable();
            let s = LatencySummary::of(&mut samples);
            assert_eq!(
                [s.p50_ns, s.p90_ns, s.p99_ns, s.max_ns],
                [0.5, 0.9, 0.99, 1.0].map(|q| nearest_rank(&sorted, q)),
                "{n} samples"
            );
        }
    }
}
