#!/usr/bin/env bash
# Relocalisation and large-motion benchmark of issue 20 (opt-in; not part of the test suite):
#   1. relocalisation on a stretch: every n-th non-keyframe frame, no prior pose, against the map
#      and keyframes of the whole run (`fslam track --relocalise-every`), repeated for a range;
#   2. large motion: tracking every 10th and every 20th frame, with the wide-baseline ORB start
#      and without it (tracker.wide_baseline_inlier_ratio=0).
set -euo pipefail

usage() {
  cat <<'USAGE'
Usage: tests/benchmarks/relocalisation.sh [options]

Options:
  --dataset DIR   default ../shared/data/redkitchen
  --frames A:B    stretch (default 0:600)
  --every N       relocalise every N-th non-keyframe frame (default 5)
  --repeats N     relocalisation runs, for the range of the times (default 3)
  --threads N     default 2
  --out DIR       default /tmp/fslam_relocalisation; logs and summary.txt
  --fslam PATH    default build/bin/fslam
  -h, --help      this text
USAGE
}

REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
export CYCLONEDDS_URI="file://${REPO}/configs/dds/loopback.xml"  # house rule, though no DDS here
DATASET="${REPO}/../shared/data/redkitchen"
FRAMES="0:600"
EVERY=5
REPEATS=3
THREADS=2
OUT="/tmp/fslam_relocalisation"
FSLAM="${REPO}/build/bin/fslam"
while [[ $# -gt 0 ]]; do
  case "$1" in
    --dataset) DATASET="$2"; shift 2 ;;
    --frames) FRAMES="$2"; shift 2 ;;
    --every) EVERY="$2"; shift 2 ;;
    --repeats) REPEATS="$2"; shift 2 ;;
    --threads) THREADS="$2"; shift 2 ;;
    --out) OUT="$2"; shift 2 ;;
    --fslam) FSLAM="$2"; shift 2 ;;
    -h|--help) usage; exit 0 ;;
    *) echo "relocalisation.sh: unknown option '$1' (see --help)" >&2; exit 2 ;;
  esac
done
[[ -x "$FSLAM" ]] || { echo "relocalisation.sh: no $FSLAM; build first (cmake --build build)" >&2; exit 1; }
[[ -d "$DATASET" ]] || { echo "relocalisation.sh: no dataset at $DATASET" >&2; exit 1; }
mkdir -p "$OUT"
PRESET=()
[[ "$DATASET" == *redkitchen* ]] && PRESET=(--config "${REPO}/configs/presets/seven_scenes.yaml")
SUMMARY="$OUT/summary.txt"
{
  echo "# $(date -u +%FT%TZ), commit $(git -C "$REPO" rev-parse --short HEAD), $(nproc) cores, --threads $THREADS"
  echo "# dataset $DATASET, frames $FRAMES"
} > "$SUMMARY"

for r in $(seq 1 "$REPEATS"); do
  log="$OUT/relocalise_$r.log"
  echo "relocalisation run $r/$REPEATS ..." >&2
  "$FSLAM" track --dataset "$DATASET" --frames "$FRAMES" "${PRESET[@]}" --threads "$THREADS" \
    --out "$OUT/relocalise_$r.tum" --relocalise-every "$EVERY" > "$log" 2> "$OUT/relocalise_$r.err"
  { echo "## relocalisation run $r"; grep -E "^relocalisation:|reloc total|reloc describe|reloc search|^ATE" "$log"; } >> "$SUMMARY"
done

A="${FRAMES%%:*}"
B="${FRAMES#*:}"
B="${B%%:*}"
for step in 10 20; do
  for ratio in default 0; do
    log="$OUT/stride${step}_wide${ratio}.log"
    extra=()
    [[ "$ratio" != default ]] && extra=(--set "tracker.wide_baseline_inlier_ratio=$ratio")
    echo "large motion: every ${step}th frame, wide_baseline_inlier_ratio $ratio ..." >&2
    "$FSLAM" track --dataset "$DATASET" --frames "$A:$B:$step" "${PRESET[@]}" --threads "$THREADS" \
      --out "$OUT/stride${step}_wide${ratio}.tum" "${extra[@]}" > "$log" 2> "$OUT/stride${step}_wide${ratio}.err"
    { echo "## every ${step}th frame, wide_baseline_inlier_ratio $ratio"; grep -E "^frames|^ATE" "$log"; } >> "$SUMMARY"
  done
done
cat "$SUMMARY"
