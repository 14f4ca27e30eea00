#!/usr/bin/env bash
# Session modes over DDS on real data (issue 20; opt-in, not part of the test suite): a map of the
# first half of a recording is streamed and saved, the server restarted, and then
#   1. a localise session (with views at --views Hz) on frames of the first half it never streamed,
#   2. an extend session maps the second half into the saved map,
#   3. a localise session on frames of the second half it never streamed, in the extended map;
# and, for comparison, one map session streams both halves in one go. Every pose is compared with
# the ground truth without alignment (the map's world is the first frame's ground truth), so the
# figures say where the camera is in the map, not only the trajectory's shape.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
DATASET="$ROOT/../shared/data/redkitchen"
HALF=300          # frames [0, HALF) are mapped first, [HALF, 2 HALF) extend
STEP=2            # every STEP-th frame is streamed by map and extend sessions
PROBE=8           # localise sessions take every PROBE-th frame, offset 1 (never streamed)
VIEWS=5
OUT=/tmp/fslam_session_modes
BIN="$ROOT/build/bin"

usage() {
  sed -n '2,9p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'
  cat <<'USAGE'

Options: --dataset DIR (default ../shared/data/redkitchen)  --half N (default 300)
         --views HZ (default 5)  --out DIR (default /tmp/fslam_session_modes)  --bin DIR
USAGE
}

while [[ $# -gt 0 ]]; do
  case "$1" in
    --dataset) DATASET="$2"; shift ;;
    --half) HALF="$2"; shift ;;
    --views) VIEWS="$2"; shift ;;
    --out) OUT="$2"; shift ;;
    --bin) BIN="$2"; shift ;;
    -h|--help) usage; exit 0 ;;
    *) echo "session_modes.sh: unknown option '$1'" >&2; usage >&2; exit 2 ;;
  esac
  shift
done
[[ -d "$DATASET" ]] || { echo "session_modes.sh: no dataset at $DATASET (../shared/data)" >&2; exit 1; }
[[ -x "$BIN/fslam-server" ]] || { echo "session_modes.sh: no $BIN/fslam-server; build first" >&2; exit 1; }

export CYCLONEDDS_URI="file://$ROOT/configs/dds/loopback.xml"  # never off loopback
rm -rf "$OUT" && mkdir -p "$OUT"
CONFIG=()
[[ "$DATASET" == *redkitchen* ]] && CONFIG=(--config "$ROOT/configs/presets/seven_scenes.yaml")
END=$((2 * HALF))
prefix="modes$$"
server=""
start_server() {
  "$BIN/fslam-server" --prefix "$prefix" --map-dir "$OUT/maps" "${CONFIG[@]}" >>"$OUT/server.log" 2>&1 &
  server=$!
}
stop_server() {
  [[ -n "$server" ]] || return 0
  kill -TERM "$server" 2>/dev/null || true
  wait "$server" 2>/dev/null || true
  server=""
}
trap stop_server EXIT
# stream NAME ARGS...: one fslam stream (queue policy: every frame tracked), report in NAME.json.
stream() {
  local name="$1"
  shift
  "$BIN/fslam" stream --dataset "$DATASET" "${CONFIG[@]}" --prefix "$prefix" --session "$name" \
    --policy queue --rate max --report "$OUT/$name.json" --out "$OUT/$name.tum" "$@" >"$OUT/$name.txt" 2>&1 ||
    { echo "session_modes.sh: stream $name failed:" >&2; tail -5 "$OUT/$name.txt" >&2; exit 1; }
}

echo "machine: $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs)"
echo "commit:  $(git -C "$ROOT" rev-parse --short HEAD)$(git -C "$ROOT" diff --quiet || echo '+dirty')"
echo "load before start: $(cut -d' ' -f1-3 /proc/loadavg)"
t0=$SECONDS
start_server
stream build --map kitchen --frames "0:$HALF:$STEP"
stop_server  # saves kitchen with its keyframes
start_server
stream localise1 --mode localise --map kitchen --frames "1:$HALF:$PROBE" --views "$VIEWS" --views-out "$OUT/views1"
stream extend --mode extend --map kitchen --frames "$HALF:$END:$STEP"
stream localise2 --mode localise --map kitchen --frames "$((HALF + 1)):$END:$PROBE"
stream oneshot --map oneshot --frames "0:$END:$STEP"
stop_server
echo "sessions took $((SECONDS - t0)) s; load after: $(cut -d' ' -f1-3 /proc/loadavg)"

python3 - "$OUT" "$DATASET" "$HALF" <<'PY'
import json, math, sys
out, dataset, half = sys.argv[1], sys.argv[2], int(sys.argv[3])

def tum(path):
    poses = {}
    for line in open(path):
        if line.startswith("#") or not line.strip():
            continue
        v = [float(x) for x in line.replace(",", " ").split()]
        poses[round(v[0] * 30)] = v[1:4]  # 7-Scenes frames are at i / 30 s
    return poses

truth = {}
import glob, os
for f in glob.glob(os.path.join(dataset, "frame-*.pose.txt")):
    i = int(os.path.basename(f)[6:12])
    m = [[float(x) for x in l.split()] for l in open(f) if l.strip()]
    truth[i] = [m[0][3], m[1][3], m[2][3]]

def errors(name, first=0):
    est = tum(f"{out}/{name}.tum")
    e = sorted(math.dist(p, truth[i]) for i, p in est.items() if i >= first and i in truth)
    return e

def line(label, name, first=0):
    r = json.load(open(f"{out}/{name}.json"))
    e = errors(name, first)
    n = len(e)
    within = sum(1 for x in e if x <= 0.05)
    extra = f", {r.get('views', 0)} views" if r.get("views") else ""
    print(f"{label:34s} {r['frames_sent']:4d} sent, {r.get('lost', 0):3d} lost, "
          f"{n:4d} compared: median {100 * e[n // 2]:.2f} cm, max {100 * e[-1]:.2f} cm, "
          f"{within}/{n} within 5 cm{extra}")

print("\nposition error against ground truth, no alignment (the map's world is frame 0's truth):")
line("map   first half (build)", "build")
line("localise first half, never streamed", "localise1")
line("extend second half, after a restart", "extend")
line("localise second half, never streamed", "localise2")
line("map   both halves in one session", "oneshot")
line("  its second half alone", "oneshot", half)
PY
