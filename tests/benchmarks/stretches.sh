# The named stretches the tracking benchmarks run on (sourced by tracking_ablation.sh and
# feature_effect.sh; not run by itself). Needs REPO, DATA, OUT and FSLAM set by the caller.
#   rk0-599, rk0-299, rk300-599  7-Scenes redkitchen (JPEG colour), with its preset
#   png50                        redkitchen frames 150-199 with PNG colour, with the preset
#   synthN                       a `fslam synth` room of seed N, 300 frames, in ${OUT}/synthN

# stretch_args STRETCH [OFFSET]: the fslam arguments of STRETCH started OFFSET frames late (0).
stretch_args() {
  local stretch="$1" k="${2:-0}" preset=(--config "${REPO}/configs/presets/seven_scenes.yaml")
  case "${stretch}" in
    rk0-599) echo --dataset "${DATA}/redkitchen" --frames "${k}:600" "${preset[@]}" ;;
    rk0-299) echo --dataset "${DATA}/redkitchen" --frames "${k}:300" "${preset[@]}" ;;
    rk300-599) echo --dataset "${DATA}/redkitchen" --frames "$((300 + k)):600" "${preset[@]}" ;;
    png50) echo --dataset "${DATA}/redkitchen_png50" --frames "${k}:50" "${preset[@]}" ;;
    synth[0-9]*) echo --dataset "${OUT}/${stretch}" --frames "${k}:300" ;;
    *) echo "unknown stretch: ${stretch}" >&2; return 1 ;;
  esac
}

# ensure_stretch STRETCH: fails on an unknown name; synthesises a synthN room once.
ensure_stretch() {
  local stretch="$1"
  stretch_args "${stretch}" >/dev/null || return 1
  if [[ "${stretch}" == synth* && ! -f "${OUT}/${stretch}/.complete" ]]; then
    echo "synthesising room seed ${stretch#synth} (300 frames) ..." >&2
    "${FSLAM}" synth --out "${OUT}/${stretch}" --frames 300 --seed "${stretch#synth}" >/dev/null
    touch "${OUT}/${stretch}/.complete"
  fi
}
