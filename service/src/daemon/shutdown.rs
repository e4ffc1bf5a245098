//! The clean stop: queued requests refused "shutting down", running detections finished and
//! answered, and no frame released while a worker may read it.

use std::time::{Duration, Instant};

use ppfd_protocol::detect::Status;

use crate::engine::EngineError;
use crate::responder::ControlActive;

use super::Daemon;

impl Daemon {
    pub(super) fn shutdown(&mut self) {
        self.shutting_down = true;
        self.stop_startup();
        for active in std::mem::take(&mut self.held_control) {
            let m = "the daemon is shutting down";
            self.control_answer(active, Status::ShuttingDown, m, &[]);
        }
        while let Some(q) = self.queue.pop_front() {
            let e = EngineError::new(Status::ShuttingDown, "the daemon is shutting down");
            self.refuse(q.active, &q.header, q.received_ns, e);
        }
        // Loads not started are answered below with the other pending control requests.
        self.waiting_loads.clear();
        self.checking_loads.clear();
        self.join_in_flight();
        let pending: Vec<ControlActive> = self.control_pending.drain().map(|(_, a)| a).collect();
        for active in pending {
            self.control_answer(
                active,
                Status::ShuttingDown,
                "the daemon is shutting down",
                &[],
            );
        }
    }

    /// Waits until no worker reads shared memory any more (each answers its request first).
    /// While shutting down, requests that come in meanwhile are answered (statistics, the model
    /// list) or refused "shutting down", not left to time out.
    fn join_in_flight(&mut self) {
        let mut last_warning = Instant::now();
        while !self.in_flight.is_empty() {
            match self.done_rx.recv_timeout(Duration::from_millis(50)) {
                Ok(c) => self.finish(c),
                Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {
                    if last_warning.elapsed() >= Duration::from_secs(5) {
                        last_warning = Instant::now();
                        tracing::warn!(
                            running = self.in_flight.len(),
                            "waiting for running detections"
                        );
                    }
                }
                Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => break,
            }
            if self.shutting_down {
                self.take_detect_requests();
                self.take_control_requests();
            }
        }
    }
}

impl Drop for Daemon {
    fn drop(&mut self) {
        // The loader signals the I/O thread's eventfd: end it while that is open.
        self.stop_startup();
        // Workers read the frames held in `in_flight`: never release them under a worker.
        self.join_in_flight();
    }
}
