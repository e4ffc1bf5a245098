//! Dead-process cleanup and camera discovery, on a thread of their own.
//!
//! Both walk iceoryx2's directories — every node's, every service's — and take milliseconds
//! (2–4 ms measured with a few hundred node entries left by earlier processes). On the I/O
//! thread that time was a stall once a second: a request arriving during it waited, and showed
//! up as milliseconds of transport in the latency tail. The housekeeper has its own iceoryx2
//! node, wakes every period (or at once when asked, e.g. when a camera announces itself), and
//! hands the camera names it finds to the I/O thread over a channel, waking it through the
//! same eventfd the workers use.

use std::sync::mpsc::{channel, sync_channel, Receiver, RecvTimeoutError, Sender};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use iceoryx2::prelude::*;
use iceoryx2::service::static_config::messaging_pattern::MessagingPattern;

use ppfd_protocol::services;

use crate::daemon::DaemonError;
use crate::wakeup::Signaller;

type Ipc = ipc::Service;

/// What the I/O thread asks of the housekeeper.
enum Ask {
    /// Look for cameras now (one announced itself).
    Scan,
    /// The I/O thread let go of this camera (or did not subscribe): report it again at the next
    /// scan that finds it.
    Forget(String),
}

/// The housekeeping thread. Dropping it stops and joins the thread.
pub struct Housekeeper {
    ask: Option<Sender<Ask>>,
    found: Receiver<Vec<String>>,
    thread: Option<JoinHandle<()>>,
}

/// The camera names among the publish-subscribe services visible with `config`.
fn list_cameras(config: &iceoryx2::config::Config) -> Vec<String> {
    let mut found = Vec::new();
    let listed = Ipc::list(config, |details| {
        if matches!(
            details.static_details.messaging_pattern(),
            MessagingPattern::PublishSubscribe(_)
        ) {
            if let Some(camera) =
                services::camera_of_service(details.static_details.name().as_str())
            {
                found.push(camera.to_owned());
            }
        }
        CallbackProgression::Continue
    });
    if let Err(e) = listed {
        tracing::warn!(error = ?e, "listing services failed");
    }
    found
}

impl Housekeeper {
    /// Starts the thread with its own node on `config`; every `period` it removes what dead
    /// processes left and lists the cameras, then signals `wake`. `thread_setup` runs first on
    /// the new thread (the daemon blocks termination signals there, so they reach the I/O
    /// thread).
    pub fn start(
        config: &iceoryx2::config::Config,
        period: Duration,
        wake: Signaller,
        thread_setup: fn(),
    ) -> Result<Housekeeper, DaemonError> {
        let (ask_tx, ask_rx) = channel();
        let (found_tx, found_rx) = channel();
        let (ready_tx, ready_rx) = sync_channel(1);
        let config = config.clone();
        let thread = std::thread::Builder::new()
            .name("ppfd-housekeeper".into())
            .spawn(move || {
                thread_setup();
                let node = NodeName::new("ppfd-housekeeper")
                    .map_err(|e| format!("node name: {e:?}"))
                    .and_then(|name| {
                        NodeBuilder::new()
                            .name(&name)
                            .config(&config)
                            .create::<Ipc>()
                            .map_err(|e| format!("cannot create the housekeeping node: {e:?}"))
                    });
                let node = match node {
                    Ok(node) => {
                        let _ = ready_tx.send(Ok(()));
                        node
                    }
                    Err(e) => {
                        let _ = ready_tx.send(Err(e));
                        return;
                    }
                };
                serve(&node, period, &ask_rx, &found_tx, wake);
            })
            .map_err(|e| DaemonError(format!("cannot start the housekeeping thread: {e}")))?;
        // A first camera scan at once: cameras that were publishing before the daemon started.
        let _ = ask_tx.send(Ask::Scan);
        match ready_rx.recv() {
            Ok(Ok(())) => Ok(Housekeeper {
                ask: Some(ask_tx),
                found: found_rx,
                thread: Some(thread),
            }),
            Ok(Err(e)) => {
                let _ = thread.join();
                Err(DaemonError(e))
            }
            Err(_) => {
                let _ = thread.join();
                Err(DaemonError("the housekeeping thread died at start".into()))
            }
        }
    }

    /// Asks for a camera scan now rather than at the next period.
    pub fn scan_now(&self) {
        if let Some(ask) = &self.ask {
            let _ = ask.send(Ask::Scan);
        }
    }

    /// Report `name` again the next time it is found (the I/O thread forgot the camera, or did
    /// not subscribe to it). A name whose service is gone at a scan is reported again anyway.
    pub fn forget(&self, name: String) {
        if let Some(ask) = &self.ask {
            let _ = ask.send(Ask::Forget(name));
        }
    }

    /// The camera names found since the last call; each name is reported once while its
    /// service exists (and again after [`Housekeeper::forget`]).
    pub fn cameras_found(&self) -> Vec<String> {
        let mut names = Vec::new();
        while let Ok(batch) = self.found.try_recv() {
            names.extend(batch);
        }
        names
    }
}

/// The thread's loop: until the I/O thread's side of `ask` is dropped.
fn serve(
    node: &Node<Ipc>,
    period: Duration,
    ask: &Receiver<Ask>,
    found: &Sender<Vec<String>>,
    wake: Signaller,
) {
    // Dead processes were cleaned up as the daemon started; the first period only looks for
    // cameras (see `start`), and cleanup follows a period later.
    let mut next = Instant::now() + period;
    let mut reported = std::collections::HashSet::new();
    loop {
        let scan_only = match ask.recv_timeout(next.saturating_duration_since(Instant::now())) {
            Ok(Ask::Scan) => true,
            Ok(Ask::Forget(name)) => {
                reported.remove(&name);
                continue;
            }
            Err(RecvTimeoutError::Timeout) => false,
            Err(RecvTimeoutError::Disconnected) => return,
        };
        let started = Instant::now();
        if !scan_only {
            next = started + period;
            let cleaned = node.try_cleanup_dead_nodes();
            if cleaned.cleanups > 0 {
                tracing::info!(
                    removed = cleaned.cleanups,
                    "removed resources of dead processes"
                );
            }
        }
        let mut cameras = list_cameras(node.config());
        // A name whose service is gone is reported again when it comes back.
        reported.retain(|name| cameras.contains(name));
        cameras.retain(|name| reported.insert(name.clone()));
        tracing::trace!(
            us = started.elapsed().as_micros() as u64,
            cameras = cameras.len(),
            "housekeeping"
        );
        if !cameras.is_empty() {
            if found.send(cameras).is_err() {
                return;
            }
            wake.signal();
        }
    }
}

impl Drop for Housekeeper {
    fn drop(&mut self) {
        drop(self.ask.take());
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::wakeup::Wakeup;

    fn config(prefix: &str) -> iceoryx2::config::Config {
        let mut config = iceoryx2::config::Config::default();
        config.global.prefix = FileName::new(prefix.as_bytes()).unwrap();
        config
    }

    /// Waits up to 5 s for the housekeeper to report something.
    fn next_found(h: &Housekeeper, wake: &Wakeup) -> Vec<String> {
        let until = Instant::now() + Duration::from_secs(5);
        while Instant::now() < until {
            let found = h.cameras_found();
            if !found.is_empty() {
                assert!(wake.drain(), "cameras reported without a wake-up");
                return found;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        Vec::new()
    }

    #[test]
    fn reports_a_camera_once_and_again_once_forgotten_or_gone() {
        let prefix = format!("hk{}_", std::process::id());
        let config = config(&prefix);
        let wake = Wakeup::new().unwrap();
        // A period far beyond the test: every report below comes from the scan at start or a
        // scan asked for.
        let h = Housekeeper::start(&config, Duration::from_secs(3600), wake.signaller(), || {})
            .unwrap();
        std::thread::sleep(Duration::from_millis(100));
        assert!(h.cameras_found().is_empty());

        let node = NodeBuilder::new().config(&config).create::<Ipc>().unwrap();
        let camera = |name| {
            services::camera_builder(&node, name)
                .unwrap()
                .create()
                .unwrap()
        };
        let _left = camera("left");
        h.scan_now();
        assert_eq!(next_found(&h, &wake), vec!["left".to_owned()]);

        let _right = camera("right");
        h.scan_now();
        // "left" is not reported again.
        assert_eq!(next_found(&h, &wake), vec!["right".to_owned()]);
        h.scan_now();
        std::thread::sleep(Duration::from_millis(200));
        assert!(h.cameras_found().is_empty());
        // Once forgotten, "left" is reported again while it exists.
        h.forget("left".to_owned());
        h.scan_now();
        assert_eq!(next_found(&h, &wake), vec!["left".to_owned()]);
        // A camera whose service went away is reported again when it is back.
        drop(_right);
        h.scan_now();
        std::thread::sleep(Duration::from_millis(200));
        assert!(h.cameras_found().is_empty());
        let _right = camera("right");
        h.scan_now();
        assert_eq!(next_found(&h, &wake), vec!["right".to_owned()]);
        drop(h); // stops and joins the thread
    }
}
