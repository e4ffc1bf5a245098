//! `ppf detect --dataset`: run the detector on one frame of a BOP dataset, in this process.

use std::path::PathBuf;

use clap::Args;
use ppfd_bop::dataset::BopDataset;
use ppfd_models::detect::detector::{Detector, RunOptions};
use rayon::prelude::*;

use crate::offline::{dataset_models, symmetric_pose_errors};

/// `ppf detect`: through the daemon on a camera's newest frame, or offline on a dataset frame.
#[derive(Args, Debug)]
pub struct DetectCommand {
    /// Camera whose newest frame the daemon should use.
    #[arg(long, conflicts_with = "dataset")]
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
    #[arg(long, value_delimiter = ',')]
    pub objects: Vec<u32>,
    /// Hypotheses per object, 1 to 16.
    #[arg(long, default_value_t = 1,
          value_parser = clap::value_parser!(u32).range(1..=crate::common::MAX_HYPOTHESES))]
    pub hypotheses: u32,
    /// Give up after this long, milliseconds (with --camera; a cluttered VGA frame takes
    /// seconds per object on a 2-core machine).
    #[arg(long, default_value_t = 30_000, conflicts_with = "dataset",
          value_parser = clap::value_parser!(u64).range(1..))]
    pub timeout_ms: u64,
    /// Print the answer as JSON (with --camera): ranks from 1 like the table, `checks` as the
    /// protocol's bits (1 re-scored, 2 refined, 4 consistent, 8 silhouette), times in ns.
    #[arg(long, conflicts_with = "dataset")]
    pub json: bool,
    /// With --camera: a JSON file of poses the objects are expected near, refined before any
    /// voting: `ppf detect --json` output, or a list of `{"object_id", "rotation",
    /// "translation_mm"}`. Poses from hints carry check bit 16.
    #[arg(long, value_name = "POSES.JSON", conflicts_with = "dataset")]
    pub hints: Option<PathBuf>,
    /// With --dataset: instead of detecting, print the rank of the first correct pose after
    /// each stage.
    #[arg(long)]
    pub diagnose: bool,
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
        if let Some(id) = (1..self.objects.len()).find_map(|i| {
            self.objects[..i]
                .contains(&self.objects[i])
                .then_some(self.objects[i])
        }) {
            return Err(format!("--objects lists object {id} twice"));
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
        Ok(DetectTarget::Camera(crate::detect::DetectArgs {
            camera: self.camera.ok_or(NO_MODE)?,
            objects: self.objects,
            hypotheses: self.hypotheses,
            timeout_ms: self.timeout_ms,
            json: self.json,
            hints: self.hints,
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
}

impl DatasetDetectArgs {
    /// The detector's parameters with this command's overrides.
    pub fn params(&self) -> Result<ppfd_models::detect::detector::DetectParams, String> {
        let mut p = ppfd_models::detect::detector::DetectParams::new();
        if let Some(s) = self.reference_step {
            p.voting.reference_step = s;
        }
        if let Some(k) = self.peaks {
            p.voting.peaks_per_reference = k;
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
    let dataset = BopDataset::open(&args.dataset)?;
    let gt = dataset
        .ground_truth(args.scene, args.image)
        .map(|g| g.to_vec())
        .unwrap_or_default();
    let ids = match &args.objects {
        ids if !ids.is_empty() => ids.clone(),
        _ if !gt.is_empty() => {
            let mut ids: Vec<u32> = gt.iter().map(|g| g.obj_id).collect();
            ids.dedup();
            ids
        }
        _ => dataset.object_ids().to_vec(),
    };
    let detector = Detector::new(args.params()?);
    let models = dataset_models(&dataset, &ids)?;
    let frame = dataset.depth_frame(args.scene, args.image)?;
    let refs: Vec<_> = models.iter().collect();
    let opts = RunOptions {
        hypotheses_per_object: args.top.max(10),
        ..Default::default()
    };
    let det = detector.detect(&frame.view(), &refs, &opts)?;
    println!("| object | D (mm) | rank | score | votes | t err (mm) | R err (°) | checks | correct (0.1 D, 15°) within top 10 |");
    println!("|---:|---:|---:|---:|---:|---:|---:|---|---|");
    let mut found = 0;
    for (o, model) in det.objects.iter().zip(&models) {
        let d = model.diameter_mm();
        let syms = dataset
            .model_info(o.object_id)
            .map(|i| i.symmetries_discrete.clone())
            .unwrap_or_default();
        let pose_errors =
            |a: &ppfd_models::Pose, b: &ppfd_models::Pose| symmetric_pose_errors(a, b, &syms);
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
    }
    if !gt.is_empty() {
        println!(
            "\n{found} of {} objects have a correct pose among their 10 best",
            det.objects.len()
        );
    }
    let t = &det.timings;
    println!(
        "\ntimes (ms): scene {:.1}, kd-tree {:.1}, voting {:.1}, clustering {:.1}, re-scoring {:.1}, ICP {:.1}, filters {:.1}, total {:.1}",
        ms(t.scene_preparation), ms(t.kd_tree), ms(t.voting), ms(t.clustering), ms(t.rescoring), ms(t.icp), ms(t.filters), ms(t.total())
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

/// Runs the stages one by one for each object and prints where the first correct pose (within
/// 0.1 D and 15° of the ground truth) ranks after each.
pub fn diagnose(args: &DatasetDetectArgs) -> Result<(), Box<dyn std::error::Error>> {
    use ppfd_models::detect::clustering::cluster_poses;
    use ppfd_models::detect::icp::refine;
    use ppfd_models::detect::plane::SupportingPlane;
    use ppfd_models::detect::rescoring::{prescreen, score_poses, Outline};
    use ppfd_models::detect::scene::{prepare, PreparedScene};
    use ppfd_models::detect::silhouette::EdgeMap;
    use ppfd_models::detect::voting::{vote_from, Selection};
    use ppfd_models::geometry::render::bounding_sphere;
    use ppfd_models::geometry::simplify::simplified_mesh;
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
    let scene = prepare(&frame.view(), &p.scene)?;
    let points = scene.oriented_points();
    let planes = SupportingPlane::find_all(&points, &p.plane);
    for pl in &planes {
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
    let edges = EdgeMap::new(&scene, &p.filters);
    // The clouds the detector would build for these objects together.
    let model_refs: Vec<&ppfd_models::model::ObjectModel> = models.iter().collect();
    let (groups, cloud_of) = p.scene_clouds(&model_refs);
    let clouds: Vec<PreparedScene> = p.prepare_clouds(&points, &groups)?;
    println!("| object | cloud points | on object | normal error (median °) | reference points on object | proposing a correct pose | clusters | rank by votes | after re-scoring | after ICP + re-scoring | best cluster t err (mm) | R err (°) | voting + clustering (ms) |");
    println!("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    let (mut in_top10, mut first_after_icp) = (0, 0);
    for (model, &group) in models.iter().zip(&cloud_of) {
        let d = model.diameter_mm();
        let truth = gt
            .iter()
            .find(|g| g.obj_id == model.object_id())
            .map(|g| g.pose)
            .ok_or("no ground truth")?; // checked above
        let syms = dataset
            .model_info(model.object_id())
            .map(|i| i.symmetries_discrete.clone())
            .unwrap_or_default();
        let ok = |pose: &ppfd_models::Pose| {
            let (dt, dr) = symmetric_pose_errors(pose, &truth, &syms);
            dt < 0.1 * d && dr < 15.0
        };
        let rank = |poses: Vec<ppfd_models::Pose>| {
            poses
                .iter()
                .position(&ok)
                .map_or("-".to_string(), |r| (r + 1).to_string())
        };
        let cloud = &clouds[group];
        // The model's surface at the true pose, the side facing the camera only: the back of a
        // thin part (a handle, a spout) lies within millimetres of its front, with the opposite
        // normal. A cloud point within 3 mm of it is on the object; its normal error is the
        // angle to the nearest such surface point's normal.
        let front: Vec<_> = surface_of(model)
            .into_iter()
            .map(|(q, n)| (truth * q, truth * n))
            .filter(|(q, n)| n.dot(&q.coords) < 0.0)
            .collect();
        // Per cloud point, once: the nearest such surface point's normal, if it is on the object.
        let surface_normals: Vec<Option<nalgebra::Vector3<f32>>> = cloud
            .points
            .positions
            .iter()
            .map(|q| {
                front
                    .iter()
                    .filter(|(m, _)| (m - q).norm() < 3.0)
                    .min_by(|a, b| (a.0 - q).norm().total_cmp(&(b.0 - q).norm()))
                    .map(|(_, n)| *n)
            })
            .collect();
        let on_object = {
            let mut errs: Vec<f32> = surface_normals
                .iter()
                .zip(&cloud.points.normals)
                .filter_map(|(mn, n)| mn.map(|mn| n.dot(&mn).clamp(-1.0, 1.0).acos().to_degrees()))
                .collect();
            errs.sort_by(f32::total_cmp);
            (
                errs.len(),
                errs.get(errs.len() / 2).copied().unwrap_or(f32::NAN),
            )
        };
        let t = std::time::Instant::now();
        let selection = Selection::new(cloud, &p.voting, &planes, d);
        let (raw, _) = vote_from(model, cloud, &selection, &p.voting);
        let clusters = cluster_poses(&raw, d, &p.clustering);
        let vote_ms = t.elapsed().as_secs_f64() * 1e3;
        // Reference points on the object, and how many of them put a correct pose among their
        // accumulator's peaks: what voting gets right before clustering weighs it.
        let references_on_object: Vec<u32> = selection
            .references
            .iter()
            .filter(|&&r| surface_normals[r].is_some())
            .map(|&r| r as u32)
            .collect();
        let proposing: std::collections::HashSet<u32> = raw
            .iter()
            .filter(|h| ok(&h.pose))
            .map(|h| h.scene_point)
            .collect();
        let references_right = references_on_object
            .iter()
            .filter(|r| proposing.contains(r))
            .count();
        let first_correct = |poses: &[ppfd_models::Pose]| poses.iter().position(&ok);
        let cluster_poses_list: Vec<_> = clusters.iter().map(|c| c.pose).collect();
        if first_correct(&cluster_poses_list).is_some_and(|r| r < 10) {
            in_top10 += 1;
        }
        let best_err = clusters
            .first()
            .map(|c| symmetric_pose_errors(&c.pose, &truth, &syms))
            .unwrap_or((f32::NAN, f32::NAN));
        let surface = model.surface_points();
        let top: Vec<_> = clusters
            .iter()
            .take(p.rescoring.top_clusters)
            .map(|c| (c.pose, c.votes))
            .collect();
        let mesh = simplified_mesh(
            &model.render_mesh(),
            p.rescoring.silhouette_mesh_cell_fraction * d,
        );
        let sphere = bounding_sphere(&mesh);
        let outline = Outline {
            mesh: &mesh,
            sphere: &sphere,
            edges: &edges,
            max_outline_px: p.filters.max_outline_px,
        };
        let coarse_outline = Outline {
            max_outline_px: p.rescoring.coarse_outline(p.filters.max_outline_px),
            ..outline
        };
        // As the detector: a sparse fit picks the clusters for the full re-scoring, and the
        // outlines before ICP are coarse; every pose kept, the table ranks them all.
        let top = prescreen(
            &top,
            &surface,
            &scene,
            p.rescoring.tolerance_mm(d),
            p.rescoring.conflict_mm(d),
            &p.rescoring,
        );
        let scored = score_poses(
            &top,
            &surface,
            &scene,
            p.rescoring.tolerance_mm(d),
            p.rescoring.conflict_mm(d),
            &p.rescoring,
            &coarse_outline,
            top.len(),
        );
        let refined: Vec<_> = scored
            .par_iter()
            .take(p.icp.top_poses)
            .map(|s| (refine(&surface, &s.pose, &scene, d, &p.icp).pose, s.votes))
            .collect();
        let rescored = score_poses(
            &refined,
            &surface,
            &scene,
            p.rescoring.refined_tolerance_mm(d),
            p.rescoring.conflict_mm(d),
            &p.rescoring,
            &outline,
            refined.len(),
        );
        let final_poses: Vec<_> = rescored.iter().map(|s| s.pose).collect();
        if first_correct(&final_poses) == Some(0) {
            first_after_icp += 1;
        }
        println!(
            "| {} | {} | {} | {:.1} | {} | {} | {} | {} | {} | {} | {:.1} | {:.1} | {vote_ms:.0} |",
            model.object_id(),
            cloud.points.len(),
            on_object.0,
            on_object.1,
            references_on_object.len(),
            references_right,
            clusters.len(),
            rank(cluster_poses_list),
            rank(scored.iter().map(|s| s.pose).collect()),
            rank(final_poses),
            best_err.0,
            best_err.1,
        );
    }
    println!(
        "\n{in_top10} of {} objects have a correct pose among the 10 best clusters; {first_after_icp} rank it first after ICP + re-scoring",
        models.len()
    );
    Ok(())
}

fn surface_of(
    model: &ppfd_models::model::ObjectModel,
) -> Vec<(nalgebra::Point3<f32>, nalgebra::Vector3<f32>)> {
    let s = model.surface_points();
    s.positions.into_iter().zip(s.normals).collect()
}
