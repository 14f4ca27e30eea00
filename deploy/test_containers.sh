#!/usr/bin/env bash
# Builds the featureslam image with podman and runs the service in containers end to end
# (opt-in: not part of `setup.sh --test`; docs/deployment.md "Containers"). As root, on Debian 12:
#   1. installs podman, runc, buildah, debootstrap (only those missing) and the two settings this
#      kind of machine needs in /etc/containers/containers.conf (runc; ulimits within the host's);
#   2. makes the base image localhost/debian:bookworm offline with debootstrap from the apt mirror
#      (no registry is reachable), cached as CACHE/debian-bookworm.tar (podman save / load);
#   3. builds localhost/featureslam:cpu from deploy/docker/Dockerfile (build stage, then a runtime
#      stage with only runtime packages), ccache in CACHE/ccache;
#   4. runs a server and a client container in one pod with --network=none (DDS stays on the pod's
#      loopback): the client makes the synthetic room, streams it, checks that every pose came
#      back and renders a frame; the map is saved to the named volume fslam-test-maps; the server
#      container is restarted and the saved map rendered again, byte-identical;
#   5. runs the Kubernetes manifest test against the image (deploy/k8s/test_manifests.sh);
#   6. reports the image size and the server's start-up time (also into CACHE/report.txt).
#
#   bash deploy/test_containers.sh [--cache DIR] [--frames N] [--jobs N] [--gpu] [--keep]
#
# --cache DIR  where the base image tar, the ccache and the report go (default out/containers)
# --gpu        also build localhost/featureslam:gpu (CUDA backend) with the host's CUDA toolkit
#              (/usr/local/cuda, mounted read-only into the build): Debian 12 has no CUDA 13
# --keep       leave the pod and the volume for inspection
# On a shared machine run it at low priority (nice -n 19): the image build compiles everything.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
# shellcheck source=../tests/common/script_support.sh
source "$ROOT/tests/common/script_support.sh"  # tracked_all
CACHE="$ROOT/out/containers"
FRAMES=60
JOBS="$(nproc)"
GPU=0
KEEP=0
usage() { awk 'NR > 1 && !/^#/ { exit } NR > 1 { sub(/^# ?/, ""); print }' "${BASH_SOURCE[0]}"; }
while [[ $# -gt 0 ]]; do
  case "$1" in
    --cache) CACHE="$(realpath -m "$2")"; shift ;;
    --frames) FRAMES="$2"; shift ;;
    --jobs) JOBS="$2"; shift ;;
    --gpu) GPU=1 ;;
    --keep) KEEP=1 ;;
    -h|--help) usage; exit 0 ;;
    *) echo "test_containers.sh: unknown option '$1'" >&2; usage >&2; exit 2 ;;
  esac
  shift
done
[[ $(id -u) -eq 0 ]] || { echo "test_containers.sh: run as root (rootful podman)" >&2; exit 1; }
log() { printf '\n== %s\n' "$*"; }
mkdir -p "$CACHE/ccache" "$CACHE/run"
REPORT="$CACHE/report.txt"
: >"$REPORT"
report() { echo "$*" | tee -a "$REPORT"; }
now() { date +%s.%N; }
seconds_since() { awk -v a="$1" -v b="$(now)" 'BEGIN { printf "%.1f", b - a }'; }

# ---- 1. podman and its settings ------------------------------------------------------------
PACKAGES=(podman runc buildah debootstrap catatonit)
missing=()
for p in "${PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [[ ${#missing[@]} -gt 0 ]]; then
  log "installing ${missing[*]}"
  apt-get update -qq
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi
CONF=/etc/containers/containers.conf
# set_conf SECTION KEY LINE: puts LINE into [SECTION] unless KEY is set there already.
set_conf() {
  mkdir -p "$(dirname "$CONF")"
  touch "$CONF"
  if awk -v s="[$1]" -v k="$2" '$0 == s { in_s = 1; next } /^\[/ { in_s = 0 }
       in_s && $1 == k { found = 1 } END { exit !found }' "$CONF"; then
    return
  fi
  if grep -qx "\[$1\]" "$CONF"; then
    sed -i "/^\[$1\]\$/a $3" "$CONF"
  else
    printf '\n[%s]\n%s\n' "$1" "$3" >>"$CONF"
  fi
  echo "containers.conf: [$1] $3"
}
# crun fails here (cgroups in hybrid mode); podman's default ulimits exceed the host's caps.
set_conf containers default_ulimits 'default_ulimits = ["nofile=20000:20000", "nproc=32768:32768"]'
set_conf engine runtime 'runtime = "runc"'
podman --version

# ---- 2. the base image, offline ------------------------------------------------------------
BASE=localhost/debian:bookworm
BASE_TAR="$CACHE/debian-bookworm.tar"
if podman image exists "$BASE"; then
  echo "base image $BASE present"
elif [[ -f "$BASE_TAR" ]]; then
  log "base image from the cache $BASE_TAR"
  podman load -i "$BASE_TAR"
else
  # The first Debian mirror apt uses (one-line or deb822 sources), not the security one.
  MIRROR="$( (cat /etc/apt/sources.list /etc/apt/sources.list.d/*.list /etc/apt/sources.list.d/*.sources \
              2>/dev/null || true) | grep -v '^ *#' | grep -oE 'https?://[^ ]+/debian/?( |$)' \
            | grep -v security | head -1 | tr -d ' ' || true)"
  MIRROR="${MIRROR:-http://deb.debian.org/debian}"
  log "base image: debootstrap bookworm from $MIRROR (about 2 minutes)"
  ROOTFS="$(mktemp -d /tmp/fslam_rootfs.XXXXXX)"
  t0=$(now)
  debootstrap --variant=minbase bookworm "$ROOTFS" "$MIRROR" >"$CACHE/debootstrap.log" 2>&1 \
    || { tail -20 "$CACHE/debootstrap.log"; exit 1; }
  tar --numeric-owner -C "$ROOTFS" -c . | podman import - "$BASE"
  rm -rf "$ROOTFS"
  podman save -o "$BASE_TAR" "$BASE"
  report "base image: debootstrap + import in $(seconds_since "$t0") s, cached in $BASE_TAR"
fi

# ---- 3. the image ----------------------------------------------------------------------------
build_image() {  # build_image TAG CUDA EXTRA_ARGS...
  local tag="$1" cuda="$2"; shift 2
  log "podman build $tag (CUDA $cuda, $JOBS jobs)"
  local t0; t0=$(now)
  podman build --network=host -f "$ROOT/deploy/docker/Dockerfile" \
    --ignorefile "$ROOT/deploy/docker/Dockerfile.dockerignore" \
    --build-arg BASE="$BASE" --build-arg CUDA="$cuda" --build-arg JOBS="$JOBS" \
    --volume "$CACHE/ccache:/ccache" "$@" -t "$tag" "$ROOT"
  local bytes; bytes=$(podman image inspect "$tag" --format '{{.Size}}')
  report "image $tag: $((bytes / 1000000)) MB, built in $(seconds_since "$t0") s"
}
IMAGE=localhost/featureslam:cpu
build_image "$IMAGE" OFF
report "base image $BASE: $(( $(podman image inspect "$BASE" --format '{{.Size}}') / 1000000 )) MB"

# ---- 4. server and client in a pod without a network -----------------------------------------
POD=fslam-test VOLUME=fslam-test-maps SERVER=fslam-test-server PREFIX=ctest
RUN="$CACHE/run"
rm -f "$RUN"/*
cleanup() {
  [[ $KEEP -eq 1 ]] && return
  podman pod rm -f "$POD" >/dev/null 2>&1 || true
  podman volume rm -f "$VOLUME" >/dev/null 2>&1 || true
}
trap cleanup EXIT
cleanup
podman volume create "$VOLUME" >/dev/null
podman pod create --name "$POD" --network none >/dev/null

wait_ready() {  # the server's health file exists: it serves
  for _ in $(seq 1 600); do
    podman exec "$SERVER" test -f /tmp/fslam-health 2>/dev/null && return 0
    sleep 0.1
  done
  podman logs "$SERVER" | tail -20
  return 1
}
log "server container"
t0=$(now)
podman run -d --pod "$POD" --name "$SERVER" --cap-add SYS_NICE -v "$VOLUME:/maps" "$IMAGE" \
  fslam-server --map-dir /maps --prefix "$PREFIX" --health-file /tmp/fslam-health >/dev/null
wait_ready
STARTUP="$(seconds_since "$t0")"
report "server container: podman run -> serving in $STARTUP s"

client() {  # client NAME SCRIPT: a client container in the pod; output in $RUN/NAME.txt
  podman run --rm --pod "$POD" -v "$RUN:/out" "$IMAGE" bash -c "$2" >"$RUN/$1.txt" 2>&1 \
    || { echo "client '$1' failed:"; tail -20 "$RUN/$1.txt"; podman logs "$SERVER" | tail -20; exit 1; }
}
log "client container: synthetic room ($FRAMES frames), stream, render, save"
client stream "fslam synth --out /tmp/room --frames $FRAMES --seed 2 \
  && fslam stream --dataset /tmp/room --prefix $PREFIX --session room --map room --policy queue \
       --out /out/trajectory.txt --report /out/stream.json \
  && fslam render --map room --frame $((FRAMES / 2)) --prefix $PREFIX --out /out/before_restart.png \
  && fslam save-map --map room --prefix $PREFIX"
grep -E "frames sent|ATE" "$RUN/stream.txt"
tracked_all "$RUN/stream.json" "$FRAMES" || { echo "FAILED: not every pose arrived"; exit 1; }
[[ -s "$RUN/before_restart.png" ]] || { echo "FAILED: no render"; exit 1; }

log "restart the server container (it saves on SIGTERM; the map stays in the volume)"
t0=$(now)
podman restart -t 60 "$SERVER" >/dev/null
wait_ready
report "server container: podman restart -> serving again in $(seconds_since "$t0") s"
podman logs "$SERVER" 2>&1 | grep "loaded map 'room'" | tail -1 || true
client render "fslam render --map room --frame $((FRAMES / 2)) --prefix $PREFIX --out /out/after_restart.png"
cmp "$RUN/before_restart.png" "$RUN/after_restart.png" \
  || { echo "FAILED: the render after the restart differs"; exit 1; }
report "render of frame $((FRAMES / 2)) before and after the restart: byte-identical"

# ---- 5. Kubernetes manifests against the image -----------------------------------------------
log "Kubernetes manifests (schema check, podman kube play)"
FSLAM_IMAGE="$IMAGE" bash "$ROOT/deploy/k8s/test_manifests.sh"

# ---- GPU variant -----------------------------------------------------------------------------
if [[ $GPU -eq 1 ]]; then
  if [[ -x /usr/local/cuda/bin/nvcc ]]; then
    build_image localhost/featureslam:gpu ON --volume /usr/local/cuda:/usr/local/cuda:ro
    podman run --rm localhost/featureslam:gpu fslam version | tee -a "$REPORT"
  else
    report "GPU image not built: no CUDA toolkit at /usr/local/cuda (Debian 12's registry has none)"
  fi
fi
log "containers: all checks passed (figures above, also in $REPORT)"
