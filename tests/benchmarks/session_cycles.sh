#!/usr/bin/env bash
# Session open / close cycles against a fresh server on the loopback profile (docs/reliability.md
# "Measured"): prints the server's memory, mappings and threads every tenth of the run.
#   bash tests/benchmarks/session_cycles.sh [--bin DIR] [--cycles N] [--window W]
# Needs a build configured with -DFSLAM_BUILD_BENCHMARKS=ON (fslam_bench_session_cycles).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
BIN="$ROOT/build/bin" CYCLES=2000 WINDOW=8
while [[ $# -gt 0 ]]; do
  case "$1" in
    --bin) BIN="$2"; shift ;;
    --cycles) CYCLES="$2"; shift ;;
    --window) WINDOW="$2"; shift ;;
    *) echo "session_cycles.sh: unknown option '$1'" >&2; exit 2 ;;
  esac
  shift
done
[[ -x "$BIN/fslam_bench_session_cycles" ]] || { echo "no $BIN/fslam_bench_session_cycles (configure with -DFSLAM_BUILD_BENCHMARKS=ON)" >&2; exit 2; }
export CYCLONEDDS_URI="file://$ROOT/configs/dds/loopback.xml"
PREFIX="cycles$$"
LOG="$(mktemp -d)/server.log"
"$BIN/fslam-server" --prefix "$PREFIX" >"$LOG" 2>&1 &
SERVER=$!
trap 'kill "$SERVER" 2>/dev/null || true; wait "$SERVER" 2>/dev/null || true' EXIT
sleep 2
# The map the sessions localise in: ten frames of the synthetic room.
"$BIN/fslam" synth --out "$(dirname "$LOG")/seq" --frames 10 >/dev/null
"$BIN/fslam" stream --policy queue --dataset "$(dirname "$LOG")/seq" --prefix "$PREFIX" --session cycles-base \
  --map cycles >/dev/null
"$BIN/fslam_bench_session_cycles" --prefix "$PREFIX" --server-pid "$SERVER" --cycles "$CYCLES" --window "$WINDOW"
