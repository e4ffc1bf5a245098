//! Shared helpers for the end-to-end tests: a transport-only engine, the generated scene and part
//! models of the pose tests, process handling, and isolation of each test under its own iceoryx2
//! prefix.

pub mod fuzz;

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdout, Command, Stdio};
use std::sync::Arc;
use std::time::{Duration, Instant};

use ppfd::engine::{
    DetectionEngine, EngineError, EngineOptions, EngineOutput, FrameView, LoadedModel,
};
use ppfd_models::model::ObjectModel;
use ppfd_models::synthetic::parts::Part;
use ppfd_models::synthetic::scene::{NoiseModel, SyntheticScene};
use ppfd_protocol::control::ModelInfo;
use ppfd_protocol::detect::{checks, DetectCounts, LatencyBreakdown, PoseHypothesis, Status};
use ppfd_protocol::text;

/// An engine for transport tests: models are `*.fake` text files (`<object id> <name>`), and a
/// detection answers, per object, hypotheses at the frame's median depth straight ahead, after
/// sleeping `delay` (cut short when the detection is cancelled). It exercises everything but the matching.
#[derive(Debug, Default)]
pub struct FakeEngine {
    /// Time one detection takes.
    pub delay: Duration,
    /// Refuse a frame whose depth values are not in a shared-memory mapping, i.e. that was
    /// copied on its way to the engine.
    pub require_shared_memory: bool,
    /// Time loading one model takes (as building a model from a large mesh does).
    pub load_delay: Duration,
    /// Time checking a model file's path takes (as a `stat` on a hung network mount does).
    pub check_delay: Duration,
}

impl FakeEngine {
    /// The delay from `PPFD_FAKE_DELAY_MS` (default 0); the shared-memory check when
    /// `PPFD_FAKE_CHECK_SHM=1`; the load delay from `PPFD_FAKE_LOAD_DELAY_MS` and the path
    /// check's from `PPFD_FAKE_PATH_CHECK_DELAY_MS` (default 0).
    pub fn from_env() -> FakeEngine {
        let ms = |name: &str| {
            Duration::from_millis(
                std::env::var(name)
                    .ok()
                    .and_then(|v| v.parse().ok())
                    .unwrap_or(0),
            )
        };
        let require_shared_memory = std::env::var("PPFD_FAKE_CHECK_SHM").as_deref() == Ok("1");
        FakeEngine {
            delay: ms("PPFD_FAKE_DELAY_MS"),
            require_shared_memory,
            load_delay: ms("PPFD_FAKE_LOAD_DELAY_MS"),
            check_delay: ms("PPFD_FAKE_PATH_CHECK_DELAY_MS"),
        }
    }
}

/// The file mapped at `addr` in this process (from `/proc/self/maps`); empty for anonymous
/// memory (heap, stack), `None` if nothing is mapped there.
pub fn mapping_of(addr: usize) -> Option<String> {
    let maps = std::fs::read_to_string("/proc/self/maps").ok()?;
    for line in maps.lines() {
        let mut fields = line.split_whitespace();
        let (start, end) = fields.next()?.split_once('-')?;
        let start = usize::from_str_radix(start, 16).ok()?;
        let end = usize::from_str_radix(end, 16).ok()?;
        if (start..end).contains(&addr) {
            return Some(fields.nth(4).unwrap_or("").to_owned());
        }
    }
    None
}

impl DetectionEngine for FakeEngine {
    fn name(&self) -> &'static str {
        "fake"
    }

    fn accepts(&self, path: &Path) -> bool {
        path.extension().is_some_and(|e| e == "fake")
    }

    fn check_load_path(&self, path: &Path) -> Result<(), EngineError> {
        std::thread::sleep(self.check_delay);
        ppfd::engine::check_load_file(path)
    }

    fn load(
        &self,
        path: &Path,
        object_id: Option<u32>,
        _cache: Option<&Path>,
    ) -> Result<LoadedModel, EngineError> {
        std::thread::sleep(self.load_delay);
        let text = std::fs::read_to_string(path).map_err(|e| {
            EngineError::new(Status::ModelError, format!("{}: {e}", path.display()))
        })?;
        let mut words = text.split_whitespace();
        let id: u32 = words.next().and_then(|w| w.parse().ok()).ok_or_else(|| {
            EngineError::new(
                Status::ModelError,
                format!("{}: expected '<object id> <name>'", path.display()),
            )
        })?;
        let name = words.next().unwrap_or("fake");
        Ok(LoadedModel {
            info: ModelInfo {
                object_id: object_id.unwrap_or(id),
                point_count: 100,
                table_entries: 1000,
                byte_size: 4096,
                diameter_mm: 100.0,
                name: text::encode_truncated(name),
                ..Default::default()
            },
            source: path.to_path_buf(),
            data: Box::new(()),
        })
    }

    fn detect(
        &self,
        frame: &FrameView<'_>,
        models: &[Arc<LoadedModel>],
        options: &EngineOptions,
    ) -> Result<EngineOutput, EngineError> {
        let started = Instant::now();
        if self.require_shared_memory {
            let first = frame.depth.as_ptr() as usize;
            let last = first + std::mem::size_of_val(frame.depth).saturating_sub(1);
            let (a, b) = (mapping_of(first), mapping_of(last));
            let in_shm =
                |m: &Option<String>| m.as_deref().is_some_and(|m| m.starts_with("/dev/shm/"));
            if !in_shm(&a) || a != b {
                return Err(EngineError::new(
                    Status::Internal,
                    format!("depth at {first:#x} is not one shared-memory mapping: {a:?} .. {b:?}"),
                ));
            }
        }
        let mut valid: Vec<u16> = frame
            .depth
            .iter()
            .copied()
            .filter(|&d| d != 0)
            .step_by(64)
            .collect();
        let z = if valid.is_empty() {
            0.0
        } else {
            let mid = valid.len() / 2;
            *valid.select_nth_unstable(mid).1 as f32 * frame.depth_scale_mm
        };
        if !self.delay.is_zero() {
            // In short naps, as the detector looks between its stages: a cancelled detection
            // ends within one.
            let until = started + self.delay;
            while Instant::now() < until {
                if options.cancel.load(std::sync::atomic::Ordering::Relaxed) {
                    return Err(EngineError::new(
                        Status::Internal,
                        "cancelled: the client is gone",
                    ));
                }
                std::thread::sleep(Duration::from_millis(10).min(until - Instant::now()));
            }
        }
        let mut hypotheses = Vec::new();
        for m in models {
            for rank in 0..options.hypotheses_per_object {
                hypotheses.push(PoseHypothesis {
                    object_id: m.info.object_id,
                    instance_rank: rank as u32,
                    rotation: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
                    translation_mm: [0.0, 0.0, z],
                    score: 1.0 / (rank as f32 + 1.0),
                    votes: 10,
                    checks: checks::RESCORED,
                });
            }
        }
        Ok(EngineOutput {
            hypotheses,
            stages: LatencyBreakdown {
                voting_ns: started.elapsed().as_nanos() as u64,
                ..Default::default()
            },
            counts: DetectCounts {
                scene_points: valid.len() as u32,
                ..Default::default()
            },
            diagnosis: if options.diagnose.is_empty() {
                Vec::new()
            } else {
                vec!["the transport-only engine has no stages to diagnose".into()]
            },
        })
    }
}

/// A unique iceoryx2 prefix for one test (removes its shared-memory files when dropped).
pub struct Prefix(pub String);

impl Prefix {
    /// A fresh prefix named after the test.
    pub fn new(test: &str) -> Prefix {
        let nanos = ppfd_protocol::clock::monotonic_now_ns() % 1_000_000_000;
        Prefix(format!("ppfdt_{test}_{}_{nanos}_", std::process::id()))
    }
}

impl Drop for Prefix {
    fn drop(&mut self) {
        let _ = ppfd_client::remove_prefix_leftovers(&self.0);
    }
}

/// A child process killed when dropped.
pub struct Proc {
    /// The process.
    pub child: Child,
    /// Its stdout, after any line already read.
    pub stdout: Option<BufReader<ChildStdout>>,
}

impl Proc {
    /// Starts `program` with `args`, stdout piped, stderr inherited.
    pub fn spawn(program: &Path, args: &[&str], envs: &[(&str, &str)]) -> Proc {
        let mut cmd = Command::new(program);
        cmd.args(args)
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit());
        for (k, v) in envs {
            cmd.env(k, v);
        }
        let mut child = cmd
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {}: {e}", program.display()));
        let stdout = child.stdout.take().map(BufReader::new);
        Proc { child, stdout }
    }

    /// Reads stdout lines until one starts with `prefix` (returned), or panics after `timeout`.
    pub fn wait_line(&mut self, prefix: &str, timeout: Duration) -> String {
        let (tx, rx) = std::sync::mpsc::channel();
        let mut reader = self.stdout.take().expect("stdout available");
        let want = prefix.to_owned();
        let handle = std::thread::spawn(move || {
            let mut line = String::new();
            loop {
                line.clear();
                match reader.read_line(&mut line) {
                    Ok(0) | Err(_) => {
                        let _ = tx.send(None);
                        return reader;
                    }
                    Ok(_) if line.starts_with(&want) => {
                        let _ = tx.send(Some(line.trim_end().to_owned()));
                        return reader;
                    }
                    Ok(_) => {}
                }
            }
        });
        match rx.recv_timeout(timeout) {
            Ok(Some(line)) => {
                self.stdout = Some(handle.join().expect("reader thread"));
                line
            }
            Ok(None) => panic!(
                "process ended before printing {prefix:?}: {:?}",
                self.child.try_wait()
            ),
            Err(_) => panic!("no {prefix:?} line within {timeout:?}"),
        }
    }

    /// Sends a signal.
    pub fn signal(&self, signal: i32) {
        // SAFETY: kill with the pid of our own child.
        unsafe { libc::kill(self.child.id() as i32, signal) };
    }

    /// Waits for exit up to `timeout`; returns the exit status, `None` if still running.
    pub fn wait_exit(&mut self, timeout: Duration) -> Option<std::process::ExitStatus> {
        let end = Instant::now() + timeout;
        loop {
            if let Ok(Some(status)) = self.child.try_wait() {
                return Some(status);
            }
            if Instant::now() > end {
                return None;
            }
            std::thread::sleep(Duration::from_millis(10));
        }
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A scratch directory in the system's temporary directory, named after the test and this
/// process, emptied when made and removed when dropped.
pub struct WorkDir(PathBuf);

impl WorkDir {
    /// A fresh, existing directory for `test`, its own also when tests running side by side
    /// (in one process) share a helper that names it.
    pub fn new(test: &str) -> WorkDir {
        static MADE: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
        let n = MADE.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let dir = std::env::temp_dir().join(format!("ppfd-e2e-{test}-{}-{n}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        WorkDir(dir)
    }
}

impl std::ops::Deref for WorkDir {
    type Target = Path;

    fn deref(&self) -> &Path {
        &self.0
    }
}

impl Drop for WorkDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Writes `*.fake` model files for `ids` into a fresh directory.
pub fn fake_model_dir(test: &str, ids: &[u32]) -> WorkDir {
    let dir = WorkDir::new(test);
    for id in ids {
        std::fs::write(
            dir.join(format!("obj_{id:06}.fake")),
            format!("{id} part{id}\n"),
        )
        .unwrap();
    }
    dir
}

/// The generated scene of the pose tests, the recipe `ppf demo` shows: every generated part
/// ([`Part::ALL`], object ids 1..=4) resting on a table, seen from a viewpoint drawn from `seed`,
/// with Kinect-like noise when `noisy`. Deterministic: the camera process and the test that
/// holds the truth build the same frame from the same seed.
pub fn parts_scene(seed: u64, noisy: bool) -> SyntheticScene {
    SyntheticScene::of_every_part(seed, noisy.then(NoiseModel::kinect))
        .expect("the generated parts make a valid scene")
}

/// The model of a generated part, built with the default parameters.
pub fn part_model(part: Part) -> ObjectModel {
    part.model().unwrap()
}

/// Builds the model of every generated part ([`part_model`]) and saves it in `dir` as
/// `<name>_<id>.ppfm`, the file the daemon maps; returns the models' diameters (mm) in
/// [`Part::ALL`] order.
pub fn write_part_models(dir: &Path) -> Vec<f32> {
    std::fs::create_dir_all(dir).unwrap();
    Part::ALL
        .iter()
        .map(|&part| {
            let model = part_model(part);
            let path = dir.join(format!("{}_{:06}.ppfm", part.name(), part.object_id()));
            ppfd_models::model::store::save(&model, &path).unwrap();
            model.diameter_mm()
        })
        .collect()
}

/// FNV-1a hash of depth values, to check that two processes hold the same frame.
pub fn depth_checksum(depth: &[u16]) -> u64 {
    depth.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &d| {
        let h = (h ^ (d & 0xff) as u64).wrapping_mul(0x0100_0000_01b3);
        (h ^ (d >> 8) as u64).wrapping_mul(0x0100_0000_01b3)
    })
}
