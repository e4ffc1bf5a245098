//! `ppf detect`: one detect request against a running daemon; prints the poses and the latency
//! breakdown.

use ppfd_client::DetectOptions;

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
    /// What the poses must satisfy, and their order.
    pub requirements: ppfd_client::Requirements,
    pub connect: Connect,
}

pub fn run(args: DetectArgs) -> Result<(), String> {
    let client = args.connect.client()?;
    let options = DetectOptions {
        hypotheses_per_object: args.hypotheses,
        timeout: millis(args.timeout_ms),
        requirements: args.requirements,
        ..Default::default()
    };
    let found = client
        .detect(&args.camera, &args.objects, &options)
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
