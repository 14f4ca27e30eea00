#!/usr/bin/env bash
# Pretrains the feature autoencoder for the builtin encoder on images the repo makes itself, and
# writes builtin.fae (generated, never committed). docs/features_autoencoder.md explains the data.
#
#   bash deploy/make_builtin_autoencoder.sh [--out FILE] [--work DIR] [--frames N] [--steps N]
#                                           [--threads N] [--fslam PATH] [--keep-images]
#
# Training images: `fslam synth` rooms with seeds 101-108 (--frames each, default 40), held-out
# images: room 109. Tests and demos evaluate on rooms 1, 5 and 7, so these rooms are not theirs.
# (Measured: 8 rooms x 40 frames reconstruct an unseen room as well as 4 rooms x 150 frames, in a
# quarter of the synthesis time.)
# They come from the same procedural generator, though: "unrelated images" only in the weak
# sense. For a learned (ONNX) encoder, pretrain on real images you provide (COCO, ScanNet, ...):
#   fslam train-autoencoder --encoder onnx --onnx-model M.onnx --images DIR... --out M.fae
# Needs a built fslam (bash deploy/setup.sh builds one in build/).
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
FSLAM="$ROOT/build/bin/fslam"
OUT="$ROOT/out/autoencoder/builtin.fae"
WORK="$ROOT/out/autoencoder/images"
FRAMES=40
STEPS=5000
THREADS="$(nproc)"
KEEP=0
TRAIN_SEEDS=(101 102 103 104 105 106 107 108)
HELD_OUT_SEED=109

usage() { sed -n '2,16p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'; }

while [[ $# -gt 0 ]]; do
  case "$1" in
    --out) OUT="$(realpath -m "$2")"; shift ;;
    --work) WORK="$(realpath -m "$2")"; shift ;;
    --frames) FRAMES="$2"; shift ;;
    --steps) STEPS="$2"; shift ;;
    --threads) THREADS="$2"; shift ;;
    --fslam) FSLAM="$(realpath -m "$2")"; shift ;;
    --keep-images) KEEP=1 ;;
    -h|--help) usage; exit 0 ;;
    *) echo "make_builtin_autoencoder.sh: unknown option '$1'" >&2; usage >&2; exit 2 ;;
  esac
  shift
done

[[ -x "$FSLAM" ]] || { echo "make_builtin_autoencoder.sh: no fslam at $FSLAM (build first: bash deploy/setup.sh, or pass --fslam)" >&2; exit 1; }

t0=$SECONDS
mkdir -p "$WORK" "$(dirname "$OUT")"
for seed in "${TRAIN_SEEDS[@]}" "$HELD_OUT_SEED"; do
  dir="$WORK/room_$seed"
  # A complete earlier sequence (index files are written last) is reused.
  if [[ -f "$dir/rgb.txt" && $(ls "$dir/rgb" | wc -l) -eq $FRAMES ]]; then
    echo "room $seed: reusing $dir"
    continue
  fi
  rm -rf "$dir"
  "$FSLAM" synth --out "$dir" --frames "$FRAMES" --seed "$seed" --threads "$THREADS"
done
t_synth=$((SECONDS - t0))

train_dirs=()
for seed in "${TRAIN_SEEDS[@]}"; do train_dirs+=("$WORK/room_$seed"); done
"$FSLAM" train-autoencoder --encoder builtin --images "${train_dirs[@]}" \
  --held-out "$WORK/room_$HELD_OUT_SEED" --steps "$STEPS" --seed 1 --threads "$THREADS" --out "$OUT"

[[ $KEEP -eq 1 ]] || rm -rf "$WORK"
echo "synthesis $t_synth s, encoding and training $((SECONDS - t0 - t_synth)) s, total $((SECONDS - t0)) s"
echo "weights: $OUT"
