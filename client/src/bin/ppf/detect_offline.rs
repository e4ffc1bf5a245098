//! `ppf detect --dataset`: run the detector on one frame of a BOP dataset, in this process.

use std::path::PathBuf;

use clap::Args;
use ppfd_models::bop::BopDataset;
use ppfd_models::detector::{DetectOptions, Detector};

use crate::offline::{dataset_models, parse_ids, pose_errors};

#[derive(Args, Debug)]
pub struct DatasetDetectArgs {
    /// A BOP dataset directory (with models/ and test/ or a single scene).
    #[arg(long)]
    pub dataset: PathBuf,
    #[arg(long)]
    pub scene: u32,
    #[arg(long)]
    pub image: u32,
    /// Object ids, comma separated; default: those in the image's ground truth, else all.
    #[arg(long)]
    pub objects: Option<String>,
    /// Hypotheses to print per object.
    #[arg(long, default_value_t = 3)]
    pub top: usize,
}

pub fn run(args: DatasetDetectArgs) -> Result<(), Box<dyn std::error::Error>> {
    let dataset = BopDataset::open(&args.dataset)?;
    let gt = dataset
        .ground_truth(args.scene, args.image)
        .map(|g| g.to_vec())
        .unwrap_or_default();
    let ids = match &args.objects {
        Some(s) => parse_ids(s)?,
        None if !gt.is_empty() => {
            let mut ids: Vec<u32> = gt.iter().map(|g| g.obj_id).collect();
            ids.dedup();
            ids
        }
        None => dataset.object_ids().to_vec(),
    };
    let models = dataset_models(&dataset, &ids)?;
    let frame = dataset.depth_frame(args.scene, args.image)?;
    let detector = Detector::default();
    let refs: Vec<_> = models.iter().collect();
    let opts = DetectOptions {
        hypotheses_per_object: args.top.max(10),
        deadline: None,
    };
    let det = detector.detect(&frame.view(), &refs, &opts)?;
    println!("| object | D (mm) | rank | score | votes | t err (mm) | R err (°) | checks | correct (0.1 D, 15°) within top 10 |");
    println!("|---:|---:|---:|---:|---:|---:|---:|---|---|");
    let mut found = 0;
    for (o, model) in det.objects.iter().zip(&models) {
        let d = model.diameter_mm();
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
                "| {} | {d:.0} | {} | {:.3} | {} | {dt} | {dr} | {flag} |",
                o.object_id,
                rank + 1,
                h.score,
                h.votes
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

/// `rescored,refined,consistent,silhouette` for the bits set.
pub fn checks_text(c: ppfd_models::detector::Checks) -> String {
    use ppfd_models::detector::Checks;
    let names = [
        (Checks::RESCORED, "R"),
        (Checks::REFINED, "I"),
        (Checks::CONSISTENT, "C"),
        (Checks::SILHOUETTE, "S"),
    ];
    names
        .iter()
        .filter(|(b, _)| c.has(*b))
        .map(|(_, n)| *n)
        .collect::<Vec<_>>()
        .join("")
}
