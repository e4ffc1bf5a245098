//! Daemon settings: defaults, then a TOML file (`--config`), then command-line flags, each
//! overriding the one before. Every key of the file has a flag of the same name.
//!
//! ```toml
//! models = "/var/lib/ppfd/models"   # *.ppfm files, and PLY meshes to build models from
//! model_cache = "/var/cache/ppfd"   # where models built from PLY files are saved
//! prefix = "ppfd_"                  # iceoryx2 resource prefix (isolates daemons)
//! workers = 0                       # detection threads; 0 = one per core
//! parallel_detections = 1           # detections running at once
//! queue_capacity = 64               # requests waiting beyond that are refused "busy"
//! max_frame_age_ms = 1000           # older camera frames are refused "camera stale"
//! housekeeping_ms = 1000            # period of camera discovery and dead-peer cleanup
//! ```

use std::path::{Path, PathBuf};

use serde::Deserialize;

/// The daemon's settings.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DaemonConfig {
    /// Directory of models to load at start (`*.ppfm`, and PLY meshes: a mesh's model is built
    /// once and reused while the mesh is unchanged).
    pub models: Option<PathBuf>,
    /// Where models built from PLY files are saved (default: beside the PLY file when
    /// writable). A built model is loaded from here on the next start if the mesh has not
    /// changed since.
    pub model_cache: Option<PathBuf>,
    /// iceoryx2 resource prefix; daemons with different prefixes never see each other.
    pub prefix: Option<String>,
    /// Detection worker threads; 0 means one per core. Detections parallelise internally, so
    /// on a small machine all cores serve one detection at a time.
    pub workers: usize,
    /// Detections running at once. 1 gives the lowest latency per request (each detection gets
    /// every worker); more trades latency for throughput with many clients.
    pub parallel_detections: usize,
    /// Requests waiting for a worker, beyond which new ones are refused `busy`: a bound on
    /// memory and on how stale an answer can get.
    pub queue_capacity: usize,
    /// A camera frame older than this at the start of a detection is refused `camera stale`
    /// (a request may ask for another limit).
    pub max_frame_age_ms: u64,
    /// Period of housekeeping: discovering cameras and removing resources of dead processes.
    pub housekeeping_ms: u64,
}

impl Default for DaemonConfig {
    fn default() -> Self {
        DaemonConfig {
            models: None,
            model_cache: None,
            prefix: None,
            workers: 0,
            parallel_detections: 1,
            queue_capacity: 64,
            max_frame_age_ms: 1000,
            housekeeping_ms: 1000,
        }
    }
}

impl DaemonConfig {
    /// Reads a TOML file; unknown keys are refused so that a typo does not pass silently.
    pub fn from_toml_file(path: &Path) -> Result<DaemonConfig, String> {
        let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
        Self::from_toml(&text).map_err(|e| format!("{}: {e}", path.display()))
    }

    /// Parses TOML text.
    pub fn from_toml(text: &str) -> Result<DaemonConfig, String> {
        toml::from_str(text).map_err(|e| e.to_string())
    }

    /// Refuses settings that cannot work.
    pub fn validate(&self) -> Result<(), String> {
        if self.parallel_detections == 0 {
            return Err("parallel_detections must be at least 1".into());
        }
        if self.queue_capacity == 0 {
            return Err("queue_capacity must be at least 1".into());
        }
        if self.housekeeping_ms == 0 {
            return Err("housekeeping_ms must be at least 1".into());
        }
        if let Some(p) = &self.prefix {
            if p.is_empty()
                || !p
                    .bytes()
                    .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-')
            {
                return Err(format!(
                    "prefix {p:?} may hold only ASCII letters, digits, '_' and '-'"
                ));
            }
        }
        Ok(())
    }

    /// Worker threads to start.
    pub fn worker_threads(&self) -> usize {
        if self.workers > 0 {
            self.workers
        } else {
            std::thread::available_parallelism()
                .map(|n| n.get())
                .unwrap_or(1)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn toml_overrides_defaults_and_refuses_unknown_keys() {
        let c = DaemonConfig::from_toml("models = \"/m\"\nparallel_detections = 2\n").unwrap();
        assert_eq!(c.models.as_deref(), Some(Path::new("/m")));
        assert_eq!(c.parallel_detections, 2);
        assert_eq!(c.queue_capacity, DaemonConfig::default().queue_capacity);
        let e = DaemonConfig::from_toml("modles = \"/m\"").unwrap_err();
        assert!(e.contains("modles"), "{e}");
    }

    #[test]
    fn unusable_settings_are_refused() {
        let c = DaemonConfig {
            parallel_detections: 0,
            ..Default::default()
        };
        assert!(c.validate().is_err());
        let c = DaemonConfig {
            prefix: Some("a/b".into()),
            ..Default::default()
        };
        assert!(c.validate().is_err());
        assert!(DaemonConfig::default().validate().is_ok());
    }
}
