//! What the subcommands share: connecting to the daemon, printing latency tables, scratch
//! folders.

use std::path::{Path, PathBuf};
use std::time::Duration;

use clap::Args;
use ppfd_client::{Client, ClientOptions, Detections, LatencyBreakdown};

/// How to reach the daemon.
#[derive(Args, Debug, Clone)]
pub struct Connect {
    /// iceoryx2 prefix of the daemon, ending with '_' (as `ppfd --prefix`; default from
    /// PPFD_PREFIX).
    #[arg(long, value_parser = parse_prefix)]
    pub prefix: Option<String>,
}

/// A prefix `ppfd` would take, refused as a usage error otherwise.
fn parse_prefix(s: &str) -> Result<String, String> {
    ppfd_client::protocol::services::check_prefix(s).map_err(|e| e.to_string())?;
    Ok(s.to_owned())
}

/// An object id as `--objects` takes it: a whole number from 1 (BOP's ids start at 1, and the
/// protocol keeps 0 for none).
pub fn object_id(s: &str) -> Result<u32, String> {
    match s.parse::<u32>() {
        Ok(0) => Err("object ids start at 1".into()),
        Ok(id) => Ok(id),
        Err(e) => Err(format!("not an object id: {e}")),
    }
}

/// Writes `files` so that a failure while writing (a full disk) leaves none of them: each goes
/// to a temporary file beside it first, and only once every one is written are they renamed
/// into place. A failure removes the temporary files; no half-written file is left.
pub fn write_all(files: &[(PathBuf, Vec<u8>)]) -> Result<(), String> {
    let temporary = |path: &Path| {
        let mut name = path.file_name().unwrap_or_default().to_os_string();
        name.push(format!(".partial-{}", std::process::id()));
        path.with_file_name(name)
    };
    let mut written: Vec<PathBuf> = Vec::with_capacity(files.len());
    let outcome = files.iter().try_for_each(|(path, bytes)| {
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir)
                .map_err(|e| format!("cannot create {}: {e}", dir.display()))?;
        }
        let partial = temporary(path);
        written.push(partial.clone());
        std::fs::write(&partial, bytes).map_err(|e| format!("cannot write {}: {e}", path.display()))
    });
    let outcome = outcome.and_then(|()| {
        files.iter().try_for_each(|(path, _)| {
            std::fs::rename(temporary(path), path)
                .map_err(|e| format!("cannot write {}: {e}", path.display()))
        })
    });
    if outcome.is_err() {
        for partial in &written {
            let _ = std::fs::remove_file(partial);
        }
    }
    outcome
}

/// A camera name as `--camera` takes it: one the protocol allows, else a usage error.
pub fn camera_name(s: &str) -> Result<String, String> {
    ppfd_client::protocol::services::check_camera_name(s).map_err(|e| e.to_string())?;
    Ok(s.to_owned())
}

/// Each id once, in the order of its first appearance: an image's ground truth lists an object
/// once per instance, not always side by side, and an object is detected (or timed) once.
pub fn distinct(ids: impl Iterator<Item = u32>) -> Vec<u32> {
    let mut seen = std::collections::BTreeSet::new();
    ids.filter(|id| seen.insert(*id)).collect()
}

/// The first object id that `ids` lists a second time.
pub fn repeated(ids: &[u32]) -> Option<u32> {
    (1..ids.len()).find_map(|i| ids[..i].contains(&ids[i]).then_some(ids[i]))
}

impl Connect {
    /// The prefix given, else the one of PPFD_PREFIX; a value of the variable that `ppfd` would
    /// refuse is refused with the variable's name, as `ppfd` refuses it.
    pub fn prefix(&self) -> Result<Option<String>, String> {
        ppfd_client::protocol::services::prefix_or_env(self.prefix.as_deref())
            .map_err(|e| e.to_string())
    }

    /// A client that detects.
    pub fn client(&self) -> Result<Client, String> {
        self.connect(ClientOptions::default())
    }

    /// A client for control requests only (`ppf stats`, `ppf models`), which wait up to
    /// `control_timeout` for their answers: without a detect port, it connects while the daemon
    /// serves its most robot clients.
    pub fn control_client(&self, control_timeout: Duration) -> Result<Client, String> {
        self.connect(ClientOptions {
            control_timeout,
            detects: false,
            ..Default::default()
        })
    }

    /// Connects with `options` under this command's prefix.
    fn connect(&self, options: ClientOptions) -> Result<Client, String> {
        let options = ClientOptions {
            prefix: self.prefix()?,
            ..options
        };
        Client::connect_with(&options).map_err(|e| e.to_string())
    }
}

/// One stage of a breakdown: its name in tables, its key in `ppf bench --json` (the protocol's
/// field name without `_ns`, which `ppf detect --json` and Python's `latency` keep) and its
/// time, ns.
pub struct Stage {
    pub label: &'static str,
    pub key: &'static str,
    pub ns: u64,
}

/// The stages of a breakdown in pipeline order ([`LatencyBreakdown::stages`]), labelled for
/// tables.
pub fn stages(l: &LatencyBreakdown) -> [Stage; 9] {
    l.stages().map(|(key, ns)| Stage {
        label: match key {
            "queue_wait" => "queue wait",
            "scene_preparation" => "scene preparation",
            "kd_tree" => "kd-tree",
            "rescoring" => "re-scoring",
            "icp" => "ICP",
            other => other,
        },
        key,
        ns,
    })
}

pub fn ms(ns: u64) -> String {
    format!("{:.3}", ns as f64 / 1e6)
}

/// Prints one request's latency breakdown.
pub fn print_latency(d: &Detections) {
    println!("latency (ms; the scene and kd-trees once per request, the later stages summed over the objects, which run side by side, so they can add up to more than the detection):");
    for Stage { label, ns, .. } in stages(&d.latency.daemon) {
        println!("  {label:<18} {:>10}", ms(ns));
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

/// Prints the hypotheses as a table: per object asked for (`objects`, in the request's order)
/// its poses best first, or a line saying it has none.
pub fn print_hypotheses(d: &Detections, objects: &[u32]) {
    for line in hypothesis_table(d, objects) {
        println!("{line}");
    }
}

/// The lines of [`print_hypotheses`].
fn hypothesis_table(d: &Detections, objects: &[u32]) -> Vec<String> {
    let mut lines = vec![format!(
        "{:>6} {:>4} {:>7} {:>6} {:>6}  {:<28} rotation (row-major)",
        "object", "rank", "score", "votes", "checks", "translation (mm)"
    )];
    for &id in objects {
        let mut poses = d.of(id).peekable();
        if poses.peek().is_none() {
            lines.push(format!("{id:>6} {:>4} (no hypothesis)", "-"));
        }
        for h in poses {
            let t = h.translation_mm;
            let r = h.rotation;
            lines.push(format!(
                "{:>6} {:>4} {:>7.3} {:>6} {:>6}  {:<28} [{:.3} {:.3} {:.3}; {:.3} {:.3} {:.3}; {:.3} {:.3} {:.3}]",
                h.object_id,
                h.instance_rank + 1,
                h.score,
                h.votes,
                checks_letters(h.checks),
                format!("{:.1} {:.1} {:.1}", t[0], t[1], t[2]),
                r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8]
            ));
        }
    }
    lines
}

/// The checks a hypothesis passed as `ppf detect --dataset` shows them: R re-scored, I refined
/// by ICP, C consistent, S silhouette on the scene's edges, H from a hint (not voted for).
pub fn checks_letters(bits: u32) -> String {
    use ppfd_client::protocol::detect::checks;
    [
        (checks::RESCORED, 'R'),
        (checks::REFINED, 'I'),
        (checks::CONSISTENT, 'C'),
        (checks::SILHOUETTE, 'S'),
        (checks::HINT, 'H'),
    ]
    .iter()
    .filter(|(bit, _)| bits & bit != 0)
    .map(|(_, letter)| *letter)
    .collect()
}

pub fn millis(ms: u64) -> Duration {
    Duration::from_millis(ms)
}

/// Detects as [`Client::detect`] does, but a camera without a frame yet ("no frame yet": the
/// daemon has just subscribed to it, and its driver's next frame is on the way) is asked again
/// until it has one, within the request's timeout.
pub fn detect_once_framed(
    client: &Client,
    camera: &str,
    objects: &[u32],
    options: &ppfd_client::DetectOptions,
) -> ppfd_client::Result<Detections> {
    until_framed(options.timeout, |left| {
        let options = ppfd_client::DetectOptions {
            timeout: left,
            ..options.clone()
        };
        client.detect(camera, objects, &options)
    })
}

/// Calls `detect` with the time left of `timeout` until its answer is other than "no frame
/// yet" or the time is up: the whole wait, the last request's included, stays within `timeout`.
fn until_framed<T>(
    timeout: Duration,
    mut detect: impl FnMut(Duration) -> ppfd_client::Result<T>,
) -> ppfd_client::Result<T> {
    let deadline = std::time::Instant::now() + timeout;
    loop {
        // At least a millisecond: a timeout of 0 is refused as malformed.
        let left = deadline
            .saturating_duration_since(std::time::Instant::now())
            .max(millis(1));
        match detect(left) {
            Err(ppfd_client::Error::Refused {
                status: ppfd_client::Status::NoFrame,
                ..
            }) if std::time::Instant::now() < deadline => std::thread::sleep(millis(20)),
            // The timeout the user gave, not what was left of it for the last try.
            Err(ppfd_client::Error::Timeout(_)) => {
                return Err(ppfd_client::Error::Timeout(timeout));
            }
            found => return found,
        }
    }
}

/// The median: the middle value, or the mean of the two middle ones; `v` is not empty.
pub fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    (v[(n - 1) / 2] + v[n / 2]) / 2.0
}

/// The median of `durations` in milliseconds.
pub fn median_ms(durations: &[Duration]) -> f64 {
    median(durations.iter().map(|d| d.as_secs_f64() * 1e3).collect())
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
        let dir = ScratchDir::path_of(name);
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir(&dir).map_err(|e| format!("cannot create {}: {e}", dir.display()))?;
        Ok(ScratchDir(dir))
    }

    /// Where [`ScratchDir::create`] puts the folder `name` of this process.
    pub fn path_of(name: &str) -> PathBuf {
        std::env::temp_dir().join(format!("{name}-{}", std::process::id()))
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

/// Ids as ascending runs: `[1, 2, 3, 5, 7, 8]` → `1-3, 5, 7-8` (a split may have dozens).
fn id_ranges(ids: &[u32]) -> String {
    let mut runs: Vec<(u32, u32)> = Vec::new();
    for &id in ids {
        match runs.last_mut() {
            Some((_, last)) if last.checked_add(1) == Some(id) => *last = id,
            _ => runs.push((id, id)),
        }
    }
    runs.iter()
        .map(|&(a, b)| {
            if a == b {
                a.to_string()
            } else {
                format!("{a}-{b}")
            }
        })
        .collect::<Vec<_>>()
        .join(", ")
}

/// The scenes a dataset has, for a message about one it has not: "the scenes are 1-3, 5".
pub fn scenes_there(scenes: &[u32]) -> String {
    match scenes.len() {
        0 => "there are no scenes".to_owned(),
        1 => format!("the only scene is {}", id_ranges(scenes)),
        _ => format!("the scenes are {}", id_ranges(scenes)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A file that cannot be written leaves none of the others, and no temporary file.
    #[test]
    fn a_failed_write_leaves_nothing() {
        let dir = ScratchDir::create("ppf-generate-write").unwrap();
        let blocked = dir.path().join("blocked");
        std::fs::write(&blocked, "a file where a folder is needed").unwrap();
        let files = vec![
            (dir.path().join("first.json"), b"{}".to_vec()),
            (blocked.join("second.png"), vec![0; 16]),
        ];
        let e = write_all(&files).unwrap_err();
        assert!(e.contains("blocked"), "{e}");
        let mut left: Vec<String> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        left.sort();
        assert_eq!(left, ["blocked"]);
        write_all(&files[..1]).unwrap();
        assert_eq!(std::fs::read(&files[0].0).unwrap(), b"{}");
    }

    #[test]
    fn an_object_of_several_instances_is_taken_once() {
        assert_eq!(distinct([1, 2, 3, 4, 1, 2].into_iter()), [1, 2, 3, 4]);
        assert_eq!(distinct([5, 5, 1].into_iter()), [5, 1]);
        assert_eq!(repeated(&[1, 2, 3, 2]), Some(2));
        assert_eq!(repeated(&[1, 2, 3]), None);
    }

    /// A camera whose first frame comes late: each request after a "no frame yet" is given only
    /// the time left, so the wait ends within the timeout, not a whole timeout after the frame.
    #[test]
    fn the_wait_for_a_first_frame_stays_within_the_timeout() {
        let timeout = millis(300);
        let start = std::time::Instant::now();
        let mut given = Vec::new();
        let found: ppfd_client::Result<()> = until_framed(timeout, |left| {
            given.push(left);
            if start.elapsed() < millis(150) {
                return Err(ppfd_client::Error::Refused {
                    status: ppfd_client::Status::NoFrame,
                    message: "no frame yet".into(),
                    value: 0,
                });
            }
            Ok(())
        });
        assert!(found.is_ok());
        assert!(given.len() >= 2, "{given:?}");
        assert!(
            given[0] <= timeout && given[0] > timeout - millis(100),
            "{given:?}"
        );
        let last = *given.last().unwrap();
        assert!(last <= timeout - millis(150), "{given:?}");
        // Never refused: "no frame yet" ends at the deadline with the last answer.
        let ended = std::time::Instant::now();
        let never = until_framed(millis(100), |left| {
            assert!(left <= millis(100));
            Err::<(), _>(ppfd_client::Error::Refused {
                status: ppfd_client::Status::NoFrame,
                message: "no frame yet".into(),
                value: 0,
            })
        });
        assert!(matches!(never, Err(ppfd_client::Error::Refused { .. })));
        assert!(ended.elapsed() >= millis(100));
        // A timeout after a wait for a frame says the timeout given, in whole milliseconds.
        let mut tries = 0;
        let late = until_framed(millis(2000), |left| {
            tries += 1;
            if tries == 1 {
                std::thread::sleep(millis(30));
                return Err(ppfd_client::Error::Refused {
                    status: ppfd_client::Status::NoFrame,
                    message: "no frame yet".into(),
                    value: 0,
                });
            }
            Err::<(), _>(ppfd_client::Error::Timeout(left))
        })
        .unwrap_err();
        assert!(
            late.to_string()
                .starts_with("no answer from ppfd within 2000 ms: "),
            "{late}"
        );
    }

    #[test]
    fn the_median_of_an_even_count_is_the_mean_of_the_middle_two() {
        assert_eq!(median(vec![3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(vec![10.0, 1.0]), 5.5);
        assert_eq!(median(vec![4.0, 1.0, 3.0, 2.0]), 2.5);
        let ms = Duration::from_millis;
        assert_eq!(median_ms(&[ms(10), ms(2)]), 6.0);
    }
    use ppfd_client::PoseHypothesis;

    fn pose(object_id: u32, instance_rank: u32, score: f32) -> PoseHypothesis {
        PoseHypothesis {
            object_id,
            instance_rank,
            rotation: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            translation_mm: [0.0, 0.0, 800.0],
            score,
            votes: 10,
            checks: 0,
        }
    }

    /// An object the daemon found no pose of gets a line saying so, in its place among the
    /// objects asked for, so that no object goes missing and a detection with no pose at all
    /// still shows a table.
    #[test]
    fn an_object_without_a_pose_is_listed_as_such() {
        let found = Detections {
            request_id: 1,
            hypotheses: vec![pose(5, 0, 0.3), pose(5, 1, 0.2), pose(8, 0, 0.1)],
            latency: Default::default(),
            counts: Default::default(),
            frame_sequence: 1,
            frame_age_ns: 0,
            diagnosis: String::new(),
        };
        let lines = hypothesis_table(&found, &[1, 5, 8, 9]);
        assert_eq!(lines.len(), 1 + 5, "{lines:#?}");
        assert_eq!(lines[1].trim_start(), "1    - (no hypothesis)");
        assert!(
            lines[2].trim_start().starts_with("5    1   0.300"),
            "{}",
            lines[2]
        );
        assert!(
            lines[3].trim_start().starts_with("5    2   0.200"),
            "{}",
            lines[3]
        );
        assert!(
            lines[4].trim_start().starts_with("8    1   0.100"),
            "{}",
            lines[4]
        );
        assert_eq!(lines[5].trim_start(), "9    - (no hypothesis)");

        let none = Detections {
            hypotheses: vec![],
            ..found
        };
        let lines = hypothesis_table(&none, &[1, 5]);
        assert_eq!(
            lines[1..],
            ["     1    - (no hypothesis)", "     5    - (no hypothesis)"]
        );
    }

    #[test]
    fn scene_ids_are_listed_as_runs() {
        assert_eq!(id_ranges(&[]), "");
        assert_eq!(id_ranges(&[2]), "2");
        assert_eq!(id_ranges(&[1, 2, 3, 5, 7, 8]), "1-3, 5, 7-8");
        assert_eq!(id_ranges(&[0, u32::MAX]), format!("0, {}", u32::MAX));
        assert_eq!(scenes_there(&[]), "there are no scenes");
        assert_eq!(scenes_there(&[2]), "the only scene is 2");
        assert_eq!(scenes_there(&[1, 2, 4]), "the scenes are 1-2, 4");
    }
}
