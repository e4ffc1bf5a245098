//! `ppf eval`: run the detector on every image of a BOP dataset that has depth, write the BOP
//! results CSV, and score it.

use std::path::PathBuf;
use std::time::Instant;

use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use ppfd_bop::dataset::BopDataset;
use ppfd_bop::eval::csv::{write_results_file, EstimateRow};
use ppfd_bop::eval::score::{dataset_targets, score_results, ScoreOptions};
use ppfd_models::detect::detector::{Detector, RunOptions};

use crate::common::scenes_there;
use crate::offline::dataset_models;

#[derive(Args, Debug)]
pub struct EvalArgs {
    /// A BOP dataset directory.
    pub dataset: PathBuf,
    /// Only this scene.
    #[arg(long)]
    pub scene: Option<u32>,
    /// Only these objects (comma separated); default: the objects of each image's ground truth,
    /// or every model when an image has none.
    #[arg(long, value_delimiter = ',', value_parser = crate::common::object_id)]
    pub objects: Vec<u32>,
    /// Hypotheses written per object and image, at least 1 (more than one only helps
    /// multi-instance targets).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..))]
    pub hypotheses: u32,
    /// The results CSV to write.
    #[arg(long, default_value = "results.csv")]
    pub out: PathBuf,
    /// Only write the CSV, do not score it.
    #[arg(long)]
    pub no_score: bool,
    /// Print the score report as JSON (there is none with --no-score).
    #[arg(long, conflicts_with = "no_score")]
    pub json: bool,
    /// Override a detector parameter, `stage.field=value` (as `ppf detect --set`); repeatable.
    #[arg(long = "set", value_name = "STAGE.FIELD=VALUE")]
    pub set: Vec<String>,
}

pub fn run(args: EvalArgs) -> Result<(), Box<dyn std::error::Error>> {
    let dataset = BopDataset::open(&args.dataset)?;
    if let Some(scene) = args.scene {
        let scenes = dataset.scene_ids();
        if !scenes.contains(&scene) {
            return Err(format!(
                "{}: no scene {scene}; {}",
                args.dataset.display(),
                scenes_there(&scenes)
            )
            .into());
        }
    }
    let mut images = Vec::new();
    for scene in dataset.scene_ids() {
        if args.scene.is_some_and(|s| s != scene) {
            continue;
        }
        for im in dataset.image_ids(scene)? {
            if dataset.has_depth(scene, im) {
                images.push((scene, im));
            }
        }
    }
    if images.is_empty() {
        let what = match args.scene {
            Some(scene) => format!("scene {scene} has"),
            None => "there is".to_owned(),
        };
        return Err(format!(
            "{}: {what} no image with depth to evaluate",
            args.dataset.display()
        )
        .into());
    }
    let ids: Vec<u32> = if args.objects.is_empty() {
        dataset.object_ids().to_vec()
    } else {
        args.objects.clone()
    };
    // Every image's files are checked before any work starts, and the objects each image
    // asks for come from its ground truth (every object where the scene has none).
    let mut wanted_per_image = Vec::with_capacity(images.len());
    // Every object a ground truth names, whose models_info.json entry scoring reads.
    let mut named = std::collections::BTreeSet::new();
    for &(scene, im) in &images {
        dataset.check_image(scene, im)?;
        let gt = dataset.ground_truth_if_any(scene, im)?;
        named.extend(gt.unwrap_or_default().iter().map(|g| g.obj_id));
        let wanted: Vec<u32> = match gt {
            Some(gt) if args.objects.is_empty() && !gt.is_empty() => {
                let mut v: Vec<u32> = gt.iter().map(|g| g.obj_id).collect();
                v.sort_unstable();
                v.dedup();
                v
            }
            _ => ids.clone(),
        };
        wanted_per_image.push(wanted);
    }
    // The models of every object an image asks for: one its ground truth names that
    // models_info.json does not list is detected too, not left out without a word.
    let mut ids = ids;
    ids.extend(wanted_per_image.iter().flatten());
    ids.sort_unstable();
    ids.dedup();
    // Scoring reads the models_info.json entry (diameter, symmetries) of each object the
    // ground truth names, when the file is there: one missing is said now, not after every
    // detection.
    if !args.no_score && dataset.has_models_info() {
        for &id in &named {
            dataset.model_info(id)?;
        }
    }
    // Parameters before models: a mistyped name fails at once, not after the builds.
    let mut params = ppfd_models::detect::detector::DetectParams::new();
    for kv in &args.set {
        params.set_from(kv)?;
    }
    params.check()?;
    // Refuse an unwritable results file now rather than after the detections, without
    // truncating one that is there: it keeps what it had until the results are written, and a
    // file made only to try is removed at once, so that a run stopped on the way (Ctrl-C)
    // leaves no empty results file, which would score as a detector that found nothing.
    let existed = args.out.exists();
    std::fs::OpenOptions::new()
        .append(true)
        .create(true)
        .open(&args.out)
        .map_err(|e| format!("{}: {e}", args.out.display()))?;
    if !existed {
        let _ = std::fs::remove_file(&args.out);
    }
    let models = dataset_models(&dataset, &ids)?;
    // A models_info.json diameter that is not its mesh's would misjudge every pose of the
    // object: said now, not after the detections.
    if !args.no_score {
        for model in &models {
            let id = model.object_id();
            let path = dataset.model_path(id)?;
            ppfd_bop::eval::score::check_diameter(&dataset, id, model.diameter_mm(), &path)?;
        }
    }
    let detector = Detector::new(params);
    let opts = RunOptions {
        hypotheses_per_object: args.hypotheses as usize,
        ..Default::default()
    };
    let bar = ProgressBar::new(images.len() as u64);
    bar.set_style(
        ProgressStyle::with_template(
            "detect {bar:30} {pos}/{len} images [{elapsed} < {eta}] {msg}",
        )
        .unwrap(),
    );
    let mut rows = Vec::new();
    let mut failed = Vec::new();
    let mut images_detected = 0usize;
    for (&(scene, im), wanted) in images.iter().zip(&wanted_per_image) {
        let refs: Vec<_> = models
            .iter()
            .filter(|m| wanted.contains(&m.object_id()))
            .collect();
        if refs.is_empty() {
            bar.inc(1);
            continue;
        }
        // The time is the detection's alone, without reading the image.
        let mut time_s = 0.0;
        let detected = dataset
            .depth_frame(scene, im)
            .map_err(|e| e.to_string())
            .and_then(|frame| {
                let t = Instant::now();
                let det = detector.detect(&frame.view(), &refs, &opts);
                time_s = t.elapsed().as_secs_f32();
                det.map_err(|e| e.to_string())
            });
        let det = match detected {
            Ok(det) => det,
            Err(e) => {
                // One frame that does not read or holds no depth to detect in costs its own
                // targets, not the images after it: they are detected, scored, and the failed
                // ones named at the end.
                bar.suspend(|| eprintln!("scene {scene} image {im}: {e}"));
                failed.push(format!("scene {scene} image {im}: {e}"));
                bar.inc(1);
                continue;
            }
        };
        images_detected += 1;
        for o in &det.objects {
            for h in &o.hypotheses {
                rows.push(EstimateRow {
                    scene_id: scene,
                    im_id: im,
                    obj_id: o.object_id,
                    score: h.score,
                    pose: h.pose,
                    time_s,
                });
            }
        }
        bar.set_message(format!("{:.2} s/image", time_s));
        bar.inc(1);
    }
    bar.finish_and_clear();
    // When no image could be detected in, the cause is the run's, not one frame's: nothing is
    // written, as an empty results file would score as a detector that found nothing.
    if images_detected == 0 {
        if let Some(first) = failed.first() {
            return Err(format!(
                "no image could be detected in ({} failed; nothing written); the first: {first}",
                failed.len()
            )
            .into());
        }
    }
    write_results_file(&args.out, &rows)?;
    let failed_note = match failed.len() {
        0 => String::new(),
        n => format!(" ({n} failed)"),
    };
    eprintln!(
        "{} estimates for {} images{failed_note} written to {}",
        rows.len(),
        images.len(),
        args.out.display()
    );
    // Said last, after the score, so that a long run's end shows it.
    let failures = || -> Result<(), Box<dyn std::error::Error>> {
        match failed.first() {
            None => Ok(()),
            Some(first) => Err(format!(
                "{} of {} images failed, so they have no estimates and their targets count as missed; the first: {first}",
                failed.len(),
                images.len()
            )
            .into()),
        }
    };
    if args.no_score {
        return failures();
    }
    let defaults = ScoreOptions::default();
    // One scene evaluated is scored against that scene's targets, not the whole dataset's.
    let targets = match args.scene {
        Some(scene) => {
            let all = dataset_targets(&dataset, defaults.visib_gt_min)?;
            Some(all.into_iter().filter(|t| t.scene_id == scene).collect())
        }
        None => None,
    };
    let options = ScoreOptions {
        targets,
        ..defaults
    };
    let report = score_results(&dataset, &rows, &options)?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        let targets = if dataset.test_targets().is_some() {
            "test_targets_bop19.json"
        } else {
            "from the ground truth (visible fraction >= 0.1)"
        };
        print!(
            "{}",
            crate::score::format_report(&args.dataset, &args.out, targets, &report)
        );
    }
    failures()
}
