#!/usr/bin/env bash
# What DDS Security costs the service: the same stream to a server on the plain loopback profile
# and on configs/dds/secure.xml (authentication, AES-GCM encryption of discovery, liveliness and
# data, access control), alternating, REPEAT times each: at full speed (throughput: frames per
# second to the last pose) and at 10 Hz (latency without queueing: frame-to-pose p50 / p99,
# client clock). Prints every run and the medians
# (docs/deployment.md "Secure profile"). Opt-in; a shared machine gives noisy figures: compare
# the two profiles within one run.
#
#   bash tests/benchmarks/dds_security_bench.sh [BIN_DIR] [--frames N] [--repeat R]
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
BIN="$ROOT/build/bin"
[[ $# -gt 0 && "$1" != --* ]] && { BIN="$1"; shift; }
FRAMES=120 REPEAT=3
while [[ $# -gt 0 ]]; do
  case "$1" in
    --frames) FRAMES="$2"; shift ;;
    --repeat) REPEAT="$2"; shift ;;
    *) echo "unknown option $1" >&2; exit 2 ;;
  esac
  shift
done
# shellcheck source=../common/script_support.sh
source "$ROOT/tests/common/script_support.sh"  # tracked_all
WORK="$(mktemp -d /tmp/fslam_secbench.XXXXXX)"
SERVER_PID=""
cleanup() { [[ -n "$SERVER_PID" ]] && kill -TERM "$SERVER_PID" 2>/dev/null; wait 2>/dev/null; rm -rf "$WORK"; }
trap cleanup EXIT
bash "$ROOT/deploy/make_certs.sh" "$WORK/certs" >/dev/null
"$BIN/fslam" synth --out "$WORK/seq" --frames "$FRAMES" --seed 6 >/dev/null 2>&1

profile_env() {  # profile_env plain|secure IDENTITY
  if [[ $1 == plain ]]; then
    echo "CYCLONEDDS_URI=file://$ROOT/configs/dds/loopback.xml"
  else
    echo "CYCLONEDDS_URI=file://$ROOT/configs/dds/secure.xml FSLAM_DDS_CERTS=$WORK/certs FSLAM_DDS_IDENTITY=$2"
  fi
}
declare -A FPS P50 P99
run() {  # run PROFILE INDEX RATE
  local prefix="bench$$$2$1$3"
  env $(profile_env "$1" server) "$BIN/fslam-server" --prefix "$prefix" >"$WORK/server.log" 2>&1 &
  SERVER_PID=$!
  for _ in $(seq 1 200); do grep -q "serving on" "$WORK/server.log" && break; sleep 0.05; done
  env $(profile_env "$1" client) "$BIN/fslam" stream --dataset "$WORK/seq" --prefix "$prefix" \
    --session s --map "m$2" --rate "$3" --policy queue --report "$WORK/stream.json" >"$WORK/stream.txt" 2>&1
  kill -TERM "$SERVER_PID"; wait "$SERVER_PID" 2>/dev/null; SERVER_PID=""
  local fps p50 p99
  fps=$(sed -n 's/.*(\([0-9.]*\) tracked frames\/s).*/\1/p' "$WORK/stream.txt")
  read -r p50 p99 < <(awk '/frame -> pose \(client clock\)/ { print $(NF-1), $NF }' "$WORK/stream.txt")
  tracked_all "$WORK/stream.json" "$FRAMES" || { echo "run $1 $2: not every pose came back"; cat "$WORK/stream.txt"; exit 1; }
  if [[ $3 == max ]]; then
    FPS[$1]+="$fps "
    printf '%-7s run %d, full speed: %6.1f frames/s\n' "$1" "$2" "$fps"
  else
    P50[$1]+="$p50 " P99[$1]+="$p99 "
    printf '%-7s run %d, %s Hz: frame->pose p50 %7.2f ms  p99 %7.2f ms\n' "$1" "$2" "$3" "$p50" "$p99"
  fi
}
median() { tr ' ' '\n' | grep -v '^$' | sort -g | awk '{ v[NR] = $1 } END { print (NR % 2) ? v[(NR + 1) / 2] : (v[NR / 2] + v[NR / 2 + 1]) / 2 }'; }
echo "$FRAMES frames of 640x480 (JPEG colour, PNG depth), $REPEAT runs per profile and rate, $(nproc) cores"
for i in $(seq 1 "$REPEAT"); do
  run plain "$i" max; run secure "$i" max
  run plain "$i" 10; run secure "$i" 10
done
for p in plain secure; do
  printf '%-7s median: %6.1f frames/s   frame->pose p50 %7.2f ms  p99 %7.2f ms\n' "$p" \
    "$(echo "${FPS[$p]}" | median)" "$(echo "${P50[$p]}" | median)" "$(echo "${P99[$p]}" | median)"
done
