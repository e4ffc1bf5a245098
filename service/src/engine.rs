//! The seam between the daemon and the matching engine: the daemon moves frames and requests,
//! an [`DetectionEngine`] loads models and finds objects. [`crate::ppf_engine::PpfEngine`] wraps
//! `ppfd_models`; tests plug in engines of their own to exercise the transport alone.

use std::any::Any;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Instant;

use ppfd_protocol::control::ModelInfo;
use ppfd_protocol::detect::{
    DetectCounts, LatencyBreakdown, PoseHint, PoseHypothesis, Requirements, Status,
};
use ppfd_protocol::frame::Intrinsics;

/// A depth frame as the engine sees it: borrowed straight from shared memory.
#[derive(Debug, Clone, Copy)]
pub struct FrameView<'a> {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Intrinsics, pixels.
    pub intrinsics: Intrinsics,
    /// Millimetres per raw depth unit.
    pub depth_scale_mm: f32,
    /// `width × height` raw depth values, row-major.
    pub depth: &'a [u16],
}

/// A model the daemon holds: what it tells clients about it, and the engine's own data.
pub struct LoadedModel {
    /// What `ListModels` reports.
    pub info: ModelInfo,
    /// The file it came from.
    pub source: PathBuf,
    /// The engine's model (for the PPF engine an `ObjectModel`, usually read from a model file).
    pub data: Box<dyn Any + Send + Sync>,
}

impl std::fmt::Debug for LoadedModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LoadedModel")
            .field("object_id", &self.info.object_id)
            .field("name", &self.info.name())
            .field("source", &self.source)
            .finish()
    }
}

/// What one detection asks for besides the frame and the models.
#[derive(Debug, Clone)]
pub struct EngineOptions {
    /// Best hypotheses wanted per object.
    pub hypotheses_per_object: usize,
    /// What the hypotheses must satisfy, and their order, as the request gave them (checked
    /// against their ranges; a region against the frame is the engine's to check).
    pub requirements: Requirements,
    /// Stop early, with [`Status::DeadlineExceeded`], when this passes.
    pub deadline: Option<Instant>,
    /// Set by the daemon when the request's client is gone: stop early (the answer would go
    /// nowhere) and free the worker for the requests behind it.
    pub cancel: Arc<AtomicBool>,
    /// The request's hints, checked against the contract (each a pose of a requested object).
    pub hints: Vec<PoseHint>,
    /// Poses to diagnose against ([`ppfd_protocol::detect::flags::DIAGNOSE`]), checked as hints
    /// are; the detection then runs from scratch, without hints.
    pub diagnose: Vec<PoseHint>,
}

/// What one detection found, in wire types.
#[derive(Debug, Clone, Default)]
pub struct EngineOutput {
    /// Hypotheses grouped by object in the order of the models given, best first.
    pub hypotheses: Vec<PoseHypothesis>,
    /// The per-stage fields (`scene_preparation_ns` … `filters_ns`); the daemon fills the rest.
    pub stages: LatencyBreakdown,
    /// Sizes of the work (`returned` is filled by the daemon).
    pub counts: DetectCounts,
    /// When [`EngineOptions::diagnose`] is not empty: per object with a pose, a heading line
    /// and one line per stage (an engine that cannot diagnose says so in one line).
    pub diagnosis: Vec<String>,
}

/// A refusal or failure of the engine, with the status the client gets.
#[derive(Debug, Clone, thiserror::Error)]
#[error("{message}")]
pub struct EngineError {
    /// Status answered to the client.
    pub status: Status,
    /// What went wrong and what was expected.
    pub message: String,
    /// The status's `error_value` (e.g. an object id).
    pub value: u64,
}

impl EngineError {
    /// An error with a status and a message.
    pub fn new(status: Status, message: impl Into<String>) -> Self {
        EngineError {
            status,
            message: message.into(),
            value: 0,
        }
    }
}

/// A matching engine the daemon can serve.
pub trait DetectionEngine: Send + Sync + 'static {
    /// Short name for logs.
    fn name(&self) -> &'static str;

    /// Whether `load` takes this file (by its extension).
    fn accepts(&self, path: &Path) -> bool;

    /// Loads a model file, or builds a model from a mesh file; `object_id` overrides the id the
    /// file implies. `cache_dir` is where a built model may be saved for the next start.
    fn load(
        &self,
        path: &Path,
        object_id: Option<u32>,
        cache_dir: Option<&Path>,
    ) -> Result<LoadedModel, EngineError>;

    /// Checks that `path` (absolute) names a file `load` may open: it exists and is a regular
    /// file, not a folder, a FIFO or a device, whose reading could block the loading thread for
    /// ever. Run on a thread of its own for each `LoadModel`, since on a hung network mount
    /// even a `stat` waits without end.
    fn check_load_path(&self, path: &Path) -> Result<(), EngineError> {
        check_load_file(path)
    }

    /// Files of a model directory to load, in order: by default every accepted file.
    fn select(&self, files: Vec<PathBuf>) -> Vec<PathBuf> {
        files.into_iter().filter(|p| self.accepts(p)).collect()
    }

    /// Finds the objects of `models` in `frame`.
    fn detect(
        &self,
        frame: &FrameView<'_>,
        models: &[Arc<LoadedModel>],
        options: &EngineOptions,
    ) -> Result<EngineOutput, EngineError>;
}

/// What [`DetectionEngine::check_load_path`] checks by default: the file exists and is a
/// regular file.
pub fn check_load_file(path: &Path) -> Result<(), EngineError> {
    let refused = |m: String| Err(EngineError::new(Status::ModelError, m));
    match path.try_exists() {
        Ok(true) => {}
        Ok(false) => return refused(format!("{}: no such file", path.display())),
        // Permission denied on a folder above it, say: the daemon runs as its own user.
        Err(e) => return refused(format!("{}: {e}", path.display())),
    }
    if path.is_dir() {
        return refused(format!(
            "{} is a folder: give one model file (.ppfm) or mesh (.ply); a folder of \
             models is loaded at start (ppfd --models)",
            path.display()
        ));
    }
    if !path.is_file() {
        return refused(format!(
            "{} is not a regular file: give one model file (.ppfm) or mesh (.ply)",
            path.display()
        ));
    }
    Ok(())
}
