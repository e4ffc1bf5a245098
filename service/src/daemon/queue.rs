//! Detect requests: taken off the port, checked against the contract and the loaded models
//! (what cannot be served is refused at once, with a status and a message), queued up to
//! `queue_capacity`, and started in arrival order as detection slots free up.

use std::sync::Arc;

use ppfd_protocol::clock::monotonic_now_ns;
use ppfd_protocol::detect::{DetectRequestHeader, FrameSource, Status};

use crate::engine::{EngineError, LoadedModel};
use crate::responder::{DetectActive, Outcome};

use super::Daemon;

/// A request waiting for a detection slot.
pub(super) struct Queued {
    pub(super) active: DetectActive,
    pub(super) header: DetectRequestHeader,
    pub(super) source: FrameSource,
    pub(super) models: Vec<Arc<LoadedModel>>,
    pub(super) received_ns: u64,
}

impl Daemon {
    pub(super) fn take_detect_requests(&mut self) {
        if self.startup.is_some() {
            // They wait in their channels until every model of the folder is there: a request
            // for a model not yet loaded would be refused "unknown object".
            return;
        }
        loop {
            match self.detect_server.receive() {
                Ok(Some(active)) => self.accept(active),
                Ok(None) => break,
                Err(e) => {
                    tracing::warn!(error = ?e, "receiving detect requests failed");
                    break;
                }
            }
        }
    }

    fn accept(&mut self, active: DetectActive) {
        let received_ns = monotonic_now_ns();
        self.stats.requests_received += 1;
        let header = *active.user_header();
        let payload_len = active.payload().len();
        tracing::debug!(request = header.request_id, objects = ?header.objects(), "request received");
        if self.shutting_down {
            let e = EngineError::new(Status::ShuttingDown, "the daemon is shutting down");
            return self.refuse(active, &header, received_ns, e);
        }
        let max_pixels = self.config.max_frame_pixels;
        let checked = header.validate(payload_len).and_then(|source| {
            if source == FrameSource::Inline {
                header.inline_frame.check_pixels(max_pixels)?;
            }
            Ok(source)
        });
        let source = match checked {
            Ok(source) => source,
            Err(e) => {
                let value = match e {
                    ppfd_protocol::ProtocolError::Version { expected, .. } => expected as u64,
                    _ => 0,
                };
                let error = EngineError {
                    status: e.status(),
                    message: e.to_string(),
                    value,
                };
                return self.refuse(active, &header, received_ns, error);
            }
        };
        let models = match self.registry.resolve(header.objects()) {
            Ok(models) => models,
            Err(e) => return self.refuse(active, &header, received_ns, e),
        };
        if self.queue.len() >= self.config.queue_capacity {
            let e = EngineError::new(
                Status::Busy,
                format!(
                    "{} requests are already waiting, the most the queue holds \
                     (queue_capacity, ppfd --queue-capacity); retry later",
                    self.queue.len()
                ),
            );
            return self.refuse(active, &header, received_ns, e);
        }
        self.queue.push_back(Queued {
            active,
            header,
            source,
            models,
            received_ns,
        });
    }

    pub(super) fn dispatch(&mut self) {
        while self.in_flight.len() < self.config.parallel_detections {
            let Some(q) = self.queue.pop_front() else {
                break;
            };
            if !self.responder.detect_client_alive(&q.active) {
                let outcome = self.responder.abandon(q.active, q.header.request_id);
                self.count(outcome);
                continue;
            }
            if !q.active.is_connected() {
                self.stats.requests_abandoned += 1;
                tracing::debug!(
                    request = q.header.request_id,
                    "client gone before its detection started"
                );
                continue;
            }
            let now = monotonic_now_ns();
            if q.header.deadline_ns != 0 && now >= q.header.deadline_ns {
                self.stats.requests_expired += 1;
                let late = now - q.header.deadline_ns;
                let e = EngineError::new(
                    Status::DeadlineExceeded,
                    format!(
                        "deadline passed {:.3} ms before a worker was free",
                        late as f64 / 1e6
                    ),
                );
                self.refuse(q.active, &q.header, q.received_ns, e);
                continue;
            }
            if let Err(e) = self.start(q) {
                let (active, header, received_ns, error) = *e;
                self.refuse(active, &header, received_ns, error);
            }
        }
    }

    pub(super) fn count(&mut self, outcome: Outcome) {
        match outcome {
            Outcome::Served {
                total_ns,
                overhead_ns,
                detection_ns,
            } => self
                .stats
                .record_served(total_ns, overhead_ns, detection_ns),
            // The answer did not reach its client: counted with those whose client went away,
            // so that every request received is served, refused or abandoned.
            Outcome::Undelivered | Outcome::Abandoned => self.stats.requests_abandoned += 1,
            Outcome::Refused => self.stats.requests_refused += 1,
        }
    }

    pub(super) fn refuse(
        &mut self,
        active: DetectActive,
        request: &DetectRequestHeader,
        received_ns: u64,
        e: EngineError,
    ) {
        let outcome = self.responder.refuse(active, request, received_ns, e);
        self.count(outcome);
    }
}
