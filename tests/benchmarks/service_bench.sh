#!/usr/bin/env bash
# Service benchmark (opt-in; not part of the test suite): frame-to-pose latency, frames tracked
# and skipped, and ATE of the real fslam-server over the loopback DDS profile.
#
# Starts fslam-server with its own topic prefix (features on or off), plays a 640x480 sequence to
# it with `fslam stream` (JPEG colour, PNG depth: the client's defaults) at --rate Hz under a
# frame policy, and prints the stream report: frames sent / tracked / skipped / errors, tracked
# frames per 30 sent, ATE over the tracked frames, and latency p50 / p99 split into client encode,
# server decode, queue, track and the rest (DDS transport and publishing). The same frames are
# then tracked in-process with `fslam track` (features as the server), so "what the service
# costs" is read off one run. Server and client share this machine's cores; the client reads and
# encodes the sequence before the session opens (`fslam stream --preload`), as a camera hands over
# its frames, and each frame's encoding still counts in its latency (--no-preload: in its slot).
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
DATASET="$ROOT/../shared/data/redkitchen"
FRAMES=""
RATE=30
POLICY=live
FEATURES=auto
OUT=/tmp/fslam_service_bench
BIN="$ROOT/build/bin"
EXTRA=()
PRELOAD=(--preload)

usage() {
  sed -n '2,13p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'
  cat <<'USAGE'

Options: --dataset DIR|synth (default ../shared/data/redkitchen; `synth`, or when absent: the
           synthetic room, 300 frames, seed 1)
         --frames A:B (default all)  --rate HZ|max (default 30)  --policy live|queue (default live)
         --features auto|off|FILE (auto: out/autoencoder/builtin.fae, made if missing)
         --out DIR  --bin DIR  --set key=value (passed to the server and to fslam track)
         --no-preload (the client reads and encodes each frame in its slot, beside the server)
USAGE
}

while [[ $# -gt 0 ]]; do
  case "$1" in
    --dataset) DATASET="$2"; shift ;;
    --frames) FRAMES="$2"; shift ;;
    --rate) RATE="$2"; shift ;;
    --policy) POLICY="$2"; shift ;;
    --features) FEATURES="$2"; shift ;;
    --out) OUT="$2"; shift ;;
    --bin) BIN="$2"; shift ;;
    --set) EXTRA+=(--set "$2"); shift ;;
    --no-preload) PRELOAD=() ;;
    -h|--help) usage; exit 0 ;;
    *) echo "service_bench.sh: unknown option '$1'" >&2; usage >&2; exit 2 ;;
  esac
  shift
done

export CYCLONEDDS_URI="file://$ROOT/configs/dds/loopback.xml"  # never off loopback
mkdir -p "$OUT"
if [[ "$DATASET" == synth || ! -d "$DATASET" ]]; then
  [[ "$DATASET" == synth ]] || echo "dataset $DATASET is absent: using the synthetic room (300 frames)"
  DATASET="$OUT/synth"
  [[ -d "$DATASET" ]] || "$BIN/fslam" synth --out "$DATASET" --frames 300 --seed 1 >/dev/null
fi
# 7-Scenes colour is not registered to depth: the preset carries the calibrated colour camera.
DATASET_ARGS=()
[[ -n "$FRAMES" ]] && DATASET_ARGS+=(--frames "$FRAMES")
[[ -f "$DATASET/camera-intrinsics.txt" || -n "$(ls "$DATASET"/frame-000000.color.* 2>/dev/null)" ]] &&
  DATASET_ARGS+=(--config "$ROOT/configs/presets/seven_scenes.yaml")
SERVER_ARGS=("${EXTRA[@]}")
# fslam track with the server's real-time tracking encoder input (server.hpp realtime_pipeline),
# so that the in-process run is the same tracker; a --set of the key overrides both.
TRACK_ARGS=(--set tracking_encoder_input=512 "${EXTRA[@]}")
if [[ "$FEATURES" != off ]]; then
  weights="$FEATURES"
  if [[ "$FEATURES" == auto ]]; then
    weights="$ROOT/out/autoencoder/builtin.fae"
    [[ -f "$weights" ]] || bash "$ROOT/deploy/make_builtin_autoencoder.sh" --out "$weights" --fslam "$BIN/fslam"
  fi
  SERVER_ARGS+=(--set "features.autoencoder_path=$weights")
  TRACK_ARGS+=(--features "$weights")
fi

echo "machine: $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs)"
echo "commit:  $(git -C "$ROOT" rev-parse --short HEAD)$(git -C "$ROOT" diff --quiet || echo '+dirty')"
echo "load before start: $(cut -d' ' -f1-3 /proc/loadavg)"
echo "features: $FEATURES; policy: $POLICY; rate: $RATE; client: ${PRELOAD[*]:-encodes in its slots (--no-preload)}"
prefix="bench$$"
"$BIN/fslam-server" --prefix "$prefix" "${SERVER_ARGS[@]}" >"$OUT/server.log" 2>&1 &
server=$!
trap 'kill -TERM $server 2>/dev/null; wait $server 2>/dev/null' EXIT
echo
echo "== fslam stream --rate $RATE --policy $POLICY over loopback ($DATASET ${FRAMES:+frames $FRAMES})"
"$BIN/fslam" stream --dataset "$DATASET" "${DATASET_ARGS[@]}" --rate "$RATE" --policy "$POLICY" \
  --prefix "$prefix" --session bench --out "$OUT/streamed.txt" --report "$OUT/stream.json" "${PRELOAD[@]}" \
  2>"$OUT/stream.err" | tee "$OUT/stream.txt" || true
grep -E "^server:" "$OUT/stream.err" | head -5 || true
kill -TERM $server
wait $server || true
trap - EXIT
tail -1 "$OUT/server.log"
python3 - "$OUT/stream.json" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))
sent, tracked = r["frames_sent"], r["tracked"]
l = r["latency"]["frame_to_pose"]
print(f"summary: {tracked}/{sent} tracked ({30.0 * tracked / max(sent, 1):.1f} of every 30), "
      f"{r['skipped']} skipped, {r['errors']} errors; frame -> pose p50 {l['p50_ms']:.1f} ms, "
      f"p99 {l['p99_ms']:.1f} ms; ATE {100 * r.get('ate', {}).get('rmse_m', float('nan')):.2f} cm")
PY
echo
echo "== the same frames in-process: fslam track --threads 1"
"$BIN/fslam" track --dataset "$DATASET" "${DATASET_ARGS[@]}" "${TRACK_ARGS[@]}" --threads 1 \
  --out "$OUT/tracked.txt" 2>/dev/null | tail -9
echo "load after: $(cut -d' ' -f1-3 /proc/loadavg)"
