#!/usr/bin/env bash
# Soak run: the real daemon on the LM-O models, a replayed camera whose driver is killed and
# restarted at random intervals, the picking-loop example asking for objects all along, and
# clients killed mid-request at random. Samples the daemon's memory and open files every 10 s
# and ends with one summary: cycles served, refused, failed and mismatched; memory and files at
# the start, their largest and at the end.
#
#   bench/soak.sh [minutes=30] [dataset=../shared/data/lmo]
#
# Exits non-zero when an answer did not match its request, a cycle's answer never came (other
# than while the daemon had no camera frame), the daemon died, or its memory or open files grew
# beyond the bounds below.
set -euo pipefail
cd "$(dirname "$0")/.."

minutes=${1:-30}
[ "$minutes" -ge 2 ] || { echo "soak: at least 2 minutes (the bounds start at 60 s)" >&2; exit 2; }
dataset=${2:-../shared/data/lmo}
# Bounds on growth over the run, from the sample at 60 s (models loaded, every kind of request
# served) to the largest.
max_rss_growth_kb=${SOAK_MAX_RSS_GROWTH_KB:-65536}
max_fd_growth=${SOAK_MAX_FD_GROWTH:-32}
# The picking loop's detect timeout: the library's 3 s holds on an idle 2-core machine; a
# shared one needs more (a timeout is counted as a lost answer).
timeout_ms=${SOAK_TIMEOUT_MS:-3000}

cargo build --release -q -p ppfd -p ppfd-cli -p ppfd-client --example picking_loop
bin=target/release
work=$(mktemp -d /tmp/ppfd-soak.XXXXXX)
export PPFD_PREFIX="soak_$$_"
pids=()
cleanup() {
    # The daemon first, with a clean stop; what is left, killed. The killed processes leave
    # their shared-memory files under this run's prefix, which nobody else uses: removed here.
    if [ -n "${daemon_pid:-}" ] && kill -TERM "$daemon_pid" 2>/dev/null; then sleep 1; fi
    for p in "${pids[@]}"; do kill -9 "$p" 2>/dev/null || true; done
    pkill -9 -f "replay .* --camera soak" 2>/dev/null || true
    wait 2>/dev/null || true
    rm -f /dev/shm/"$PPFD_PREFIX"* /tmp/iceoryx2/services/"$PPFD_PREFIX"* \
        /tmp/iceoryx2/"$PPFD_PREFIX"* 2>/dev/null || true
}
trap cleanup EXIT

echo "soak: $minutes min on $dataset; logs in $work"
"$bin/ppfd" --models "$dataset/models" >"$work/daemon.log" 2>&1 &
daemon_pid=$!
pids+=("$daemon_pid")
for _ in $(seq 600); do
    grep -q "ppfd ready" "$work/daemon.log" && break
    sleep 1
done
grep -q "ppfd ready" "$work/daemon.log" || { echo "soak: the daemon did not start" >&2; exit 1; }

start_camera() {
    "$bin/ppf" replay "$dataset" --camera soak --loop --fps 15 >>"$work/camera.log" 2>&1 &
    camera_pid=$!
}
start_camera

end=$(($(date +%s) + minutes * 60))
# One picking loop for the whole run: cycles enough to outlast it; it is stopped at the end.
"$bin/examples/picking_loop" soak 1000000 1,5,6 8,9,10 11,12 --timeout-ms "$timeout_ms" >"$work/picking.log" 2>&1 &
loop_pid=$!
pids+=("$loop_pid")

# The camera driver dies (killed outright or stopped) every 20–90 s and comes back 0–3 s later.
(
    while [ "$(date +%s)" -lt "$end" ]; do
        sleep $((20 + RANDOM % 70))
        if [ $((RANDOM % 2)) -eq 0 ]; then kill -9 "$camera_pid"; else kill -INT "$camera_pid"; fi
        wait "$camera_pid" 2>/dev/null || true
        echo "$(date +%s) camera restarted" >>"$work/events.log"
        sleep $((RANDOM % 4))
        start_camera
    done
    kill -9 "$camera_pid" 2>/dev/null || true
) &
pids+=("$!")

# Clients that ask for two objects and are killed 0–2 s after they start (a client takes some
# milliseconds to connect and send).
(
    killed=0
    while [ "$(date +%s)" -lt "$end" ]; do
        "$bin/ppf" detect --camera soak --objects 1,5 --timeout-ms 3000 >/dev/null 2>&1 &
        c=$!
        sleep "0.$((RANDOM % 10))$((RANDOM % 10))"
        sleep $((RANDOM % 2))
        kill -9 "$c" 2>/dev/null && killed=$((killed + 1))
        wait "$c" 2>/dev/null || true
        echo "$killed" >"$work/killed"
        sleep $((RANDOM % 3))
    done
) &
pids+=("$!")

echo "time_s,rss_kb,open_files" >"$work/samples.csv"
t0=$(date +%s)
while [ "$(date +%s)" -lt "$end" ]; do
    if ! kill -0 "$daemon_pid" 2>/dev/null; then
        echo "soak: the daemon died; see $work/daemon.log" >&2
        exit 1
    fi
    rss=$(awk '/^VmRSS/ {print $2}' "/proc/$daemon_pid/status")
    fds=$(ls "/proc/$daemon_pid/fd" | wc -l)
    echo "$(($(date +%s) - t0)),$rss,$fds" >>"$work/samples.csv"
    sleep 10
done
# TERM, not INT: a job started with & from a script ignores SIGINT. The counts below come from
# the loop's lines, not from its summary.
kill -TERM "$loop_pid" 2>/dev/null || true
sleep 1

picks=$(grep -c "pick object" "$work/picking.log" || true)
mismatched=$(grep -c "MISMATCH" "$work/picking.log" || true)
# Answers that never came: a timeout, a request let go, the daemon gone. A camera between two
# drivers is refused (stale, no frame), which the cell expects; those are counted apart.
lost=$(grep -cE "no answer from ppfd|let go of the request|ppfd exited" "$work/picking.log" || true)
waited=$(grep -cE "camera stale|retrying" "$work/picking.log" || true)
restarts=$(wc -l <"$work/events.log" 2>/dev/null || echo 0)
killed=$(cat "$work/killed" 2>/dev/null || echo 0)
read -r rss0 fd0 < <(awk -F, 'NR > 1 && ($1 >= 60 || r == "") {r = $2; f = $3; if ($1 >= 60) exit} END {print r, f}' "$work/samples.csv")
read -r rss_max fd_max < <(awk -F, 'NR > 1 && $1 >= 60 {if ($2 > r) r = $2; if ($3 > f) f = $3} END {print r, f}' "$work/samples.csv")
read -r rss1 fd1 < <(tail -1 "$work/samples.csv" | awk -F, '{print $2, $3}')
samples=$(($(wc -l <"$work/samples.csv") - 1))

echo "| minutes | cycles served | refused while the camera restarted | lost | mismatched | camera restarts | clients killed | daemon RSS at 60 s / max / end (MB) | open files at 60 s / max / end |"
echo "|---:|---:|---:|---:|---:|---:|---:|---|---|"
printf "| %s | %s | %s | %s | %s | %s | %s | %.1f / %.1f / %.1f | %s / %s / %s |\n" \
    "$minutes" "$picks" "$waited" "$lost" "$mismatched" "$restarts" "$killed" \
    "$(echo "$rss0 / 1024" | bc -l)" "$(echo "$rss_max / 1024" | bc -l)" "$(echo "$rss1 / 1024" | bc -l)" \
    "$fd0" "$fd_max" "$fd1"
echo "($samples samples every 10 s in $work/samples.csv)"

status=0
[ "$mismatched" -eq 0 ] || { echo "soak: $mismatched mismatched answers" >&2; status=1; }
[ "$lost" -eq 0 ] || { echo "soak: $lost answers lost" >&2; status=1; }
[ $((rss_max - rss0)) -le "$max_rss_growth_kb" ] || { echo "soak: memory grew by $((rss_max - rss0)) kB" >&2; status=1; }
[ $((fd_max - fd0)) -le "$max_fd_growth" ] || { echo "soak: open files grew by $((fd_max - fd0))" >&2; status=1; }
exit $status
