#!/usr/bin/env bash
# Four sessions with features on (issue 23, opt-in; not part of the test suite): does mapping
# still grow the maps when tracking four 30 Hz streams with the feature encoder fills every core?
# Starts fslam-server with the builtin autoencoder, runs tests/common/load_main.cpp (4 sessions at
# 30 Hz, JPEG colour, 2 queriers: renders and promptless segmentations, 2 per second each) for
# SECONDS, and prints per session what was tracked / skipped, the maps' Gaussians and resident
# memory every 10 s, and how many queries failed (a segmentation of a map whose Gaussians carry no
# features yet fails with "the map carries no features").
#   tests/benchmarks/features_overload.sh [--bin DIR] [--seconds N] [--weights FILE] [--out DIR]
set -uo pipefail
REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
BIN="$REPO/build/bin" LOAD_S=60 WEIGHTS="$REPO/out/autoencoder/builtin.fae" OUT=""
while [[ $# -gt 0 ]]; do
  case "$1" in
    --bin) BIN="$2"; shift 2 ;;
    --seconds) LOAD_S="$2"; shift 2 ;;
    --weights) WEIGHTS="$2"; shift 2 ;;
    --out) OUT="$2"; shift 2 ;;
    -h|--help) sed -n '2,9p' "${BASH_SOURCE[0]}"; exit 0 ;;
    *) echo "unknown option: $1 (see --help)" >&2; exit 2 ;;
  esac
done
[[ -x "$BIN/fslam-server" && -x "$BIN/fslam_load" ]] || { echo "no fslam-server / fslam_load in $BIN: build first" >&2; exit 1; }
if [[ ! -f "$WEIGHTS" ]]; then
  echo "making the builtin autoencoder weights ($WEIGHTS) ..." >&2
  bash "$REPO/deploy/make_builtin_autoencoder.sh" --threads 2 --out "$WEIGHTS" >&2 || exit 1
fi
export CYCLONEDDS_URI="file://$REPO/configs/dds/loopback.xml"  # no DDS traffic off this machine
source "$REPO/tests/common/script_support.sh"
WORK="$(mktemp -d /tmp/fslam_features_overload.XXXXXX)"
PREFIX="fover$$"
cleanup() { stop_started; [[ -n "$OUT" ]] && mkdir -p "$OUT" && cp "$WORK"/*.json "$WORK"/*.log "$OUT"/ 2>/dev/null; rm -rf "$WORK"; }
trap cleanup EXIT
"$BIN/fslam" synth --out "$WORK/seq" --frames 60 --seed 7 >/dev/null 2>&1 || { echo "synth failed"; exit 1; }
start_server "$WORK/server.log" 0 --set "features.autoencoder_path=$WEIGHTS" ||
  { echo "the server did not start:"; tail "$WORK/server.log"; exit 1; }
echo "# $(date -u +%FT%TZ) commit $(git -C "$REPO" rev-parse --short HEAD) host $(hostname) cores $(nproc), $LOAD_S s"
timeout $((LOAD_S + 150)) "$BIN/fslam_load" "$PREFIX" "$WORK/seq" "$LOAD_S" 4 --rate 30 --encoding jpeg \
  --queriers 2 --query-rate 2 >"$WORK/report.json" 2>"$WORK/load.log" || { echo "the load tool failed:"; tail "$WORK/load.log"; exit 1; }
python3 - "$WORK/report.json" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))
for i, s in enumerate(r["sessions"]):
    p99 = [f"{w[1]:.0f}" for w in s["latency_ms"] if w[1] > 0]
    print(f"session {i}: sent {s['sent']}, tracked {s['tracked']}, skipped {s['skipped']}, errors {s['errors']}; "
          f"pose p99 per 10 s {', '.join(p99)} ms")
q = r["queries"]
print(f"queries: {q['ok']} answered, {q['failed']} failed")
series, next_t = [], 0.0
for k, (t, rss, g) in enumerate(r["status"]):
    if t >= next_t or k == len(r["status"]) - 1:
        series.append(f"{t:.0f} s {g / 1000:.1f}k Gaussians {rss:.0f} MiB")
        next_t = t + 10.0
print("maps over time: " + "; ".join(series))
PY
