#!/usr/bin/env bash
# How long a map session's close takes (the server maps what it accepted, then refines), on a
# fresh server per run on the loopback profile (docs/reliability.md "Measured"):
#   bash tests/benchmarks/close_under_load.sh [--bin DIR] [--runs N] [--hogs H] [--beside]
# Session B streams frames 0:100:2 of the synthetic room (seed 9) with the queue policy and closes
# with --refine 20; prints B's close_s per run. --hogs H: H busy loops (`yes`, nice 0) run
# meanwhile. --beside: session A streams the room's 160 frames live at 15 Hz while B streams and
# closes, and A's frame -> pose latency is printed too (what B's close costs another session).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
BIN="$ROOT/build/bin" RUNS=3 HOGS=0 BESIDE=0
while [[ $# -gt 0 ]]; do
  case "$1" in
    --bin) BIN="$2"; shift ;;
    --runs) RUNS="$2"; shift ;;
    --hogs) HOGS="$2"; shift ;;
    --beside) BESIDE=1 ;;
    *) echo "close_under_load.sh: unknown option '$1'" >&2; exit 2 ;;
  esac
  shift
done
[[ -x "$BIN/fslam-server" && -x "$BIN/fslam" ]] || { echo "no fslam-server / fslam in $BIN (build first)" >&2; exit 2; }
export CYCLONEDDS_URI="file://$ROOT/configs/dds/loopback.xml"  # no DDS traffic off this machine
source "$ROOT/tests/common/script_support.sh"
WORK="$(mktemp -d)"
cleanup() { stop_started || true; rm -rf "$WORK"; }  # || true: its kills and waits may fail under set -e
trap cleanup EXIT
"$BIN/fslam" synth --out "$WORK/seq" --frames 160 --seed 9 >/dev/null 2>&1

for run in $(seq 1 "$RUNS"); do
  PREFIX="close$$r$run"
  rm -rf "$WORK/maps"
  start_server "$WORK/server.log" || { echo "the server did not start:"; tail "$WORK/server.log"; exit 1; }
  for _ in $(seq 1 "$HOGS"); do yes >/dev/null & PIDS+=($!); done
  if [[ $BESIDE == 1 ]]; then
    "$BIN/fslam" stream --policy live --rate 15 --timeout 120 --dataset "$WORK/seq" --prefix "$PREFIX" \
      --session a --map ma --report "$WORK/a.json" >"$WORK/a.log" 2>&1 &
    A=$!
    sleep 2
  fi
  "$BIN/fslam" stream --policy queue --timeout 120 --dataset "$WORK/seq" --prefix "$PREFIX" --session b \
    --map mb --frames 0:100:2 --refine 20 --report "$WORK/b.json" >"$WORK/b.log" 2>&1 || true
  [[ $BESIDE == 1 ]] && { wait "$A" || true; }
  stop_started || true  # the hogs and the server (which saves on the way out)
  PIDS=()
  python3 - "$WORK" "$run" "$BESIDE" <<'EOF'
import json, sys
work, run, beside = sys.argv[1], sys.argv[2], sys.argv[3] == "1"
b = json.load(open(work + "/b.json"))
line = "run %s: B closed %s in %.1f s" % (run, b["closed"], b["close_s"])
if beside:
    a = json.load(open(work + "/a.json"))
    l = a["latency"]
    line += "; A tracked %d of %d, frame -> pose p50 %.0f / p99 %.0f ms, tracking p50 %.0f / p99 %.0f ms" % (
        a["tracked"], a["frames_sent"], l["frame_to_pose"]["p50_ms"], l["frame_to_pose"]["p99_ms"],
        l["server_track"]["p50_ms"], l["server_track"]["p99_ms"])
print(line, flush=True)
EOF
done
