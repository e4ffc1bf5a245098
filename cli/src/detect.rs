//! `ppf detect`: one detect request against a running daemon; prints the poses and the latency
//! breakdown.

use std::path::{Path, PathBuf};

use ppfd_client::{DetectOptions, PoseHint};

use crate::common::{millis, print_hypotheses, print_latency, Connect};

/// What `ppf detect --camera` asks for; the flags are parsed with the dataset form of the command
/// ([`crate::detect_offline::DetectCommand`]).
#[derive(Debug)]
pub struct DetectArgs {
    /// Camera whose newest frame to use.
    pub camera: String,
    /// Object ids.
    pub objects: Vec<u32>,
    /// Hypotheses per object.
    pub hypotheses: u32,
    /// Give up after this long, milliseconds.
    pub timeout_ms: u64,
    /// Print the answer as JSON.
    pub json: bool,
    /// A JSON file of poses to refine first.
    pub hints: Option<PathBuf>,
    pub connect: Connect,
}

/// The poses of a hints file: the `hypotheses` of `ppf detect --json` output, or a list of
/// objects with `object_id`, `rotation` (9 numbers, row-major) and `translation_mm` (3).
pub fn read_hints(path: &Path) -> Result<Vec<PoseHint>, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let value: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| format!("{}: not JSON: {e}", path.display()))?;
    let list = value
        .get("hypotheses")
        .unwrap_or(&value)
        .as_array()
        .ok_or_else(|| {
            format!(
                "{}: expected a list of poses, or an object with a \"hypotheses\" list (ppf \
                 detect --json)",
                path.display()
            )
        })?;
    list.iter()
        .enumerate()
        .map(|(i, entry)| {
            let numbers = |field: &str, n: usize| -> Result<Vec<f32>, String> {
                let bad = || {
                    format!(
                        "{}: pose {i}: \"{field}\" must be a list of {n} numbers",
                        path.display()
                    )
                };
                let values = entry
                    .get(field)
                    .and_then(|v| v.as_array())
                    .ok_or_else(bad)?;
                if values.len() != n {
                    return Err(bad());
                }
                values
                    .iter()
                    .map(|v| v.as_f64().map(|x| x as f32).ok_or_else(bad))
                    .collect()
            };
            let object_id = entry
                .get("object_id")
                .and_then(|v| v.as_u64())
                .and_then(|v| u32::try_from(v).ok())
                .ok_or_else(|| {
                    format!(
                        "{}: pose {i}: \"object_id\" must be an object id",
                        path.display()
                    )
                })?;
            let mut hint = PoseHint {
                object_id,
                ..Default::default()
            };
            hint.rotation.copy_from_slice(&numbers("rotation", 9)?);
            hint.translation_mm
                .copy_from_slice(&numbers("translation_mm", 3)?);
            Ok(hint)
        })
        .collect()
}

pub fn run(args: DetectArgs) -> Result<(), String> {
    let hints = match &args.hints {
        Some(path) => read_hints(path)?,
        None => Vec::new(),
    };
    let client = args.connect.client()?;
    let options = DetectOptions {
        hypotheses_per_object: args.hypotheses,
        timeout: millis(args.timeout_ms),
        ..Default::default()
    };
    let found = client
        .detect_with_hints(&args.camera, &args.objects, &hints, &options)
        .map_err(|e| e.to_string())?;
    if args.json {
        let hyps: Vec<serde_json::Value> = found
            .hypotheses
            .iter()
            .map(|h| {
                serde_json::json!({
                    "object_id": h.object_id, "rank": h.instance_rank + 1, "score": h.score, "votes": h.votes,
                    "checks": h.checks, "rotation": h.rotation, "translation_mm": h.translation_mm,
                })
            })
            .collect();
        let l = &found.latency;
        let latency: serde_json::Map<String, serde_json::Value> = crate::common::stages(&l.daemon)
            .iter()
            .map(|(n, v)| {
                let key = n.to_lowercase().replace([' ', '-'], "_");
                (format!("{key}_ns"), (*v).into())
            })
            .chain([
                ("detection_ns".to_owned(), l.daemon.detection_ns.into()),
                (
                    "response_transport_ns".to_owned(),
                    l.response_transport_ns.into(),
                ),
                ("end_to_end_ns".to_owned(), l.end_to_end_ns.into()),
                ("overhead_ns".to_owned(), l.overhead_ns().into()),
            ])
            .collect();
        let out = serde_json::json!({
            "request_id": found.request_id, "frame_sequence": found.frame_sequence,
            "frame_age_ns": found.frame_age_ns, "hypotheses": hyps, "latency": latency,
            "counts": { "scene_points": found.counts.scene_points, "reference_points": found.counts.reference_points,
                        "pairs": found.counts.pairs, "hypotheses": found.counts.hypotheses },
        });
        println!(
            "{}",
            serde_json::to_string_pretty(&out).map_err(|e| e.to_string())?
        );
        return Ok(());
    }
    println!(
        "frame {} ({:.1} ms old): {} scene points, {} reference points, {} pairs",
        found.frame_sequence,
        found.frame_age_ns as f64 / 1e6,
        found.counts.scene_points,
        found.counts.reference_points,
        found.counts.pairs
    );
    print_hypotheses(&found, &args.objects);
    print_latency(&found);
    Ok(())
}
