//! Answers to requests, sent by whichever thread holds the request: the I/O thread refuses what
//! it cannot serve and answers control requests; the pool worker that ran a detection answers
//! it itself, so that a finished detection reaches its client without waking the I/O thread
//! first (on two vCPUs that wake-up alone cost about 40 µs).
//!
//! The daemon's ports are `ipc_threadsafe` for this: an active request can move to a worker, and
//! the responses notifier is shared behind a mutex with its cache of listener keys.

use std::collections::HashMap;
use std::sync::Mutex;

use iceoryx2::active_request::ActiveRequest;
use iceoryx2::identifiers::UniqueClientId;
use iceoryx2::port::notifier::{ListenerKey, Notifier};
use iceoryx2::prelude::*;
use iceoryx2::service::dynamic_config::request_response::ClientDetails;

use ppfd_protocol::clock::monotonic_now_ns;
use ppfd_protocol::control::{ControlRequest, ControlResponseHeader, ModelInfo};
use ppfd_protocol::detect::{DetectRequestHeader, DetectResponseHeader, PoseHypothesis};
use ppfd_protocol::services::{self, limits, ControlService, DetectService};
use ppfd_protocol::text;

use crate::engine::{EngineError, EngineOutput};

/// The daemon's iceoryx2 service variant: inter-process, with ports that may cross threads.
pub type Ipc = ipc_threadsafe::Service;
/// A detect request taken off the port, until it is answered.
pub type DetectActive =
    ActiveRequest<Ipc, [u16], DetectRequestHeader, [PoseHypothesis], DetectResponseHeader>;
/// A control request taken off the port, until it is answered.
pub type ControlActive = ActiveRequest<Ipc, ControlRequest, (), [ModelInfo], ControlResponseHeader>;

/// The daemon's request ports.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Port {
    /// The `ppfd/detect` server.
    Detect,
    /// The `ppfd/control` server.
    Control,
}

/// How an abandoned request was let go (see [`Responder::release_one_abandoned`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Release {
    /// Its response channel no longer waited for it.
    Safe,
    /// Beyond [`MAX_ABANDONED_HELD`]: its channel may have served a new client's request.
    Forced,
}

/// What became of a request once answered (or not), for the statistics.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Outcome {
    /// Poses sent; latencies in ns.
    Served {
        /// From the client's send to the response's send; 0 when the client gave no send time.
        total_ns: u64,
        /// Transport and queue wait: from the client's send to the start of the detection.
        overhead_ns: u64,
        /// From the start of the detection to its end on the worker.
        detection_ns: u64,
    },
    /// An answer (poses or a refusal) that could not be loaned or sent.
    Undelivered,
    /// Refused with an error status (sent if the client could still take it).
    Refused,
    /// The client died or stopped waiting before its answer.
    Abandoned,
}

/// What the answer to a detection needs besides the engine's output.
#[derive(Debug, Clone, Copy)]
pub struct Served {
    /// The request's header.
    pub header: DetectRequestHeader,
    /// When the I/O thread took the request off the port, `CLOCK_MONOTONIC` ns.
    pub received_ns: u64,
    /// Sequence number of the frame used (0 for an inline frame without one).
    pub frame_sequence: u64,
    /// Age of that frame when the detection started, ns; 0 when it has no capture time.
    pub frame_age_ns: u64,
    /// When the detection started on its worker, `CLOCK_MONOTONIC` ns.
    pub started_ns: u64,
    /// When the detection ended, `CLOCK_MONOTONIC` ns.
    pub finished_ns: u64,
}

/// Sends responses and wakes their clients; shared by the I/O thread and the workers.
pub struct Responder {
    detect_service: DetectService<Ipc>,
    control_service: ControlService<Ipc>,
    wake: Mutex<Wake>,
    abandoned: Mutex<Abandoned>,
    refusals: Mutex<RefusalLog>,
}

/// How often the log names a refusal of one status: a misconfigured camera refused at every
/// request of a picking loop would otherwise fill the journal.
const REFUSAL_LOG_PERIOD_NS: u64 = 60_000_000_000;

/// When each status's refusal was last logged, and how many went unlogged since.
#[derive(Default)]
struct RefusalLog {
    by_status: HashMap<u32, (u64, u64)>,
}

impl RefusalLog {
    /// Whether a refusal of `status` at `now_ns` is logged, and if so how many of that status
    /// went unlogged before it: the first of a status is, then one per
    /// [`REFUSAL_LOG_PERIOD_NS`].
    fn note(&mut self, status: u32, now_ns: u64) -> Option<u64> {
        match self.by_status.get_mut(&status) {
            Some((last, quiet)) if now_ns.saturating_sub(*last) < REFUSAL_LOG_PERIOD_NS => {
                *quiet += 1;
                None
            }
            Some((last, quiet)) => {
                *last = now_ns;
                Some(std::mem::take(quiet))
            }
            None => {
                self.by_status.insert(status, (now_ns, 0));
                Some(0)
            }
        }
    }
}

/// At most this many requests of dead clients are held back (see
/// [`Responder::release_one_abandoned`]).
pub const MAX_ABANDONED_HELD: usize = limits::MAX_CLIENTS;

/// Requests of clients that died before their answer, held until releasing them cannot touch
/// another client's channel (see [`Responder::release_one_abandoned`]).
#[derive(Default)]
struct Abandoned {
    detect: Vec<DetectActive>,
    control: Vec<ControlActive>,
}

struct Wake {
    notifier: Notifier<Ipc>,
    /// The listener of each reply token seen, so that waking a client is one call.
    keys: HashMap<u64, ListenerKey>,
}

impl Responder {
    /// A responder for the daemon's detect and control services, waking clients through the
    /// `ppfd/responses` event `notifier`.
    pub fn new(
        detect_service: DetectService<Ipc>,
        control_service: ControlService<Ipc>,
        notifier: Notifier<Ipc>,
    ) -> Responder {
        Responder {
            detect_service,
            control_service,
            wake: Mutex::new(Wake {
                notifier,
                keys: HashMap::new(),
            }),
            abandoned: Mutex::new(Abandoned::default()),
            refusals: Mutex::new(RefusalLog::default()),
        }
    }

    /// Answers a finished detection: its poses, or its error.
    pub fn answer(
        &self,
        active: DetectActive,
        job: &Served,
        result: Result<EngineOutput, EngineError>,
    ) -> Outcome {
        if !self.detect_client_alive(&active) {
            return self.abandon(active, job.header.request_id);
        }
        if !active.is_connected() {
            tracing::debug!(
                request = job.header.request_id,
                "client gone before its answer"
            );
            return Outcome::Abandoned;
        }
        let output = match result {
            Ok(output) => output,
            Err(e) => return self.refuse(active, &job.header, job.received_ns, e),
        };
        let mut response = DetectResponseHeader {
            request_id: job.header.request_id,
            frame_sequence: job.frame_sequence,
            frame_age_ns: job.frame_age_ns,
            latency: output.stages,
            counts: output.counts,
            ..Default::default()
        };
        if !output.diagnosis.is_empty() {
            response.set_diagnosis(&output.diagnosis);
        }
        let send_ns = job.header.send_time_ns;
        response.latency.transport_ns = if send_ns != 0 {
            job.received_ns.saturating_sub(send_ns)
        } else {
            0
        };
        response.latency.queue_wait_ns = job.started_ns.saturating_sub(job.received_ns);
        response.latency.detection_ns = job.finished_ns.saturating_sub(job.started_ns);
        let hypotheses =
            &output.hypotheses[..output.hypotheses.len().min(limits::MAX_RESPONSE_HYPOTHESES)];
        response.counts.returned = hypotheses.len() as u32;
        response.hypothesis_count = hypotheses.len() as u32;
        let Some(total_ns) =
            self.send_detect(&active, job.header.reply_token, response, hypotheses)
        else {
            return Outcome::Undelivered;
        };
        tracing::debug!(
            request = job.header.request_id,
            hypotheses = hypotheses.len(),
            detection_us = response.latency.detection_ns / 1000,
            total_us = total_ns / 1000,
            "request served"
        );
        Outcome::Served {
            total_ns,
            overhead_ns: response.latency.transport_ns + response.latency.queue_wait_ns,
            detection_ns: response.latency.detection_ns,
        }
    }

    /// Refuses a request with the error's status and message.
    pub fn refuse(
        &self,
        active: DetectActive,
        request: &DetectRequestHeader,
        received_ns: u64,
        e: EngineError,
    ) -> Outcome {
        if !self.detect_client_alive(&active) {
            return self.abandon(active, request.request_id);
        }
        let logged = self
            .refusals
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .note(e.status.code(), monotonic_now_ns());
        match logged {
            Some(unlogged) => tracing::info!(
                request = request.request_id,
                status = %e.status,
                reason = %e.message,
                unlogged_since = unlogged,
                "request refused (one line per status a minute; ppf stats counts them all)"
            ),
            None => {
                tracing::debug!(request = request.request_id, status = %e.status, reason = %e.message, "request refused")
            }
        }
        let mut response = DetectResponseHeader {
            request_id: request.request_id,
            status: e.status.code(),
            error_value: e.value,
            message: text::encode_truncated(&e.message),
            ..Default::default()
        };
        if request.send_time_ns != 0 {
            response.latency.transport_ns = received_ns.saturating_sub(request.send_time_ns);
        }
        match self.send_detect(&active, request.reply_token, response, &[]) {
            Some(_) => Outcome::Refused,
            None => Outcome::Undelivered,
        }
    }

    /// Whether the client that sent `active` still exists. A dead client's connection slot may
    /// already serve a new client (iceoryx2 reuses it once the dead node is cleaned up, which any
    /// process may do): answering the old request would then touch the new client's channel,
    /// and so may dropping it (see [`Responder::abandon`]).
    pub fn detect_client_alive(&self, active: &DetectActive) -> bool {
        self.detect_client_listed(active.origin())
    }

    /// Whether the detect client `origin` (of a request a worker holds) still exists.
    pub fn detect_client_listed(&self, origin: UniqueClientId) -> bool {
        listed(
            |visit| self.detect_service.dynamic_config().list_clients(visit),
            origin,
        )
    }

    /// As [`Responder::detect_client_alive`], for a control request.
    pub fn control_client_alive(&self, active: &ControlActive) -> bool {
        let origin = active.origin();
        listed(
            |visit| self.control_service.dynamic_config().list_clients(visit),
            origin,
        )
    }

    /// Sends a response and wakes its client. Returns the total latency (client send → now).
    fn send_detect(
        &self,
        active: &DetectActive,
        reply_token: u64,
        mut header: DetectResponseHeader,
        hypotheses: &[PoseHypothesis],
    ) -> Option<u64> {
        let loaned = match active.loan_slice_uninit(hypotheses.len()) {
            Ok(r) => r,
            Err(e) => {
                tracing::warn!(request = header.request_id, error = ?e, "cannot loan a response");
                return None;
            }
        };
        let mut response = loaned.write_from_slice(hypotheses);
        let now = monotonic_now_ns();
        let send_time_ns = active.user_header().send_time_ns;
        header.response_send_ns = now;
        header.latency.total_ns = if send_time_ns != 0 {
            now.saturating_sub(send_time_ns)
        } else {
            0
        };
        *response.user_header_mut() = header;
        if let Err(e) = response.send() {
            tracing::debug!(request = header.request_id, error = ?e, "response not delivered");
            return None;
        }
        self.notify_reply(reply_token);
        Some(header.latency.total_ns)
    }

    /// Wakes the listener of the client that gave `token` (0: the client polls).
    pub fn notify_reply(&self, token: u64) {
        if token == 0 {
            return;
        }
        let mut wake = self.wake.lock().unwrap_or_else(|p| p.into_inner());
        let Wake { notifier, keys } = &mut *wake;
        if let Some(key) = keys.get(&token) {
            if notifier.notify_single_listener(key).is_ok() {
                return;
            }
            keys.remove(&token);
        }
        let Ok(name) = PortName::new(&services::reply_listener_name(token)) else {
            return;
        };
        let mut found = None;
        notifier.for_each_listener(|monofier, details| {
            if details.listener_name == name {
                let _ = monofier.notify();
                found = Some(monofier.listener_key());
                CallbackProgression::Stop
            } else {
                CallbackProgression::Continue
            }
        });
        match found {
            Some(key) => {
                keys.insert(token, key);
            }
            None => tracing::debug!(token, "no listener to wake for this reply"),
        }
    }

    /// Bounds the cache of listener keys (clients come and go over weeks).
    pub fn trim(&self) {
        let mut wake = self.wake.lock().unwrap_or_else(|p| p.into_inner());
        if wake.keys.len() > 4 * limits::MAX_CLIENTS {
            wake.keys.clear();
        }
    }
}

/// Whether `origin` is among the clients that `list_clients` walks (a service's
/// `dynamic_config().list_clients`).
fn listed(
    list_clients: impl FnOnce(&mut dyn FnMut(&ClientDetails) -> CallbackProgression),
    origin: UniqueClientId,
) -> bool {
    let mut alive = false;
    list_clients(&mut |c: &ClientDetails| {
        alive = c.client_id == origin;
        if alive {
            CallbackProgression::Stop
        } else {
            CallbackProgression::Continue
        }
    });
    alive
}

impl Responder {
    /// Takes a dead client's request without answering it; [`Responder::release_one_abandoned`]
    /// lets go of it later.
    ///
    /// Dropping a request does two things: it returns the request's memory to its client's
    /// connection (iceoryx2 checks that the connection is still that client's), and it closes
    /// the response channel at the client's slot if the channel still waits for this request's
    /// id. The slot is an index that a new client may already hold, and request ids start at 0
    /// in every client, so a new client's first request can wait on that very channel under the
    /// same id: dropping the old request now could cut the new client off. Never dropping it
    /// is no better: the request's memory stays borrowed, iceoryx2 keeps the dead client's
    /// connection (its shared memory mapped, file descriptors open), and once more such
    /// connections pile up than its expired-connection buffer holds (128 by default) it
    /// panics, taking the daemon down.
    pub fn abandon(&self, active: DetectActive, request_id: u64) -> Outcome {
        tracing::debug!(request = request_id, "client died before its answer");
        self.lock_abandoned().detect.push(active);
        Outcome::Abandoned
    }

    /// As [`Responder::abandon`], for a control request.
    pub fn abandon_control(&self, active: ControlActive) {
        self.lock_abandoned().control.push(active);
    }

    /// Drops one abandoned request whose response channel no longer waits for it: the slot is
    /// empty (the daemon's ports saw the dead client go) or its channel serves another request
    /// id. Those still waiting stay for a later call: the daemon has not yet seen the dead
    /// client removed, or a new client's request waits on the same channel under the same id
    /// (until it is answered). Beyond [`MAX_ABANDONED_HELD`] one is dropped all the same (a
    /// control request first, else the oldest detect request): a new client might lose its
    /// request's answer (the client library then returns `Error::Dropped` at once), but the
    /// daemon stays up. Returns which port's request was dropped, if any, and how.
    ///
    /// The check and the drop are two steps: a new client that sends its first request on that
    /// very slot and channel in the microseconds between them would lose it the same way.
    ///
    /// One at a time, because of how iceoryx2 (0.10) forgets a dead client's connection: the
    /// next `receive` on the port removes the connections that no longer hold borrowed
    /// requests, but when two or more become free at once behind one that still holds a request,
    /// it takes the wrong one off its list and keeps that client's connection (its shared
    /// memory mapped, a slot of a fixed-size store taken) for good. So the I/O thread calls
    /// this, then `receive` on the port named, until nothing is left to drop.
    pub fn release_one_abandoned(&self) -> Option<(Port, Release)> {
        let mut abandoned = self.lock_abandoned();
        if let Some(i) = abandoned.detect.iter().position(|a| !a.is_connected()) {
            drop(abandoned.detect.remove(i));
            return Some((Port::Detect, Release::Safe));
        }
        if let Some(i) = abandoned.control.iter().position(|a| !a.is_connected()) {
            drop(abandoned.control.remove(i));
            return Some((Port::Control, Release::Safe));
        }
        if abandoned.detect.len() + abandoned.control.len() > MAX_ABANDONED_HELD {
            if !abandoned.control.is_empty() {
                drop(abandoned.control.remove(0));
                return Some((Port::Control, Release::Forced));
            }
            drop(abandoned.detect.remove(0));
            return Some((Port::Detect, Release::Forced));
        }
        None
    }

    /// How many requests of dead clients are held.
    pub fn abandoned_held(&self) -> usize {
        let abandoned = self.lock_abandoned();
        abandoned.detect.len() + abandoned.control.len()
    }

    fn lock_abandoned(&self) -> std::sync::MutexGuard<'_, Abandoned> {
        self.abandoned.lock().unwrap_or_else(|p| p.into_inner())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The first refusal of a status is logged, then one a minute per status with the count
    /// of those left out; another status is logged at once.
    #[test]
    fn refusals_are_logged_once_a_minute_per_status() {
        let mut log = RefusalLog::default();
        let second = 1_000_000_000;
        assert_eq!(log.note(4, 10 * second), Some(0));
        assert_eq!(log.note(4, 11 * second), None);
        assert_eq!(log.note(4, 69 * second), None);
        assert_eq!(log.note(7, 69 * second), Some(0), "another status");
        assert_eq!(log.note(4, 70 * second), Some(2));
        assert_eq!(log.note(4, 71 * second), None);
        assert_eq!(log.note(4, 200 * second), Some(1));
    }

    fn crosses_threads<T: Send>() {}
    fn shared_by_threads<T: Send + Sync>() {}

    /// What lets a pool worker answer its request: the request moves to the worker and the
    /// responder is shared. With the single-threaded `ipc` variant neither would compile.
    #[test]
    fn requests_move_to_workers_and_the_responder_is_shared() {
        crosses_threads::<DetectActive>();
        shared_by_threads::<Responder>();
        shared_by_threads::<std::sync::Arc<Responder>>();
    }
}
