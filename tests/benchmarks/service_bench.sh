#!/usr/bin/env bash
# Service benchmark (opt-in; not part of the test suite): frame-to-pose latency and sustained
# frame rate of the real fslam-server over the loopback DDS profile.
#
# Starts fslam-server with its own topic prefix, plays a 640x480 sequence to it with
# `fslam stream` (JPEG colour, PNG depth: the client's defaults) at --rate Hz, and prints the
# stream report: poses received, server errors and drops, frames per second, ATE, and latency
# p50 / p99 split into client encode, server decode, queue, track and the rest (DDS transport and
# publishing). The same frames are then tracked in-process with `fslam track`, so "what the
# service adds to tracking" is read off one run. Then stops the server with SIGTERM.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
DATASET="$ROOT/../shared/data/redkitchen"
FRAMES="0:600"
RATE=30
OUT=/tmp/fslam_service_bench
BIN="$ROOT/build/bin"

usage() {
  sed -n '2,10p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'
  cat <<'USAGE'

Options: --dataset DIR (default ../shared/data/redkitchen; the synthetic room when absent)
         --frames A:B (default 0:600)  --rate HZ|max (default 30)  --out DIR  --bin DIR
USAGE
}

while [[ $# -gt 0 ]]; do
  case "$1" in
    --dataset) DATASET="$2"; shift ;;
    --frames) FRAMES="$2"; shift ;;
    --rate) RATE="$2"; shift ;;
    --out) OUT="$2"; shift ;;
    --bin) BIN="$2"; shift ;;
    -h|--help) usage; exit 0 ;;
    *) echo "service_bench.sh: unknown option '$1'" >&2; usage >&2; exit 2 ;;
  esac
  shift
done

export CYCLONEDDS_URI="file://$ROOT/configs/dds/loopback.xml"  # never off loopback
mkdir -p "$OUT"
if [[ ! -d "$DATASET" ]]; then
  echo "dataset $DATASET is absent: using the synthetic room (300 frames)"
  DATASET="$OUT/synth"
  [[ -d "$DATASET" ]] || "$BIN/fslam" synth --out "$DATASET" --frames 300 --seed 1 >/dev/null
  FRAMES="0:300"
fi

echo "machine: $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs)"
echo "commit:  $(git -C "$ROOT" rev-parse --short HEAD)$(git -C "$ROOT" diff --quiet || echo '+dirty')"
echo "load before start: $(cut -d' ' -f1-3 /proc/loadavg)"
prefix="bench$$"
"$BIN/fslam-server" --prefix "$prefix" >"$OUT/server.log" 2>&1 &
server=$!
trap 'kill -TERM $server 2>/dev/null; wait $server 2>/dev/null' EXIT
sleep 1
echo
echo "== fslam stream --rate $RATE over loopback ($DATASET, frames $FRAMES)"
"$BIN/fslam" stream --dataset "$DATASET" --frames "$FRAMES" --rate "$RATE" --prefix "$prefix" \
  --session bench --out "$OUT/streamed.txt" 2>"$OUT/stream.err" | tee "$OUT/stream.txt"
grep -E "^server:|dropped" "$OUT/stream.err" | head -20 || true
kill -TERM $server
wait $server || true
trap - EXIT
tail -1 "$OUT/server.log"
echo
echo "== the same frames in-process: fslam track --threads 1"
"$BIN/fslam" track --dataset "$DATASET" --frames "$FRAMES" --threads 1 --out "$OUT/tracked.txt" \
  2>/dev/null | tail -12
echo "load after: $(cut -d' ' -f1-3 /proc/loadavg)"
