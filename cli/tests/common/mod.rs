//! What the command-line tests share: scratch folders, and showing what a command printed. The real data is found with
//! `ppfd_bop::shared_test_data`.

use std::path::PathBuf;

/// A fresh scratch directory, `<temp>/ppf-<name>-<pid>`, removed when dropped.
#[allow(dead_code)] // not every test file writes files
pub struct Scratch(pub PathBuf);

#[allow(dead_code)]
impl Scratch {
    pub fn new(name: &str) -> Scratch {
        let dir = std::env::temp_dir().join(format!("ppf-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        Scratch(dir)
    }

    pub fn join(&self, name: &str) -> PathBuf {
        self.0.join(name)
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Prints what `command` gave, for a failing test to show.
#[allow(dead_code)]
pub fn show(command: &std::process::Command, out: &std::process::Output) {
    eprintln!(
        "{command:?}: {:?}\nstdout:\n{}\nstderr:\n{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// How long [`ServedPart::publish_every_until_done`] lets a command run: detections of one
/// part take well under a second each, so a minute is a hang.
pub const COMMAND_LIMIT: std::time::Duration = std::time::Duration::from_secs(60);

/// A daemon (`ppf serve`) over one generated part's mesh, and a camera `cam` that publishes a
/// generated scene of that part, under a prefix of their own; the daemon is stopped when
/// dropped.
#[allow(dead_code)] // not every test file serves a camera
pub struct ServedPart {
    pub part: ppfd_models::synthetic::parts::Part,
    pub mesh: ppfd_models::geometry::mesh::Mesh,
    pub scene: ppfd_models::synthetic::scene::SyntheticScene,
    pub prefix: String,
    pub models: PathBuf,
    daemon: std::process::Child,
    /// Taken in `drop` before the prefix's leftovers are removed.
    camera: Option<ppfd_client::CameraPublisher>,
}

#[allow(dead_code)]
impl ServedPart {
    /// Serves `part` in a scene of `seed`, with files under `scratch`.
    pub fn start(
        scratch: &Scratch,
        name: &str,
        part: ppfd_models::synthetic::parts::Part,
        seed: u64,
    ) -> ServedPart {
        use ppfd_models::synthetic::scene::{NoiseModel, SceneSpec};
        use std::io::BufRead;
        let models = scratch.join("models");
        std::fs::create_dir_all(&models).unwrap();
        let mesh = part.mesh();
        std::fs::write(
            models.join(format!("obj_{:06}.ply", part.object_id())),
            mesh.to_ply_ascii(),
        )
        .unwrap();
        let scene = SceneSpec::new(seed)
            .object(part.object_id(), &mesh)
            .noise(Some(NoiseModel::kinect()))
            .build()
            .unwrap();
        let prefix = format!("ppf_{name}_{}_", std::process::id());
        let mut daemon = std::process::Command::new(env!("CARGO_BIN_EXE_ppf"))
            .args(["serve", "--prefix", &prefix, "--models"])
            .arg(&models)
            .arg("--model-cache")
            .arg(scratch.join("cache"))
            .stdout(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        let ready = std::io::BufReader::new(daemon.stdout.take().unwrap())
            .lines()
            .map_while(Result::ok)
            .any(|l| l.starts_with("ppfd ready"));
        assert!(ready, "the daemon never came up");
        let f = &scene.frame;
        let k = f.intrinsics;
        let camera = ppfd_client::CameraPublisher::new(
            Some(&prefix),
            "cam",
            1,
            f.width,
            f.height,
            ppfd_client::Intrinsics {
                fx: k.fx,
                fy: k.fy,
                cx: k.cx,
                cy: k.cy,
            },
            f.depth_scale_mm,
        )
        .unwrap();
        ServedPart {
            part,
            mesh,
            scene,
            prefix,
            models,
            daemon,
            camera: Some(camera),
        }
    }

    /// Publishes the scene's frame every 100 ms until `command` (started with its output
    /// piped) ends; its output.
    pub fn publish_until_done(&mut self, command: std::process::Child) -> std::process::Output {
        self.publish_every_until_done(std::time::Duration::from_millis(100), command)
    }

    /// Publishes the scene's frame every `period` until `command` ends; its output. A command
    /// still running after [`COMMAND_LIMIT`] is killed and the test fails: one that hangs
    /// fails here rather than holding the test run.
    pub fn publish_every_until_done(
        &mut self,
        period: std::time::Duration,
        mut command: std::process::Child,
    ) -> std::process::Output {
        let deadline = std::time::Instant::now() + COMMAND_LIMIT;
        loop {
            if std::time::Instant::now() > deadline {
                let _ = command.kill();
                let out = command.wait_with_output().unwrap();
                panic!(
                    "the command did not end within {COMMAND_LIMIT:?}; it printed\n{}\n{}",
                    String::from_utf8_lossy(&out.stdout),
                    String::from_utf8_lossy(&out.stderr)
                );
            }
            let camera = self.camera.as_mut().expect("the camera lives until drop");
            camera
                .loan()
                .and_then(|l| l.write_from_slice(&self.scene.frame.depth))
                .and_then(|r| r.send(ppfd_client::monotonic_now_ns()))
                .unwrap();
            if command.try_wait().unwrap().is_some() {
                break;
            }
            camera.idle(period).unwrap();
        }
        command.wait_with_output().unwrap()
    }
}

impl Drop for ServedPart {
    fn drop(&mut self) {
        // SAFETY: signals our own child, the daemon.
        unsafe { libc::kill(self.daemon.id() as i32, libc::SIGTERM) };
        let _ = self.daemon.wait();
        // Once every process of the prefix is gone, what iceoryx2 leaves of it goes too.
        drop(self.camera.take());
        let _ = ppfd_client::remove_prefix_leftovers(&self.prefix);
    }
}
