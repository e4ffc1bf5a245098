#!/usr/bin/env bash
# Runs OpenCV's PPF detector (cv2.ppf_match_3d) on BOP datasets and scores its results with
# `ppf score`, next to any other results CSV given.
#
#   bench/peers/run.sh [DATASET...]        default: ../shared/data/lmo ../shared/data/synth-lmo-dev
#   OPENCV_ARGS="--max-images 3" bench/peers/run.sh ../shared/data/synth-lmo-dev
#   EXTRA_CSV=results/ppfd_lmo.csv bench/peers/run.sh ../shared/data/lmo   (one dataset: scores that CSV too)
#
# Paths are relative to the repository root. Results go to results/peers/<dataset>/.
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
repo="$(cd "$here/../.." && pwd)"
cd "$repo"

venv="$here/.venv"
if [ ! -x "$venv/bin/python" ]; then
    python3 -m venv "$venv"
fi
if ! "$venv/bin/python" -c "import cv2, numpy" 2>/dev/null; then
    "$venv/bin/pip" install --quiet --upgrade pip
    "$venv/bin/pip" install --quiet -r "$here/requirements.txt"
fi
"$venv/bin/python" - <<'PY'
import cv2
if not hasattr(cv2, "ppf_match_3d"):
    raise SystemExit(f"OpenCV {cv2.__version__} has no ppf_match_3d module (it is in the contrib wheels)")
print(f"OpenCV {cv2.__version__} with cv2.ppf_match_3d")
PY

cargo build --release -p ppfd-cli --quiet
ppf="$repo/target/release/ppf"

datasets=("$@")
if [ ${#datasets[@]} -eq 0 ]; then
    datasets=(../shared/data/lmo ../shared/data/synth-lmo-dev)
fi
# One process for every dataset: the detectors are trained once (minutes per object).
pairs=()
for dataset in "${datasets[@]}"; do
    out="results/peers/$(basename "$dataset")"
    mkdir -p "$out"
    # An earlier run's files (another scene distance's) would be scored as this run's.
    rm -f "$out"/opencv_ppf*.csv "$out"/opencv_ppf*.score.txt "$out"/opencv_ppf*.score.json
    pairs+=("$dataset" "$out/opencv_ppf.csv")
done
# shellcheck disable=SC2086
"$venv/bin/python" -u "$here/opencv_ppf.py" "${pairs[@]}" ${OPENCV_ARGS:-} \
    2> >(tee results/peers/opencv_ppf.log >&2)

# With --max-images the images left out would count as misses: only the images run are scored.
only=()
case " ${OPENCV_ARGS:-} " in *" --max-images "*) only=(--only-result-images) ;; esac
for dataset in "${datasets[@]}"; do
    out="results/peers/$(basename "$dataset")"
    # One file per scene distance when several are given (opencv_ppf_sd<distance>.csv).
    csvs=("$out"/opencv_ppf*.csv)
    if [ ${#datasets[@]} -eq 1 ] && [ -n "${EXTRA_CSV:-}" ]; then
        csvs+=("$EXTRA_CSV")
    fi
    for csv in "${csvs[@]}"; do
        echo
        echo "== $dataset: $csv"
        "$ppf" score "$dataset" "$csv" "${only[@]}" | tee "${csv%.csv}.score.txt"
        "$ppf" score "$dataset" "$csv" "${only[@]}" --json > "${csv%.csv}.score.json"
    done
done
