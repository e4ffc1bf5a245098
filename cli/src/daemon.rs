//! `ppf models` and `ppf stats`: the daemon's control requests.

use std::path::{Path, PathBuf};
use std::time::Duration;

use clap::Args;
use ppfd_client::DaemonStats;

use crate::common::{ms, Connect};

#[derive(Args, Debug)]
pub struct ModelsArgs {
    /// Load a model file (`.ppfm`) or build one from a PLY mesh; a relative path is taken
    /// from the current folder (the daemon is sent the absolute path).
    #[arg(long)]
    pub load: Option<PathBuf>,
    /// Object id for `--load`; without it, the id the file gives (a `.ppfm` file's own, or the
    /// digits ending a PLY file's name).
    #[arg(long, requires = "load", value_parser = clap::value_parser!(u32).range(1..))]
    pub id: Option<u32>,
    /// Drop the model with this object id (not with `--load`: one change per call).
    #[arg(long, conflicts_with = "load")]
    pub drop: Option<u32>,
    /// Give up waiting for the daemon's answer after this long, milliseconds (building a model
    /// from a mesh of millions of faces takes a while; a daemon that dies is noticed at once).
    #[arg(long, default_value_t = 600_000, value_parser = clap::value_parser!(u64).range(1..))]
    pub timeout_ms: u64,
    #[command(flatten)]
    pub connect: Connect,
}

pub fn models(args: ModelsArgs) -> Result<(), String> {
    let client = args
        .connect
        .control_client(Duration::from_millis(args.timeout_ms))?;
    if let Some(path) = &args.load {
        let path = absolute_path(path)?;
        let before = client.models().map_err(|e| e.to_string())?;
        let m = client
            .load_model(&path, args.id.unwrap_or(0))
            .map_err(|e| match e {
                // Whatever the daemon says, the message names the file.
                ppfd_client::Error::Refused { ref message, .. } if message.contains(&path) => {
                    e.to_string()
                }
                e => format!("{path}: {e}"),
            })?;
        let replaced = before.iter().any(|b| b.object_id == m.object_id);
        println!(
            "{} object {} ({}): {} points, {} bytes",
            if replaced { "replaced" } else { "loaded" },
            m.object_id,
            m.name(),
            m.point_count,
            m.byte_size
        );
    }
    if let Some(id) = args.drop {
        client.drop_model(id).map_err(|e| e.to_string())?;
        println!("dropped object {id}");
    }
    let listing = client.model_listing().map_err(|e| e.to_string())?;
    let models = &listing.models;
    println!(
        "{:>6}  {:<24} {:>8} {:>12} {:>12} {:>10}  symmetry",
        "object", "name", "points", "table", "bytes", "diameter"
    );
    for m in models {
        println!(
            "{:>6}  {:<24} {:>8} {:>12} {:>12} {:>8.1}mm  {}",
            m.object_id,
            m.name(),
            m.point_count,
            m.table_entries,
            m.byte_size,
            m.diameter_mm,
            symmetry_text(m)
        );
    }
    println!("{}", count_line(&listing));
    Ok(())
}

/// A model's symmetry in a few words: "none"; "2-fold" for two poses that look alike (its
/// discrete symmetries and the identity); "axis" for any turn about one; "axis, 2-fold".
fn symmetry_text(m: &ppfd_client::ModelInfo) -> String {
    let fold = (m.discrete_symmetries > 0)
        .then(|| format!("{}-fold", u32::from(m.discrete_symmetries) + 1));
    match (m.continuous_symmetry != 0, fold) {
        (false, None) => "none".into(),
        (false, Some(fold)) => fold,
        (true, None) => "axis".into(),
        (true, Some(fold)) => format!("axis, {fold}"),
    }
}

/// The closing line of `ppf models`: how many models, and that the list is cut short when the
/// daemon holds more than a listing carries.
fn count_line(listing: &ppfd_client::ModelListing) -> String {
    if listing.is_partial() {
        format!(
            "{} models, the {} of lowest id listed (a listing holds at most {})",
            listing.loaded,
            listing.models.len(),
            ppfd_client::protocol::services::limits::MAX_LISTED_MODELS
        )
    } else {
        format!("{} models", listing.loaded)
    }
}

/// `path` from the current folder, as text for the request: the daemon runs in a folder of
/// its own, where a relative path would name another file or none.
fn absolute_path(path: &Path) -> Result<String, String> {
    let absolute =
        std::path::absolute(path).map_err(|e| format!("--load {}: {e}", path.display()))?;
    absolute.to_str().map(str::to_owned).ok_or_else(|| {
        format!(
            "--load {}: the path is not UTF-8, which a request to the daemon cannot carry",
            absolute.display()
        )
    })
}

#[derive(Args, Debug)]
pub struct StatsArgs {
    /// Print as JSON.
    #[arg(long)]
    pub json: bool,
    /// Give up waiting for the daemon's answer after this long, milliseconds (a daemon answers
    /// from its start, also while it loads the models it starts with).
    #[arg(long, default_value_t = 5_000, value_parser = clap::value_parser!(u64).range(1..))]
    pub timeout_ms: u64,
    #[command(flatten)]
    pub connect: Connect,
}

pub fn stats(args: StatsArgs) -> Result<(), String> {
    let client = args
        .connect
        .control_client(Duration::from_millis(args.timeout_ms))?;
    let (s, message) = client.statistics().map_err(|e| e.to_string())?;
    let detector = message.strip_prefix("detector:").unwrap_or(&message).trim();
    if args.json {
        let mut json = stats_json(&s);
        json["detector"] = detector.into();
        println!(
            "{}",
            serde_json::to_string_pretty(&json).map_err(|e| e.to_string())?
        );
        return Ok(());
    }
    println!("uptime            {:.1} s", s.uptime_ns as f64 / 1e9);
    println!("detector          {detector}");
    println!(
        "requests          {} received, {} served, {} refused ({} past deadline), {} abandoned",
        s.requests_received,
        s.requests_served,
        s.requests_refused,
        s.requests_expired,
        s.requests_abandoned
    );
    // The daemon takes a camera's frames when it needs one (a request, or its housekeeping
    // round) and keeps the newest; frames published in between are skipped, not lost work.
    println!(
        "frames received   {} (taken when needed; frames a newer one replaced before then are \
         not counted)",
        s.frames_received
    );
    println!(
        "cameras           {} subscribed (one without a driver is forgotten after a while)",
        s.cameras
    );
    println!(
        "models            {} ({:.1} MB)",
        s.models_loaded,
        s.model_bytes as f64 / 1e6
    );
    let files = |n: u64| format!("{n} file{}", if n == 1 { "" } else { "s" });
    if s.startup_files_done < s.startup_files {
        println!(
            "loading           {} of {} of the models folder done; detections wait until every model is loaded",
            s.startup_files_done,
            files(s.startup_files)
        );
    }
    if s.startup_files_failed > 0 {
        println!(
            "failed at start   {} of the models folder (the log names each)",
            files(s.startup_files_failed)
        );
    }
    if s.model_loads_running + s.model_loads_waiting > 0 {
        println!(
            "model loads       {} running, {} waiting",
            s.model_loads_running, s.model_loads_waiting
        );
    }
    println!("resident memory   {:.1} MB", s.resident_bytes as f64 / 1e6);
    println!(
        "now               {} running, {} queued",
        s.in_flight, s.queued
    );
    let window = format!("last {:.0} s", s.recent_window_ns as f64 / 1e9);
    // The daemon's side only: from the client's send to the response sent. A client's end to
    // end adds the response's way back (`ppf detect` and `ppf bench` print it).
    for (span, [total, overhead, detection]) in [
        ("since start", [&s.total, &s.overhead, &s.detection]),
        (
            window.as_str(),
            [&s.recent_total, &s.recent_overhead, &s.recent_detection],
        ),
    ] {
        println!(
            "latency (ms), {span:<12} {:>8} {:>8} {:>8} {:>8} {:>8}",
            "count", "p50", "p90", "p99", "max"
        );
        for (name, l) in [
            ("send → answered", total),
            ("transport+queue", overhead),
            ("detection", detection),
        ] {
            // Without samples there are no percentiles: a dash, not a latency of 0.
            let at = |ns: u64| {
                if l.count == 0 {
                    "–".to_owned()
                } else {
                    ms(ns)
                }
            };
            println!(
                "  {name:<24} {:>8} {:>8} {:>8} {:>8} {:>8}",
                l.count,
                at(l.p50_ns),
                at(l.p90_ns),
                at(l.p99_ns),
                at(l.max_ns)
            );
        }
    }
    Ok(())
}

fn stats_json(s: &DaemonStats) -> serde_json::Value {
    let l = |l: &ppfd_client::protocol::control::LatencySummary| serde_json::json!({"count": l.count, "p50_ns": l.p50_ns, "p90_ns": l.p90_ns, "p99_ns": l.p99_ns, "max_ns": l.max_ns});
    serde_json::json!({
        "uptime_ns": s.uptime_ns, "requests_received": s.requests_received, "requests_served": s.requests_served,
        "requests_refused": s.requests_refused, "requests_expired": s.requests_expired,
        "requests_abandoned": s.requests_abandoned, "frames_received": s.frames_received, "cameras": s.cameras,
        "models_loaded": s.models_loaded, "model_bytes": s.model_bytes, "resident_bytes": s.resident_bytes,
        "in_flight": s.in_flight, "queued": s.queued,
        "startup_files": s.startup_files, "startup_files_done": s.startup_files_done,
        "startup_files_failed": s.startup_files_failed,
        "model_loads_running": s.model_loads_running, "model_loads_waiting": s.model_loads_waiting,
        "total": l(&s.total), "overhead": l(&s.overhead), "detection": l(&s.detection),
        "recent_window_ns": s.recent_window_ns, "recent_total": l(&s.recent_total),
        "recent_overhead": l(&s.recent_overhead), "recent_detection": l(&s.recent_detection),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use ppfd_client::{ModelInfo, ModelListing};

    #[test]
    fn symmetries_read_in_words() {
        let with = |discrete_symmetries, continuous_symmetry| {
            symmetry_text(&ModelInfo {
                discrete_symmetries,
                continuous_symmetry,
                ..ModelInfo::default()
            })
        };
        assert_eq!(with(0, 0), "none");
        assert_eq!(with(1, 0), "2-fold");
        assert_eq!(with(3, 0), "4-fold");
        assert_eq!(with(0, 1), "axis");
        assert_eq!(with(1, 1), "axis, 2-fold");
        assert_eq!(with(u16::MAX, 0), "65536-fold");
    }

    #[test]
    fn a_listing_cut_short_says_how_many_are_loaded() {
        let listing = |listed: usize, loaded: usize| ModelListing {
            models: vec![ModelInfo::default(); listed],
            loaded,
        };
        assert_eq!(count_line(&listing(3, 3)), "3 models");
        assert_eq!(
            count_line(&listing(256, 300)),
            "300 models, the 256 of lowest id listed (a listing holds at most 256)"
        );
    }
}
