#!/usr/bin/env bash
# Issue 19's "features on beat features off" measured over start offsets (opt-in benchmark; not
# part of the test suite). Tracking ATE on redkitchen 0-599 moves by a few millimetres when the
# run starts a frame later, as much as the features' effect, so one run per setting cannot tell
# the two apart: this runs features off and on from K start frames per stretch and prints the
# mean and range of each and the change of the means.
set -euo pipefail

usage() {
  cat <<'USAGE'
Usage: tests/benchmarks/feature_effect.sh [options]

For each stretch and each start offset k = 0..K-1 (the stretch's frames from its first + k),
runs `fslam track` (the point-map target: its trajectory is the one `fslam run` gives, mapping
does not move it) with features off and with `--features WEIGHTS`, and prints per stretch the
ATE RMSE (cm) of both over the offsets (mean, min-max), the change of the means, and on how many
offsets features on was the lower; then the mean over the redkitchen stretches. redkitchen ATE
is the one `fslam track` prints (0.1 mm steps); synthetic rooms are scored with `fslam eval`
against their ground truth.

Options:
  --stretches LIST  comma-separated, from rk0-599, rk0-299, rk300-599, png50 (redkitchen
                    150-199, PNG colour), synthN (a `fslam synth` room of seed N, 300 frames)
                    (default rk0-599,rk0-299,rk300-599,png50,synth21,synth13)
  --offsets K       start offsets per stretch (default 8)
  --set KEY=VALUE   a setting for both rows (repeatable), e.g. tracker.gicp.feature_gamma=0.25
  --threads N       default 2
  --weights FILE    autoencoder weights (default out/autoencoder/builtin.fae; made by
                    deploy/make_builtin_autoencoder.sh when missing)
  --data DIR        default ../shared/data beside the repository
  --out DIR         default /tmp/fslam_feature_effect; trajectories, runs.txt and summary.txt
  --fslam PATH      default build/bin/fslam
  -h, --help        this text
USAGE
}

REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
export CYCLONEDDS_URI="file://${REPO}/configs/dds/loopback.xml"  # house rule, though no DDS here
STRETCHES="rk0-599,rk0-299,rk300-599,png50,synth21,synth13"
OFFSETS=8
THREADS=2
WEIGHTS="${REPO}/out/autoencoder/builtin.fae"
DATA="${REPO}/../shared/data"
OUT="/tmp/fslam_feature_effect"
FSLAM="${REPO}/build/bin/fslam"
SETTINGS=()
while [[ $# -gt 0 ]]; do
  case "$1" in
    --stretches) STRETCHES="$2"; shift 2 ;;
    --offsets) OFFSETS="$2"; shift 2 ;;
    --set) SETTINGS+=(--set "$2"); shift 2 ;;
    --threads) THREADS="$2"; shift 2 ;;
    --weights) WEIGHTS="$2"; shift 2 ;;
    --data) DATA="$2"; shift 2 ;;
    --out) OUT="$2"; shift 2 ;;
    --fslam) FSLAM="$2"; shift 2 ;;
    -h|--help) usage; exit 0 ;;
    *) echo "unknown option: $1 (see --help)" >&2; exit 2 ;;
  esac
done
[[ "${OFFSETS}" =~ ^[1-9][0-9]*$ ]] || { echo "--offsets must be a positive integer" >&2; exit 2; }
[[ -x "${FSLAM}" ]] || { echo "no fslam binary at ${FSLAM}: build first (deploy/setup.sh)" >&2; exit 1; }
mkdir -p "${OUT}"
if [[ ! -f "${WEIGHTS}" ]]; then
  echo "making the builtin autoencoder weights (${WEIGHTS}) ..." >&2
  bash "${REPO}/deploy/make_builtin_autoencoder.sh" --threads "${THREADS}" --out "${WEIGHTS}" >&2
fi

# shellcheck source=tests/benchmarks/stretches.sh
source "${REPO}/tests/benchmarks/stretches.sh"
IFS=',' read -r -a stretch_list <<<"${STRETCHES}"
for stretch in "${stretch_list[@]}"; do ensure_stretch "${stretch}"; done

RUNS="${OUT}/runs.txt"
: >"${RUNS}"
total=$(( ${#stretch_list[@]} * OFFSETS * 2 ))
done_runs=0
for stretch in "${stretch_list[@]}"; do
  for ((k = 0; k < OFFSETS; ++k)); do
    for row in off on; do
      trajectory="${OUT}/${stretch}_${k}_${row}.txt"
      features=()
      [[ "${row}" == on ]] && features=(--features "${WEIGHTS}")
      log="${trajectory%.txt}.log"
      # shellcheck disable=SC2046  # the argument list is a word list by design
      if ! "${FSLAM}" track $(stretch_args "${stretch}" "${k}") ${SETTINGS[@]+"${SETTINGS[@]}"} \
           ${features[@]+"${features[@]}"} --threads "${THREADS}" --out "${trajectory}" >"${log}" 2>&1; then
        echo "fslam track failed for ${stretch} offset ${k} features ${row}: see ${log}" >&2
        exit 1
      fi
      if [[ "${stretch}" == synth* ]]; then
        ate_m=$("${FSLAM}" eval --gt "${OUT}/${stretch}/groundtruth.txt" --est "${trajectory}" |
                awk '$1 == "ATE" && $2 == "trans" {print $5}')
      else
        ate_m=$(awk '/^ATE RMSE/ {print $3}' "${log}")
      fi
      [[ -n "${ate_m}" ]] || { echo "no ATE for ${stretch} offset ${k} features ${row}: see ${log}" >&2; exit 1; }
      echo "${stretch} ${k} ${row} ${ate_m}" >>"${RUNS}"
      done_runs=$((done_runs + 1))
      echo "[${done_runs}/${total}] ${stretch} offset ${k} features ${row}: ATE ${ate_m} m" >&2
    done
  done
done

SUMMARY="${OUT}/summary.txt"
{
  echo "# $(date -u +%FT%TZ) commit $(git -C "${REPO}" rev-parse --short HEAD)$(git -C "${REPO}" diff --quiet || echo +dirty) threads ${THREADS} host $(hostname) offsets ${OFFSETS}${SETTINGS[*]:+ settings ${SETTINGS[*]}}"
  awk -v offsets="${OFFSETS}" '
    function add(s, r, v) {
      n[s, r]++; sum[s, r] += v
      if (!((s, r) in lo) || v < lo[s, r]) lo[s, r] = v
      if (!((s, r) in hi) || v > hi[s, r]) hi[s, r] = v
    }
    { v = $4 * 100; add($1, $3, v); ate[$1, $2, $3] = v; if (!($1 in seen)) { seen[$1] = 1; order[++m] = $1 } }
    END {
      print "| stretch | offsets | features off: mean (min-max) cm | features on: mean (min-max) cm | change of the means | offsets where on < off |"
      print "|---|---|---|---|---|---|"
      for (i = 1; i <= m; ++i) {
        s = order[i]; off = sum[s, "off"] / n[s, "off"]; on = sum[s, "on"] / n[s, "on"]; wins = 0
        for (k = 0; k < offsets; ++k) wins += (ate[s, k, "on"] < ate[s, k, "off"])
        printf "| %s | %d | %.3f (%.2f-%.2f) | %.3f (%.2f-%.2f) | %+.1f %% | %d of %d |\n", s, n[s, "off"], off, lo[s, "off"], hi[s, "off"], on, lo[s, "on"], hi[s, "on"], 100 * (on / off - 1), wins, offsets
        if (s ~ /^(rk|png)/) { rk_off += off; rk_on += on; rk++ }
      }
      if (rk > 0)
        printf "mean over the %d redkitchen stretches: off %.3f cm, on %.3f cm, change %+.1f %%\n", rk, rk_off / rk, rk_on / rk, 100 * (rk_on / rk_off - 1)
    }' "${RUNS}"
} | tee "${SUMMARY}"
