#!/usr/bin/env bash
# Checks the Kubernetes manifests without a cluster (docs/deployment.md "Kubernetes"):
#   1. schema and featureslam's rules: node validate/validate.mjs (npm packages kubernetes-models
#      and yaml, installed once by `bash deploy/setup.sh --k8s-check`, i.e. npm ci in validate/);
#   2. podman kube play of what podman runs (podman/fslam-play.yaml: ConfigMap, PVC, Deployment)
#      with --network none, using the image deploy/test_containers.sh builds ($FSLAM_IMAGE,
#      default localhost/featureslam:cpu): the server must become ready, create a map of its
#      group from a short stream, list it in the map directory, then go down cleanly.
# Each part skips with a message when its tools are missing; exit 77 when both skipped.
set -uo pipefail
HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
IMAGE="${FSLAM_IMAGE:-localhost/featureslam:cpu}"
RAN=0 FAILED=0

if ! command -v node >/dev/null; then
  echo "SKIPPED schema check: node is not installed (bash deploy/setup.sh --k8s-check)"
elif [[ ! -d "$HERE/validate/node_modules/kubernetes-models" ]]; then
  echo "SKIPPED schema check: npm packages missing (bash deploy/setup.sh --k8s-check)"
else
  RAN=1
  node "$HERE/validate/validate.mjs" || FAILED=1
fi

PLAY="$HERE/podman/fslam-play.yaml"
if ! command -v podman >/dev/null; then
  echo "SKIPPED podman kube play: podman is not installed (bash deploy/test_containers.sh installs it)"
elif [[ $(id -u) -ne 0 ]]; then
  echo "SKIPPED podman kube play: needs root (rootful podman)"
elif ! podman image exists "$IMAGE"; then
  echo "SKIPPED podman kube play: no image $IMAGE (bash deploy/test_containers.sh builds it)"
else
  RAN=1
  down() {
    podman kube down "$PLAY" >/dev/null 2>&1
    podman volume rm -f fslam-kitchen-maps >/dev/null 2>&1
  }
  down
  trap down EXIT
  # The image named in the file is the default one; another is substituted on the way in.
  played="$(mktemp /tmp/fslam_play.XXXXXX.yaml)"
  sed "s|image: localhost/featureslam:cpu|image: $IMAGE|" "$PLAY" >"$played"
  if podman kube play --network none "$played" >/dev/null; then
    pod="$(podman pod ps --filter label=app.kubernetes.io/name=featureslam --format '{{.Name}}' | grep kitchen | head -1)"
    ctr="$(podman ps --filter "pod=$pod" --format '{{.Names}}' | grep -v infra | head -1)"
    ready=0
    for _ in $(seq 1 300); do
      podman exec "$ctr" test -f /tmp/fslam-health 2>/dev/null && { ready=1; break; }
      sleep 0.1
    done
    if [[ $ready -eq 1 ]]; then
      echo "ok: the played Deployment's server is ready (pod $pod, container $ctr)"
      if podman exec "$ctr" bash -c "fslam synth --out /tmp/s --frames 10 >/dev/null 2>&1 \
           && fslam stream --dataset /tmp/s --prefix fslam --session k --map kitchen-1 >/tmp/stream.txt 2>&1 \
           && fslam maps --prefix fslam" >/tmp/fslam_play_maps.txt 2>&1 \
         && grep -Eq '^kitchen-1 +kitchen ' /tmp/fslam_play_maps.txt; then
        echo "ok: it creates kitchen-1 in its group and lists it in the map directory"
      else
        echo "FAILED: stream into the played server"; cat /tmp/fslam_play_maps.txt; FAILED=1
      fi
    else
      echo "FAILED: the played server never became ready"; podman logs "$ctr" 2>&1 | tail -20; FAILED=1
    fi
    rm -f /tmp/fslam_play_maps.txt "$played"
  else
    echo "FAILED: podman kube play refused $PLAY"; FAILED=1
  fi
fi

[[ $FAILED -ne 0 ]] && exit 1
[[ $RAN -eq 0 ]] && exit 77
echo "Kubernetes manifests: all checks that could run passed"
