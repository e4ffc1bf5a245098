//! `ppf bench` against a daemon (`ppf serve`) over one part, this test publishing the part's
//! scene as a camera: failed requests are counted by kind beside the figures of those served,
//! and a client whose warm-up fails ends the run rather than leaving the others waiting for it.

mod common;

use std::process::{Command, Stdio};

use common::{show, Scratch, ServedPart};
use ppfd_models::synthetic::parts::Part;

/// An object id the daemon does not hold.
const UNKNOWN: &str = "99";

/// `ppf bench` with two clients, 4 requests in all and `warmup` each: client 0 asks for the
/// served part, client 1 for an object the daemon does not hold.
fn bench_one_unknown(served: &ServedPart, warmup: &str, json: bool) -> Command {
    let part = served.part.object_id().to_string();
    let mut command = Command::new(env!("CARGO_BIN_EXE_ppf"));
    command
        .args(["bench", "--prefix", &served.prefix, "--camera", "cam"])
        .args(["--objects", &part, "--objects", UNKNOWN])
        .args(["--clients", "2", "--requests", "4", "--warmup", warmup])
        .args(json.then_some("--json"))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    command
}

/// Two clients, one asking for the part and one for an object the daemon does not hold, with
/// no warm-up: the part's requests wait for the camera's first frame and are measured, the
/// others are counted as refused, and the exit status says that requests failed.
#[test]
fn bench_counts_failed_requests_beside_the_served() {
    let scratch = Scratch::new("bench-failures");
    let mut served = ServedPart::start(&scratch, "bench_failures", Part::TPipe, 5);
    let mut command = bench_one_unknown(&served, "0", true);
    let out = served.publish_until_done(command.spawn().unwrap());
    show(&command, &out);
    assert_eq!(out.status.code(), Some(1));
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON on stdout");
    assert_eq!(report["served"], 2, "the part's two requests are served");
    assert_eq!(report["failed"], 2);
    let failures = report["failures"].as_array().unwrap();
    assert_eq!(failures.len(), 1, "{failures:?}");
    assert_eq!(failures[0]["count"], 2);
    assert!(
        failures[0]["kind"].as_str().unwrap().starts_with("refused"),
        "{failures:?}"
    );
    let clients = report["per_client"].as_array().unwrap();
    assert_eq!(
        (clients[0]["served"].clone(), clients[0]["failed"].clone()),
        (2.into(), 0.into())
    );
    assert_eq!(
        (clients[1]["served"].clone(), clients[1]["failed"].clone()),
        (0.into(), 2.into())
    );
    // The frames the two served requests were detected in: one or two, each with its age.
    let distinct = report["distinct_frames"].as_u64().unwrap();
    assert!((1..=2).contains(&distinct), "{report}");
    assert!(report["frame_age"]["max_ns"].is_u64(), "{report}");
    // A client with nothing served has no figures, not zeros.
    assert!(clients[0]["end_to_end_p50_ns"].is_u64(), "{clients:?}");
    assert!(clients[1]["end_to_end_p50_ns"].is_null(), "{clients:?}");
    // The distribution is of the same samples as the table: the same median and maximum.
    let distribution = report["end_to_end_distribution"].as_array().unwrap();
    let at = |q: f64| {
        distribution
            .iter()
            .find(|d| d["quantile"].as_f64() == Some(q))
            .map(|d| d["ns"].clone())
    };
    let end_to_end = &report["latency"]["end_to_end"];
    assert_eq!(at(0.5), Some(end_to_end["p50_ns"].clone()), "{report}");
    assert_eq!(at(1.0), Some(end_to_end["max_ns"].clone()), "{report}");
    // The keys are the protocol's field names without `_ns`, each with its figures in ns.
    for key in ["queue_wait", "rescoring", "icp", "end_to_end", "overhead"] {
        assert!(report["latency"][key]["p50_ns"].is_u64(), "{key}: {report}");
    }
    assert!(report["latency"]["end_to_end"]["mean_ns"].is_u64());
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("2 of 4 requests failed"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// One client's warm-up is refused: the run ends with that refusal, and the other client,
/// which warmed up, does not wait at the start line for it.
#[test]
fn a_failed_warmup_ends_the_run() {
    let scratch = Scratch::new("bench-warmup");
    let mut served = ServedPart::start(&scratch, "bench_warmup", Part::TPipe, 5);
    let mut command = bench_one_unknown(&served, "1", false);
    let out = served.publish_until_done(command.spawn().unwrap());
    show(&command, &out);
    assert_eq!(out.status.code(), Some(1));
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(
        e.contains("client 1's warm-up") && e.contains(UNKNOWN),
        "{e}"
    );
    assert!(
        out.stdout.is_empty(),
        "no figures for a run that never started"
    );
    // With --json, the error as JSON too, for a script that reads it.
    let mut command = bench_one_unknown(&served, "1", true);
    let out = served.publish_until_done(command.spawn().unwrap());
    show(&command, &out);
    assert_eq!(out.status.code(), Some(1));
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON on stdout");
    let error = json["error"].as_str().unwrap_or_default();
    assert!(
        error.contains("client 1's warm-up") && error.contains(UNKNOWN),
        "{json}"
    );
}

/// A run whose every request fails prints no latency table (a table of zeros would read as
/// measurements), and says why; its JSON has no figures (`null`) and no distribution.
#[test]
fn a_run_with_nothing_served_prints_no_figures() {
    let scratch = Scratch::new("bench-none");
    let mut served = ServedPart::start(&scratch, "bench_none", Part::TPipe, 5);
    for json in [false, true] {
        let mut command = Command::new(env!("CARGO_BIN_EXE_ppf"));
        command
            .args(["bench", "--prefix", &served.prefix, "--camera", "cam"])
            .args(["--objects", UNKNOWN, "--requests", "3", "--warmup", "0"])
            .args(json.then_some("--json"))
            .stdout(Stdio::piped())
            .stderr(Stdio::piped());
        let out = served.publish_until_done(command.spawn().unwrap());
        show(&command, &out);
        assert_eq!(out.status.code(), Some(1));
        if json {
            let report: serde_json::Value =
                serde_json::from_slice(&out.stdout).expect("JSON on stdout");
            assert_eq!(
                (report["served"].clone(), report["failed"].clone()),
                (0.into(), 3.into())
            );
            for key in ["queue_wait", "end_to_end", "overhead"] {
                assert!(report["latency"][key].is_null(), "{key}: {report}");
            }
            assert_eq!(report["end_to_end_distribution"], serde_json::json!([]));
            assert_eq!(report["distinct_frames"], 0);
            assert!(report["frame_age"].is_null(), "{report}");
        } else {
            let stdout = String::from_utf8_lossy(&out.stdout);
            assert!(
                stdout.contains("3 failed, none served, so no latency figures"),
                "{stdout}"
            );
            assert!(
                !stdout.contains("p50") && !stdout.contains("percentile"),
                "{stdout}"
            );
        }
    }
}
