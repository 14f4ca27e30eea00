#!/usr/bin/env bash
# ROS 2 input latency against the native one (opt-in benchmark; not part of the test suite).
#
# Starts fslam-server with the ROS 2 bridge on (ros2.*, docs/ros2.md) on the loopback profile and
# plays the same sequence twice at --rate Hz, live policy: once as a ROS 2 camera driver would
# (fslam_bench_ros2_latency: sensor_msgs Image rgb8 + 32FC1 + CameraInfo, raw) timing image
# publication -> PoseStamped, once with the native client (`fslam stream`: JPEG colour, PNG depth)
# timing push_frame -> pose. Prints p50 / p99 of both. Server and clients share this machine's
# cores: run it on an idle machine and report the machine, thread count and commit
# (docs/benchmarks.md).
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
BIN="$ROOT/build/bin"
FRAMES=300
RATE=10
OUT=/tmp/fslam_ros2_latency_bench
# reliable: no fragment of a megabyte image is lost on the way (best_effort loses whole frames
# when the socket receive buffer overflows: docs/ros2.md, QoS)
RELIABILITY=reliable

while [[ $# -gt 0 ]]; do
  case "$1" in
    --frames) FRAMES="$2"; shift ;;
    --rate) RATE="$2"; shift ;;
    --bin) BIN="$2"; shift ;;
    --out) OUT="$2"; shift ;;
    --reliability) RELIABILITY="$2"; shift ;;
    -h|--help) sed -n '2,11p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'
               echo "Options: --frames N (default 300, synthetic room)  --rate HZ (default 10)  --bin DIR  --out DIR  --reliability reliable|best_effort"
               exit 0 ;;
    *) echo "ros2_latency_bench.sh: unknown option '$1'" >&2; exit 2 ;;
  esac
  shift
done
[[ -x "$BIN/fslam_bench_ros2_latency" ]] || {
  echo "build it first: cmake -S $ROOT -B $ROOT/build -DFSLAM_BUILD_BENCHMARKS=ON && cmake --build $ROOT/build --target fslam_bench_ros2_latency" >&2
  exit 2
}

export CYCLONEDDS_URI="file://$ROOT/configs/dds/loopback.xml"  # never off loopback
mkdir -p "$OUT"
SEQ="$OUT/synth$FRAMES"
[[ -d "$SEQ" ]] || "$BIN/fslam" synth --out "$SEQ" --frames "$FRAMES" --seed 1 >/dev/null
PREFIX="r2bench$$"
NS="/r2bench$$"
SERVER_PID=""
trap '[[ -n "$SERVER_PID" ]] && kill -TERM "$SERVER_PID" 2>/dev/null; [[ -n "$SERVER_PID" ]] && wait "$SERVER_PID" 2>/dev/null' EXIT
"$BIN/fslam-server" --prefix "$PREFIX" --set ros2.enabled=true \
  --set ros2.colour_topic="$NS/color/image_raw" --set ros2.depth_topic="$NS/depth/image_raw" \
  --set ros2.camera_info_topic="$NS/color/camera_info" --set ros2.pose_topic="$NS/fslam/pose" \
  --set ros2.path_topic="$NS/fslam/path" --set ros2.tf_topic="$NS/tf" --set ros2.map="ros2_$PREFIX" \
  --set ros2.reliability="$RELIABILITY" \
  >"$OUT/server.log" 2>&1 &
SERVER_PID=$!
for _ in $(seq 1 200); do grep -q "serving on" "$OUT/server.log" && break; sleep 0.1; done

echo "== ROS 2 input ($FRAMES frames at $RATE Hz, raw rgb8 + 32FC1)"
"$BIN/fslam_bench_ros2_latency" --dataset "$SEQ" --namespace "$NS" --pose-topic "$NS/fslam/pose" --rate "$RATE"
echo "== native client ($FRAMES frames at $RATE Hz, JPEG + PNG, fslam stream)"
"$BIN/fslam" stream --dataset "$SEQ" --prefix "$PREFIX" --session "native$$" --rate "$RATE" --policy live \
  --report "$OUT/native.json" >"$OUT/native.txt" 2>"$OUT/native.err" || true
python3 - "$OUT/native.json" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))
l = r["latency"]["frame_to_pose"]
print(f"native: {r['frames_sent']} frames sent, {r['tracked']} tracked, {r['skipped']} skipped")
print(f"native push_frame -> pose, ms: p50 {l['p50_ms']:.2f} p99 {l['p99_ms']:.2f}")
PY
