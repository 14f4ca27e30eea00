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
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
MODE=build
BUILD_DIR="$ROOT/build"
JOBS="$(nproc)"
CUDA=AUTO
OUT="$ROOT/out/demo"
INSTALL=1
K8S_CHECK=0

usage() { awk 'NR > 1 && !/^#/ { exit } NR > 1 { sub(/^# ?/, ""); print }' "${BASH_SOURCE[0]}"; }

while [[ $# -gt 0 ]]; do
  case "$1" in
    --demo) MODE=demo ;;
    --test) MODE=test ;;
    --build-only) MODE=build ;;
    --install-only) MODE=install ;;
    --build-dir) BUILD_DIR="$(realpath -m "$2")"; shift ;;
    --jobs) JOBS="$2"; shift ;;
    --cuda) CUDA="$2"; shift ;;
    --out) OUT="$(realpath -m "$2")"; shift ;;
    --no-install) INSTALL=0 ;;
    --k8s-check) K8S_CHECK=1 ;;
    -h|--help) usage; exit 0 ;;
    *) echo "setup.sh: unknown option '$1'" >&2; usage >&2; exit 2 ;;
  esac
  shift
done

log() { printf '\n== %s\n' "$*"; }

# Debian 12 packages of the product (see ../shared/platform.md for what each is for).
PACKAGES=(
  build-essential cmake ninja-build pkg-config git ccache
  libeigen3-dev libopencv-dev libflann-dev libceres-dev
  cyclonedds-dev cyclonedds-tools libopenimageio-dev openimageio-tools
  libgtest-dev libgmock-dev libyaml-cpp-dev nlohmann-json3-dev libcli11-dev libspdlog-dev libtbb-dev
  python3-onnx  # tests only: writes the tiny ONNX models of the onnx feature encoder's tests
  openssl iproute2  # tests only: DDS Security certificates, network namespaces of the scale-out test
)

install_packages() {
  local missing=()
  for p in "${PACKAGES[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
  done
  if [[ ${#missing[@]} -eq 0 ]]; then
    log "packages: all ${#PACKAGES[@]} present"
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
      -DFSLAM_WITH_CUDA="$CUDA"
  else
    cmake "$BUILD_DIR" -DFSLAM_WITH_CUDA="$CUDA" >/dev/null
  fi
  log "build ($JOBS jobs)"
  local t0=$SECONDS
  cmake --build "$BUILD_DIR" -j "$JOBS"
  echo "build took $((SECONDS - t0)) s; binaries in $BUILD_DIR/bin"
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
  log "tests (ctest, $JOBS jobs, DDS on loopback)"
  ctest --test-dir "$BUILD_DIR" --output-on-failure -j "$JOBS" --timeout 900
}

# The main job, end to end over DDS: a server on the loopback profile, the synthetic room
# streamed to it at 30 Hz, renders requested from poses of the trajectory, the map saved, and the
# server stopped cleanly (it saves its maps on the way out).
run_demo() {
  local fslam="$BUILD_DIR/bin/fslam" server="$BUILD_DIR/bin/fslam-server"
  local prefix="demo$$" server_pid=""
  rm -rf "$OUT/maps" "$OUT/renders"
  mkdir -p "$OUT/renders"
  log "main job: built-in synthetic room through the service -> $OUT"
  "$fslam" version
  "$fslam" synth --out "$OUT/sequence" --frames 300 --seed 1
  "$fslam" info --dataset "$OUT/sequence"
  # Feature autoencoder weights for the builtin encoder, pretrained on other synthetic rooms
  # (made once, then reused).
  local weights="$ROOT/out/autoencoder/builtin.fae"
  if [[ ! -f "$weights" ]]; then
    log "feature autoencoder weights (deploy/make_builtin_autoencoder.sh, about a minute)"
    bash "$ROOT/deploy/make_builtin_autoencoder.sh" --out "$weights" --fslam "$fslam"
  fi

  log "server (prefix $prefix, maps in $OUT/maps, features on, log $OUT/server.log)"
  "$server" --prefix "$prefix" --map-dir "$OUT/maps" --set "features.autoencoder_path=$weights" \
    >"$OUT/server.log" 2>&1 &
  server_pid=$!
  # The server is ours: stop it whatever happens below.
  trap '[[ -n "$server_pid" ]] && kill -TERM "$server_pid" 2>/dev/null; wait "$server_pid" 2>/dev/null' EXIT

  log "stream the sequence at 30 Hz (JPEG colour, PNG depth)"
  "$fslam" stream --dataset "$OUT/sequence" --prefix "$prefix" --session demo --map room \
    --rate 30 --out "$OUT/trajectory.txt" | tee "$OUT/stream.txt"

  log "renders from the server, at tracked poses of the trajectory"
  for frame in 0 75 150 225 299; do
    "$fslam" render --map room --frame "$frame" --prefix "$prefix" \
      --out "$OUT/renders/frame_$(printf %03d "$frame").png"
  done
  log "segmentation from the server: instances without a prompt, and one click"
  mkdir -p "$OUT/segmentation"
  "$fslam" segment --map room --frame 150 --prefix "$prefix" \
    --out "$OUT/segmentation/instances_150.png" --overlay "$OUT/segmentation/instances_150_overlay.png"
  "$fslam" segment --map room --frame 150 --points 320,300 --prefix "$prefix" \
    --out "$OUT/segmentation/click_150.png" --overlay "$OUT/segmentation/click_150_overlay.png"
  "$fslam" status --prefix "$prefix" | tee "$OUT/status.txt"
  "$fslam" save-map --map room --prefix "$prefix"

  log "stop the server"
  kill -TERM "$server_pid"
  wait "$server_pid"
  server_pid=""
  trap - EXIT
  cat "$OUT/server.log"

  "$fslam" eval --gt "$OUT/sequence/groundtruth.txt" --est "$OUT/trajectory.txt" \
    --json "$OUT/trajectory_eval.json" --plot "$OUT/trajectory.png"
  log "outputs"
  echo "sequence:        $OUT/sequence (TUM layout: rgb/, depth/, labels/, groundtruth.txt)"
  echo "trajectory:      $OUT/trajectory.txt (poses the server sent back, TUM format)"
  echo "stream report:   $OUT/stream.txt (poses received, ATE, frame-to-pose latency by stage)"
  echo "renders:         $OUT/renders/ (colour, depth, normals, opacity from the served map)"
  echo "segmentation:    $OUT/segmentation/ (promptless instances and a one-click mask, with overlays)"
  echo "map:             $OUT/maps/room/ (map.ply: 3DGS PLY; poses, camera; served again on restart)"
  echo "trajectory plot: $OUT/trajectory.png (tracked vs ground truth)"
  echo "evaluation:      $OUT/trajectory_eval.json (ATE, RPE)"
  echo "server:          $OUT/server.log, $OUT/status.txt"
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
build
case "$MODE" in
  test) run_tests ;;
  demo) run_demo ;;
  build) ;;
esac
