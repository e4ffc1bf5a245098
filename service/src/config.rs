//! Daemon settings: defaults, then a TOML file (`--config`), then `PPFD_PREFIX` (for the prefix),
//! then command-line flags, each overriding the one before. Every top-level key of the file has a
//! flag of the same name; the `[detector]` table's entries are `--set` flags.
//!
//! ```toml
//! models = "/var/lib/ppfd/models"   # *.ppfm files, and PLY meshes to build models from
//!                                   # (a relative path is relative to this file's folder)
//! model_cache = "/var/cache/ppfd"   # where models built from PLY files are saved
//!                                   # (default $PPFD_CACHE, $XDG_CACHE_HOME/ppfd or ~/.cache/ppfd)
//! prefix = "ppfd_"                  # iceoryx2 resource prefix (isolates daemons)
//! workers = 0                       # detection threads; 0 = one per core
//! parallel_detections = 1           # detections running at once
//! queue_capacity = 64               # requests waiting beyond that are refused "busy" (1 to 4096)
//! max_frame_age_ms = 1000           # older camera frames are refused "camera stale"
//! housekeeping_ms = 1000            # period of camera discovery and dead-peer cleanup
//! forget_camera_after_ms = 60000    # a camera without a driver this long is forgotten
//! max_frame_pixels = 16777216       # larger frames are refused "invalid frame"
//!
//! [detector]                        # detector parameters by name (`ppf detect --set` names)
//! voting.reference_step = 2         # every 2nd evenly spread candidate votes: about half the voting time
//! filters.min_silhouette_fraction = 0.5
//! ```

use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::error::{Error, Result};

/// The most worker threads, and detections at once, a configuration may ask for; far more than
/// cores any one machine has.
pub const MAX_THREADS: usize = 256;

/// Workers, and detections at once, per core at most: beyond it threads only take turns, and
/// each running detection holds its scratch memory (with 256 of each on two cores, 32 clients
/// saw an overhead p99 of 3.4 s).
pub const MAX_THREADS_PER_CORE: usize = 4;

/// The largest `housekeeping_ms`: a minute. Dead processes and cameras wait this long at most.
pub const MAX_HOUSEKEEPING_MS: u64 = 60_000;

/// The largest `max_frame_age_ms`: an hour. An older frame is no picture of the cell.
pub const MAX_FRAME_AGE_MS: u64 = 3_600_000;

/// The largest `forget_camera_after_ms`: a day.
pub const MAX_FORGET_CAMERA_AFTER_MS: u64 = 86_400_000;

/// The largest `max_frame_pixels`: 16384 × 16384. A detection takes about 95 bytes per pixel,
/// so a frame this large would take about 25 GB.
pub const MAX_FRAME_PIXELS_CEILING: u64 = 16384 * 16384;

/// A configuration file: a few hundred bytes in practice.
pub const CONFIG_FILE: ppfd_models::file::Limit = ppfd_models::file::Limit {
    what: "configuration file",
    max_bytes: 1 << 20,
    raise: "a configuration is a few hundred bytes: is this the right file?",
};

/// The largest request queue the daemon accepts (each queued request keeps its client's
/// request memory borrowed).
pub const MAX_QUEUE_CAPACITY: usize = 4096;

/// The daemon's settings.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DaemonConfig {
    /// Directory of models to load at start (`*.ppfm`, and PLY meshes: a mesh's model is built
    /// once and reused while the mesh is unchanged).
    pub models: Option<PathBuf>,
    /// Where models built from PLY files are saved; by default `$PPFD_CACHE`,
    /// `$XDG_CACHE_HOME/ppfd` or `~/.cache/ppfd` (the cache of `ppf eval` and `ppf detect
    /// --dataset` too), never the meshes' folder. A built model is loaded from here on the next
    /// start if the mesh has not changed since; a model file beside its mesh is used as well.
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
    /// A camera that has had no driver publishing on it for this long is forgotten at the next
    /// housekeeping round: its subscription, its last frame and the shared memory they keep
    /// mapped are let go, and requests naming it are refused "unknown camera" until a driver
    /// publishes under that name again. The time counts from the first housekeeping round
    /// that finds the camera without a driver (a killed driver's publisher counts until the
    /// round that cleans up after it); 0 forgets it at that first round. Without it a cell whose camera names change (a driver
    /// that names its stream per run) would pile up one subscription per name for good.
    pub forget_camera_after_ms: u64,
    /// The largest frame, in pixels, the daemon detects in (a camera's or an inline one); a
    /// larger one is refused "invalid frame" with this limit named. A detection takes about
    /// 95 bytes per pixel, so the default (4096 × 4096) bounds one at about 1.6 GB.
    pub max_frame_pixels: u64,
    /// Detector parameters that differ from the defaults, as `(stage.field, value)`: the file's
    /// `[detector]` table, then `--set stage.field=value` flags. Checked at start; an unknown
    /// name or a bad value stops the daemon before it serves.
    #[serde(deserialize_with = "detector_table")]
    pub detector: Vec<(String, String)>,
}

/// The `[detector]` table, flattened: `voting.reference_step = 4` (a dotted key, or a
/// `[detector.voting]` table) becomes `("voting.reference_step", "4")`. A value is a number or
/// true/false, and a parameter is set once: TOML refuses a key given twice in one form, and this
/// the same parameter given as a quoted key (`"voting.reference_step"`) and in a table, where the
/// last would win unseen.
fn detector_table<'de, D>(deserializer: D) -> Result<Vec<(String, String)>, D::Error>
where
    D: serde::Deserializer<'de>,
{
    fn flatten<E: serde::de::Error>(
        prefix: &str,
        table: &toml::Table,
        out: &mut Vec<(String, String)>,
    ) -> Result<(), E> {
        for (name, value) in table {
            let key = if prefix.is_empty() {
                name.clone()
            } else {
                format!("{prefix}.{name}")
            };
            let text = match value {
                toml::Value::Table(t) => {
                    flatten(&key, t, out)?;
                    continue;
                }
                toml::Value::Integer(i) => i.to_string(),
                toml::Value::Float(f) => f.to_string(),
                toml::Value::Boolean(b) => b.to_string(),
                other => {
                    return Err(E::custom(format!(
                        "detector.{key}: a number or true/false, got {other}"
                    )))
                }
            };
            if out.iter().any(|(k, _)| *k == key) {
                return Err(E::custom(format!(
                    "detector.{key} is set twice (as a quoted \"a.b\" key and in a table): set it \
                     once"
                )));
            }
            out.push((key, text));
        }
        Ok(())
    }
    let table = toml::Table::deserialize(deserializer)?;
    let mut out = Vec::new();
    flatten("", &table, &mut out)?;
    Ok(out)
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
            forget_camera_after_ms: 60_000,
            max_frame_pixels: ppfd_protocol::DEFAULT_MAX_FRAME_PIXELS as u64,
            detector: Vec::new(),
        }
    }
}

impl DaemonConfig {
    /// [`DaemonConfig::model_cache`], or the default cache ([`ppfd_models::model::store::default_cache_dir`]).
    pub fn model_cache_dir(&self) -> PathBuf {
        self.model_cache
            .clone()
            .unwrap_or_else(ppfd_models::model::store::default_cache_dir)
    }

    /// Reads a TOML file; unknown keys are refused so that a typo does not pass silently.
    ///
    /// Relative `models` and `model_cache` paths are taken relative to the file's folder, not to
    /// wherever the daemon happens to be started from: the file and the folders it names move
    /// together.
    pub fn from_toml_file(path: &Path) -> Result<DaemonConfig> {
        let text =
            ppfd_models::file::read_text_bounded(path, &CONFIG_FILE).map_err(Error::ConfigRead)?;
        let mut c =
            toml::from_str::<DaemonConfig>(&text).map_err(|source| Error::ConfigSyntax {
                path: path.to_path_buf(),
                source,
            })?;
        let folder = path.parent().unwrap_or(Path::new(""));
        for dir in [&mut c.models, &mut c.model_cache].into_iter().flatten() {
            if dir.is_relative() {
                *dir = folder.join(&*dir);
            }
        }
        Ok(c)
    }

    /// Parses TOML text.
    pub fn from_toml(text: &str) -> Result<DaemonConfig> {
        Ok(toml::from_str(text)?)
    }

    /// The detector's parameters: the defaults with [`DaemonConfig::detector`] applied in
    /// order.
    pub fn detect_params(&self) -> Result<ppfd_models::detect::detector::DetectParams> {
        let mut p = ppfd_models::detect::detector::DetectParams::new();
        for (key, value) in &self.detector {
            p.set(key, value).map_err(Error::DetectorParameter)?;
        }
        p.check().map_err(Error::DetectorParameter)?;
        Ok(p)
    }

    /// Refuses settings that cannot work.
    pub fn validate(&self) -> Result<()> {
        self.detect_params()?;
        if self.parallel_detections == 0 {
            return Err(Error::NoParallelDetections);
        }
        let cores = available_cores();
        let max = (MAX_THREADS_PER_CORE * cores).min(MAX_THREADS);
        if self.workers > max || self.parallel_detections > max {
            return Err(Error::TooManyThreads {
                workers: self.workers,
                parallel_detections: self.parallel_detections,
                cores,
                max,
            });
        }
        if self.queue_capacity == 0 || self.queue_capacity > MAX_QUEUE_CAPACITY {
            return Err(Error::QueueCapacity(self.queue_capacity));
        }
        if self.housekeeping_ms == 0 {
            return Err(Error::NoHousekeepingPeriod);
        }
        if self.max_frame_age_ms == 0 {
            return Err(Error::NoFrameAge);
        }
        for (key, value, max) in [
            ("housekeeping_ms", self.housekeeping_ms, MAX_HOUSEKEEPING_MS),
            ("max_frame_age_ms", self.max_frame_age_ms, MAX_FRAME_AGE_MS),
            (
                "forget_camera_after_ms",
                self.forget_camera_after_ms,
                MAX_FORGET_CAMERA_AFTER_MS,
            ),
            (
                "max_frame_pixels",
                self.max_frame_pixels,
                MAX_FRAME_PIXELS_CEILING,
            ),
        ] {
            if value > max {
                return Err(Error::TooLarge { key, value, max });
            }
        }
        if self.max_frame_pixels == 0 {
            return Err(Error::NoFramePixels);
        }
        if let Some(p) = &self.prefix {
            ppfd_protocol::services::check_prefix(p).map_err(|e| Error::Prefix(e.to_string()))?;
        }
        Ok(())
    }

    /// The detector parameters the daemon runs with, as the statistics' message: `detector:` and
    /// the parameters set (by the file, then the flags; the last of a repeated name), or
    /// `defaults` when none is, cut to at most `max_bytes` with a pointer to the start-up log,
    /// which lists them all.
    pub fn detector_summary(&self, max_bytes: usize) -> String {
        let mut last: Vec<(&str, &str)> = Vec::new();
        for (key, value) in &self.detector {
            last.retain(|(k, _)| k != key);
            last.push((key, value));
        }
        if last.is_empty() {
            return "detector: defaults".into();
        }
        let mut out = String::from("detector:");
        for (i, (key, value)) in last.iter().enumerate() {
            let item = format!(" {key}={value}");
            let more = format!(" (+{} more in the start-up log)", last.len() - i);
            let room_after = if i + 1 == last.len() {
                0
            } else {
                more.len() + 1
            };
            if out.len() + item.len() + room_after > max_bytes {
                out.push_str(&more);
                return out;
            }
            out.push_str(&item);
        }
        out
    }

    /// Worker threads to start.
    pub fn worker_threads(&self) -> usize {
        if self.workers > 0 {
            self.workers
        } else {
            available_cores()
        }
    }
}

/// The cores this process may run on.
pub fn available_cores() -> usize {
    std::thread::available_parallelism()
        .map(|n| n.get())
        .unwrap_or(1)
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
        let e = DaemonConfig::from_toml("modles = \"/m\"")
            .unwrap_err()
            .to_string();
        assert!(e.contains("modles"), "{e}");
    }

    /// `models` and `model_cache` given relative in a file are relative to the file's folder;
    /// absolute ones stay as they are.
    #[test]
    fn relative_folders_in_a_file_are_relative_to_the_file() {
        let dir = std::env::temp_dir().join(format!("ppfd-config-rel-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("ppfd.toml");
        std::fs::write(
            &file,
            "models = \"models\"\nmodel_cache = \"/var/cache/x\"\n",
        )
        .unwrap();
        let c = DaemonConfig::from_toml_file(&file).unwrap();
        assert_eq!(c.models.as_deref(), Some(dir.join("models").as_path()));
        assert_eq!(c.model_cache.as_deref(), Some(Path::new("/var/cache/x")));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A device or FIFO given as the configuration is refused at once, and a file beyond the
    /// limit is not read whole.
    #[test]
    fn a_configuration_that_is_not_a_small_regular_file_is_refused() {
        for special in ["/dev/null", "/dev/zero"] {
            let e = DaemonConfig::from_toml_file(Path::new(special))
                .unwrap_err()
                .to_string();
            assert!(e.contains("not a regular file"), "{e}");
        }
        let file = std::env::temp_dir().join(format!("ppfd-config-big-{}", std::process::id()));
        std::fs::write(&file, vec![b'#'; CONFIG_FILE.max_bytes as usize + 1]).unwrap();
        let e = DaemonConfig::from_toml_file(&file).unwrap_err().to_string();
        std::fs::remove_file(&file).unwrap();
        assert!(e.contains("largest configuration file"), "{e}");
    }

    #[test]
    fn detector_table_gives_named_parameters() {
        let c = DaemonConfig::from_toml(
            "[detector]\nvoting.reference_step = 4\nplane.exclude_behind = false\n\
             [detector.filters]\nmin_silhouette_fraction = 0.5\n",
        )
        .unwrap();
        let p = c.detect_params().unwrap();
        assert_eq!(p.voting.reference_step, 4);
        assert!(!p.plane.exclude_behind);
        assert_eq!(p.filters.min_silhouette_fraction, 0.5);
        assert!(c.validate().is_ok());
        // Everything else keeps its default.
        let mut expected = ppfd_models::detect::detector::DetectParams::new();
        expected.voting.reference_step = 4;
        expected.plane.exclude_behind = false;
        expected.filters.min_silhouette_fraction = 0.5;
        assert_eq!(format!("{p:?}"), format!("{expected:?}"));
    }

    #[test]
    fn bad_detector_parameters_are_refused_by_name() {
        for (text, said) in [
            (
                "[detector]\nvoting.reference_steps = 4\n",
                "voting.reference_steps",
            ),
            (
                "[detector]\nvoting.reference_step = -4\n",
                "voting.reference_step",
            ),
            (
                "[detector]\nvoting.reference_step = [4]\n",
                "detector.voting.reference_step",
            ),
            (
                "[detector]\nfilters.min_silhouette_fraction = nan\n",
                "finite",
            ),
            (
                "[detector]\nscene.max_depth_mm = \"4000\"\n",
                "detector.scene.max_depth_mm: a number or true/false, got \"4000\"",
            ),
            (
                "[detector.voting]\nreference_step = 2\n[detector]\n\"voting.reference_step\" = 3\n",
                "detector.voting.reference_step is set twice",
            ),
        ] {
            let e = DaemonConfig::from_toml(text)
                .and_then(|c| c.validate())
                .unwrap_err()
                .to_string();
            assert!(e.contains(said), "{text}: {e}");
        }
    }

    #[test]
    fn the_detector_summary_names_the_settings_and_fits_its_message() {
        let with = |pairs: &[(&str, &str)]| DaemonConfig {
            detector: pairs
                .iter()
                .map(|(k, v)| (k.to_string(), v.to_string()))
                .collect(),
            ..Default::default()
        };
        assert_eq!(with(&[]).detector_summary(192), "detector: defaults");
        let c = with(&[
            ("voting.reference_step", "3"),
            ("icp.iterations", "5"),
            ("voting.reference_step", "2"),
        ]);
        assert_eq!(
            c.detector_summary(192),
            "detector: icp.iterations=5 voting.reference_step=2"
        );
        let names: Vec<String> = (0..40).map(|i| format!("stage.field_{i}")).collect();
        let pairs: Vec<(&str, &str)> = names.iter().map(|n| (n.as_str(), "1")).collect();
        let m = with(&pairs).detector_summary(192);
        assert!(m.len() <= 192, "{m}");
        assert!(m.ends_with("more in the start-up log)"), "{m}");
        assert!(
            m.starts_with("detector: stage.field_0=1 stage.field_1=1"),
            "{m}"
        );
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
        let max = (MAX_THREADS_PER_CORE * available_cores()).min(MAX_THREADS);
        for (workers, parallel_detections) in
            [(100_000, 1), (0, 1_000_000), (max + 1, 1), (0, max + 1)]
        {
            let c = DaemonConfig {
                workers,
                parallel_detections,
                ..Default::default()
            };
            let m = c.validate().unwrap_err().to_string();
            assert!(m.contains(&format!("at most {max}")), "{m}");
        }
        let c = DaemonConfig {
            workers: max,
            parallel_detections: max,
            ..Default::default()
        };
        assert!(c.validate().is_ok());
        let c = DaemonConfig {
            max_frame_age_ms: 0,
            ..Default::default()
        };
        assert!(c
            .validate()
            .unwrap_err()
            .to_string()
            .contains("max_frame_age_ms"));
        for (key, c) in [
            (
                "housekeeping_ms",
                DaemonConfig {
                    housekeeping_ms: u64::MAX,
                    ..Default::default()
                },
            ),
            (
                "max_frame_age_ms",
                DaemonConfig {
                    max_frame_age_ms: u64::MAX,
                    ..Default::default()
                },
            ),
            (
                "forget_camera_after_ms",
                DaemonConfig {
                    forget_camera_after_ms: u64::MAX,
                    ..Default::default()
                },
            ),
            (
                "max_frame_pixels",
                DaemonConfig {
                    max_frame_pixels: u64::MAX,
                    ..Default::default()
                },
            ),
        ] {
            let m = c.validate().unwrap_err().to_string();
            assert!(m.contains(key) && m.contains("at most"), "{m}");
        }
        let c = DaemonConfig {
            max_frame_pixels: 0,
            ..Default::default()
        };
        assert!(c.validate().is_err());
        for queue_capacity in [0, MAX_QUEUE_CAPACITY + 1] {
            let c = DaemonConfig {
                queue_capacity,
                ..Default::default()
            };
            assert!(c
                .validate()
                .unwrap_err()
                .to_string()
                .contains("queue_capacity must be 1 to 4096"));
        }
        let c = DaemonConfig {
            detector: vec![("scene.min_depth_mm".into(), "6000".into())],
            ..Default::default()
        };
        assert!(c
            .validate()
            .unwrap_err()
            .to_string()
            .contains("scene.max_depth_mm"));
        assert!(DaemonConfig::default().validate().is_ok());
    }
}
