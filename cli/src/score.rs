//! `ppf score`: score a BOP results CSV (from any method) against a BOP dataset and print the
//! benchmark's figures per object and overall.

use std::collections::BTreeSet;
use std::fmt::Write as _;
use std::io::Write as _;
use std::path::PathBuf;

use clap::Args;
use ppfd_bop::dataset::{read_test_targets, BopDataset};
use ppfd_bop::eval::{
    read_results, score_results, targets_from_ground_truth, ObjectScore, ScoreOptions, ScoreReport,
};

#[derive(Args, Debug)]
pub struct ScoreArgs {
    /// BOP dataset root (camera.json, models/, models_eval/, test/…).
    pub dataset: PathBuf,
    /// Results file: `scene_id,im_id,obj_id,score,R,t,time`, one estimate per line.
    pub results: PathBuf,
    /// Print the report as JSON instead of tables.
    #[arg(long)]
    pub json: bool,
    /// Test targets: a file, or a file name in the dataset root. When the default is missing,
    /// every visible-enough object of the ground truth is a target.
    #[arg(long, default_value = "test_targets_bop19.json")]
    pub targets: PathBuf,
    /// Split folder of the dataset (default: `test`).
    #[arg(long)]
    pub split: Option<String>,
    /// Score only the images that have an estimate in the results (for a run over part of a
    /// dataset; the benchmark itself counts every target).
    #[arg(long)]
    pub only_result_images: bool,
}

pub fn run(args: ScoreArgs) -> Result<(), Box<dyn std::error::Error>> {
    let dataset = match &args.split {
        Some(split) => BopDataset::open_split(&args.dataset, split)?,
        None => BopDataset::open(&args.dataset)?,
    };
    let targets_path = if args.targets.is_file() {
        Some(args.targets.clone())
    } else {
        let in_root = args.dataset.join(&args.targets);
        if in_root.is_file() {
            Some(in_root)
        } else if args.targets.as_os_str() == "test_targets_bop19.json" {
            None
        } else {
            return Err(format!("targets file {} not found", args.targets.display()).into());
        }
    };
    let rows = read_results(&args.results)?;
    let mut targets = match &targets_path {
        Some(path) => Some(read_test_targets(path)?),
        None => None,
    };
    if args.only_result_images {
        let images: BTreeSet<(u32, u32)> = rows.iter().map(|r| (r.scene_id, r.im_id)).collect();
        let all = match targets {
            Some(t) => t,
            None => targets_from_ground_truth(&dataset, ScoreOptions::default().visib_gt_min)?,
        };
        targets = Some(
            all.into_iter()
                .filter(|t| images.contains(&(t.scene_id, t.im_id)))
                .collect(),
        );
    }
    let options = ScoreOptions {
        targets,
        ..ScoreOptions::default()
    };
    let report = score_results(&dataset, &rows, &options)?;
    let text = if args.json {
        serde_json::to_string_pretty(&report)? + "\n"
    } else {
        let targets = if targets_path.is_none() {
            "from the ground truth (visible fraction >= 0.1)".to_string()
        } else {
            args.targets.display().to_string()
        };
        format_report(&args.dataset, &args.results, &targets, &report)
    };
    let mut stdout = std::io::stdout().lock();
    match stdout
        .write_all(text.as_bytes())
        .and_then(|_| stdout.flush())
    {
        // A reader that stops early (`| head`) is not an error.
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
        other => Ok(other?),
    }
}

/// `report` as tables; `targets` says where the targets came from.
pub fn format_report(
    dataset: &std::path::Path,
    results: &std::path::Path,
    targets: &str,
    report: &ScoreReport,
) -> String {
    let mut out = String::new();
    let _ = writeln!(out, "dataset  {}", dataset.display());
    let _ = writeln!(out, "results  {}", results.display());
    let skipped = match (report.skipped_targets, &report.first_missing_depth) {
        (0, _) => "none skipped".to_string(),
        (n, Some(first)) => {
            format!("{n} skipped (their images have no depth here; the first would be {first})")
        }
        (n, None) => format!("{n} skipped (their images have no depth here)"),
    };
    let _ = writeln!(
        out,
        "targets  {targets}: {} scored in {} images, {skipped}",
        report.overall.targets, report.images
    );
    let _ = writeln!(
        out,
        "estimates  {} read, {} scored, {} ignored (no target, or beyond inst_count)",
        report.estimates_read, report.overall.estimates, report.estimates_ignored
    );
    let time = |t: Option<f64>| t.map_or("-".to_string(), |s| format!("{s:.3} s"));
    let _ = writeln!(
        out,
        "time  {} per image, {} per target",
        time(report.mean_time_per_image_s),
        time(report.mean_time_per_target_s)
    );
    for note in &report.notes {
        let _ = writeln!(out, "note  {note}");
    }
    out.push('\n');
    let [a, b] = [0, 1].map(|i| {
        report
            .bop18_thresholds
            .get(i)
            .map_or("-".to_string(), |t| format!("VSD<{t}"))
    });
    let _ = writeln!(
        out,
        "| object | targets | GT | estimates | {a} | {b} | AR | AR_VSD | AR_MSSD | AR_MSPD |"
    );
    let _ = writeln!(out, "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for row in report
        .objects
        .iter()
        .chain(std::iter::once(&report.overall))
    {
        format_row(&mut out, row);
    }
    out.push('\n');
    let _ = writeln!(out, "| visible fraction | GT | {a} | {b} |");
    let _ = writeln!(out, "|---|---:|---:|---:|");
    for bin in &report.visib_bins {
        let recall = |i: usize| {
            bin.recall_bop18
                .get(i)
                .map_or("-".to_string(), |r| format!("{r:.3}"))
        };
        let _ = writeln!(
            out,
            "| {:.1}–{:.1} | {} | {} | {} |",
            bin.min,
            bin.max,
            bin.gt_count,
            recall(0),
            recall(1)
        );
    }
    out.push('\n');
    let _ = writeln!(
        out,
        "VSD<θ: BOP 2018 recall (δ 15 mm, τ 20 mm). AR: BOP 2019 average recall \
         = mean(AR_VSD, AR_MSSD, AR_MSPD)."
    );
    out
}

fn format_row(out: &mut String, row: &ObjectScore) {
    let name = row.obj_id.map_or("all".to_string(), |id| format!("{id}"));
    let recall = |i: usize| {
        row.recall_bop18
            .get(i)
            .map_or("-".to_string(), |r| format!("{r:.3}"))
    };
    let _ = writeln!(
        out,
        "| {name} | {} | {} | {} | {} | {} | {:.3} | {:.3} | {:.3} | {:.3} |",
        row.targets,
        row.gt_count,
        row.estimates,
        recall(0),
        recall(1),
        row.ar,
        row.ar_vsd,
        row.ar_mssd,
        row.ar_mspd
    );
}
