//! What the subcommands share: connecting to the daemon, printing latency tables, scratch
//! folders.

use std::path::{Path, PathBuf};
use std::time::Duration;

use clap::Args;
use ppfd_client::{Client, ClientOptions, Detections, LatencyBreakdown};

/// How to reach the daemon.
#[derive(Args, Debug, Clone)]
pub struct Connect {
    /// iceoryx2 prefix of the daemon (as `ppfd --prefix`; default from PPFD_PREFIX).
    #[arg(long)]
    pub prefix: Option<String>,
}

impl Connect {
    pub fn client(&self) -> Result<Client, String> {
        self.client_with(ClientOptions::default().control_timeout)
    }

    /// A client whose control requests wait up to `control_timeout` for their answers.
    pub fn client_with(&self, control_timeout: Duration) -> Result<Client, String> {
        let options = ClientOptions {
            prefix: self.prefix.clone().or_else(ppfd_client::prefix_from_env),
            control_timeout,
            ..Default::default()
        };
        Client::connect_with(&options).map_err(|e| e.to_string())
    }
}

/// The stages of a breakdown, named, in pipeline order (ns).
pub fn stages(l: &LatencyBreakdown) -> [(&'static str, u64); 9] {
    [
        ("transport", l.transport_ns),
        ("queue wait", l.queue_wait_ns),
        ("scene preparation", l.scene_preparation_ns),
        ("kd-tree", l.kd_tree_ns),
        ("voting", l.voting_ns),
        ("clustering", l.clustering_ns),
        ("re-scoring", l.rescoring_ns),
        ("ICP", l.icp_ns),
        ("filters", l.filters_ns),
    ]
}

pub fn ms(ns: u64) -> String {
    format!("{:.3}", ns as f64 / 1e6)
}

/// Prints one request's latency breakdown.
pub fn print_latency(d: &Detections) {
    println!("latency (ms):");
    for (name, ns) in stages(&d.latency.daemon) {
        println!("  {name:<18} {:>10}", ms(ns));
    }
    println!(
        "  {:<18} {:>10}",
        "detection",
        ms(d.latency.daemon.detection_ns)
    );
    println!("  {:<18} {:>10}", "hand-back", ms(d.latency.hand_back_ns()));
    println!(
        "  {:<18} {:>10}",
        "response transport",
        ms(d.latency.response_transport_ns)
    );
    println!("  {:<18} {:>10}", "end to end", ms(d.latency.end_to_end_ns));
    println!("  {:<18} {:>10}", "overhead", ms(d.latency.overhead_ns()));
}

/// Prints hypotheses as a table.
pub fn print_hypotheses(d: &Detections) {
    println!(
        "{:>6} {:>4} {:>7} {:>6} {:>6}  {:<28} rotation (row-major)",
        "object", "rank", "score", "votes", "checks", "translation (mm)"
    );
    for h in &d.hypotheses {
        let t = h.translation_mm;
        let r = h.rotation;
        println!(
            "{:>6} {:>4} {:>7.3} {:>6} {:>6}  {:<28} [{:.3} {:.3} {:.3}; {:.3} {:.3} {:.3}; {:.3} {:.3} {:.3}]",
            h.object_id,
            h.instance_rank + 1,
            h.score,
            h.votes,
            checks_letters(h.checks),
            format!("{:.1} {:.1} {:.1}", t[0], t[1], t[2]),
            r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8]
        );
    }
}

/// The checks a hypothesis passed as `ppf detect --dataset` shows them: R re-scored, I refined
/// by ICP, C consistent, S silhouette on the scene's edges.
pub fn checks_letters(bits: u32) -> String {
    use ppfd_client::protocol::detect::checks;
    [
        (checks::RESCORED, 'R'),
        (checks::REFINED, 'I'),
        (checks::CONSISTENT, 'C'),
        (checks::SILHOUETTE, 'S'),
    ]
    .iter()
    .filter(|(bit, _)| bits & bit != 0)
    .map(|(_, letter)| *letter)
    .collect()
}

pub fn millis(ms: u64) -> Duration {
    Duration::from_millis(ms)
}

/// Hypotheses per object a detect request may ask for: the protocol's limit, as clap ranges take
/// it (`ppf detect --hypotheses`, `ppf demo --hypotheses`).
pub const MAX_HYPOTHESES: i64 = ppfd_client::protocol::MAX_HYPOTHESES_PER_OBJECT as i64;

/// A scratch folder of this process, `<temp>/<name>-<pid>`, removed with all it holds when
/// dropped: on every way out of a command, an error included.
pub struct ScratchDir(PathBuf);

impl ScratchDir {
    /// Creates the folder empty (a leftover of an earlier process with this pid is removed
    /// first). It must be this process's own: one that someone made meanwhile is refused.
    pub fn create(name: &str) -> Result<ScratchDir, String> {
        let dir = std::env::temp_dir().join(format!("{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir(&dir).map_err(|e| format!("cannot create {}: {e}", dir.display()))?;
        Ok(ScratchDir(dir))
    }

    pub fn path(&self) -> &Path {
        &self.0
    }
}

impl Drop for ScratchDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}
