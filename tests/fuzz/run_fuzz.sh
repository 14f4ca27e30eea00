#!/usr/bin/env bash
# Builds the libFuzzer targets (clang, ASan + UBSan; FSLAM_FUZZ=ON in its own build folder), then
# runs each over its seed corpus for a bounded time and prints a table of execs, coverage and
# crashes (docs/reliability.md). Exits 1 when any target crashed, leaked or timed out.
#
#   bash tests/fuzz/run_fuzz.sh                  # smoke: 10 s per target (what --test runs)
#   bash tests/fuzz/run_fuzz.sh --seconds 600    # a long run, 10 minutes per target
#   bash tests/fuzz/run_fuzz.sh --only frame,ply --seconds 60
#   bash tests/fuzz/run_fuzz.sh --seeds          # regenerate tests/fuzz/corpus from make_seeds
#                                                (inputs that crashed, regression-*, are kept)
#   bash tests/fuzz/run_fuzz.sh --opt 0          # the smoke deploy/setup.sh --test runs: an -O0
#                                                build, quicker to make, 2-5x fewer execs per second
#
# Options: --opt 0|1 (default 1)  --build-dir DIR (default build-fuzz, build-fuzz-O0 with --opt 0)
# --jobs N  --out DIR (default out/fuzz: the corpus grown by the run, crash files and logs; the
# committed seed corpus is never modified)
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
BUILD_DIR=""
OPT=1
OUT="$ROOT/out/fuzz"
SECONDS_EACH=10
JOBS="$(nproc)"
ONLY=""
SEEDS=0
TARGETS=(frame request ply trajectory keyframes keyframe_images dataset autoencoder onnx config)

while [[ $# -gt 0 ]]; do
  case "$1" in
    --build-dir) BUILD_DIR="$(realpath -m "$2")"; shift ;;
    --opt) OPT="$2"; shift ;;
    --out) OUT="$(realpath -m "$2")"; shift ;;
    --seconds) SECONDS_EACH="$2"; shift ;;
    --jobs) JOBS="$2"; shift ;;
    --only) ONLY="$2"; shift ;;
    --seeds) SEEDS=1 ;;
    -h|--help) awk 'NR > 1 && !/^#/ { exit } NR > 1 { sub(/^# ?/, ""); print }' "${BASH_SOURCE[0]}"; exit 0 ;;
    *) echo "run_fuzz.sh: unknown option '$1'" >&2; exit 2 ;;
  esac
  shift
done
[[ -n "$ONLY" ]] && IFS=, read -r -a TARGETS <<<"$ONLY"
case "$OPT" in
  1) [[ -n "$BUILD_DIR" ]] || BUILD_DIR="$ROOT/build-fuzz" ;;
  0) [[ -n "$BUILD_DIR" ]] || BUILD_DIR="$ROOT/build-fuzz-O0" ;;
  *) echo "run_fuzz.sh: --opt takes 0 or 1, not '$OPT'" >&2; exit 2 ;;
esac

command -v clang++ >/dev/null || { echo "run_fuzz.sh: clang++ not found (deploy/setup.sh --test installs clang)" >&2; exit 1; }
if [[ ! -f "$BUILD_DIR/CMakeCache.txt" ]]; then
  echo "== configure $BUILD_DIR (clang -O$OPT, FSLAM_FUZZ=ON, no CUDA, no tests)"
  # Line tables only: stack traces keep file:line. -O1 is libFuzzer's usual level
  # (RelWithDebInfo's -O2 -g took 443 s against 324 s); -O0 builds in 222-228 s against -O1's
  # 370-371 s (dev-2c-intel, alternating, docs/benchmarks.md), for a smoke whose 10 s per target
  # replay the seeds and mutate a while at 2-5x fewer execs per second.
  CC=clang CXX=clang++ cmake -S "$ROOT" -B "$BUILD_DIR" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo \
    -DCMAKE_C_FLAGS_RELWITHDEBINFO="-O$OPT -gline-tables-only -DNDEBUG" \
    -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O$OPT -gline-tables-only -DNDEBUG" \
    -DFSLAM_FUZZ=ON -DFSLAM_WITH_CUDA=OFF -DFSLAM_BUILD_TESTS=OFF >/dev/null
fi
t0=$SECONDS
cmake --build "$BUILD_DIR" -j "$JOBS" --target fslam_fuzz_make_seeds "${TARGETS[@]/#/fslam_fuzz_}" fslam_fuzz_onnx
echo "== fuzz build took $((SECONDS - t0)) s"

CORPUS="$ROOT/tests/fuzz/corpus"
if [[ $SEEDS -eq 1 ]]; then
  models="$ROOT/build/test_models/onnx"
  [[ -d "$models" ]] || models=""
  # Generated seeds are rewritten; inputs that once crashed (regression-*) are kept.
  find "$CORPUS" -type f ! -name 'regression-*' -delete 2>/dev/null || true
  "$BUILD_DIR/bin/fslam_fuzz_make_seeds" "$CORPUS" $models
  mkdir -p "$CORPUS/config" && cp "$ROOT"/configs/presets/*.yaml "$CORPUS/config/"
  exit 0
fi

# ASan: fail on leaks too; UBSan: print the stack. Options a finding needs to be reproducible.
export ASAN_OPTIONS="detect_leaks=1:abort_on_error=1:symbolize=1"
export UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1"
mkdir -p "$OUT"
failed=0
printf '\n%-12s %10s %9s %7s %7s %8s  %s\n' target execs exec/s cov ft corpus result
for name in "${TARGETS[@]}"; do
  work="$OUT/$name"
  rm -rf "$work/corpus" && mkdir -p "$work/corpus" "$work/crashes"
  [[ -d "$CORPUS/$name" ]] && cp -r "$CORPUS/$name/." "$work/corpus/"
  set +e
  TMPDIR="$work" "$BUILD_DIR/bin/fslam_fuzz_$name" "$work/corpus" -max_total_time="$SECONDS_EACH" \
    -timeout=20 -rss_limit_mb=2048 -malloc_limit_mb=2048 -print_final_stats=1 \
    -artifact_prefix="$work/crashes/" >"$work/log.txt" 2>&1
  rc=$?
  set -e
  # The last status line: "#N DONE cov: C ft: F corp: K/..." (or the last "#N ..." before a crash).
  line=$(grep -E '^#[0-9]+' "$work/log.txt" | tail -1)
  execs=$(sed -nE 's/^#([0-9]+).*/\1/p' <<<"$line")
  cov=$(sed -nE 's/.*cov: ([0-9]+).*/\1/p' <<<"$line")
  ft=$(sed -nE 's/.*ft: ([0-9]+).*/\1/p' <<<"$line")
  corp=$(sed -nE 's/.*corp: ([0-9]+).*/\1/p' <<<"$line")
  rate=$(sed -nE 's/^stat::average_exec_per_sec: *([0-9]+)/\1/p' "$work/log.txt")
  result=ok
  if [[ $rc -ne 0 ]]; then
    result="FAILED (rc $rc; $work/log.txt, inputs in $work/crashes)"
    failed=1
  fi
  printf '%-12s %10s %9s %7s %7s %8s  %s\n' "$name" "${execs:-?}" "${rate:-?}" "${cov:-?}" "${ft:-?}" "${corp:-?}" "$result"
done
echo "(execs over ${SECONDS_EACH} s per target, one process each; cov = instrumented edges reached)"
exit $failed
