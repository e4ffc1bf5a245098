//! The loaded models, by object id. Owned by the I/O thread; a running detection holds `Arc`s
//! of its models, so dropping a model never pulls it from under a worker.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use ppfd_protocol::control::ModelInfo;
use ppfd_protocol::detect::Status;

use crate::engine::{DetectionEngine, EngineError, LoadedModel};

/// The refusal of a model file of object id 0.
pub fn object_id_zero(path: &Path) -> EngineError {
    EngineError::new(
        Status::ModelError,
        format!(
            "{}: object id 0; ids start at 1 (rename the file, e.g. obj_000001, or give an id)",
            path.display()
        ),
    )
}

/// Models by object id.
#[derive(Default)]
pub struct Registry {
    models: BTreeMap<u32, Arc<LoadedModel>>,
    /// Files of the models folder that did not load at start, with why: a request for the
    /// object a file's name gives is told, rather than only that the id is unknown.
    failed: BTreeMap<PathBuf, String>,
}

impl Registry {
    /// The files of `dir` that the engine takes, in the order they load.
    pub fn model_files(engine: &dyn DetectionEngine, dir: &Path) -> crate::Result<Vec<PathBuf>> {
        let entries = std::fs::read_dir(dir).map_err(|source| crate::Error::ModelDirectory {
            path: dir.to_path_buf(),
            source,
        })?;
        let mut files = Vec::new();
        for path in entries.filter_map(|e| e.ok().map(|e| e.path())) {
            if path.is_file() {
                files.push(path);
            } else if path.symlink_metadata().is_ok() && path.metadata().is_err() {
                tracing::warn!(path = %path.display(), "a link whose target cannot be read: skipped");
            } else if !path.is_dir() {
                // A FIFO, socket or device: never read, and said so.
                tracing::warn!(path = %path.display(), "not a regular file: skipped");
            }
        }
        files.sort();
        Ok(engine.select(files))
    }

    /// Loads `files` in order (see [`Registry::model_files`]), asking `stop` before each: once
    /// it says yes, the files left are not loaded. Each model goes to `loaded` as it comes; a
    /// file that fails (or gives an object id loaded from an earlier file: the first is kept)
    /// is logged and goes to `failed`.
    pub fn load_files(
        engine: &dyn DetectionEngine,
        files: &[PathBuf],
        cache_dir: Option<&Path>,
        stop: &dyn Fn() -> bool,
        loaded: &mut dyn FnMut(LoadedModel),
        failed: &mut dyn FnMut(PathBuf, EngineError),
    ) {
        let mut loaded_from: BTreeMap<u32, PathBuf> = BTreeMap::new();
        for path in files {
            if stop() {
                tracing::info!(
                    loaded = loaded_from.len(),
                    "model loading stopped: stop requested"
                );
                break;
            }
            match engine
                .load(path, None, cache_dir)
                .and_then(Self::with_valid_id)
            {
                Ok(model) if loaded_from.contains_key(&model.info.object_id) => {
                    let id = model.info.object_id;
                    let e = EngineError::new(
                        Status::ModelError,
                        format!(
                            "object id {id} is already loaded from {}: one model per id (the first loaded is kept)",
                            loaded_from[&id].display()
                        ),
                    );
                    tracing::error!(path = %path.display(), error = %e, "model not loaded");
                    failed(path.clone(), e);
                }
                Ok(model) => {
                    loaded_from.insert(model.info.object_id, path.clone());
                    tracing::info!(
                        object_id = model.info.object_id,
                        name = %model.info.name(),
                        bytes = model.info.byte_size,
                        path = %path.display(),
                        "model loaded"
                    );
                    loaded(model);
                }
                Err(e) => {
                    tracing::error!(path = %path.display(), error = %e, "model not loaded");
                    failed(path.clone(), e);
                }
            }
        }
    }

    /// `model`, or the refusal of its object id 0: ids start at 1 (BOP's do; in a control
    /// request 0 stands for "the id the file gives").
    pub fn with_valid_id(model: LoadedModel) -> Result<LoadedModel, EngineError> {
        if model.info.object_id == 0 {
            return Err(object_id_zero(&model.source));
        }
        Ok(model)
    }

    /// Adds a model, replacing one of the same id.
    pub fn insert(&mut self, model: LoadedModel) -> Option<Arc<LoadedModel>> {
        // A model's source is the file it was read from (a mesh's cached model), not the mesh
        // that failed: failures are let go of by the object id their file's name gives.
        let id = model.info.object_id;
        self.failed
            .retain(|path, _| crate::ppf_engine::object_id_of_file(path) != Some(id));
        self.models.insert(id, Arc::new(model))
    }

    /// Records that the models folder's file `path` did not load, and why.
    pub fn record_failure(&mut self, path: PathBuf, reason: String) {
        self.failed.insert(path, reason);
    }

    /// Drops a model.
    pub fn remove(&mut self, object_id: u32) -> Option<Arc<LoadedModel>> {
        self.models.remove(&object_id)
    }

    /// The models of `ids`, in that order, or the first unknown id.
    pub fn resolve(&self, ids: &[u32]) -> Result<Vec<Arc<LoadedModel>>, EngineError> {
        ids.iter()
            .map(|id| {
                self.models.get(id).cloned().ok_or_else(|| {
                    // The list of ids first: the reason of a failure may be long, and the
                    // message is cut to fit the answer.
                    let mut message =
                        format!("unknown object id {id}: loaded are {}", self.id_list());
                    if let Some((path, reason)) = self
                        .failed
                        .iter()
                        .find(|(path, _)| crate::ppf_engine::object_id_of_file(path) == Some(*id))
                    {
                        message += &format!("; {} did not load: {reason}", path.display());
                    }
                    EngineError {
                        status: Status::UnknownObject,
                        message,
                        value: *id as u64,
                    }
                })
            })
            .collect()
    }

    /// What `ListModels` reports, by object id.
    pub fn infos(&self) -> Vec<ModelInfo> {
        self.models.values().map(|m| m.info).collect()
    }

    /// Number of models.
    pub fn len(&self) -> usize {
        self.models.len()
    }

    /// Whether no model is loaded.
    pub fn is_empty(&self) -> bool {
        self.models.is_empty()
    }

    /// Bytes of all models.
    pub fn bytes(&self) -> u64 {
        self.models.values().map(|m| m.info.byte_size).sum()
    }

    fn id_list(&self) -> String {
        if self.models.is_empty() {
            return "none".into();
        }
        let ids: Vec<String> = self.models.keys().take(16).map(|k| k.to_string()).collect();
        let more = if self.models.len() > 16 { ", ..." } else { "" };
        format!("{}{more}", ids.join(", "))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A FIFO and a dangling link in the models folder are never opened, and the log says each
    /// was skipped, and why.
    #[test]
    fn special_files_in_the_models_folder_are_skipped_with_a_log_line() {
        let dir = std::env::temp_dir().join(format!("ppfd-registry-fifo-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let fifo = dir.join("obj_000001.ply");
        let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
        // SAFETY: a valid NUL-terminated path.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        std::fs::write(dir.join("obj_000002.ply"), "ply").unwrap();
        std::os::unix::fs::symlink(dir.join("gone.ply"), dir.join("obj_000003.ply")).unwrap();
        let engine = crate::ppf_engine::PpfEngine::default();
        let mut files = Vec::new();
        let log = crate::test_log::capture(|| {
            files = Registry::model_files(&engine, &dir).unwrap();
        });
        let _ = std::fs::remove_dir_all(&dir);
        assert_eq!(files, vec![dir.join("obj_000002.ply")]);
        assert!(
            log.contains("not a regular file: skipped") && log.contains("obj_000001.ply"),
            "{log}"
        );
        assert!(
            log.contains("a link whose target cannot be read: skipped")
                && log.contains("obj_000003.ply"),
            "{log}"
        );
    }
}
