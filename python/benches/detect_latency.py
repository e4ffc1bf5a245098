"""The Python client's latency against a running daemon, to set beside `ppf bench`: one client
sends requests back to back and reports p50/p90/p99/max, in milliseconds, of

- `call`: the Python call `client.detect(...)` from entry to return (perf_counter), which adds
  the binding's work on both sides (arguments in, result objects out) to
- `end to end`: the client library's own measure, request sent → response received, the one
  `ppf bench` reports;
- `overhead`: end to end minus detection, as `ppf bench`.

    python python/benches/detect_latency.py --camera kinect --objects 1,5,6 --requests 2000 --prefix fb_
"""

import argparse
import json
import math
import time

import ppfd


def nearest_rank(sorted_values: list, q: float) -> int:
    """The smallest sample with at least `q` of the samples at or below it, as `ppf bench`."""
    if not sorted_values:
        return 0
    rank = math.ceil(min(max(q, 0.0), 1.0) * len(sorted_values))
    return sorted_values[min(max(rank, 1), len(sorted_values)) - 1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--camera", required=True)
    parser.add_argument("--objects", required=True, help="object ids, comma-separated")
    parser.add_argument("--requests", type=int, default=200)
    parser.add_argument("--warmup", type=int, default=5)
    parser.add_argument("--hypotheses", type=int, default=1)
    parser.add_argument("--timeout", type=float, default=30.0, help="seconds per request")
    parser.add_argument("--prefix", default=None)
    parser.add_argument("--json", action="store_true", help="print the results as JSON")
    args = parser.parse_args()
    if args.requests < 1:
        parser.error("--requests must be at least 1")
    objects = [int(i) for i in args.objects.split(",")]

    client = ppfd.Client(prefix=args.prefix)
    for _ in range(args.warmup):
        client.detect(args.camera, objects, args.hypotheses, args.timeout)
    call, end_to_end, overhead = [], [], []
    started = time.perf_counter()
    for _ in range(args.requests):
        t0 = time.perf_counter_ns()
        found = client.detect(args.camera, objects, args.hypotheses, args.timeout)
        call.append(time.perf_counter_ns() - t0)
        end_to_end.append(found.latency["end_to_end_ns"])
        overhead.append(found.latency["overhead_ns"])
    seconds = time.perf_counter() - started

    # The keys of `ppf bench --json`: the stage's name and `p50_ns` ... `max_ns`.
    rows = {"call": call, "end_to_end": end_to_end, "overhead": overhead}
    quantiles = {"p50": 0.5, "p90": 0.9, "p99": 0.99, "max": 1.0}
    table = {
        name: {q: nearest_rank(sorted(values), at) for q, at in quantiles.items()}
        for name, values in rows.items()
    }
    if args.json:
        latency = {name: {f"{q}_ns": v for q, v in row.items()} for name, row in table.items()}
        print(json.dumps({"requests": args.requests, "seconds": seconds, "latency": latency},
                         indent=2))
        return
    print(f"{args.requests} requests in {seconds:.2f} s: {args.requests / seconds:.1f} "
          f"requests/s (camera {args.camera}, objects {objects}, Python client)")
    print(f"{'ms':<20}" + "".join(f"{q:>10}" for q in quantiles))
    for name, values in table.items():
        label = name.replace("_", " ")
        print(f"{label:<20}" + "".join(f"{v / 1e6:>10.3f}" for v in values.values()))


if __name__ == "__main__":
    main()
