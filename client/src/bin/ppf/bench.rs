//! `ppf bench`: latency profile of a running daemon — K client threads (one iceoryx2 client
//! each) send N requests in all, back to back; p50/p90/p99/max per stage and end to end, the
//! overhead (end to end minus detection), throughput, and an HDR histogram.

use std::time::Instant;

use clap::Args;
use hdrhistogram::Histogram;
use ppfd_client::{DetectOptions, Latency};

use crate::common::{millis, ms, stages, Connect};

#[derive(Args, Debug)]
pub struct BenchArgs {
    /// Camera whose newest frame to use.
    #[arg(long)]
    pub camera: String,
    /// Object ids, comma-separated.
    #[arg(long, value_delimiter = ',', required = true)]
    pub objects: Vec<u32>,
    /// Requests in all (after warm-up).
    #[arg(long, default_value_t = 200)]
    pub requests: usize,
    /// Client threads sending at once.
    #[arg(long, default_value_t = 1)]
    pub clients: usize,
    /// Requests per client before measuring.
    #[arg(long, default_value_t = 5)]
    pub warmup: usize,
    /// Hypotheses per object.
    #[arg(long, default_value_t = 1)]
    pub hypotheses: u32,
    /// Timeout per request, milliseconds.
    #[arg(long, default_value_t = 30_000)]
    pub timeout_ms: u64,
    /// Print the results as JSON.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub connect: Connect,
}

fn histogram() -> Histogram<u64> {
    Histogram::new_with_bounds(1, 3_600_000_000_000, 3).expect("valid bounds")
}

struct Measure {
    name: &'static str,
    histogram: Histogram<u64>,
}

pub fn run(args: BenchArgs) -> Result<(), String> {
    if args.clients == 0 || args.requests == 0 {
        return Err("--clients and --requests must be at least 1".into());
    }
    let options = DetectOptions {
        hypotheses_per_object: args.hypotheses,
        timeout: millis(args.timeout_ms),
        ..Default::default()
    };
    let started = std::sync::Barrier::new(args.clients);
    let per_client: Vec<usize> = (0..args.clients)
        .map(|i| args.requests / args.clients + usize::from(i < args.requests % args.clients))
        .collect();
    let wall = std::sync::Mutex::new(None::<Instant>);
    let results: Vec<Result<Vec<Latency>, String>> = std::thread::scope(|s| {
        let handles: Vec<_> = per_client
            .iter()
            .map(|&n| {
                let (args, options, started, wall) = (&args, &options, &started, &wall);
                s.spawn(move || -> Result<Vec<Latency>, String> {
                    let client = args.connect.client()?;
                    for _ in 0..args.warmup {
                        client
                            .detect(&args.camera, &args.objects, options)
                            .map_err(|e| e.to_string())?;
                    }
                    started.wait();
                    wall.lock().unwrap().get_or_insert_with(Instant::now);
                    let mut out = Vec::with_capacity(n);
                    for _ in 0..n {
                        let d = client
                            .detect(&args.camera, &args.objects, options)
                            .map_err(|e| e.to_string())?;
                        out.push(d.latency);
                    }
                    Ok(out)
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
    for r in results {
        all.extend(r?);
    }

    let names: Vec<&'static str> = stages(&Default::default())
        .iter()
        .map(|(n, _)| *n)
        .collect();
    let mut measures: Vec<Measure> = names
        .iter()
        .map(|&name| Measure {
            name,
            histogram: histogram(),
        })
        .collect();
    for extra in [
        "detection",
        "hand-back",
        "response transport",
        "end to end",
        "overhead",
    ] {
        measures.push(Measure {
            name: extra,
            histogram: histogram(),
        });
    }
    for l in &all {
        let values: Vec<u64> = stages(&l.daemon)
            .iter()
            .map(|(_, v)| *v)
            .chain([
                l.daemon.detection_ns,
                l.hand_back_ns(),
                l.response_transport_ns,
                l.end_to_end_ns,
                l.overhead_ns(),
            ])
            .collect();
        for (m, v) in measures.iter_mut().zip(values) {
            m.histogram.saturating_record(v.max(1));
        }
    }
    let throughput = all.len() as f64 / elapsed.as_secs_f64().max(1e-9);
    let end_to_end = &measures[measures.len() - 2].histogram;

    if args.json {
        let rows: serde_json::Map<String, serde_json::Value> = measures
            .iter()
            .map(|m| {
                let h = &m.histogram;
                (
                    m.name.replace([' ', '-'], "_"),
                    serde_json::json!({
                        "p50_ns": h.value_at_quantile(0.5), "p90_ns": h.value_at_quantile(0.9),
                        "p99_ns": h.value_at_quantile(0.99), "max_ns": h.max(), "mean_ns": h.mean(),
                    }),
                )
            })
            .collect();
        let distribution: Vec<serde_json::Value> = end_to_end
            .iter_quantiles(1)
            .map(|v| serde_json::json!({"quantile": v.quantile_iterated_to(), "ns": v.value_iterated_to()}))
            .collect();
        let out = serde_json::json!({
            "camera": args.camera, "objects": args.objects, "requests": all.len(), "clients": args.clients,
            "seconds": elapsed.as_secs_f64(), "throughput_per_s": throughput,
            "latency": rows, "end_to_end_distribution": distribution,
        });
        println!(
            "{}",
            serde_json::to_string_pretty(&out).map_err(|e| e.to_string())?
        );
        return Ok(());
    }

    println!(
        "{} requests from {} clients in {:.2} s: {:.1} requests/s (camera {}, objects {:?})",
        all.len(),
        args.clients,
        elapsed.as_secs_f64(),
        throughput,
        args.camera,
        args.objects
    );
    println!(
        "{:<20} {:>10} {:>10} {:>10} {:>10}",
        "ms", "p50", "p90", "p99", "max"
    );
    for m in &measures {
        let h = &m.histogram;
        println!(
            "{:<20} {:>10} {:>10} {:>10} {:>10}",
            m.name,
            ms(h.value_at_quantile(0.5)),
            ms(h.value_at_quantile(0.9)),
            ms(h.value_at_quantile(0.99)),
            ms(h.max())
        );
    }
    println!("\nend to end, HDR histogram (ms at percentile):");
    for q in [0.0, 0.25, 0.5, 0.75, 0.9, 0.95, 0.99, 0.999, 1.0] {
        println!(
            "  {:>7.3}%  {:>10}",
            q * 100.0,
            ms(end_to_end.value_at_quantile(q))
        );
    }
    Ok(())
}
