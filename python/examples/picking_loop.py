"""A multi-object warehouse picking loop, as `client/examples/picking_loop.rs`. Each cycle takes
the next order (a few object ids), asks the daemon for them in the camera's newest frame, picks
the best-scored instance, "moves the robot" there and reports the cycle time. Refusals (stale
camera, unknown object) are handled the way a cell controller would: skip, report, go on.

    python python/examples/picking_loop.py kinect 20 1,5,6 8,9
"""

import argparse
import sys
import time

import ppfd


def order_of(text: str) -> list:
    """One order: object ids from 1, comma-separated."""
    try:
        ids = [int(i) for i in text.split(",") if i]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: object ids are whole numbers, comma-separated")
    if not ids or min(ids) < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: give object ids from 1, comma-separated")
    return ids


def positive(text: str) -> float:
    """A number of seconds above 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number")
    if not value > 0:
        raise argparse.ArgumentTypeError(f"{text!r}: give seconds above 0")
    return value


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("camera", nargs="?", default="kinect")
    parser.add_argument("cycles", nargs="?", type=int, default=10)
    parser.add_argument("orders", nargs="*", type=order_of, default=[[1, 5, 6], [8, 9]],
                        help="object ids of one order, comma-separated")
    parser.add_argument("--prefix", default=None, help="iceoryx2 prefix (default: PPFD_PREFIX)")
    parser.add_argument("--timeout", type=positive, default=None,
                        help="seconds per request (default: the client's, 3 s)")
    args = parser.parse_args()
    orders = args.orders
    # One line per cycle as it ends, also into a pipe or a journal.
    sys.stdout.reconfigure(line_buffering=True)

    client = ppfd.Client(prefix=args.prefix)
    picked = failed = 0
    both = ppfd.Checks.CONSISTENT | ppfd.Checks.SILHOUETTE
    cycles = 0
    interrupted = False
    try:
        for cycle in range(args.cycles):
            cycles = cycle + 1
            order = orders[cycle % len(orders)]
            start = time.monotonic()
            try:
                # Each object's best pose: a second pose that passes both filters is often a
                # partial fit beside the first, and a cell would send the robot to it.
                found = client.detect(args.camera, order, hypotheses=1, timeout=args.timeout,
                                      max_frame_age=0.5)
            except ppfd.CameraStale as e:
                print(f"cycle {cycle}: camera stale ({e.value / 1e6:.0f} ms), waiting for the driver")
                time.sleep(0.2)
                continue
            except (ppfd.NoDaemon, ppfd.DaemonGone, ppfd.NoFrame, ppfd.UnknownCamera,
                    ppfd.Busy) as e:
                # Waiting out the daemon (restarting, or not yet up), or a camera that has not
                # published yet: retrying at once would spin.
                print(f"cycle {cycle}: {e}; retrying in 0.5 s")
                time.sleep(0.5)
                continue
            except ppfd.Error as e:
                print(f"cycle {cycle}: {e}")
                failed += 1
                time.sleep(0.1)
                continue
            # The best-scored pose that passed both filters, of any object of the order, is the
            # next pick; a pose that failed one is listed, never picked.
            passed = [d for d in found if d.checks & both == both]
            best = max(passed, key=lambda d: d.score, default=None)
            if best is None:
                print(f"cycle {cycle}: nothing of {order} in view")
                continue
            x, y, z = best.pose[:3, 3]
            # A real cell would plan a grasp from best.pose and move the arm here.
            picked += 1
            latency = found.latency
            print(
                f"cycle {cycle}: order {order} -> pick object {best.object_id} "
                f"(score {best.score:.2f}) at ({x:.0f}, {y:.0f}, {z:.0f}) mm; "
                f"cycle {(time.monotonic() - start) * 1e3:.1f} ms "
                f"(detection {latency['detection_ns'] / 1e6:.1f} ms, "
                f"overhead {latency['overhead_ns'] / 1e6:.3f} ms, "
                f"frame {found.frame_sequence} aged {found.frame_age_ns / 1e6:.1f} ms)",
                flush=True,
            )
    except KeyboardInterrupt:
        # Ctrl-C ends the loop with the summary of the cycles run, as the cell's log needs.
        interrupted = True
    stopped = " (stopped by Ctrl-C)" if interrupted else ""
    print(f"{picked} picks in {cycles} cycles{stopped}; {failed} failed")
    if interrupted:
        return 130
    if cycles > 0 and failed == cycles:
        print("error: every cycle failed", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
