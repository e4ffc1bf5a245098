//! `ppf bench`: latency profile of a running daemon — K client threads (one iceoryx2 client
//! each) send N requests in all, back to back; p50/p90/p99/max per stage and end to end (exact,
//! from every request's value), the overhead (end to end minus detection), throughput, an HDR
//! histogram of end to end, and with several clients the same per client (each may ask for
//! its own objects: `--objects 1,5 --objects 8,9`), which shows whether one starves another.
//!
//! A request that fails (refused, timed out, dropped) is counted by kind and left out of the
//! figures, and the run exits 1 after printing them; a client whose connection or warm-up
//! fails ends the run before it starts. Until a client's first answer, a camera without a
//! frame yet is waited for within the request's timeout, as `ppf detect` does.

use std::time::Instant;

use clap::Args;
use ppfd_client::protocol::control::nearest_rank;
use ppfd_client::{DetectOptions, Error, Latency};

use crate::common::{detect_once_framed, millis, ms, stages, Connect};

#[derive(Args, Debug)]
pub struct BenchArgs {
    /// Camera whose newest frame to use.
    #[arg(long, value_parser = crate::common::camera_name)]
    pub camera: String,
    /// Object ids, comma-separated; repeated, one list per client in turn (client i asks for
    /// list i modulo the number of lists).
    #[arg(long, required = true, value_parser = parse_objects)]
    pub objects: Vec<Objects>,
    /// Requests in all (after warm-up), at least one per client.
    #[arg(long, default_value_t = 200,
          value_parser = at_least_one)]
    pub requests: usize,
    /// Client threads sending at once.
    #[arg(long, default_value_t = 1,
          value_parser = at_least_one)]
    pub clients: usize,
    /// Requests per client before measuring.
    #[arg(long, default_value_t = 5)]
    pub warmup: usize,
    /// Hypotheses per object, 1 to 16.
    #[arg(long, default_value_t = 1,
          value_parser = clap::value_parser!(u32).range(1..=crate::common::MAX_HYPOTHESES))]
    pub hypotheses: u32,
    /// Timeout per request, milliseconds.
    #[arg(long, default_value_t = 30_000, value_parser = clap::value_parser!(u64).range(1..))]
    pub timeout_ms: u64,
    /// Print the results as JSON.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub connect: Connect,
}

/// One client's object ids (one `--objects` list).
#[derive(Clone, Debug, PartialEq)]
pub struct Objects(pub Vec<u32>);

fn parse_objects(list: &str) -> Result<Objects, String> {
    list.split(',')
        .map(|id| crate::common::object_id(id.trim()).map_err(|e| format!("object id {id:?}: {e}")))
        .collect::<Result<Vec<u32>, String>>()
        .map(Objects)
}

/// One row of the table: every request's value, for exact percentiles.
struct Measure {
    /// In the table.
    label: &'static str,
    /// In JSON.
    key: &'static str,
    samples: Vec<u64>,
}

impl Measure {
    fn new(label: &'static str, key: &'static str) -> Self {
        Measure {
            label,
            key,
            samples: Vec::new(),
        }
    }

    fn record(&mut self, ns: u64) {
        self.samples.push(ns);
    }

    /// The exact value at quantile `q` (nearest rank) of the samples, which must be sorted. A
    /// histogram's quantiles would be its buckets' bounds, three significant digits: at half a
    /// second a quarter of a millisecond apart, too coarse for the overhead beside a detection,
    /// and a maximum other than the table's.
    fn at(&self, q: f64) -> u64 {
        nearest_rank(&self.samples, q)
    }

    /// The JSON figures; `null` with no sample, as zeros would read as measurements.
    fn json(&self) -> serde_json::Value {
        if self.samples.is_empty() {
            return serde_json::Value::Null;
        }
        let mean = (self.samples.iter().map(|&v| u128::from(v)).sum::<u128>()
            / self.samples.len() as u128) as u64;
        serde_json::json!({
            "p50_ns": self.at(0.5), "p90_ns": self.at(0.9),
            "p99_ns": self.at(0.99), "max_ns": self.at(1.0), "mean_ns": mean,
        })
    }
}

/// The quantiles of the end-to-end distribution, printed and in `--json`.
const DISTRIBUTION_QUANTILES: [f64; 9] = [0.0, 0.25, 0.5, 0.75, 0.9, 0.95, 0.99, 0.999, 1.0];

/// The object lists as given: `1,5` or, one per client in turn, `1,5; 8`.
fn objects_text(objects: &[Objects]) -> String {
    objects
        .iter()
        .map(|o| o.0.iter().map(u32::to_string).collect::<Vec<_>>().join(","))
        .collect::<Vec<_>>()
        .join("; ")
}

/// A count of at least 1.
fn at_least_one(s: &str) -> Result<usize, String> {
    match s.parse::<usize>() {
        Ok(0) => Err("must be at least 1".into()),
        Ok(n) => Ok(n),
        Err(e) => Err(e.to_string()),
    }
}

impl BenchArgs {
    /// Refuses flags that do not go together (a usage error).
    pub fn check(&self) -> Result<(), String> {
        self.connect.prefix()?;
        if self.requests < self.clients {
            return Err(format!(
                "--requests {} is fewer than --clients {}: --requests counts the requests of \
                 all clients together, at least one each; give --requests {} or more, or fewer \
                 clients",
                self.requests, self.clients, self.clients
            ));
        }
        Ok(())
    }
}

pub fn run(args: BenchArgs) -> Result<(), String> {
    let options = DetectOptions {
        hypotheses_per_object: args.hypotheses,
        timeout: millis(args.timeout_ms),
        ..Default::default()
    };
    let objects_of = |client: usize| &args.objects[client % args.objects.len()].0[..];
    let started = std::sync::Barrier::new(args.clients);
    // Set by a client whose connection or warm-up failed: the others stop at the start line
    // instead of measuring a run that ends in that error.
    let warmup_failed = std::sync::atomic::AtomicBool::new(false);
    let per_client: Vec<usize> = (0..args.clients)
        .map(|i| args.requests / args.clients + usize::from(i < args.requests % args.clients))
        .collect();
    let wall = std::sync::Mutex::new(None::<Instant>);
    let results: Vec<Result<ClientRun, String>> = std::thread::scope(|s| {
        let handles: Vec<_> = per_client
            .iter()
            .enumerate()
            .map(|(i, &n)| {
                let (args, options, started, wall) = (&args, &options, &started, &wall);
                let warmup_failed = &warmup_failed;
                let objects = objects_of(i);
                s.spawn(move || -> Result<ClientRun, String> {
                    // A camera the daemon has just subscribed to has no frame until its
                    // driver's next one: until the first answer, such a refusal is waited
                    // out within the request's timeout, as `ppf detect` does, not counted.
                    let mut answered = false;
                    let mut request = |client: &ppfd_client::Client| {
                        let found = if answered {
                            client.detect(&args.camera, objects, options)
                        } else {
                            detect_once_framed(client, &args.camera, objects, options)
                        };
                        answered |= found.is_ok();
                        found
                    };
                    let warmed = args.connect.client().and_then(|client| {
                        for _ in 0..args.warmup {
                            request(&client).map_err(|e| format!("client {i}'s warm-up: {e}"))?;
                        }
                        Ok(client)
                    });
                    if warmed.is_err() {
                        warmup_failed.store(true, std::sync::atomic::Ordering::SeqCst);
                    }
                    // Every client reaches the start line, failed or not, so none waits forever.
                    started.wait();
                    let client = warmed?;
                    let mut run = ClientRun::default();
                    if warmup_failed.load(std::sync::atomic::Ordering::SeqCst) {
                        return Ok(run);
                    }
                    wall.lock().unwrap().get_or_insert_with(Instant::now);
                    run.served.reserve(n);
                    for _ in 0..n {
                        match request(&client) {
                            Ok(d) => {
                                run.served.push(d.latency);
                                run.frames.push(FrameUsed {
                                    sequence: d.frame_sequence,
                                    age_ns: d.frame_age_ns,
                                });
                            }
                            Err(e) => run.failures.count(&e),
                        }
                    }
                    Ok(run)
                })
            })
            .collect();
        handles
            .into_iter()
            .map(|h| {
                h.join()
                    .unwrap_or_else(|_| Err("a client thread panicked".into()))
            })
            .collect()
    });
    let elapsed = wall
        .lock()
        .unwrap()
        .map(|t| t.elapsed())
        .unwrap_or_default();
    let mut all = Vec::new();
    let mut frames_used = Vec::new();
    let mut per_client = Vec::new();
    let mut failures = Failures::default();
    for (i, r) in results.into_iter().enumerate() {
        let r = match r {
            Ok(r) => r,
            Err(e) => {
                // A script that reads --json gets JSON here too: the error that ended the run.
                if args.json {
                    println!("{}", serde_json::json!({ "error": e }));
                }
                return Err(e);
            }
        };
        per_client.push(ClientFigures::of(i, objects_of(i), &r));
        failures.add(&r.failures);
        all.extend(r.served);
        frames_used.extend(r.frames);
    }
    let failed = failures.total();

    let mut measures: Vec<Measure> = stages(&Default::default())
        .iter()
        .map(|stage| Measure::new(stage.label, stage.key))
        .collect();
    for (label, key) in [
        ("detection", "detection"),
        ("hand-back", "hand_back"),
        ("response transport", "response_transport"),
        ("end to end", "end_to_end"),
        ("overhead", "overhead"),
    ] {
        measures.push(Measure::new(label, key));
    }
    for l in &all {
        let values: Vec<u64> = stages(&l.daemon)
            .iter()
            .map(|stage| stage.ns)
            .chain([
                l.daemon.detection_ns,
                l.hand_back_ns(),
                l.response_transport_ns,
                l.end_to_end_ns,
                l.overhead_ns(),
            ])
            .collect();
        for (m, v) in measures.iter_mut().zip(values) {
            m.record(v);
        }
    }
    for m in &mut measures {
        m.samples.sort_unstable();
    }
    let throughput = all.len() as f64 / elapsed.as_secs_f64().max(1e-9);
    let end_to_end = &measures[measures.len() - 2];
    let frames = FrameFigures::of(&frames_used);

    if args.json {
        let rows: serde_json::Map<String, serde_json::Value> = measures
            .iter()
            .map(|m| (m.key.to_owned(), m.json()))
            .collect();
        // Nothing served: no quantiles, rather than zeros.
        let distribution: Vec<serde_json::Value> = DISTRIBUTION_QUANTILES
            .iter()
            .filter(|_| !end_to_end.samples.is_empty())
            .map(|&q| serde_json::json!({"quantile": q, "ns": end_to_end.at(q)}))
            .collect();
        let out = serde_json::json!({
            "camera": args.camera, "objects": args.objects.iter().map(|o| o.0.clone()).collect::<Vec<_>>(),
            "served": all.len(), "failed": failed, "failures": failures.json(), "clients": args.clients,
            "seconds": elapsed.as_secs_f64(), "throughput_per_s": throughput,
            "latency": rows, "end_to_end_distribution": distribution,
            "distinct_frames": frames.distinct, "frame_age": frames.age.json(),
            "per_client": per_client.iter().map(ClientFigures::json).collect::<Vec<_>>(),
        });
        println!(
            "{}",
            serde_json::to_string_pretty(&out).map_err(|e| e.to_string())?
        );
        return failures.outcome(all.len());
    }

    println!(
        "{} requests served from {} client{} in {:.2} s: {:.1} requests/s (camera {}, objects {})",
        all.len(),
        args.clients,
        if args.clients == 1 { "" } else { "s" },
        elapsed.as_secs_f64(),
        throughput,
        args.camera,
        objects_text(&args.objects)
    );
    if all.is_empty() {
        // Tables of zeros would read as measurements.
        println!(
            "{failed} failed, none served, so no latency figures: {}",
            failures.summary()
        );
        return failures.outcome(0);
    }
    if failed > 0 {
        println!(
            "{failed} failed, not in the figures below: {}",
            failures.summary()
        );
    }
    println!(
        "{:<20} {:>10} {:>10} {:>10} {:>10}   (the scene and kd-trees once per request; the \
         later stages summed over the objects, which run side by side, so they can add up to \
         more than the detection)",
        "ms", "p50", "p90", "p99", "max"
    );
    for m in &measures {
        println!(
            "{:<20} {:>10} {:>10} {:>10} {:>10}",
            m.label,
            ms(m.at(0.5)),
            ms(m.at(0.9)),
            ms(m.at(0.99)),
            ms(m.at(1.0))
        );
    }
    println!(
        "\nframes: the {} requests served were detected in {} distinct frames (by sequence \
         number); frame age at the detection's start p50 {} ms, max {} ms",
        all.len(),
        frames.distinct,
        ms(frames.age.at(0.5)),
        ms(frames.age.at(1.0))
    );
    if per_client.len() > 1 {
        println!("\nper client (ms):");
        println!(
            "{:<8} {:<16} {:>8} {:>8} {:>12} {:>12} {:>12} {:>14} {:>14} {:>14}",
            "client",
            "objects",
            "served",
            "failed",
            "e2e p50",
            "e2e p99",
            "e2e max",
            "queue wait p50",
            "queue wait max",
            "overhead p50"
        );
        for c in &per_client {
            c.print();
        }
    }
    println!("\nend to end (ms at percentile, nearest rank):");
    for q in DISTRIBUTION_QUANTILES {
        println!("  {:>7.3}%  {:>10}", q * 100.0, ms(end_to_end.at(q)));
    }
    failures.outcome(all.len())
}

/// One client's measured requests: the latencies of those served, the frames they were
/// detected in, and the failures.
#[derive(Default)]
struct ClientRun {
    served: Vec<Latency>,
    frames: Vec<FrameUsed>,
    failures: Failures,
}

/// The camera frame a served request was detected in.
#[derive(Clone, Copy)]
struct FrameUsed {
    sequence: u64,
    /// From the frame's capture to the detection's start, ns.
    age_ns: u64,
}

/// What the served requests detected in: how many distinct frames (by sequence number), and
/// the frames' ages when their detections started. Requests faster than the camera, or a
/// camera that stopped, show as fewer frames than requests and older frames.
struct FrameFigures {
    distinct: usize,
    age: Measure,
}

impl FrameFigures {
    fn of(frames: &[FrameUsed]) -> FrameFigures {
        let distinct = frames
            .iter()
            .map(|f| f.sequence)
            .collect::<std::collections::BTreeSet<_>>()
            .len();
        let mut age = Measure::new("frame age", "frame_age");
        for f in frames {
            age.record(f.age_ns);
        }
        age.samples.sort_unstable();
        FrameFigures { distinct, age }
    }
}

/// Failed requests by kind (a refusal's status, a timeout, the daemon gone, ...): how many, and
/// the first one's message.
#[derive(Default)]
struct Failures(std::collections::BTreeMap<String, (usize, String)>);

impl Failures {
    fn count(&mut self, e: &Error) {
        let kind = match e {
            Error::Refused { status, .. } => format!("refused: {status}"),
            Error::Timeout(_) => "timeout".into(),
            Error::Dropped => "dropped".into(),
            Error::DaemonGone => "daemon gone".into(),
            Error::Interrupted => "interrupted".into(),
            Error::NoDaemon { .. } => "no daemon".into(),
            _ => "transport".into(),
        };
        self.0.entry(kind).or_insert_with(|| (0, e.to_string())).0 += 1;
    }

    fn add(&mut self, other: &Failures) {
        for (kind, (n, message)) in &other.0 {
            self.0
                .entry(kind.clone())
                .or_insert_with(|| (0, message.clone()))
                .0 += n;
        }
    }

    fn total(&self) -> usize {
        self.0.values().map(|(n, _)| n).sum()
    }

    /// `timeout 3 (the first: no answer from ppfd within 80 ms: …); ...`
    fn summary(&self) -> String {
        self.0
            .iter()
            .map(|(kind, (n, message))| format!("{kind} {n} (the first: {message})"))
            .collect::<Vec<_>>()
            .join("; ")
    }

    fn json(&self) -> serde_json::Value {
        self.0
            .iter()
            .map(|(kind, (n, message))| serde_json::json!({"kind": kind, "count": n, "first_message": message}))
            .collect()
    }

    /// The run's exit: an error when any request failed, after the figures of those served.
    fn outcome(&self, served: usize) -> Result<(), String> {
        match self.total() {
            0 => Ok(()),
            failed => Err(format!(
                "{failed} of {} requests failed: {}",
                failed + served,
                self.summary()
            )),
        }
    }
}

/// One client's share of the run: how many of its requests were served and how long they took,
/// beside the others'.
struct ClientFigures {
    client: usize,
    objects: Vec<u32>,
    failed: usize,
    end_to_end: Vec<u64>,
    queue_wait: Vec<u64>,
    overhead: Vec<u64>,
}

impl ClientFigures {
    fn of(client: usize, objects: &[u32], run: &ClientRun) -> ClientFigures {
        let latencies = &run.served;
        let sorted = |f: &dyn Fn(&Latency) -> u64| {
            let mut v: Vec<u64> = latencies.iter().map(f).collect();
            v.sort_unstable();
            v
        };
        ClientFigures {
            client,
            objects: objects.to_vec(),
            failed: run.failures.total(),
            end_to_end: sorted(&|l| l.end_to_end_ns),
            queue_wait: sorted(&|l| l.daemon.queue_wait_ns),
            overhead: sorted(&|l| l.overhead_ns()),
        }
    }

    /// The value at `q` of `sorted`, `None` when this client had nothing served.
    fn at(sorted: &[u64], q: f64) -> Option<u64> {
        (!sorted.is_empty()).then(|| nearest_rank(sorted, q))
    }

    fn print(&self) {
        let objects: Vec<String> = self.objects.iter().map(u32::to_string).collect();
        // A client with nothing served shows dashes: zeros would read as measurements.
        let shown = |sorted: &[u64], q: f64| Self::at(sorted, q).map_or("-".to_owned(), ms);
        println!(
            "{:<8} {:<16} {:>8} {:>8} {:>12} {:>12} {:>12} {:>14} {:>14} {:>14}",
            self.client,
            objects.join(","),
            self.end_to_end.len(),
            self.failed,
            shown(&self.end_to_end, 0.5),
            shown(&self.end_to_end, 0.99),
            shown(&self.end_to_end, 1.0),
            shown(&self.queue_wait, 0.5),
            shown(&self.queue_wait, 1.0),
            shown(&self.overhead, 0.5),
        );
    }

    fn json(&self) -> serde_json::Value {
        serde_json::json!({
            "client": self.client, "objects": self.objects, "served": self.end_to_end.len(),
            "failed": self.failed,
            "end_to_end_p50_ns": Self::at(&self.end_to_end, 0.5),
            "end_to_end_p99_ns": Self::at(&self.end_to_end, 0.99),
            "end_to_end_max_ns": Self::at(&self.end_to_end, 1.0),
            "queue_wait_p50_ns": Self::at(&self.queue_wait, 0.5),
            "queue_wait_max_ns": Self::at(&self.queue_wait, 1.0),
            "overhead_p50_ns": Self::at(&self.overhead, 0.5),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn object_lists_read_as_given() {
        let lists = [Objects(vec![1, 5]), Objects(vec![8])];
        assert_eq!(objects_text(&lists[..1]), "1,5");
        assert_eq!(objects_text(&lists), "1,5; 8");
    }

    #[test]
    fn percentiles_are_exact_samples() {
        // Three values within half a millisecond at half a second: one bucket of a histogram of
        // three significant digits, told apart here.
        let mut m = Measure::new("end to end", "end_to_end");
        for v in [544_700_000u64, 544_220_000, 600_000_000, 544_450_000] {
            m.record(v);
        }
        m.samples.sort_unstable();
        assert_eq!(m.at(0.0), 544_220_000);
        assert_eq!(m.at(0.25), 544_220_000);
        assert_eq!(m.at(0.5), 544_450_000);
        assert_eq!(m.at(0.75), 544_700_000);
        assert_eq!(m.at(1.0), 600_000_000);
    }
}
