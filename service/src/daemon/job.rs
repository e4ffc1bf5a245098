//! A detection started: the request's frame resolved (the newest sample of its camera, or its
//! own inline payload) and checked, and a job on the pool that reads the depth in place, runs
//! the engine and answers the client itself.

use std::rc::Rc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::Sender;
use std::sync::Arc;

use iceoryx2::identifiers::UniqueClientId;
use ppfd_protocol::clock::{instant_of, monotonic_now_ns};
use ppfd_protocol::detect::{flags, DetectRequestHeader, FrameSource, Status};
use ppfd_protocol::frame::FrameHeader;

use crate::engine::{EngineError, EngineOptions, FrameView};
use crate::responder::{DetectActive, Outcome, Served};
use crate::wakeup::Signaller;

use super::queue::Queued;
use super::{Daemon, FrameSample};

/// Depth values in shared memory that a worker reads. Valid while the sample (held by the I/O
/// thread) or the request (held by the job itself) they belong to lives (see the `daemon`
/// module's documentation).
struct SharedDepth {
    ptr: *const u16,
    len: usize,
}

// SAFETY: the memory is shared memory that nobody writes while the sample/request is held
// (a published sample and a sent request are immutable), and the holder outlives the job.
unsafe impl Send for SharedDepth {}

impl SharedDepth {
    /// # Safety
    /// The sample or request the values belong to must be alive and unchanged.
    unsafe fn values(&self) -> &[u16] {
        // SAFETY: by the caller's promise the pointer and length describe live memory.
        unsafe { std::slice::from_raw_parts(self.ptr, self.len) }
    }
}

/// A request whose detection runs (its worker holds the request and answers it). The frame is
/// released only with the record, after the job reported.
pub(super) struct InFlight {
    _frame: Option<Rc<FrameSample>>,
    /// The client that sent the request, to tell whether it is still there.
    pub(super) client: UniqueClientId,
    /// Set to stop the detection early: its client is gone.
    pub(super) cancel: Arc<AtomicBool>,
    /// Set by the worker when it starts the job: a job handed to the pool may wait there for
    /// a worker (the statistics' queued and running detections). It stays set until the I/O
    /// thread has the job's completion, so a finished job counts as running, never as waiting.
    pub(super) started: Arc<AtomicBool>,
}

/// A job's report, sent after its worker answered the request.
pub(super) struct Completion {
    pub(super) job: u64,
    pub(super) outcome: Outcome,
}

impl Daemon {
    /// Resolves the frame and starts the job; gives the request back with the reason it could
    /// not start.
    #[allow(clippy::type_complexity)]
    pub(super) fn start(
        &mut self,
        q: Queued,
    ) -> Result<(), Box<(DetectActive, DetectRequestHeader, u64, EngineError)>> {
        let now = monotonic_now_ns();
        let max_age_ns = if q.header.max_frame_age_ns != 0 {
            q.header.max_frame_age_ns
        } else {
            self.config.max_frame_age_ms.saturating_mul(1_000_000)
        };
        let (frame_header, depth, hold) = match &q.source {
            FrameSource::Inline => {
                if let Some(e) = stamped_ahead(&q.header.inline_frame, now, "the frame is") {
                    return Err(Box::new((q.active, q.header, q.received_ns, e)));
                }
                let payload = q.active.payload();
                (
                    q.header.inline_frame,
                    SharedDepth {
                        ptr: payload.as_ptr(),
                        len: payload.len(),
                    },
                    None,
                )
            }
            FrameSource::Camera(name) => {
                let camera = match self.open_camera(name) {
                    Ok(c) => c,
                    Err(e) => return Err(Box::new((q.active, q.header, q.received_ns, e))),
                };
                let arrived = camera.refresh(name);
                let newest = camera.newest.clone();
                let driverless = !camera.has_driver();
                self.stats.frames_received += arrived;
                let Some(sample) = newest else {
                    let e = EngineError::new(
                        Status::NoFrame,
                        format!("camera {name:?} has published no frame yet"),
                    );
                    return Err(Box::new((q.active, q.header, q.received_ns, e)));
                };
                let fh = *sample.user_header();
                let checked = fh
                    .validate(sample.payload().len())
                    .and_then(|()| fh.check_pixels(self.config.max_frame_pixels));
                if let Err(e) = checked {
                    let e = EngineError::new(
                        e.status(),
                        format!("camera {name:?} published a bad frame: {e}"),
                    );
                    return Err(Box::new((q.active, q.header, q.received_ns, e)));
                }
                let whose = format!("camera {name:?} has its frames");
                if fh.capture_time_ns == 0 {
                    // Its age would read as the machine's uptime: "stale" would blame the camera.
                    let e = EngineError::new(
                        Status::InvalidFrame,
                        format!(
                            "{whose} unstamped (capture_time_ns 0): the stale check needs their \
                             CLOCK_MONOTONIC capture time (monotonic_now_ns); 0 is for inline \
                             frames"
                        ),
                    );
                    return Err(Box::new((q.active, q.header, q.received_ns, e)));
                }
                let named = fh.camera_name();
                if !named.is_empty() && named != name.as_str() {
                    // Poses in another camera's frame of reference would send a robot to the
                    // wrong place.
                    let e = EngineError::new(
                        Status::InvalidFrame,
                        format!(
                            "{whose} named camera {named:?} in their header: a driver publishes \
                             another camera's frames under this name (each camera needs a name of \
                             its own)"
                        ),
                    );
                    return Err(Box::new((q.active, q.header, q.received_ns, e)));
                }
                if let Some(e) = stamped_ahead(&fh, now, &whose) {
                    return Err(Box::new((q.active, q.header, q.received_ns, e)));
                }
                if let Some(mut e) = stale(name, &fh, now, max_age_ns) {
                    // A frame stale because its driver has gone is not a slow camera: said so,
                    // not left to read as "raise the age limit".
                    if driverless {
                        e.message += "; no driver publishes on it any more: restart its driver";
                    }
                    return Err(Box::new((q.active, q.header, q.received_ns, e)));
                }
                let payload = sample.payload();
                let depth = SharedDepth {
                    ptr: payload.as_ptr(),
                    len: payload.len(),
                };
                (fh, depth, Some(sample))
            }
        };
        // A camera frame is judged again when the detection starts: with more detections at once
        // than workers, a job can wait for a worker after this check.
        let camera = match &q.source {
            FrameSource::Camera(name) => Some(name.clone()),
            FrameSource::Inline => None,
        };

        let job = self.next_job;
        self.next_job += 1;
        let engine = self.engine.clone();
        let models = q.models;
        let cancel = Arc::new(AtomicBool::new(false));
        // With DIAGNOSE the hints field carries the poses to diagnose against.
        let poses = q.header.hints().to_vec();
        let (hints, diagnose) = if q.header.flags & flags::DIAGNOSE != 0 {
            (Vec::new(), poses)
        } else {
            (poses, Vec::new())
        };
        let options = EngineOptions {
            hypotheses_per_object: q.header.hypotheses_per_object as usize,
            requirements: q.header.requirements,
            deadline: (q.header.deadline_ns != 0).then(|| instant_of(q.header.deadline_ns)),
            cancel: cancel.clone(),
            hints,
            diagnose,
        };
        let done = self.done_tx.clone();
        let signaller = self.signaller;
        let responder = self.responder.clone();
        let (active, header, received_ns) = (q.active, q.header, q.received_ns);
        let client = active.origin();
        let request_id = header.request_id;
        let started = Arc::new(AtomicBool::new(false));
        let started_flag = started.clone();
        self.pool.spawn(move || {
            // First, so that it is dropped last: the completion goes out even if what follows
            // panics, and the I/O thread then releases the frame and stops waiting for the job.
            let mut report = Report {
                job,
                outcome: Outcome::Undelivered,
                done,
                signaller,
            };
            let started_ns = monotonic_now_ns();
            started_flag.store(true, Ordering::Relaxed);
            let _span = tracing::debug_span!("detect", request = request_id).entered();
            let frame_age_ns = if frame_header.capture_time_ns != 0 {
                started_ns.saturating_sub(frame_header.capture_time_ns)
            } else {
                0
            };
            // SAFETY: see `SharedDepth`: a camera sample stays alive and unchanged on the I/O
            // thread until it has received this job's completion; an inline frame lies in
            // `active`, which this job drops only after the detection.
            let depth = unsafe { depth.values() };
            let frame = FrameView {
                width: frame_header.width,
                height: frame_header.height,
                intrinsics: frame_header.intrinsics,
                depth_scale_mm: frame_header.depth_scale_mm,
                depth,
            };
            let stale_now = camera
                .as_deref()
                .and_then(|name| stale(name, &frame_header, started_ns, max_age_ns));
            let result = match stale_now {
                Some(e) => Err(e),
                None => std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                    engine.detect(&frame, &models, &options)
                }))
                .unwrap_or_else(|_| {
                    Err(EngineError::new(
                        Status::Internal,
                        "the detection failed unexpectedly (panic)",
                    ))
                }),
            };
            let finished_ns = monotonic_now_ns();
            // The deadline is looked at between stages, so the last stage may end past it; its
            // client stops waiting at the deadline, and poses sent then would be counted
            // served though none waited for them.
            let result = in_time(result, &header, finished_ns);
            let served = Served {
                header,
                received_ns,
                frame_sequence: frame_header.sequence,
                frame_age_ns,
                started_ns,
                finished_ns,
            };
            // Answered from here: the client does not wait for the I/O thread to wake up. The
            // request (and an inline frame in it) is released only after the answer.
            report.outcome = responder.answer(active, &served, result);
        });
        self.in_flight.insert(
            job,
            InFlight {
                _frame: hold,
                client,
                cancel,
                started,
            },
        );
        Ok(())
    }

    /// Records what the worker did with its request and releases the frame it read.
    pub(super) fn finish(&mut self, c: Completion) {
        self.in_flight.remove(&c.job);
        self.count(c.outcome);
    }
}

/// A job's completion, sent to the I/O thread when dropped: at the job's end, or while a panic
/// unwinds it (iceoryx2 panics on some failures of its own). Until the job has answered, the
/// outcome is [`Outcome::Undelivered`]: a job that panics before its answer is sent leaves its
/// client without one.
pub(super) struct Report {
    pub(super) job: u64,
    pub(super) outcome: Outcome,
    pub(super) done: Sender<Completion>,
    pub(super) signaller: Signaller,
}

impl Drop for Report {
    fn drop(&mut self) {
        // The receiver lives as long as the daemon, which waits for every job.
        let _ = self.done.send(Completion {
            job: self.job,
            outcome: self.outcome,
        });
        self.signaller.signal();
    }
}

/// `result`, or for a detection that finished at `finished_ns`, after the request's deadline,
/// its refusal as such.
fn in_time<T>(
    result: Result<T, EngineError>,
    header: &DetectRequestHeader,
    finished_ns: u64,
) -> Result<T, EngineError> {
    if result.is_err() || header.deadline_ns == 0 || finished_ns <= header.deadline_ns {
        return result;
    }
    let ms = |ns: u64| ns as f64 / 1e6;
    Err(EngineError::new(
        Status::DeadlineExceeded,
        format!(
            "deadline exceeded: the detection finished {:.1} ms after the request's deadline, \
             {:.1} ms after it was sent; a longer timeout waits for it",
            ms(finished_ns - header.deadline_ns),
            ms(finished_ns.saturating_sub(header.send_time_ns))
        ),
    ))
}

/// `camera stale` when the camera's frame is older than the limit at `now`.
fn stale(name: &str, frame: &FrameHeader, now: u64, max_age_ns: u64) -> Option<EngineError> {
    let age = now.saturating_sub(frame.capture_time_ns);
    (age > max_age_ns).then(|| EngineError {
        status: Status::CameraStale,
        message: format!(
            "camera {name:?} is stale: its newest frame (sequence {}) is {:.1} ms old, the limit is {:.1} ms",
            frame.sequence,
            age as f64 / 1e6,
            max_age_ns as f64 / 1e6
        ),
        value: age,
    })
}

/// A frame stamped further than this ahead of the daemon's clock was not stamped with it.
/// Stamps taken by the driver just after the daemon read its clock are a few microseconds
/// ahead; a driver stamping wall-clock time is decades ahead. A frame stamped ahead reads as
/// younger than it is, by up to this much: a camera stopped that long ago still passes the
/// stale check, so the bound is kept small beside frame ages (`max_frame_age_ms`, 1 s).
const MAX_STAMP_AHEAD_NS: u64 = 100_000_000;

/// The refusal of a frame stamped more than [`MAX_STAMP_AHEAD_NS`] ahead of `now`; `whose`
/// begins the message ("the frame is", "camera \"x\" has its frames").
fn stamped_ahead(frame: &FrameHeader, now: u64, whose: &str) -> Option<EngineError> {
    let ahead = frame.capture_time_ns.saturating_sub(now);
    (ahead > MAX_STAMP_AHEAD_NS).then(|| {
        EngineError::new(
            Status::InvalidFrame,
            format!(
                "{whose} stamped {} ahead of this machine's CLOCK_MONOTONIC (at most {}), so \
                 frame age cannot be told: stamp with monotonic_now_ns, not wall-clock time",
                duration_text(ahead),
                duration_text(MAX_STAMP_AHEAD_NS)
            ),
        )
    })
}

/// `ns` for a message: in milliseconds up to a second, seconds up to two minutes, hours up to
/// two days, else days.
fn duration_text(ns: u64) -> String {
    let s = ns as f64 / 1e9;
    if s < 1.0 {
        format!("{:.0} ms", s * 1e3)
    } else if s < 120.0 {
        format!("{s:.1} s")
    } else if s < 48.0 * 3600.0 {
        format!("{:.1} h", s / 3600.0)
    } else {
        format!("{:.0} days", s / 86400.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Poses of a detection that ended past the request's deadline are not sent as served: the
    /// answer says by how much it was late. One in time, one without a deadline and a refusal
    /// go as they are.
    #[test]
    fn a_detection_finished_past_its_deadline_is_refused_as_such() {
        let header = DetectRequestHeader {
            send_time_ns: 1_000_000_000,
            deadline_ns: 1_250_000_000,
            ..Default::default()
        };
        let late = in_time(Ok::<u32, EngineError>(7), &header, 1_256_000_000).unwrap_err();
        assert_eq!(late.status, Status::DeadlineExceeded);
        assert!(
            late.message.contains(
                "finished 6.0 ms after the request's deadline, 256.0 ms after it was sent"
            ),
            "{}",
            late.message
        );
        assert_eq!(
            in_time(Ok::<u32, EngineError>(7), &header, 1_250_000_000).unwrap(),
            7
        );
        let unbounded = DetectRequestHeader {
            deadline_ns: 0,
            ..header
        };
        assert_eq!(
            in_time(Ok::<u32, EngineError>(7), &unbounded, u64::MAX).unwrap(),
            7
        );
        let refused = in_time(
            Err::<u32, _>(EngineError::new(Status::InvalidFrame, "bad")),
            &header,
            2_000_000_000,
        )
        .unwrap_err();
        assert_eq!(refused.status, Status::InvalidFrame);
    }
}
