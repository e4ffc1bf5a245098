//! `ppf profile`: time the detector's stages on one dataset frame, per object, over repeated
//! runs, and print medians (release build for real figures). With `--hints-from-truth`, time
//! detections from the image's ground-truth poses as hints against detections from scratch.

use std::path::PathBuf;
use std::time::Duration;

use clap::Args;
use ppfd_bop::dataset::BopDataset;
use ppfd_models::detect::detector::{
    Checks, DetectParams, Detector, Hint, RunOptions, StageTimings,
};

use crate::common::median;
use crate::offline::dataset_models;

#[derive(Args, Debug)]
pub struct ProfileArgs {
    /// A BOP dataset directory.
    #[arg(long)]
    pub dataset: PathBuf,
    /// Scene id in the dataset.
    #[arg(long)]
    pub scene: u32,
    /// Image id in the scene.
    #[arg(long)]
    pub image: u32,
    /// Object ids (comma separated); default: the image's ground truth.
    #[arg(long, value_delimiter = ',', value_parser = crate::common::object_id)]
    pub objects: Vec<u32>,
    /// Runs (at least 1); the table shows medians.
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u32).range(1..))]
    pub repeat: u32,
    /// Override a detector parameter, `stage.field=value` (as `ppf detect --set`); repeatable.
    #[arg(long = "set", value_name = "STAGE.FIELD=VALUE")]
    pub set: Vec<String>,
    /// Instead of the stage table: each run detects from scratch, then with the image's
    /// ground-truth poses as hints; prints the medians of both and their ratio.
    #[arg(long)]
    pub hints_from_truth: bool,
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

pub fn run(args: ProfileArgs) -> Result<(), Box<dyn std::error::Error>> {
    let dataset = BopDataset::open(&args.dataset)?;
    let ids = if args.objects.is_empty() {
        crate::common::distinct(
            dataset
                .ground_truth(args.scene, args.image)?
                .iter()
                .map(|g| g.obj_id),
        )
    } else {
        if let Some(id) = crate::common::repeated(&args.objects) {
            return Err(format!("--objects lists object {id} twice").into());
        }
        args.objects.clone()
    };
    // Parameters before models: a mistyped name fails at once, not after the builds.
    let mut params = DetectParams::new();
    for kv in &args.set {
        params.set_from(kv)?;
    }
    params.check()?;
    let models = dataset_models(&dataset, &ids)?;
    let refs: Vec<_> = models.iter().collect();
    let frame = dataset.depth_frame(args.scene, args.image)?;
    let detector = Detector::new(params);
    let opts = RunOptions {
        hypotheses_per_object: 1,
        ..Default::default()
    };
    let repeat = args.repeat;
    if args.hints_from_truth {
        let hints: Vec<Hint> = dataset
            .ground_truth(args.scene, args.image)?
            .iter()
            .filter(|g| ids.contains(&g.obj_id))
            .map(|g| Hint {
                object_id: g.obj_id,
                pose: g.pose,
            })
            .collect();
        return compare_hinted(&detector, &frame.view(), &refs, hints, repeat);
    }
    let mut per_object: Vec<Vec<StageTimings>> = vec![Vec::new(); refs.len()];
    let mut frame_runs = Vec::new();
    // The same frame and parameters give the same counts every run: the last run's are shown.
    let mut counts = Vec::new();
    for _ in 0..repeat {
        let det = detector.detect(&frame.view(), &refs, &opts)?;
        for (i, t) in det.per_object_timings.iter().enumerate() {
            per_object[i].push(*t);
        }
        frame_runs.push((det.timings, det.elapsed));
        counts = det.per_object_counts;
    }
    let side_by_side = if rayon::current_num_threads() > 1 {
        "Objects run side by side: an object's times include waiting for the cores the others \
         hold, and the frame's wall time is below the sum of the objects'"
    } else {
        "One thread: the objects run one after another, and the frame's wall time adds the \
         scene's preparation and clouds to the objects'"
    };
    println!("medians of {repeat} runs, ms; what voting did (the same every run). {side_by_side}");
    println!("| object | voting | clustering | voting + clustering | re-scoring | ICP | filters | object total | cloud points | reference points | pairs | votes | ns per vote |");
    println!("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for ((m, runs), c) in models.iter().zip(&per_object).zip(&counts) {
        let col =
            |f: &dyn Fn(&StageTimings) -> Duration| median(runs.iter().map(|t| ms(f(t))).collect());
        let voting = col(&|t| t.voting);
        println!(
            "| {} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {} | {} | {:.2} M | {:.1} M | {:.1} |",
            m.object_id(),
            voting,
            col(&|t| t.clustering),
            col(&|t| t.voting + t.clustering),
            col(&|t| t.rescoring),
            col(&|t| t.icp),
            col(&|t| t.filters),
            col(&|t| t.total()),
            c.scene_points,
            c.reference_points,
            c.pairs as f64 / 1e6,
            c.votes as f64 / 1e6,
            // Wall time over votes, the pairs' features and look-ups included; with the other
            // objects running beside it, about twice the time on cores of its own.
            voting * 1e6 / (c.votes.max(1) as f64),
        );
    }
    let col = |f: &dyn Fn(&(StageTimings, Duration)) -> Duration| {
        median(frame_runs.iter().map(|t| ms(f(t))).collect())
    };
    println!(
        "\nwhole frame ({} objects): scene preparation {:.1}, kd-trees {:.1}, wall time {:.1} ms",
        refs.len(),
        col(&|t| t.0.scene_preparation),
        col(&|t| t.0.kd_tree),
        col(&|t| t.1)
    );
    Ok(())
}

/// Detections from scratch and from `hints`, alternately `repeat` times each (so that a busy
/// machine slows both alike): their medians, their ratio, and how many objects the hinted runs
/// answered from their hints.
fn compare_hinted(
    detector: &Detector,
    frame: &ppfd_models::geometry::camera::DepthFrame,
    models: &[&ppfd_models::model::ObjectModel],
    hints: Vec<Hint>,
    repeat: u32,
) -> Result<(), Box<dyn std::error::Error>> {
    let scratch = RunOptions {
        hypotheses_per_object: 1,
        ..Default::default()
    };
    let hinted = RunOptions {
        hints,
        ..scratch.clone()
    };
    let (mut from_scratch, mut from_hints) = (Vec::new(), Vec::new());
    let mut last = None;
    for _ in 0..repeat {
        let t = std::time::Instant::now();
        detector.detect(frame, models, &scratch)?;
        from_scratch.push(ms(t.elapsed()));
        let t = std::time::Instant::now();
        last = Some(detector.detect(frame, models, &hinted)?);
        from_hints.push(ms(t.elapsed()));
    }
    // The same frame and hints give the same answers every run: the last run's are shown.
    let det = last.ok_or("no run")?;
    let mut answered = 0;
    for o in &det.objects {
        let from_hint = o
            .hypotheses
            .first()
            .is_some_and(|h| h.checks.has(Checks::HINT));
        answered += usize::from(from_hint);
        let best = o.hypotheses.first().map_or("no pose".to_owned(), |h| {
            format!(
                "score {:.3}, checks {}",
                h.score,
                crate::common::checks_letters(h.checks.0)
            )
        });
        let how = if from_hint { "from its hint" } else { "voted" };
        println!("object {}: {how}, {best}", o.object_id);
    }
    let (a, b) = (median(from_scratch), median(from_hints));
    println!(
        "{} objects, medians of {repeat} alternating runs: from scratch {a:.1} ms, from the \
         ground-truth poses as hints {b:.1} ms ({answered} answered from their hints): {:.1}x",
        models.len(),
        a / b
    );
    Ok(())
}
