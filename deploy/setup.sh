#!/usr/bin/env bash
# featureslam set-up: install the Debian 12 packages (only those missing), configure, build, then
# run the main job (--demo) or the whole test suite (--test). Safe to run again: every step skips
# what is already done, and the build is incremental (ccache when present).
#
#   bash deploy/setup.sh --demo    # install, build, run the main job on the built-in default
#   bash deploy/setup.sh --test    # install, build, run every test (what .ci/run calls)
#
# Options: --install-only (the packages, nothing else; used by deploy/docker/Dockerfile)
#          --build-dir DIR (default build)  --jobs N (default: all cores)
#          --cuda AUTO|ON|OFF (default AUTO: the CUDA backend is built when nvcc is found)
#          --out DIR (demo output, default out/demo)  --no-install (skip apt)
#          --k8s-check (also: node + npm ci in deploy/k8s/validate, for the Kubernetes manifest
#          test; containers are deploy/test_containers.sh, opt-in and separate)
#          --fuzz-seconds N (--test: after ctest, every libFuzzer target runs N s over its seed
#          corpus, tests/fuzz/run_fuzz.sh --opt 0 (an -O0 build, the quicker to make); default
#          10, 0 = skip)
#          --sanitize address|thread (an instrumented build in build-asan / build-tsan; with
#          --test: the whole suite under ASan + UBSan, or the threaded server tests under TSan;
#          docs/reliability.md)
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
MODE=build
BUILD_DIR="$ROOT/build"
JOBS="$(nproc)"
CUDA=AUTO
OUT="$ROOT/out/demo"
INSTALL=1
K8S_CHECK=0
FUZZ_SECONDS=10
SANITIZE=""
BUILD_DIR_SET=0

usage() { awk 'NR > 1 && !/^#/ { exit } NR > 1 { sub(/^# ?/, ""); print }' "${BASH_SOURCE[0]}"; }

while [[ $# -gt 0 ]]; do
  case "$1" in
    --demo) MODE=demo ;;
    --test) MODE=test ;;
    --build-only) MODE=build ;;
    --install-only) MODE=install ;;
    --build-dir) BUILD_DIR="$(realpath -m "$2")"; BUILD_DIR_SET=1; shift ;;
    --jobs) JOBS="$2"; shift ;;
    --cuda) CUDA="$2"; shift ;;
    --out) OUT="$(realpath -m "$2")"; shift ;;
    --no-install) INSTALL=0 ;;
    --k8s-check) K8S_CHECK=1 ;;
    --fuzz-seconds) FUZZ_SECONDS="$2"; shift ;;
    --sanitize) SANITIZE="$2"; shift ;;
    -h|--help) usage; exit 0 ;;
    *) echo "setup.sh: unknown option '$1'" >&2; usage >&2; exit 2 ;;
  esac
  shift
done

log() { printf '\n== %s\n' "$*"; }

case "$SANITIZE" in
  "") ;;
  address) [[ $BUILD_DIR_SET -eq 1 ]] || BUILD_DIR="$ROOT/build-asan"; CUDA=OFF ;;
  thread) [[ $BUILD_DIR_SET -eq 1 ]] || BUILD_DIR="$ROOT/build-tsan"; CUDA=OFF ;;
  *) echo "setup.sh: --sanitize takes address or thread, not '$SANITIZE'" >&2; exit 2 ;;
esac

# Debian 12 packages of the product (see ../shared/platform.md for what each is for).
PACKAGES=(
  build-essential cmake ninja-build pkg-config git ccache
  libeigen3-dev libopencv-dev libflann-dev libceres-dev
  cyclonedds-dev cyclonedds-tools libopenimageio-dev openimageio-tools
  libgtest-dev libgmock-dev libyaml-cpp-dev nlohmann-json3-dev libcli11-dev libtbb-dev
  libpng-dev  # the client writes depth PNGs itself (client/src/depth_png.hpp)
  libboost-dev  # Boost.Beast (headers only): fslam-gateway's HTTP + WebSocket (docs/viewer.md)
  libsqlite3-dev  # rosbag2 recordings in the sqlite3 storage: fslam stream --rosbag2 (docs/ros2.md)
  python3-onnx  # tests only: writes the tiny ONNX models of the onnx feature encoder's tests
  openssl iproute2  # tests only: DDS Security certificates, network namespaces of the scale-out test
)

# The browser viewer's page is bundled with npm (bundle_viewer); its end-to-end test drives Debian's
# chromium (installed for --test only: about 80 MB, 47 s on dev-2c).
VIEWER_PACKAGES=(nodejs npm)
TEST_PACKAGES=(chromium)
# The libFuzzer targets (tests/fuzz) build with Debian's clang and its compiler-rt.
FUZZ_PACKAGES=(clang libclang-rt-14-dev)

install_packages() { install_missing "${PACKAGES[@]}"; }

# Installs those of the given Debian packages that are missing.
install_missing() {
  local missing=()
  for p in "$@"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
  done
  if [[ ${#missing[@]} -eq 0 ]]; then
    log "packages: all $# present"
    return
  fi
  log "packages: installing ${missing[*]}"
  local sudo=()
  if [[ $(id -u) -ne 0 ]]; then
    command -v sudo >/dev/null || { echo "setup.sh: run as root, or install: ${missing[*]}" >&2; exit 1; }
    sudo=(sudo)
  fi
  "${sudo[@]}" apt-get update -qq
  DEBIAN_FRONTEND=noninteractive "${sudo[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}"
}

build() {
  local generator=()
  command -v ninja >/dev/null && generator=(-G Ninja)
  if [[ ! -f "$BUILD_DIR/CMakeCache.txt" ]]; then
    log "configure ($BUILD_DIR, CUDA $CUDA)"
    cmake -S "$ROOT" -B "$BUILD_DIR" "${generator[@]}" -DCMAKE_BUILD_TYPE=Release \
      -DFSLAM_WITH_CUDA="$CUDA" -DFSLAM_SANITIZE="$SANITIZE"
  else
    cmake "$BUILD_DIR" -DFSLAM_WITH_CUDA="$CUDA" -DFSLAM_SANITIZE="$SANITIZE" >/dev/null
  fi
  log "build ($JOBS jobs)"
  local t0=$SECONDS
  cmake --build "$BUILD_DIR" -j "$JOBS"
  echo "build took $((SECONDS - t0)) s; binaries in $BUILD_DIR/bin"
}

# The viewer's page (docs/viewer.md): npm installs three.js, Spark and esbuild (and puppeteer-core
# for the browser test) from the npm registry as package-lock.json pins them, and esbuild bundles
# the page into $BUILD_DIR/viewer, which fslam-gateway serves; nothing is fetched at run time.
# Node and npm come from Debian when missing. Without npm the page is skipped; the rest builds.
bundle_viewer() {
  local web="$ROOT/client/gateway/web"
  if ! command -v npm >/dev/null; then
    if [[ $INSTALL -eq 1 ]]; then
      install_missing "${VIEWER_PACKAGES[@]}"
    else
      echo "viewer: npm not found; the page is not bundled (fslam-gateway needs it; see docs/viewer.md)"
      return
    fi
  fi
  local t0=$SECONDS
  # npm ci again only when the lock file changed since the last install.
  if [[ ! -f "$web/node_modules/.package-lock.json" || "$web/package-lock.json" -nt "$web/node_modules/.package-lock.json" ]]; then
    log "viewer: npm ci ($web)"
    (cd "$web" && npm ci --no-audit --no-fund --loglevel=error)
  fi
  node "$web/build.mjs" "$BUILD_DIR/viewer"
  echo "viewer page took $((SECONDS - t0)) s"
}

# No DDS traffic may leave loopback on these machines: every process started from here uses it.
export CYCLONEDDS_URI="file://$ROOT/configs/dds/loopback.xml"

run_tests() {
  local data="$ROOT/../shared/data"
  if [[ -d "$data" ]]; then
    echo "real data: $data"
  else
    echo "real data: $data is absent; tests that need it will be skipped"
  fi
  if [[ "$SANITIZE" == thread ]]; then
    # The threaded code: server sessions, ingest, queries and mapping threads, the pipeline's
    # tracking / mapping / loop-closure threads, the map versions (docs/reliability.md).
    # FSLAM_LIBRARY_THREADS=1: TBB and OpenCV start no workers (they are not instrumented, and
    # TSan would report their joins as races), so the threads left are our own.
    log "tests under TSan (the threaded tests, $JOBS jobs, DDS on loopback, FSLAM_LIBRARY_THREADS=1)"
    # tests/tsan.supp: reports inside GDAL and Cyclone DDS themselves (each entry says why).
    FSLAM_LIBRARY_THREADS=1 \
      TSAN_OPTIONS="halt_on_error=1:second_deadlock_stack=1:suppressions=$ROOT/tests/tsan.supp" \
      ctest --test-dir "$BUILD_DIR" --output-on-failure -j "$JOBS" --timeout 1800 \
      -R '^(Service[A-Za-z]*|Client|SynthPipeline|LoopOnSynthRoom|LoopClosureCli|MapVersions|MapFiles|Ros2Bridge)\.'
    return
  fi
  if [[ "$SANITIZE" == address ]]; then
    log "tests under ASan + UBSan ($JOBS jobs, DDS on loopback)"
    export ASAN_OPTIONS="detect_leaks=1:abort_on_error=1" UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1"
    ctest --test-dir "$BUILD_DIR" --output-on-failure -j "$JOBS" --timeout 1800
    return
  fi
  log "tests (ctest, $JOBS jobs, DDS on loopback)"
  ctest --test-dir "$BUILD_DIR" --output-on-failure -j "$JOBS" --timeout 900
  if [[ "$FUZZ_SECONDS" -gt 0 ]]; then
    log "fuzz smoke: every libFuzzer target for $FUZZ_SECONDS s (tests/fuzz/run_fuzz.sh)"
    bash "$ROOT/tests/fuzz/run_fuzz.sh" --opt 0 --seconds "$FUZZ_SECONDS" --jobs "$JOBS"
  fi
}

# The main job, end to end over DDS: a server on the loopback profile (features on), the
# synthetic room streamed to it live at 30 Hz, renders requested from poses of the trajectory,
# promptless and one-click segmentation, the map saved, and the server stopped cleanly (it
# saves its maps on the way out). Ends with a summary of what it wrote and the figures.
DEMO_SERVER_PID="" DEMO_GATEWAY_PID=""  # globals: the EXIT trap runs after run_demo's locals are gone
stop_demo_server() {
  local pid
  for pid in "$DEMO_GATEWAY_PID" "$DEMO_SERVER_PID"; do
    [[ -n "$pid" ]] || continue
    kill -TERM "$pid" 2>/dev/null || true
    wait "$pid" 2>/dev/null || true
  done
  DEMO_SERVER_PID="" DEMO_GATEWAY_PID=""
}

run_demo() {
  local fslam="$BUILD_DIR/bin/fslam" server="$BUILD_DIR/bin/fslam-server"
  local prefix="demo$$" t0=$SECONDS
  rm -rf "$OUT/maps" "$OUT/renders" "$OUT/segmentation"
  mkdir -p "$OUT/renders" "$OUT/segmentation"
  log "main job: built-in synthetic room through the service -> $OUT"
  "$fslam" version
  [[ -d "$OUT/sequence" ]] || "$fslam" synth --out "$OUT/sequence" --frames 300 --seed 1
  "$fslam" info --dataset "$OUT/sequence"
  # Feature autoencoder weights for the builtin encoder, pretrained on other synthetic rooms
  # (made once, then reused).
  local weights="$ROOT/out/autoencoder/builtin.fae"
  if [[ ! -f "$weights" ]]; then
    log "feature autoencoder weights (deploy/make_builtin_autoencoder.sh, about a minute and a half)"
    bash "$ROOT/deploy/make_builtin_autoencoder.sh" --out "$weights" --fslam "$fslam"
  fi

  log "server (prefix $prefix, maps in $OUT/maps, features on, log $OUT/server.log)"
  "$server" --prefix "$prefix" --map-dir "$OUT/maps" --set "features.autoencoder_path=$weights" \
    >"$OUT/server.log" 2>&1 &
  DEMO_SERVER_PID=$!
  trap stop_demo_server EXIT  # the server is ours: stop it whatever happens below
  # The browser viewer (docs/viewer.md), on loopback, on a free port.
  local viewer_url="(no viewer: the page was not bundled; docs/viewer.md)"
  if [[ -x "$BUILD_DIR/bin/fslam-gateway" && -f "$BUILD_DIR/viewer/index.html" ]]; then
    rm -f "$OUT/gateway.port"
    "$BUILD_DIR/bin/fslam-gateway" --prefix "$prefix" --port 0 --port-file "$OUT/gateway.port" \
      >"$OUT/gateway.log" 2>&1 &
    DEMO_GATEWAY_PID=$!
    local i
    for i in $(seq 50); do [[ -s "$OUT/gateway.port" ]] && break; sleep 0.1; done
    [[ -s "$OUT/gateway.port" ]] && viewer_url="http://127.0.0.1:$(cat "$OUT/gateway.port")/"
  fi
  log "viewer: $viewer_url (open it in a browser while the demo runs: the map grows live)"

  log "stream the sequence live at 30 Hz (JPEG colour, PNG depth, encoded before the clock starts as a camera's; the server skips to the newest frame when behind)"
  "$fslam" stream --dataset "$OUT/sequence" --prefix "$prefix" --session demo --map room \
    --rate 30 --policy live --preload --out "$OUT/trajectory.txt" --report "$OUT/stream.json" | tee "$OUT/stream.txt"

  log "renders from the server, at tracked poses of the trajectory"
  local frame
  local tracked_frames
  tracked_frames=$(python3 -c "
import json; r = json.load(open('$OUT/stream.json')); print(' '.join(str(f) for f in r['tracked_frame_ids'][::60][:5]))")
  for frame in $tracked_frames; do
    "$fslam" render --map room --frame "$frame" --prefix "$prefix" \
      --out "$OUT/renders/frame_$(printf %03d "$frame").png"
  done
  local seg_frame
  seg_frame=$(python3 -c "
import json; r = json.load(open('$OUT/stream.json')); ids = r['tracked_frame_ids']; print(ids[len(ids) // 2])")
  log "segmentation from the server at frame $seg_frame: instances without a prompt, and one click"
  "$fslam" segment --map room --frame "$seg_frame" --prefix "$prefix" \
    --out "$OUT/segmentation/instances.png" --overlay "$OUT/segmentation/instances_overlay.png"
  "$fslam" segment --map room --frame "$seg_frame" --points 320,300 --prefix "$prefix" \
    --out "$OUT/segmentation/click.png" --overlay "$OUT/segmentation/click_overlay.png"
  "$fslam" status --prefix "$prefix" | tee "$OUT/status.txt"
  "$fslam" save-map --map room --prefix "$prefix"

  if [[ -n "${FSLAM_DEMO_KEEP_VIEWER:-}" && -n "$DEMO_GATEWAY_PID" ]]; then
    log "viewer still serving at $viewer_url (FSLAM_DEMO_KEEP_VIEWER set): press Enter to stop"
    read -r _ || true
  fi
  log "stop the gateway and the server"
  [[ -n "$DEMO_GATEWAY_PID" ]] && { kill -TERM "$DEMO_GATEWAY_PID"; wait "$DEMO_GATEWAY_PID" || true; }
  DEMO_GATEWAY_PID=""
  kill -TERM "$DEMO_SERVER_PID"
  wait "$DEMO_SERVER_PID"
  DEMO_SERVER_PID=""
  trap - EXIT
  cat "$OUT/server.log"

  "$fslam" eval --gt "$OUT/sequence/groundtruth.txt" --est "$OUT/trajectory.txt" \
    --json "$OUT/trajectory_eval.json" --plot "$OUT/trajectory.png"
  log "main job done in $((SECONDS - t0)) s; outputs"
  echo "sequence:        $OUT/sequence (TUM layout: rgb/, depth/, labels/, groundtruth.txt)"
  echo "trajectory:      $OUT/trajectory.txt (poses the server sent back, TUM format)"
  echo "stream report:   $OUT/stream.txt, $OUT/stream.json (tracked / skipped, ATE, latency by stage)"
  echo "renders:         $OUT/renders/ (colour, depth, normals, opacity from the served map)"
  echo "segmentation:    $OUT/segmentation/ (promptless instances and a one-click mask, with overlays)"
  echo "map:             $OUT/maps/room/ (map.ply: 3DGS PLY; poses, camera; served again on restart)"
  echo "trajectory plot: $OUT/trajectory.png (tracked vs ground truth)"
  echo "evaluation:      $OUT/trajectory_eval.json (ATE, RPE)"
  echo "server:          $OUT/server.log, $OUT/status.txt"
  echo "viewer:          $viewer_url during the run (FSLAM_DEMO_KEEP_VIEWER=1 keeps it up at the end); $OUT/gateway.log"
  python3 - "$OUT/stream.json" "$OUT/trajectory_eval.json" <<'PY'
import json, sys
s, e = json.load(open(sys.argv[1])), json.load(open(sys.argv[2]))
lat = s["latency"]["frame_to_pose"]
ate = e.get("ate", {}).get("rmse_m", e.get("ate_rmse_m", float("nan")))
print(f"\nfigures: {s['tracked']} of {s['frames_sent']} frames tracked, {s['skipped']} skipped "
      f"(live policy), {s['errors']} errors; ATE {100 * ate:.2f} cm; frame -> pose "
      f"p50 {lat['p50_ms']:.0f} ms, p99 {lat['p99_ms']:.0f} ms")
PY
}

# Opt-in: the offline schema check of deploy/k8s needs node and two npm packages (locked in
# deploy/k8s/validate/package-lock.json); fetched here once, never at test time.
install_k8s_check() {
  if ! command -v npm >/dev/null; then
    [[ $INSTALL -eq 1 ]] || { echo "setup.sh: --k8s-check needs npm (or drop --no-install)" >&2; exit 1; }
    PACKAGES=(nodejs npm)
    install_packages
  fi
  if [[ ! -d "$ROOT/deploy/k8s/validate/node_modules/kubernetes-models" ]]; then
    log "npm ci in deploy/k8s/validate (kubernetes-models, yaml)"
    npm ci --prefix "$ROOT/deploy/k8s/validate" --no-audit --no-fund
  fi
}

[[ $INSTALL -eq 1 ]] && install_packages
[[ $K8S_CHECK -eq 1 ]] && install_k8s_check
[[ "$MODE" == install ]] && exit 0
[[ $INSTALL -eq 1 && "$MODE" == test ]] && install_missing "${TEST_PACKAGES[@]}"
[[ $INSTALL -eq 1 && "$MODE" == test && "$FUZZ_SECONDS" -gt 0 && -z "$SANITIZE" ]] && install_missing "${FUZZ_PACKAGES[@]}"
build
bundle_viewer
case "$MODE" in
  test) run_tests ;;
  demo) run_demo ;;
  build) ;;
esac
