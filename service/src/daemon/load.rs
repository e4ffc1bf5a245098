//! A model loaded or built at run time (`LoadModel`): the path's form checked on the I/O
//! thread, the file itself on a thread of its own (on a hung network mount a `stat` waits
//! without end), the loading on a thread of its own (building from a large mesh takes
//! seconds), the model put in the registry when it reports. One model loads at a time and the
//! rest wait their turn, up to [`MAX_WAITING_LOADS`] with those being checked: a build takes
//! memory in proportion to its mesh, and builds at once would add up.

use std::path::PathBuf;

use ppfd_protocol::control::ControlRequest;
use ppfd_protocol::detect::Status;

use crate::engine::{EngineError, LoadedModel};
use crate::registry::Registry;
use crate::responder::ControlActive;
use crate::termination::block_termination_signals;

use super::Daemon;

/// Loads waiting for the one that runs, their files being checked or checked; one more is
/// refused "busy".
pub const MAX_WAITING_LOADS: usize = 16;

/// A load waiting for its turn: its job (its control request is in `control_pending`), the
/// path and the object id asked for.
pub(super) struct WaitingLoad {
    job: u64,
    path: PathBuf,
    object_id: Option<u32>,
}

/// What a checking or loading thread reports.
pub(super) enum LoadReport {
    /// The file of a load was checked ([`crate::engine::DetectionEngine::check_load_path`]).
    Checked {
        job: u64,
        result: Result<(), EngineError>,
    },
    /// A model was loaded, or failed to.
    Loaded {
        job: u64,
        result: Result<LoadedModel, EngineError>,
    },
}

impl Daemon {
    /// Starts loading the model file or mesh `request` names, once its path passes; answered
    /// when the loading thread reports ([`Daemon::finish_load`]).
    pub(super) fn load_model(&mut self, active: ControlActive, request: ControlRequest) {
        let path = PathBuf::from(request.path().into_owned());
        if request.path().is_empty() {
            return self.control_answer(
                active,
                Status::InvalidRequest,
                "LoadModel needs a path",
                &[],
            );
        }
        if path.is_relative() {
            let m = format!(
                "{} is a relative path, and ppfd's working directory is not the \
                 caller's: give an absolute path",
                path.display()
            );
            return self.control_answer(active, Status::InvalidRequest, &m, &[]);
        }
        let waiting = self.loads_waiting();
        if waiting >= MAX_WAITING_LOADS {
            let m = format!(
                "{waiting} model loads are already waiting (one loads at a time, at most \
                 {MAX_WAITING_LOADS} wait); retry later"
            );
            return self.control_answer(active, Status::Busy, &m, &[]);
        }
        let object_id = (request.object_id != 0).then_some(request.object_id);
        let job = self.next_job;
        self.next_job += 1;
        let engine = self.engine.clone();
        let check_path = path.clone();
        let spawned = self.spawn_reporting(
            "ppfd-check",
            "checking the file",
            move || engine.check_load_path(&check_path),
            move |result| LoadReport::Checked { job, result },
        );
        if let Err(e) = spawned {
            let m = format!("cannot start checking the file: {e}");
            return self.control_answer(active, Status::Internal, &m, &[]);
        }
        self.control_pending.insert(job, active);
        self.checking_loads.insert(
            job,
            WaitingLoad {
                job,
                path,
                object_id,
            },
        );
    }

    /// Runs `work` on a thread named `name`, off the I/O thread, and sends what `report` makes
    /// of its result to the I/O thread, waking it. A panic in `work` is an internal error that
    /// says what was `doing`; the thread takes no termination signal (the I/O thread reads them).
    fn spawn_reporting<T: Send + 'static>(
        &self,
        name: &str,
        doing: &'static str,
        work: impl FnOnce() -> Result<T, EngineError> + Send + 'static,
        report: impl FnOnce(Result<T, EngineError>) -> LoadReport + Send + 'static,
    ) -> std::io::Result<()> {
        let tx = self.loaded_tx.clone();
        let signaller = self.signaller;
        std::thread::Builder::new()
            .name(name.into())
            .spawn(move || {
                block_termination_signals();
                let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(work))
                    .unwrap_or_else(|_| {
                        Err(EngineError::new(
                            Status::Internal,
                            format!("{doing} failed unexpectedly (panic)"),
                        ))
                    });
                let _ = tx.send(report(result));
                signaller.signal();
            })
            .map(|_| ())
    }

    /// Loads not running yet: their files being checked, or waiting for their turn.
    pub(super) fn loads_waiting(&self) -> usize {
        self.checking_loads.len() + self.waiting_loads.len()
    }

    /// What a checking or loading thread reported.
    pub(super) fn load_report(&mut self, report: LoadReport) {
        match report {
            LoadReport::Checked { job, result } => self.finish_check(job, result),
            LoadReport::Loaded { job, result } => self.finish_load(job, result),
        }
    }

    /// A load whose file passed waits for its turn; one whose file did not is answered.
    fn finish_check(&mut self, job: u64, result: Result<(), EngineError>) {
        let Some(load) = self.checking_loads.remove(&job) else {
            return;
        };
        match result {
            Ok(()) if !self.shutting_down => {
                self.waiting_loads.push_back(load);
                self.start_next_load();
            }
            Ok(()) => {}
            Err(e) => {
                if let Some(active) = self.control_pending.remove(&job) {
                    self.control_answer(active, e.status, &e.message, &[]);
                }
            }
        }
    }

    /// Starts the next waiting load on a thread of its own, unless one is running.
    fn start_next_load(&mut self) {
        if self.loading.is_some() {
            return;
        }
        let Some(WaitingLoad {
            job,
            path,
            object_id,
        }) = self.waiting_loads.pop_front()
        else {
            return;
        };
        let engine = self.engine.clone();
        let cache = Some(self.config.model_cache_dir());
        // Building a model from a mesh may take seconds: off the I/O thread and off the
        // detection workers.
        let spawned = self.spawn_reporting(
            "ppfd-load",
            "loading",
            move || engine.load(&path, object_id, cache.as_deref()),
            move |result| {
                release_freed_memory();
                LoadReport::Loaded { job, result }
            },
        );
        match spawned {
            Ok(_) => self.loading = Some(job),
            Err(e) => {
                if let Some(active) = self.control_pending.remove(&job) {
                    self.control_answer(
                        active,
                        Status::Internal,
                        &format!("cannot start loading: {e}"),
                        &[],
                    );
                }
                self.start_next_load();
            }
        }
    }

    fn finish_load(&mut self, job: u64, result: Result<LoadedModel, EngineError>) {
        if self.loading == Some(job) {
            self.loading = None;
            if !self.shutting_down {
                self.start_next_load();
            }
        }
        let result = result.and_then(Registry::with_valid_id);
        let Some(active) = self.control_pending.remove(&job) else {
            // Nobody to answer; the log still says why (an answer's refusal is logged as it
            // is sent).
            if let Err(e) = &result {
                tracing::warn!(error = %e.message, "model not loaded; its client has gone");
            }
            return;
        };
        match result {
            Ok(model) => {
                let info = model.info;
                // Named: a model file asked for by name may come from the mesh beside it.
                let source = model.source.display().to_string();
                let replaced = self.registry.insert(model).is_some();
                let msg = format!(
                    "{} object {} ({}), {} bytes, from {source}",
                    if replaced { "replaced" } else { "loaded" },
                    info.object_id,
                    info.name(),
                    info.byte_size
                );
                tracing::info!("{msg}");
                self.control_answer(active, Status::Ok, &msg, &[info]);
            }
            Err(e) => {
                let status = if e.status == Status::Internal {
                    Status::Internal
                } else {
                    Status::ModelError
                };
                self.control_answer(active, status, &e.message, &[]);
            }
        }
    }
}

/// Hands the memory a build freed back to the system. A build's temporaries are many times
/// its model's size, and glibc keeps freed pages in its arenas: in a daemon that runs for
/// weeks they would stay resident, and the next build, unable to reuse them all, would take
/// its peak on top of them. In `tests/tests/limits.rs`, four loads in a row peak at 122–123 MB
/// above idle with this and 123–133 MB without it on a quiet host, and up to 185 MB without it
/// on a busy one.
fn release_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only returns free memory of the allocator's own arenas to the system.
    unsafe {
        libc::malloc_trim(0);
    }
}
