//! The models folder, loaded at start on a thread of its own, one model after the other: the
//! I/O thread takes each as it comes, answers statistics meanwhile and holds the other control
//! requests until the folder is done.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{channel, Receiver};
use std::sync::Arc;
use std::time::Instant;

use crate::engine::{DetectionEngine, LoadedModel};
use crate::registry::Registry;
use crate::termination::block_termination_signals;
use crate::wakeup::Signaller;

use crate::error::{resource, Result};

use super::Daemon;

/// The models folder loading at start on a thread of its own, one model after the other; the
/// I/O thread takes each as it comes.
pub(super) struct StartupLoad {
    dir: PathBuf,
    /// How many model files the folder holds.
    files: usize,
    /// Files done (loaded or failed), and failed.
    done: usize,
    failed: usize,
    started: Instant,
    stop: Arc<AtomicBool>,
    events: Receiver<StartupEvent>,
    thread: Option<std::thread::JoinHandle<()>>,
}

enum StartupEvent {
    Loaded(LoadedModel),
    /// A file that did not load, and why.
    Failed(PathBuf, String),
    /// Every file done, or the loading stopped.
    Finished,
}

impl StartupLoad {
    pub(super) fn start(
        engine: Arc<dyn DetectionEngine>,
        dir: PathBuf,
        files: Vec<PathBuf>,
        cache_dir: PathBuf,
        signaller: Signaller,
    ) -> Result<StartupLoad> {
        let stop = Arc::new(AtomicBool::new(false));
        let (tx, events) = channel();
        let file_count = files.len();
        let thread = {
            let stop = stop.clone();
            std::thread::Builder::new()
                .name("ppfd-load".into())
                .spawn(move || {
                    block_termination_signals();
                    let send = |event| {
                        let _ = tx.send(event);
                        signaller.signal();
                    };
                    Registry::load_files(
                        engine.as_ref(),
                        &files,
                        Some(&cache_dir),
                        &|| stop.load(Ordering::SeqCst),
                        &mut |model| send(StartupEvent::Loaded(model)),
                        &mut |path, e| send(StartupEvent::Failed(path, e.message)),
                    );
                    send(StartupEvent::Finished);
                })
                .map_err(resource("cannot start the model loading thread"))?
        };
        Ok(StartupLoad {
            dir,
            files: file_count,
            done: 0,
            failed: 0,
            started: Instant::now(),
            stop,
            events,
            thread: Some(thread),
        })
    }

    /// Puts the models loaded since the last call into `registry`; whether the loading is over.
    fn take(&mut self, registry: &mut Registry) -> bool {
        // Looked at first: a thread that has ended (even by a panic) has sent all it will.
        let ended = self.thread.as_ref().is_none_or(|t| t.is_finished());
        let mut finished = false;
        while let Ok(event) = self.events.try_recv() {
            match event {
                StartupEvent::Loaded(model) => {
                    self.done += 1;
                    registry.insert(model);
                }
                StartupEvent::Failed(path, reason) => {
                    self.done += 1;
                    self.failed += 1;
                    registry.record_failure(path, reason);
                }
                StartupEvent::Finished => finished = true,
            }
        }
        finished || ended
    }

    fn join(&mut self) {
        if let Some(thread) = self.thread.take() {
            if thread.join().is_err() {
                tracing::error!("the model loading thread panicked");
            }
        }
    }

    /// Files to load, files loaded or failed so far, files failed.
    pub(super) fn progress(&self) -> (u64, u64, u64) {
        (self.files as u64, self.done as u64, self.failed as u64)
    }
}

impl Daemon {
    /// Takes the models loaded at start so far; once the folder is done, logs it, handles the
    /// control requests held meanwhile and lets detections in.
    pub(super) fn poll_startup(&mut self) {
        let Some(startup) = &mut self.startup else {
            return;
        };
        if !startup.take(&mut self.registry) {
            return;
        }
        let mut startup = self.startup.take().expect("loading");
        startup.join();
        // Files the loading never reached (its thread ended early) count as failed: the
        // loading is over, and "done" says so.
        let (files, done, failed) = startup.progress();
        self.startup_files = (files, files, failed + (files - done));
        if startup.files == 0 {
            tracing::warn!(
                dir = %startup.dir.display(),
                "no model in the models folder: nothing can be detected until one is loaded (ppf models --load)"
            );
        }
        tracing::info!(
            loaded = self.registry.len(),
            failed = startup.failed,
            bytes = self.registry.bytes(),
            ms = startup.started.elapsed().as_millis() as u64,
            dir = %startup.dir.display(),
            "models loaded"
        );
        for active in std::mem::take(&mut self.held_control) {
            self.control(active);
        }
    }

    /// Ends the loading at start, if it runs, after the model being loaded.
    pub(super) fn stop_startup(&mut self) {
        if let Some(startup) = self.startup.as_mut() {
            startup.stop.store(true, Ordering::SeqCst);
            startup.join();
            startup.take(&mut self.registry);
        }
    }
}
