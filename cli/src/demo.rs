//! `ppf demo`: the whole path on one machine — starts a `ppfd` daemon as a child process (under
//! a private iceoryx2 prefix), publishes a depth frame as a camera (by default a generated scene
//! of the generated parts; no data files needed), asks for the objects in it,
//! prints each pose against the truth and the latency breakdown, and stops everything.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use clap::Args;
use ppfd::model_cache::{load_or_build, MeshSource, ModelFiles, Origin};
use ppfd_bop::dataset::BopDataset;
use ppfd_client::{
    monotonic_now_ns, CameraPublisher, Client, ClientOptions, DetectOptions, Detections, Intrinsics,
};
use ppfd_models::geometry::camera::OwnedDepthFrame;
use ppfd_models::geometry::mesh::Mesh;
use ppfd_models::model::store;
use ppfd_models::model::symmetry::Symmetry;
use ppfd_models::model::ModelParams;
use ppfd_models::synthetic::parts::Part;
use ppfd_models::synthetic::scene::{NoiseModel, SyntheticScene};
use ppfd_models::Pose;

use crate::common::{print_latency, ScratchDir, MAX_HYPOTHESES};
use crate::stop;

/// The demo's work folder, `<temp>/ppf-demo-<pid>`.
const WORK_DIR: &str = "ppf-demo";

#[derive(Args, Debug)]
pub struct DemoArgs {
    /// Take the scene and the object meshes from a BOP dataset instead of generating them.
    #[arg(long)]
    pub dataset: Option<PathBuf>,
    /// Seed of the generated scene (default 1).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Render the generated scene without sensor noise.
    #[arg(long)]
    pub no_noise: bool,
    /// Scene and image of the dataset given with --dataset (default: the first with depth).
    #[arg(long, num_args = 2, value_names = ["SCENE", "IMAGE"])]
    pub image: Option<Vec<u32>>,
    /// Where models built from the meshes are kept between runs.
    #[arg(long)]
    pub model_cache: Option<PathBuf>,
    /// A `ppfd` executable to start (default: this executable's built-in daemon, `ppf serve`).
    #[arg(long)]
    pub ppfd: Option<PathBuf>,
    /// Poses shown per object, best first, 1 to 16 (each against the nearest true instance).
    #[arg(long, default_value_t = 1,
          value_parser = clap::value_parser!(u32).range(1..=MAX_HYPOTHESES))]
    pub hypotheses: u32,
    /// Write a picture of the frame with each pose's outline, axes and label (id, #rank,
    /// score), and the truth's outline (PNG).
    #[arg(long, value_name = "PNG")]
    pub overlay: Option<PathBuf>,
    #[command(flatten)]
    pub requirements: crate::requirements::RequirementArgs,
}

/// A scene to detect in, with the truth.
struct DemoScene {
    frame: OwnedDepthFrame,
    truth: Vec<(u32, Pose)>,
    /// The objects' symmetries, through which poses are compared with the truth.
    symmetries: Vec<(u32, Symmetry)>,
    /// Files for the daemon's model directory, with the object id each is for: meshes (built
    /// by the daemon) or model files.
    model_files: Vec<(u32, PathBuf)>,
    label: String,
}

/// The generated parts ([`Part::ALL`]) resting on a table, seen from a viewpoint drawn from
/// `seed`, with Kinect-like noise unless `no_noise` ([`SyntheticScene::of_every_part`]); and
/// each part's mesh. `ppf demo` shows it and `ppf generate` writes it.
pub fn parts_scene(
    seed: u64,
    no_noise: bool,
) -> Result<(Vec<(Part, Mesh)>, SyntheticScene), String> {
    let meshes: Vec<(Part, Mesh)> = Part::ALL.iter().map(|p| (*p, p.mesh())).collect();
    let objects: Vec<(u32, &Mesh)> = meshes.iter().map(|(p, m)| (p.object_id(), m)).collect();
    let noise = (!no_noise).then(NoiseModel::kinect);
    let scene = SyntheticScene::resting(seed, noise, 0, &objects).map_err(|e| e.to_string())?;
    Ok((meshes, scene))
}

/// The embedded default: the generated parts resting on a table, seen by a Kinect-like camera.
fn generated_scene(args: &DemoArgs, cache: &Path) -> Result<DemoScene, String> {
    let seed = args.seed.unwrap_or(1);
    let (meshes, scene) = parts_scene(seed, args.no_noise)?;
    // Models are built here once and kept in the cache; the daemon maps the files.
    let params = ModelParams::default();
    let mut model_files = Vec::new();
    for (part, mesh) in &meshes {
        let path = cache.join(format!("{}_{:06}.ppfm", part.name(), part.object_id()));
        let started = Instant::now();
        let source = MeshSource::Mesh {
            mesh,
            name: part.name(),
        };
        let cached = load_or_build(source, part.object_id(), &params, &ModelFiles::at(&path))
            .map_err(|e| e.to_string())?;
        for why in &cached.rejected {
            println!("{why}");
        }
        if let Some(e) = cached.not_saved {
            return Err(e.to_string());
        }
        if cached.origin == Origin::Built {
            println!(
                "built the model of {} in {:.1} s",
                part.name(),
                started.elapsed().as_secs_f64()
            );
        }
        model_files.push((part.object_id(), path));
    }
    let noise = if args.no_noise {
        ""
    } else {
        ", Kinect-like noise"
    };
    Ok(DemoScene {
        frame: scene.frame,
        truth: scene.ground_truth,
        // The generated parts have none.
        symmetries: Vec::new(),
        model_files,
        label: format!("generated parts on a table, seed {seed}{noise}"),
    })
}

fn bop_scene(args: &DemoArgs, root: &Path) -> Result<DemoScene, String> {
    let dataset = BopDataset::open(root).map_err(|e| e.to_string())?;
    let (scene, im) = match &args.image {
        Some(v) => (v[0], v[1]),
        None => dataset
            .scene_ids()
            .into_iter()
            .flat_map(|s| {
                dataset
                    .image_ids(s)
                    .unwrap_or_default()
                    .into_iter()
                    .map(move |i| (s, i))
            })
            .find(|&(s, i)| dataset.has_depth(s, i))
            .ok_or_else(|| format!("{}: no image with depth", root.display()))?,
    };
    let frame = dataset.depth_frame(scene, im).map_err(|e| e.to_string())?;
    let truth: Vec<(u32, Pose)> = dataset
        .ground_truth(scene, im)
        .map_err(|e| e.to_string())?
        .iter()
        .map(|g| (g.obj_id, g.pose))
        .collect();
    let mut meshes: Vec<(u32, PathBuf)> = Vec::new();
    for (id, _) in &truth {
        if !meshes.iter().any(|(known, _)| known == id) {
            let path = dataset.model_path(*id).map_err(|e| e.to_string())?;
            meshes.push((*id, path));
        }
    }
    let symmetries = meshes
        .iter()
        .map(|(id, _)| dataset.symmetry(*id).map(|s| (*id, s)))
        .collect::<Result<_, _>>()
        .map_err(|e| e.to_string())?;
    Ok(DemoScene {
        frame,
        truth,
        symmetries,
        model_files: meshes,
        label: format!("{} scene {scene} image {im}", root.display()),
    })
}

/// The name `file` (the model of object `id`) is linked under in the daemon's model folder: a
/// mesh as `obj_<id>.ply`, since the daemon takes a mesh's object id from the digits ending its
/// name and a dataset may call it anything (`obj.ply`, `duck.ply`); a model file (`.ppfm`)
/// under its own name, as it holds its object id.
fn link_name(id: u32, file: &Path) -> std::ffi::OsString {
    let is_model_file = file
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case(store::EXTENSION));
    match file.file_name() {
        Some(name) if is_model_file => name.to_owned(),
        _ => format!("obj_{id:06}.ply").into(),
    }
}

/// What a demo run leaves on the machine: its work folder (the daemon's model folder of links)
/// and the daemon. Dropped on every way out of [`run`], an error included: stops the daemon,
/// then removes the folder.
struct DemoRun {
    work: ScratchDir,
    daemon: Option<Daemon>,
    /// The demo's own iceoryx2 prefix, whose leftover files go once the daemon has stopped
    /// (the camera and the client, declared after this, are dropped before it).
    prefix: String,
}

impl Drop for DemoRun {
    fn drop(&mut self) {
        // The daemon first: it has the folder open. `work` removes the folder after this.
        drop(self.daemon.take());
        let _ = ppfd_client::remove_prefix_leftovers(&self.prefix);
    }
}

/// The daemon command: the given `ppfd` executable, else this executable's `serve` (the same
/// daemon code, so `cargo run -p ppfd-cli --bin ppf -- demo` needs nothing else built).
fn daemon_command(given: &Option<PathBuf>) -> Result<(PathBuf, Vec<&'static str>), String> {
    match given {
        Some(p) => Ok((p.clone(), vec![])),
        None => {
            let me =
                std::env::current_exe().map_err(|e| format!("cannot find this executable: {e}"))?;
            Ok((me, vec!["serve"]))
        }
    }
}

/// A child process stopped (SIGTERM, then SIGKILL) when dropped, or when the demo is stopped
/// by a signal ([`crate::stop`]).
struct Daemon(Child);

impl Daemon {
    fn new(child: Child) -> Daemon {
        stop::set_child(Some(child.id()));
        Daemon(child)
    }
}

impl Drop for Daemon {
    fn drop(&mut self) {
        stop::set_child(None);
        // SAFETY: signals our own child.
        unsafe { libc::kill(self.0.id() as i32, libc::SIGTERM) };
        let end = Instant::now() + Duration::from_secs(5);
        while Instant::now() < end {
            if let Ok(Some(_)) = self.0.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn start_daemon(
    (exe, first): &(PathBuf, Vec<&'static str>),
    models: &Path,
    cache: &Path,
    prefix: &str,
) -> Result<Daemon, String> {
    let mut child = Command::new(exe)
        .args(first)
        .arg("--models")
        .arg(models)
        .arg("--model-cache")
        .arg(cache)
        .args(["--prefix", prefix])
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .map_err(|e| format!("cannot start {} {}: {e}", exe.display(), first.join(" ")))?;
    let stdout = child.stdout.take().expect("piped stdout");
    let daemon = Daemon::new(child);
    let mut line = String::new();
    let mut reader = BufReader::new(stdout);
    loop {
        line.clear();
        match reader.read_line(&mut line) {
            Ok(0) | Err(_) => {
                return Err("ppfd stopped before it was ready (see its log above)".into())
            }
            Ok(_) if line.starts_with("ppfd ready") => break,
            Ok(_) => {}
        }
    }
    std::thread::spawn(move || for _ in reader.lines() {});
    Ok(daemon)
}

/// A pose this near a true one is counted as found.
const CORRECT_MM: f32 = 20.0;
const CORRECT_DEG: f32 = 10.0;

/// The lines of the pose table: per object of the truth (each once, in the truth's order) its
/// poses best first, each against the nearest true instance of that object, or a line saying
/// it has none; and how many true instances their object's best pose is within 20 mm and 10
/// degrees of. Poses are compared through their object's symmetry in `symmetries` (none for
/// an object not there).
fn pose_table(
    found: &Detections,
    truth: &[(u32, Pose)],
    symmetries: &[(u32, Symmetry)],
) -> (Vec<String>, usize) {
    let mut lines = vec![format!(
        "{:>6} {:>4} {:>6} {:>10} {:>10} {:>8}",
        "object", "rank", "score", "dt (mm)", "dR (deg)", "checks"
    )];
    let none = Symmetry::default();
    let errors = |id: u32, pose: &Pose, truth: &Pose| {
        symmetries
            .iter()
            .find(|(known, _)| *known == id)
            .map_or(&none, |(_, s)| s)
            .pose_errors(pose, truth)
    };
    let mut objects: Vec<u32> = Vec::new();
    for (id, _) in truth {
        if !objects.contains(id) {
            objects.push(*id);
        }
    }
    for id in objects {
        let mut poses = found.of(id).peekable();
        if poses.peek().is_none() {
            lines.push(format!("{id:>6} {:>4} (no hypothesis)", "-"));
        }
        for h in poses {
            let pose = h.isometry();
            let (dt, dr) = truth
                .iter()
                .filter(|(t, _)| *t == id)
                .map(|(_, t)| errors(id, &pose, t))
                .min_by(|a, b| a.0.total_cmp(&b.0))
                .expect("the object is in the truth");
            lines.push(format!(
                "{:>6} {:>4} {:>6.3} {:>10.1} {:>10.1} {:>8}",
                id,
                h.instance_rank + 1,
                h.score,
                dt,
                dr,
                crate::common::checks_letters(h.checks)
            ));
        }
    }
    let correct = truth
        .iter()
        .filter(|(id, t)| {
            found.best(*id).is_some_and(|h| {
                let (dt, dr) = errors(*id, &h.isometry(), t);
                dt < CORRECT_MM && dr < CORRECT_DEG
            })
        })
        .count();
    (lines, correct)
}

impl DemoArgs {
    /// A flag that the chosen scene cannot use: `--image` picks a dataset's frame, `--seed` and
    /// `--no-noise` shape a generated scene.
    pub fn flag_without_its_scene(&self) -> Option<&'static str> {
        match &self.dataset {
            None if self.image.is_some() => Some(
                "--image SCENE IMAGE picks a frame of a BOP dataset: give --dataset DIR too \
                 (without it the demo generates its scene; --seed N draws another)",
            ),
            Some(_) if self.seed.is_some() => Some(
                "--seed draws a generated scene; with --dataset the scene is the dataset's \
                 frame (--image SCENE IMAGE picks another)",
            ),
            Some(_) if self.no_noise => Some(
                "--no-noise renders a generated scene without sensor noise; with --dataset \
                 the frame is the sensor's own",
            ),
            _ => None,
        }
    }
}

pub fn run(args: DemoArgs) -> Result<(), String> {
    // Before any thread starts (model building runs on a pool).
    stop::handle_stop_signals(Some(ScratchDir::path_of(WORK_DIR)));
    if let Some(path) = &args.overlay {
        crate::overlay::check_path(path)?;
    }
    let cache = args
        .model_cache
        .clone()
        .unwrap_or_else(|| std::env::temp_dir().join("ppf-demo-models"));
    std::fs::create_dir_all(&cache).map_err(|e| format!("{}: {e}", cache.display()))?;
    let scene = match &args.dataset {
        Some(root) => bop_scene(&args, root)?,
        None => generated_scene(&args, &cache)?,
    };
    stop::check()?;
    println!(
        "scene: {} ({}x{}), objects {:?}",
        scene.label,
        scene.frame.width,
        scene.frame.height,
        scene.truth.iter().map(|t| t.0).collect::<Vec<_>>()
    );

    // The daemon loads the model files (or builds models from meshes once, into the cache).
    // Declared before the camera and the client, so dropped after them.
    let prefix = format!("ppfd_demo_{}_", std::process::id());
    let mut run = DemoRun {
        work: ScratchDir::create(WORK_DIR)?,
        daemon: None,
        prefix: prefix.clone(),
    };
    let models = run.work.path().join("models");
    std::fs::create_dir_all(&models).map_err(|e| format!("{}: {e}", models.display()))?;
    for (id, file) in &scene.model_files {
        let link = models.join(link_name(*id, file));
        let abs = std::fs::canonicalize(file).map_err(|e| format!("{}: {e}", file.display()))?;
        std::os::unix::fs::symlink(&abs, &link).map_err(|e| format!("{}: {e}", link.display()))?;
    }
    let exe = daemon_command(&args.ppfd)?;
    println!(
        "starting the daemon: {} {} (models cached in {})",
        exe.0.display(),
        exe.1.join(" "),
        cache.display()
    );
    let started = Instant::now();
    run.daemon = Some(start_daemon(&exe, &models, &cache, &prefix)?);
    stop::check()?;
    println!("daemon ready in {:.1} s", started.elapsed().as_secs_f64());

    let f = &scene.frame;
    let k = f.intrinsics;
    let mut camera = CameraPublisher::new(
        Some(&prefix),
        "demo",
        1,
        f.width,
        f.height,
        Intrinsics {
            fx: k.fx,
            fy: k.fy,
            cx: k.cx,
            cy: k.cy,
        },
        f.depth_scale_mm,
    )
    .map_err(|e| e.to_string())?;
    let client = Client::connect_with(&ClientOptions {
        prefix: Some(prefix.clone()),
        ..Default::default()
    })
    .map_err(|e| e.to_string())?;
    let ids = crate::common::distinct(scene.truth.iter().map(|t| t.0));
    let options = DetectOptions {
        hypotheses_per_object: args.hypotheses,
        timeout: Duration::from_secs(900),
        requirements: args.requirements.wire()?,
        ..Default::default()
    };
    // Publish until the daemon has subscribed and answers from this camera.
    let deadline = Instant::now() + Duration::from_secs(10);
    let found = loop {
        stop::check()?;
        camera
            .loan()
            .and_then(|l| l.write_from_slice(&f.depth))
            .and_then(|r| r.send(monotonic_now_ns()))
            .map_err(|e| e.to_string())?;
        match client.detect("demo", &ids, &options) {
            Ok(found) => break found,
            Err(ppfd_client::Error::Refused { status, .. })
                if matches!(
                    status,
                    ppfd_client::Status::NoFrame | ppfd_client::Status::UnknownCamera
                ) && Instant::now() < deadline =>
            {
                std::thread::sleep(Duration::from_millis(50));
            }
            Err(e) => return Err(e.to_string()),
        }
    };
    stop::check()?;

    println!();
    let (rows, correct) = pose_table(&found, &scene.truth, &scene.symmetries);
    for row in rows {
        println!("{row}");
    }
    println!(
        "{correct} of {} objects within 20 mm and 10 degrees\n",
        scene.truth.len()
    );
    print_latency(&found);
    if let Some(path) = &args.overlay {
        let meshes = scene
            .model_files
            .iter()
            .map(|(id, file)| Ok((*id, crate::overlay::mesh_of_file(file)?)))
            .collect::<Result<Vec<(u32, Mesh)>, String>>()?;
        crate::overlay::draw_detections(&f.view(), None, &meshes, &found, &scene.truth)
            .write_png(path)?;
        println!("\noverlay written to {}", path.display());
    }
    drop(camera);
    drop(client);
    drop(run);
    println!("\ndaemon stopped");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The daemon takes a mesh's object id from the digits ending its name: a dataset's mesh
    /// is linked under the name that gives its id, whatever the dataset calls it.
    #[test]
    fn a_mesh_is_linked_under_a_name_that_gives_its_object_id() {
        for (id, file, name) in [
            (19, "/d/data/obj.ply", "obj_000019.ply"),
            (5, "/d/models/obj_000005.ply", "obj_000005.ply"),
            (7, "/d/duck3.PLY", "obj_000007.ply"),
            (2, "/cache/bracket_000002.ppfm", "bracket_000002.ppfm"),
        ] {
            let link = link_name(id, Path::new(file));
            assert_eq!(link, name, "{file}");
            assert_eq!(
                ppfd::ppf_engine::object_id_of_file(Path::new(&link)),
                Some(id)
            );
        }
    }

    /// `--hypotheses N` shows N poses per object, ranked, each against the nearest true
    /// instance of its object (only the best was shown, so the flag changed nothing seen), and
    /// an object without a pose gets a line saying so. Found counts the best poses, as before.
    /// A pose turned by a symmetry of its object is as right as the truth: the table and the
    /// count go through the object's symmetry.
    #[test]
    fn the_pose_table_compares_through_the_objects_symmetry() {
        let truth = [(7, Pose::translation(0.0, 0.0, 800.0))];
        // Turned half about the object's z axis.
        let found = Detections {
            request_id: 1,
            hypotheses: vec![ppfd_client::PoseHypothesis {
                object_id: 7,
                instance_rank: 0,
                rotation: [-1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 1.0],
                translation_mm: [0.0, 0.0, 800.0],
                score: 0.5,
                votes: 10,
                checks: ppfd_client::checks::RESCORED,
            }],
            latency: Default::default(),
            counts: Default::default(),
            frame_sequence: 1,
            frame_age_ns: 0,
            diagnosis: String::new(),
        };
        let half_turn = Symmetry::from_stored(&[[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]], &[]);
        let half_turn = half_turn.unwrap();
        let (lines, correct) = pose_table(&found, &truth, &[(7, half_turn)]);
        assert_eq!(correct, 1, "{lines:#?}");
        assert!(
            lines[1].split_whitespace().nth(4) == Some("0.0"),
            "{lines:#?}"
        );
        let (lines, correct) = pose_table(&found, &truth, &[]);
        assert_eq!(correct, 0, "{lines:#?}");
        assert!(
            lines[1].split_whitespace().nth(4) == Some("180.0"),
            "{lines:#?}"
        );
    }

    #[test]
    fn the_pose_table_shows_every_pose_asked_for() {
        let at = |x: f32| Pose::translation(x, 0.0, 800.0);
        let pose = |object_id, instance_rank, x: f32, score| ppfd_client::PoseHypothesis {
            object_id,
            instance_rank,
            rotation: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            translation_mm: [x, 0.0, 800.0],
            score,
            votes: 10,
            checks: ppfd_client::checks::RESCORED,
        };
        let found = Detections {
            request_id: 1,
            // Object 5: the best pose 2 mm off the first instance, the second 3 mm off the
            // other; object 8: one pose, 150 mm off.
            hypotheses: vec![
                pose(5, 0, 2.0, 0.3),
                pose(5, 1, 303.0, 0.2),
                pose(8, 0, 150.0, 0.1),
            ],
            latency: Default::default(),
            counts: Default::default(),
            frame_sequence: 1,
            frame_age_ns: 0,
            diagnosis: String::new(),
        };
        let truth = [(5, at(0.0)), (8, at(0.0)), (5, at(300.0)), (9, at(0.0))];
        let (lines, correct) = pose_table(&found, &truth, &[]);
        let cells: Vec<Vec<&str>> = lines
            .iter()
            .map(|l| l.split_whitespace().collect())
            .collect();
        assert_eq!(cells.len(), 1 + 4, "{lines:#?}");
        assert_eq!(cells[1], ["5", "1", "0.300", "2.0", "0.0", "R"]);
        assert_eq!(cells[2], ["5", "2", "0.200", "3.0", "0.0", "R"]);
        assert_eq!(cells[3], ["8", "1", "0.100", "150.0", "0.0", "R"]);
        assert_eq!(lines[4].trim_start(), "9    - (no hypothesis)");
        assert_eq!(
            correct, 1,
            "the best pose of object 5 is at its first instance"
        );
    }
}
