//! A model loaded or built at run time (`LoadModel`): the path checked on the I/O thread, the
//! loading on a thread of its own (building from a large mesh takes seconds), the model put in
//! the registry when it reports.

use std::path::PathBuf;

use ppfd_protocol::control::ControlRequest;
use ppfd_protocol::detect::Status;

use crate::engine::{EngineError, LoadedModel};
use crate::registry::Registry;
use crate::responder::ControlActive;
use crate::termination::block_termination_signals;

use super::Daemon;

/// A loading thread's report.
pub(super) struct ModelLoaded {
    job: u64,
    result: Result<LoadedModel, EngineError>,
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
        if path.exists() && !path.is_dir() && !path.is_file() {
            // A FIFO or a device: reading it could block the loading thread forever.
            let m = format!(
                "{} is not a regular file: give one model file (.ppfm) or mesh (.ply)",
                path.display()
            );
            return self.control_answer(active, Status::ModelError, &m, &[]);
        }
        if path.is_dir() {
            let m = format!(
                "{} is a folder: give one model file (.ppfm) or mesh (.ply); a folder \
                 of models is loaded at start (ppfd --models)",
                path.display()
            );
            return self.control_answer(active, Status::ModelError, &m, &[]);
        }
        let object_id = (request.object_id != 0).then_some(request.object_id);
        let job = self.next_job;
        self.next_job += 1;
        self.control_pending.insert(job, active);
        let engine = self.engine.clone();
        let cache = Some(self.config.model_cache_dir());
        let tx = self.loaded_tx.clone();
        let signaller = self.signaller;
        // Building a model from a mesh may take seconds: off the I/O thread and off the
        // detection workers.
        let spawned = std::thread::Builder::new()
            .name("ppfd-load".into())
            .spawn(move || {
                block_termination_signals();
                let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                    engine.load(&path, object_id, cache.as_deref())
                }))
                .unwrap_or_else(|_| {
                    Err(EngineError::new(
                        Status::Internal,
                        "loading failed unexpectedly (panic)",
                    ))
                });
                let _ = tx.send(ModelLoaded { job, result });
                signaller.signal();
            });
        if let Err(e) = spawned {
            if let Some(active) = self.control_pending.remove(&job) {
                self.control_answer(
                    active,
                    Status::Internal,
                    &format!("cannot start loading: {e}"),
                    &[],
                );
            }
        }
    }

    pub(super) fn finish_load(&mut self, m: ModelLoaded) {
        let Some(active) = self.control_pending.remove(&m.job) else {
            return;
        };
        match m.result.and_then(Registry::with_valid_id) {
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
