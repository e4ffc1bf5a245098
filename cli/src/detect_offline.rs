//! `ppf detect --dataset`: run the detector on one frame of a BOP dataset, in this process.

use std::path::PathBuf;

use clap::Args;
use ppfd_bop::dataset::BopDataset;
use ppfd_models::detect::detector::{Detector, Hint, RunOptions};

use crate::offline::dataset_models;

/// `ppf detect`: through the daemon on a camera's newest frame, or offline on a dataset frame.
#[derive(Args, Debug)]
pub struct DetectCommand {
    /// Camera whose newest frame the daemon should use.
    #[arg(long, conflicts_with = "dataset", value_parser = crate::common::camera_name)]
    pub camera: Option<String>,
    /// A BOP dataset directory: detect in one of its frames in this process, no daemon.
    #[arg(long, requires_all = ["scene", "image"])]
    pub dataset: Option<PathBuf>,
    /// Scene id (with --dataset).
    #[arg(long)]
    pub scene: Option<u32>,
    /// Image id (with --dataset).
    #[arg(long)]
    pub image: Option<u32>,
    /// Object ids, comma separated (with --dataset: default those in the image's ground truth).
    #[arg(long, value_delimiter = ',', value_parser = crate::common::object_id)]
    pub objects: Vec<u32>,
    /// Hypotheses per object, 1 to 16.
    #[arg(long, default_value_t = 1,
          value_parser = clap::value_parser!(u32).range(1..=crate::common::MAX_HYPOTHESES))]
    pub hypotheses: u32,
    /// Give up after this long, milliseconds (with --camera; eight objects in a cluttered VGA
    /// frame take about half a second on a 2-core machine, docs/BENCHMARKS.md).
    #[arg(long, default_value_t = 30_000, conflicts_with = "dataset",
          value_parser = clap::value_parser!(u64).range(1..))]
    pub timeout_ms: u64,
    /// Print the answer as JSON (with --camera): ranks from 1 like the table, `checks` as the
    /// protocol's bits (1 re-scored, 2 refined, 4 consistent, 8 silhouette, 16 from a
    /// hint), times in ns.
    #[arg(long, conflicts_with = "dataset")]
    pub json: bool,
    /// With --camera: a JSON file of poses the objects are expected near, refined before any
    /// voting: `ppf detect --json` output, or a list of `{"object_id", "rotation",
    /// "translation_mm"}`. Poses from hints carry check bit 16.
    #[arg(long, value_name = "POSES.JSON", conflicts_with = "dataset")]
    pub hints: Option<PathBuf>,
    /// With --dataset: print, per object, where the best candidate near the ground truth stands
    /// after each stage and at which stage it is lost, one line per stage (the detection runs
    /// too; about twice its time).
    #[arg(long)]
    pub diagnose: bool,
    /// With --camera: a JSON file of the poses the objects are believed at (as --hints takes
    /// them; poses of objects not asked for are left out). The daemon detects from scratch and says, per object with a pose, after each
    /// stage where the best candidate near it stands and at which stage it was lost; about
    /// twice the detection's time.
    #[arg(long, value_name = "POSES.JSON", conflicts_with_all = ["dataset", "hints"])]
    pub diagnose_against: Option<PathBuf>,
    /// With --dataset, override: every n-th evenly spread candidate is a reference point
    /// (`--set voting.reference_step=N`).
    #[arg(long)]
    pub reference_step: Option<usize>,
    /// With --dataset, override: accumulator peaks per reference point
    /// (`--set voting.peaks_per_reference=K`).
    #[arg(long)]
    pub peaks: Option<usize>,
    /// With --dataset: override any detector parameter, e.g. `--set scene.normal_radius_mm=8`
    /// (repeatable; an unknown name is answered with the names of its stage). The daemon's
    /// parameters are set when it starts (`ppfd --set`).
    #[arg(long = "set", value_name = "STAGE.FIELD=VALUE")]
    pub set: Vec<String>,
    /// Write a picture of the frame with each pose's outline, axes and label (id, #rank,
    /// score), and the ground truth's outline when known (PNG).
    #[arg(long, value_name = "PNG")]
    pub overlay: Option<PathBuf>,
    /// With --camera --overlay: the folder of the daemon's models (PLY meshes named by object
    /// id, or model files, which hold theirs; as given to `ppfd --models`), whose meshes the
    /// outlines are drawn from.
    #[arg(long, requires = "overlay", conflicts_with = "dataset")]
    pub models: Option<PathBuf>,
    #[command(flatten)]
    pub requirements: crate::requirements::RequirementArgs,
    #[command(flatten)]
    pub connect: crate::common::Connect,
}

/// What `ppf detect` says when given neither of its two modes (clap's "required: --camera" would
/// hide the offline one).
pub const NO_MODE: &str = "ppf detect has two modes; give one of
  --camera NAME                        a camera's newest frame, through the daemon
  --dataset DIR --scene N --image N    a frame of a BOP dataset, in this process (no daemon)";

pub enum DetectTarget {
    Camera(crate::detect::DetectArgs),
    Dataset(DatasetDetectArgs),
}

impl DetectCommand {
    /// Whether one of the two modes is given (`--camera` or `--dataset`); without, the command
    /// is refused with [`NO_MODE`] as a usage error.
    pub fn has_mode(&self) -> bool {
        self.camera.is_some() || self.dataset.is_some()
    }

    pub fn into_target(self) -> Result<DetectTarget, String> {
        if let Some(id) = crate::common::repeated(&self.objects) {
            return Err(format!("--objects lists object {id} twice"));
        }
        if self.diagnose
            && (self.overlay.is_some() || self.requirements.wire()? != Default::default())
        {
            return Err(
                "--diagnose ranks the first correct pose after each stage, without request \
                 options or an overlay: leave those out, or leave out --diagnose"
                    .into(),
            );
        }
        if let Some(dataset) = self.dataset {
            if self.connect.prefix.is_some() {
                return Err(
                    "--prefix names a daemon's iceoryx2 prefix, for --camera; --dataset \
                            detects in this process, without a daemon"
                        .into(),
                );
            }
            return Ok(DetectTarget::Dataset(DatasetDetectArgs {
                dataset,
                scene: self.scene.ok_or("--dataset needs --scene")?,
                image: self.image.ok_or("--dataset needs --image")?,
                objects: self.objects,
                diagnose: self.diagnose,
                reference_step: self.reference_step,
                peaks: self.peaks,
                top: self.hypotheses as usize,
                set: self.set,
                requirements: self.requirements.wire()?,
                overlay: self.overlay,
            }));
        }
        let given = |flags: &[(&'static str, bool)]| -> Vec<&'static str> {
            flags
                .iter()
                .filter(|(_, on)| *on)
                .map(|(f, _)| *f)
                .collect()
        };
        let frame_flags = given(&[
            ("--scene", self.scene.is_some()),
            ("--image", self.image.is_some()),
            ("--diagnose", self.diagnose),
        ]);
        if !frame_flags.is_empty() {
            return Err(format!(
                "{} {} a frame of a BOP dataset: give --dataset as well; with --camera the \
                 frame is the camera's newest",
                frame_flags.join(", "),
                if frame_flags.len() == 1 {
                    "works on"
                } else {
                    "work on"
                }
            ));
        }
        let parameter_flags = given(&[
            ("--reference-step", self.reference_step.is_some()),
            ("--peaks", self.peaks.is_some()),
            ("--set", !self.set.is_empty()),
        ]);
        if !parameter_flags.is_empty() {
            return Err(format!(
                "{} {} the detector's parameters for --dataset only; through the daemon \
                 (--camera) the parameters are the daemon's, set when it starts (`ppfd --set`)",
                parameter_flags.join(", "),
                if parameter_flags.len() == 1 {
                    "sets"
                } else {
                    "set"
                }
            ));
        }
        if self.objects.is_empty() {
            return Err("--camera needs --objects".into());
        }
        if self.overlay.is_some() && self.models.is_none() {
            return Err(
                "--camera --overlay needs --models DIR, the daemon's models folder, to draw \
                 the outlines from"
                    .into(),
            );
        }
        Ok(DetectTarget::Camera(crate::detect::DetectArgs {
            camera: self.camera.ok_or(NO_MODE)?,
            objects: self.objects,
            hypotheses: self.hypotheses,
            timeout_ms: self.timeout_ms,
            json: self.json,
            requirements: self.requirements.wire()?,
            overlay: self.overlay.zip(self.models),
            hints: self.hints,
            diagnose_against: self.diagnose_against,
            connect: self.connect,
        }))
    }
}

/// Offline detection on one frame of a BOP dataset.
#[derive(Debug)]
pub struct DatasetDetectArgs {
    pub dataset: PathBuf,
    pub scene: u32,
    pub image: u32,
    pub objects: Vec<u32>,
    pub diagnose: bool,
    pub reference_step: Option<usize>,
    pub peaks: Option<usize>,
    pub top: usize,
    pub set: Vec<String>,
    pub requirements: ppfd_client::Requirements,
    pub overlay: Option<PathBuf>,
}

impl DatasetDetectArgs {
    /// The detector's parameters with this command's overrides.
    pub fn params(&self) -> Result<ppfd_models::detect::detector::DetectParams, String> {
        let mut p = ppfd_models::detect::detector::DetectParams::new();
        // Through `set`, for its ranges: the flags are names for two of its keys.
        if let Some(s) = self.reference_step {
            p.set("voting.reference_step", &s.to_string())?;
        }
        if let Some(k) = self.peaks {
            p.set("voting.peaks_per_reference", &k.to_string())?;
        }
        for kv in &self.set {
            p.set_from(kv)?;
        }
        p.check()?;
        Ok(p)
    }
}

pub fn run(args: DatasetDetectArgs) -> Result<(), Box<dyn std::error::Error>> {
    if args.diagnose {
        return diagnose(&args);
    }
    if let Some(path) = &args.overlay {
        crate::overlay::check_path(path)?;
    }
    let dataset = BopDataset::open(&args.dataset)?;
    dataset.check_image(args.scene, args.image)?;
    let gt = dataset
        .ground_truth_if_any(args.scene, args.image)?
        .map(|g| g.to_vec())
        .unwrap_or_default();
    let ids = match &args.objects {
        ids if !ids.is_empty() => ids.clone(),
        _ if !gt.is_empty() => crate::common::distinct(gt.iter().map(|g| g.obj_id)),
        _ => dataset.object_ids().to_vec(),
    };
    let detector = Detector::new(args.params()?);
    let models = dataset_models(&dataset, &ids)?;
    let frame = dataset.depth_frame(args.scene, args.image)?;
    let refs: Vec<_> = models.iter().collect();
    let opts = RunOptions {
        hypotheses_per_object: args.top.max(10),
        requirements: ppfd::ppf_engine::detector_requirements(&args.requirements)?,
        ..Default::default()
    };
    let det = detector.detect(&frame.view(), &refs, &opts)?;
    println!("| object | D (mm) | rank | score | votes | t err (mm) | R err (°) | checks | correct (0.1 D, 15°) within top 10 |");
    println!("|---:|---:|---:|---:|---:|---:|---:|---|---|");
    let mut found = 0;
    for (o, model) in det.objects.iter().zip(&models) {
        let d = model.diameter_mm();
        // Judged through the symmetries `models_info.json` gives, discrete and continuous.
        let symmetry = dataset.symmetry(o.object_id).map_err(|e| e.to_string())?;
        let pose_errors = |a: &ppfd_models::Pose, b: &ppfd_models::Pose| symmetry.pose_errors(a, b);
        let truth = gt.iter().find(|g| g.obj_id == o.object_id).map(|g| g.pose);
        let correct_rank = truth.and_then(|t| {
            o.hypotheses.iter().take(10).position(|h| {
                let (dt, dr) = pose_errors(&h.pose, &t);
                dt < 0.1 * d && dr < 15.0
            })
        });
        if correct_rank.is_some() {
            found += 1;
        }
        for (rank, h) in o.hypotheses.iter().take(args.top).enumerate() {
            let (dt, dr) = truth
                .map(|t| pose_errors(&h.pose, &t))
                .map_or(("-".into(), "-".into()), |(a, b)| {
                    (format!("{a:.1}"), format!("{b:.1}"))
                });
            let flag = if rank == 0 {
                correct_rank.map_or("no".to_string(), |r| format!("yes (rank {})", r + 1))
            } else {
                String::new()
            };
            println!(
                "| {} | {d:.0} | {} | {:.3} | {} | {dt} | {dr} | {} | {flag} |",
                o.object_id,
                rank + 1,
                h.score,
                h.votes,
                crate::common::checks_letters(h.checks.0)
            );
        }
        if o.hypotheses.is_empty() {
            let flag = if truth.is_some() { "no" } else { "-" };
            println!(
                "| {} | {d:.0} | - | (no hypothesis) | | | | | {flag} |",
                o.object_id
            );
        }
    }
    if let Some(path) = &args.overlay {
        let meshes: Vec<_> = models.iter().map(|m| m.render_mesh()).collect();
        let colour = dataset
            .colour_path(args.scene, args.image)
            .and_then(|p| crate::overlay::colour_or_note(&p));
        let view = frame.view();
        let mut overlay = colour
            .and_then(|(w, h, rgb)| crate::overlay::Overlay::from_colour(&view, w, h, rgb))
            .unwrap_or_else(|| crate::overlay::Overlay::from_depth(&view));
        let truth: Vec<crate::overlay::Drawn> = gt
            .iter()
            .filter_map(|g| {
                let i = ids.iter().position(|&id| id == g.obj_id)?;
                Some(crate::overlay::Drawn {
                    mesh: &meshes[i],
                    pose: g.pose,
                    colour: crate::overlay::TRUTH,
                    label: None,
                })
            })
            .collect();
        let poses: Vec<crate::overlay::Drawn> = det
            .objects
            .iter()
            .zip(&meshes)
            .flat_map(|(o, mesh)| {
                o.hypotheses
                    .iter()
                    .take(args.top)
                    .enumerate()
                    .map(move |(rank, h)| crate::overlay::Drawn {
                        mesh,
                        pose: h.pose,
                        colour: crate::overlay::check_colour(h.checks.0),
                        label: Some(crate::overlay::label(o.object_id, rank, h.score)),
                    })
            })
            .collect();
        overlay.draw_all(&truth, &poses);
        overlay.write_png(path)?;
        println!("overlay written to {}", path.display());
    }
    if !gt.is_empty() {
        println!(
            "\n{found} of {} objects have a correct pose among their 10 best",
            det.objects.len()
        );
    }
    let t = &det.timings;
    println!(
        "\ntimes (ms; stages summed over objects, which run side by side): scene {:.1}, kd-tree {:.1}, voting {:.1}, clustering {:.1}, re-scoring {:.1}, ICP {:.1}, filters {:.1}; wall time {:.1}",
        ms(t.scene_preparation), ms(t.kd_tree), ms(t.voting), ms(t.clustering), ms(t.rescoring), ms(t.icp), ms(t.filters), ms(det.elapsed)
    );
    println!(
        "counts: {} scene points, {} reference points, {} pairs, {} votes, {} hypotheses",
        det.counts.scene_points,
        det.counts.reference_points,
        det.counts.pairs,
        det.counts.votes,
        det.counts.hypotheses
    );
    Ok(())
}

fn ms(d: std::time::Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// For each object: how its scene cloud looks against the ground truth (points on the object,
/// their normals' error), then the stages one by one ([`ppfd_models::detect::diagnosis`]):
/// where the best candidate near the ground truth stands after each, and where it was lost.
pub fn diagnose(args: &DatasetDetectArgs) -> Result<(), Box<dyn std::error::Error>> {
    use ppfd_models::detect::diagnosis::{
        diagnose_targets, NEAR_ROTATION_DEG, NEAR_TRANSLATION_FRACTION,
    };
    let dataset = BopDataset::open(&args.dataset)?;
    let gt = dataset.ground_truth(args.scene, args.image)?.to_vec();
    let ids = if args.objects.is_empty() {
        gt.iter().map(|g| g.obj_id).collect()
    } else {
        args.objects.clone()
    };
    let p = args.params()?;
    // Every stage is judged against the ground truth: refuse an object without one before
    // building anything.
    if let Some(missing) = ids.iter().find(|&&id| !gt.iter().any(|g| g.obj_id == id)) {
        let present: Vec<String> = gt.iter().map(|g| g.obj_id.to_string()).collect();
        return Err(format!(
            "object {missing} has no ground truth in scene {} image {} (it has {}); --diagnose needs it",
            args.scene,
            args.image,
            present.join(", ")
        )
        .into());
    }
    let models = dataset_models(&dataset, &ids)?;
    let frame = dataset.depth_frame(args.scene, args.image)?;
    let model_refs: Vec<&ppfd_models::model::ObjectModel> = models.iter().collect();
    // The first true instance of each object is its target.
    let targets: Vec<Hint> = ids
        .iter()
        .filter_map(|&id| gt.iter().find(|g| g.obj_id == id))
        .map(|g| Hint {
            object_id: g.obj_id,
            pose: g.pose,
        })
        .collect();
    let opts = RunOptions {
        hypotheses_per_object: args.top.max(1),
        ..Default::default()
    };
    // The objects of one detection change each other's poses only through the exclusion across
    // objects, which the stages run object by object cannot see: the detection itself settles
    // each result stage.
    let detected = if models.len() > 1 {
        Some(Detector::new(p.clone()).detect(&frame.view(), &model_refs, &opts)?)
    } else {
        None
    };
    // No deadline here: the command runs every stage to its end.
    let diagnosis = diagnose_targets(
        &p,
        &frame.view(),
        &model_refs,
        &targets,
        &opts,
        detected.as_ref(),
    )?;
    for pl in &diagnosis.planes {
        println!(
            "large plane: normal ({:.3}, {:.3}, {:.3}), {:.0} mm from the camera, {:.0} mm wide, {:.0} % of the scene on it",
            pl.normal.x,
            pl.normal.y,
            pl.normal.z,
            pl.offset.abs(),
            pl.extent_mm,
            100.0 * pl.inlier_fraction
        );
    }
    println!("| object | cloud points | on object | normal error (median °) | reference points on object | lost at |");
    println!("|---:|---:|---:|---:|---:|---|");
    for d in &diagnosis.objects {
        let c = &d.cloud;
        let median = c
            .normal_error_median_deg
            .map_or("–".to_string(), |e| format!("{e:.1}"));
        println!(
            "| {} | {} | {} | {median} | {} | {} |",
            d.object_id,
            c.cloud_points,
            c.on_object,
            c.references_on_object,
            d.lost_at().unwrap_or("found"),
        );
    }
    println!();
    for d in &diagnosis.objects {
        for line in d.lines() {
            println!("{line}");
        }
    }
    let found = diagnosis
        .objects
        .iter()
        .filter(|d| d.lost_at().is_none())
        .count();
    println!(
        "\n{found} of {} objects found near the ground truth (within {} D and {}°)",
        models.len(),
        NEAR_TRANSLATION_FRACTION,
        NEAR_ROTATION_DEG
    );
    Ok(())
}
