#!/usr/bin/env bash
# Tracking ablation of issue 19 (opt-in; not part of the test suite): GICP target (point map or
# Gaussian map), features off / on, opacity alpha off / on, and the form of L_feat, on real and
# synthetic stretches, with ATE, tracking time and the map's held-out PSNR in one table.
set -euo pipefail

usage() {
  cat <<'USAGE'
Usage: tests/benchmarks/tracking_ablation.sh [options]

Runs `fslam run` (mapping on, as fast as it can, --threads N) once per row and stretch and prints
one table: ATE RMSE (cm), median tracking ms per frame (wall / the tracking thread's CPU),
held-out PSNR (dB), frames/s, map size, the held-out decoded-feature error of the heads before /
after online LoRA where L_feat is decoded, and the median over frames of the registration's mean feature similarity (eq. feat_dist
at the solution; 1: the frame's features equal their matched targets'). Rows (--rows picks some, comma-separated):
  points           point map target, features off (the default without weights)
  points-feat      point map target, features on (the default with weights)
  gauss            Gaussian map target (mapper.insert_from=source), features off, alpha on, each
                   target covariance divided by the keyframes that see it (observation_weight)
  gauss-noalpha    Gaussian map target, features off, alpha off
  gauss-feat       Gaussian map target, features on, alpha on (the paper's formulation, with
                   the observation weight)
  gauss-feat-noalpha  Gaussian map target, features on, alpha off
  gauss-feat-latent   as gauss-feat with the latent L_feat (mapper.feature_loss=latent)
  gauss-nbr        as gauss, target covariances from the neighbouring means
                   (tracker.map_target.covariance=neighbours) instead of each Gaussian's disc
  gauss-feat-nbr   as gauss-feat, covariances from the neighbouring means
  gauss-wait       as gauss, tracking waits after each keyframe for the target that contains it
                   (tracker.map_target.wait_for_mapper: no lag behind the tracker; not real time)
  gauss-feat-wait  as gauss-feat, tracking waits for the target (the paper's formulation, no lag)
  gauss-noprune    as gauss, no importance pruning (mapper.prune_percentile_*=0)
  gauss-noobs      as gauss, each Gaussian weighing as one observation
                   (tracker.map_target.observation_weight=false: the paper's eq. gicp_sets)
  gauss-feat-noobs as gauss-feat without the observation weight (the paper's formulation as written)
  gauss-wait-noobs as gauss-wait without the observation weight
Stretches (--stretches picks some): rk0-599, rk0-299, rk300-599 (7-Scenes redkitchen), png50
(redkitchen frames 150-199, PNG colour), synth (a `fslam synth` room, 300 frames, Kinect noise,
seed --synth-seed).

Options:
  --rows LIST       default: all rows
  --stretches LIST  default: rk0-599,rk0-299,rk300-599,png50,synth
  --synth-seed N    room seed (default 21)
  --threads N       default 2
  --weights FILE    autoencoder weights (default out/autoencoder/builtin.fae; made by
                    deploy/make_builtin_autoencoder.sh when missing)
  --data DIR        default ../shared/data beside the repository
  --out DIR         default /tmp/fslam_tracking_ablation; each run's folder and summary.txt
  --fslam PATH      default build/bin/fslam
  -h, --help        this text
USAGE
}

REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
export CYCLONEDDS_URI="file://${REPO}/configs/dds/loopback.xml"  # house rule, though no DDS here
ROWS="points,points-feat,gauss,gauss-noalpha,gauss-feat,gauss-feat-noalpha,gauss-feat-latent,gauss-nbr,gauss-feat-nbr"
STRETCHES="rk0-599,rk0-299,rk300-599,png50,synth"
SYNTH_SEED=21
THREADS=2
WEIGHTS="${REPO}/out/autoencoder/builtin.fae"
DATA="${REPO}/../shared/data"
OUT="/tmp/fslam_tracking_ablation"
FSLAM="${REPO}/build/bin/fslam"
while [[ $# -gt 0 ]]; do
  case "$1" in
    --rows) ROWS="$2"; shift 2 ;;
    --stretches) STRETCHES="$2"; shift 2 ;;
    --synth-seed) SYNTH_SEED="$2"; shift 2 ;;
    --threads) THREADS="$2"; shift 2 ;;
    --weights) WEIGHTS="$2"; shift 2 ;;
    --data) DATA="$2"; shift 2 ;;
    --out) OUT="$2"; shift 2 ;;
    --fslam) FSLAM="$2"; shift 2 ;;
    -h|--help) usage; exit 0 ;;
    *) echo "unknown option: $1 (see --help)" >&2; exit 2 ;;
  esac
done
[[ -x "${FSLAM}" ]] || { echo "no fslam binary at ${FSLAM}: build first (deploy/setup.sh)" >&2; exit 1; }
mkdir -p "${OUT}"
if [[ ",${ROWS}," == *-feat* && ! -f "${WEIGHTS}" ]]; then
  echo "making the builtin autoencoder weights (${WEIGHTS}) ..." >&2
  bash "${REPO}/deploy/make_builtin_autoencoder.sh" --threads "${THREADS}" --out "${WEIGHTS}" >&2
fi

# Per row: the settings on top of the stretch's preset.
row_args() {
  local gauss=(--set tracker.target=gaussians --set mapper.insert_from=source)
  case "$1" in
    points) ;;
    points-feat) echo --features "${WEIGHTS}" ;;
    gauss) echo "${gauss[@]}" ;;
    gauss-noalpha) echo "${gauss[@]}" --set tracker.gicp.use_opacity=false ;;
    gauss-feat) echo "${gauss[@]}" --features "${WEIGHTS}" ;;
    gauss-feat-noalpha) echo "${gauss[@]}" --features "${WEIGHTS}" --set tracker.gicp.use_opacity=false ;;
    gauss-feat-latent) echo "${gauss[@]}" --features "${WEIGHTS}" --set mapper.feature_loss=latent ;;
    gauss-nbr) echo "${gauss[@]}" --set tracker.map_target.covariance=neighbours ;;
    gauss-feat-nbr) echo "${gauss[@]}" --features "${WEIGHTS}" --set tracker.map_target.covariance=neighbours ;;
    gauss-wait) echo "${gauss[@]}" --set tracker.map_target.wait_for_mapper=true ;;
    gauss-feat-wait) echo "${gauss[@]}" --features "${WEIGHTS}" --set tracker.map_target.wait_for_mapper=true ;;
    gauss-noprune) echo "${gauss[@]}" --set mapper.prune_percentile_mapping=0 --set mapper.prune_percentile_tracking=0 ;;
    gauss-noobs) echo "${gauss[@]}" --set tracker.map_target.observation_weight=false ;;
    gauss-feat-noobs) echo "${gauss[@]}" --features "${WEIGHTS}" --set tracker.map_target.observation_weight=false ;;
    gauss-wait-noobs) echo "${gauss[@]}" --set tracker.map_target.wait_for_mapper=true --set tracker.map_target.observation_weight=false ;;
    *) echo "unknown row: $1" >&2; return 1 ;;
  esac
}

# The stretches (tests/benchmarks/stretches.sh); `synth` is the room of --synth-seed.
# shellcheck source=tests/benchmarks/stretches.sh
source "${REPO}/tests/benchmarks/stretches.sh"
stretch_name() { if [[ "$1" == synth ]]; then echo "synth${SYNTH_SEED}"; else echo "$1"; fi; }
IFS=',' read -r -a stretch_list <<<"${STRETCHES}"
for stretch in "${stretch_list[@]}"; do ensure_stretch "$(stretch_name "${stretch}")"; done

SUMMARY="${OUT}/summary.txt"
{
  echo "# $(date -u +%FT%TZ) commit $(git -C "${REPO}" rev-parse --short HEAD)$(git -C "${REPO}" diff --quiet || echo +dirty) threads ${THREADS} host $(hostname)"
  echo "| stretch | row | ATE cm | tracking ms p50 (wall / thread CPU) | held-out PSNR dB | frames/s | Gaussians | decoded error pretrained -> online | feature similarity p50 |"
  echo "|---|---|---|---|---|---|---|---|---|"
} | tee "${SUMMARY}"
IFS=',' read -r -a row_list <<<"${ROWS}"
for stretch in "${stretch_list[@]}"; do
  for row in "${row_list[@]}"; do
    dir="${OUT}/${stretch}/${row}"
    mkdir -p "${dir}"
    # shellcheck disable=SC2046  # the argument lists are word lists by design
    if ! "${FSLAM}" run $(stretch_args "$(stretch_name "${stretch}")") $(row_args "${row}") --threads "${THREADS}" \
        --renders 0 --out "${dir}" >"${dir}/log.txt" 2>&1; then
      echo "| ${stretch} | ${row} | failed: see ${dir}/log.txt |" | tee -a "${SUMMARY}"
      continue
    fi
    python3 - "${dir}/metrics.json" "${stretch}" "${row}" <<'PY' | tee -a "${SUMMARY}"
import json, sys
m = json.load(open(sys.argv[1]))
ate = m.get("ate", {}).get("rmse_m")
track = m["timing"]["tracking_per_frame"].get("median_ms", m["timing"]["tracking_per_frame"].get("median"))
cpu = m["timing"].get("tracking_cpu_per_frame", {}).get("median_ms")
psnr = m["held_out"].get("psnr_db", m["held_out"].get("psnr"))
fps = m["timing"]["frames_per_second"]
dec = m.get("decoded_features")
dec_text = f"{dec['held_out_error_pretrained']:.4f} -> {dec['held_out_error_online']:.4f}" if dec else "-"
fmt = lambda v, f: (f % v) if isinstance(v, (int, float)) else "-"
similarity = m.get("registration", {}).get("feature_weight", {}).get("median")
print(f"| {sys.argv[2]} | {sys.argv[3]} | {fmt(ate * 100 if ate is not None else None, '%.2f')} | "
      f"{fmt(track, '%.1f')} / {fmt(cpu, '%.1f')} | {fmt(psnr, '%.2f')} | {fps:.2f} | {m['map']['gaussians']} | {dec_text} | {fmt(similarity, '%.3f')} |")
PY
  done
done
echo "wrote ${SUMMARY}" >&2
