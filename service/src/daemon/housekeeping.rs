//! The I/O thread's share of housekeeping (cleanup and discovery run on the
//! [`Housekeeper`](crate::housekeeper::Housekeeper)'s thread): older frames released, dead
//! clients' requests let go of and their detections cancelled.

use std::sync::atomic::Ordering;
use std::time::Instant;

use crate::responder::{self, Port, Release};

use super::Daemon;

impl Daemon {
    /// The I/O thread's share of housekeeping: release older frames, bound the reply-key
    /// cache, let go of dead clients' requests.
    pub(super) fn housekeeping(&mut self) {
        self.last_housekeeping = Instant::now();
        // Keep only the newest frame of each camera, releasing older ones to their drivers.
        for (name, camera) in &mut self.cameras {
            self.stats.frames_received += camera.refresh(name);
        }
        self.forget_driverless_cameras();
        self.responder.trim();
        self.drop_dead_clients_requests();
        self.drop_dead_clients_held_control();
        self.cancel_dead_clients_detections();
        self.release_abandoned();
    }

    /// Stops the running detections of clients that died: they would hold a worker for
    /// seconds to compute an answer nobody reads, while the queue waits behind them.
    fn cancel_dead_clients_detections(&mut self) {
        for (job, f) in &self.in_flight {
            if !f.cancel.load(Ordering::Relaxed) && !self.responder.detect_client_listed(f.client) {
                f.cancel.store(true, Ordering::Relaxed);
                tracing::debug!(job, "client gone: its running detection is cancelled");
            }
        }
    }

    /// Lets go of the dead clients' requests that can be let go of (see
    /// [`Responder::release_one_abandoned`]), one at a time.
    pub(super) fn release_abandoned(&mut self) {
        let mut forced = 0;
        while let Some((port, release)) = self.responder.release_one_abandoned() {
            forced += usize::from(release == Release::Forced);
            // The receive lets iceoryx2 forget the dead client's connection (and takes any
            // request that came in meanwhile).
            match port {
                Port::Detect => self.take_detect_requests(),
                Port::Control => self.take_control_requests(),
            }
        }
        if forced > 0 {
            tracing::warn!(
                released = forced,
                "released requests of dead clients whose channels may serve new clients (more than {} held)",
                responder::MAX_ABANDONED_HELD
            );
        }
        let held = self.responder.abandoned_held();
        if held > 0 {
            tracing::debug!(held, "requests of dead clients not yet released");
        }
    }

    /// Lets go of the control requests held while the models folder loads whose clients are
    /// gone: each keeps the dead client's connection in the server's buffer of expired
    /// connections, which iceoryx2 panics beyond, and a monitor polling the model list with a
    /// short timeout leaves one per poll for as long as the folder takes to load.
    pub(super) fn drop_dead_clients_held_control(&mut self) {
        if self.held_control.is_empty() {
            return;
        }
        let held = std::mem::take(&mut self.held_control);
        for active in held {
            if self.responder.control_client_alive(&active) {
                self.held_control.push(active);
            } else {
                self.responder.abandon_control(active);
            }
        }
    }

    /// Takes the queued requests of clients that died off the queue: while queued, each keeps
    /// the dead client's connection (and its shared memory) alive.
    fn drop_dead_clients_requests(&mut self) {
        if self.queue.is_empty() {
            return;
        }
        let queued = std::mem::take(&mut self.queue);
        for q in queued {
            if self.responder.detect_client_alive(&q.active) {
                self.queue.push_back(q);
            } else {
                let outcome = self.responder.abandon(q.active, q.header.request_id);
                self.count(outcome);
            }
        }
    }
}
