#!/usr/bin/env bash
# Tracking benchmark against peers (opt-in; not part of the test suite).
#
# Runs our `fslam track` and two Open3D 0.16 peers (RGB-D odometry with the hybrid term, and
# generalized ICP on 2 cm voxels; see tracking_peers.py) on the same frames in one run,
# evaluates every trajectory with `fslam eval` against the same ground truth, and prints one
# table with ATE and per-frame time, plus the ratios of ours to each peer. Timings on this
# 2-core machine are noisy, which is why the peers are re-measured in the same run rather than
# quoted, and why each row also says how busy the machine was with other work meanwhile.
set -euo pipefail

usage() {
  cat <<'EOF'
Usage: tests/benchmarks/tracking_bench.sh [options]

Runs `fslam track` (when build/bin/fslam has that subcommand) with 1 thread and with --threads,
Open3D RGB-D odometry (hybrid term) with --threads, and Open3D generalized ICP with --threads and
with 1 thread, on the same frames, one after another; evaluates each with `fslam eval` and prints
method, ATE RMSE (cm), median and p99 ms per frame, threads, and ours/peer ratios.

Options:
  --dataset DIR   sequence folder, 7-Scenes or TUM (default: ../shared/data/redkitchen
                  beside the repository)
  --frames A:B    frame positions A..B-1 (default 0:600)
  --threads N     thread count for the multi-threaded runs (default: nproc)
  --out DIR       output folder (default /tmp/fslam_tracking_bench); trajectories, logs,
                  eval JSONs and summary.txt land here
  --skip-rgbd     leave out the Open3D RGB-D odometry (about 3 min for 600 frames on 2 idle
                  cores, twice that or more when the machine is shared)
  --skip-ours     leave out fslam track even where it exists
  --init MODE     peers' initial guess per frame: identity (default) or velocity (previous
                  relative motion)
  --fslam PATH    fslam binary (default build/bin/fslam)
  --max-wait S    before each run, wait up to S seconds for other processes to leave the
                  cores idle (default 600; 0: start at once)
  -h, --help      this text

Needs Debian's python3-open3d (apt-get install -y python3-open3d), used through /usr/bin/python3.
Per-frame time is preprocessing + registration, image decoding excluded (peers), or what
`fslam track` reports in its stage summary (a row labelled total/frame with median and p99
columns, in ms; else wall time / frames, marked). The peers' median and p99 are over the
"clean" frames, those during which other processes used less than half a core (/proc/stat is
machine-wide); the table says how many frames that is. Runs take long: progress lines are
printed as they go; run it under nohup for the full sequence.
EOF
}

REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
# House rule: every run exports the loopback DDS profile, whether or not it opens DDS.
export CYCLONEDDS_URI="file://${REPO}/configs/dds/loopback.xml"

DATASET="${REPO}/../shared/data/redkitchen"
FRAMES="0:600"
THREADS="$(nproc)"
OUT="/tmp/fslam_tracking_bench"
SKIP_RGBD=0
SKIP_OURS=0
INIT="identity"
FSLAM="${REPO}/build/bin/fslam"
MAX_WAIT=600
PY=/usr/bin/python3   # Debian's interpreter: python3-open3d is not visible to a pyenv python

while [[ $# -gt 0 ]]; do
  case "$1" in
    --dataset) DATASET="$2"; shift 2 ;;
    --frames) FRAMES="$2"; shift 2 ;;
    --threads) THREADS="$2"; shift 2 ;;
    --out) OUT="$2"; shift 2 ;;
    --skip-rgbd) SKIP_RGBD=1; shift ;;
    --skip-ours) SKIP_OURS=1; shift ;;
    --init) INIT="$2"; shift 2 ;;
    --fslam) FSLAM="$2"; shift 2 ;;
    --max-wait) MAX_WAIT="$2"; shift 2 ;;
    -h|--help) usage; exit 0 ;;
    *) echo "tracking_bench: unknown option '$1' (see --help)" >&2; exit 2 ;;
  esac
done

log() { echo "[tracking_bench $(date +%H:%M:%S)] $*"; }

if [[ ! -d "$DATASET" ]]; then
  log "SKIP: dataset folder $DATASET not found (the real data lives in ../shared/data)"
  exit 0
fi
DATASET="$(cd "$DATASET" && pwd)"
if [[ ! -x "$FSLAM" ]]; then
  echo "tracking_bench: $FSLAM not found; build first (bash deploy/setup.sh or cmake --build build)" >&2
  exit 1
fi
if ! "$PY" -c 'import open3d' 2>/dev/null; then
  echo "tracking_bench: Open3D missing for $PY; as root: apt-get install -y python3-open3d" >&2
  exit 1
fi
[[ "$FRAMES" =~ ^[0-9]*:[0-9]*$ ]] || { echo "tracking_bench: --frames must be A:B" >&2; exit 2; }
[[ "$THREADS" =~ ^[1-9][0-9]*$ ]] || { echo "tracking_bench: --threads must be >= 1" >&2; exit 2; }

mkdir -p "$OUT"
# A previous run's files would otherwise enter this run's table.
rm -f "$OUT"/{ours,rgbd,gicp}_t*.{txt,log} "$OUT"/{ours,peers}_t*.{log,json} \
  "$OUT"/eval_*.{json,log} "$OUT"/groundtruth.txt "$OUT"/summary.txt
PEERS="${REPO}/tests/benchmarks/tracking_peers.py"

# CPU seconds used so far by every process on the machine (user+nice+system+irq+softirq+steal).
busy_ticks() { awk '/^cpu /{print $2+$3+$4+$7+$8+$9; exit}' /proc/stat; }

# Waits until the machine has been idle (< 0.2 busy cores) for 5 s, at most MAX_WAIT seconds:
# the cores are shared with other tenants' builds, which would otherwise land in the timings.
wait_quiet() {
  local waited=0 hz a b
  hz=$(getconf CLK_TCK)
  while (( waited < MAX_WAIT )); do
    a=$(busy_ticks); sleep 5; b=$(busy_ticks); waited=$((waited + 5))
    if (( b - a < hz )); then return 0; fi   # (b - a) / hz / 5 s < 0.2 cores
    (( waited % 60 == 0 )) && log "waiting for idle cores ($(( (b - a) * 100 / hz / 5 ))% of a core busy elsewhere, ${waited}s)"
  done
  (( MAX_WAIT > 0 )) && log "machine still busy after ${MAX_WAIT}s; measuring anyway (see busy-other)"
  return 0
}

# Runs a command with its output in a log and writes NAME.run.json: wall time, CPU time of the
# command, and the mean number of cores other processes kept busy meanwhile (/proc/stat is
# machine-wide; a build in another container is the usual culprit for bad figures here).
run_measured() {
  local name="$1"; shift
  wait_quiet
  "$PY" - "$OUT/$name.run.json" "$OUT/$name.log" "$@" <<'EOF'
import json, os, resource, subprocess, sys, time
out, log, cmd = sys.argv[1], sys.argv[2], sys.argv[3:]
def busy():
    with open("/proc/stat") as f:
        v = [int(x) for x in f.readline().split()[1:]]
    return (v[0] + v[1] + v[2] + v[5] + v[6] + v[7]) / os.sysconf("SC_CLK_TCK")
b0, t0 = busy(), time.perf_counter()
with open(log, "w") as f:
    # Progress lines go both to the terminal and to the log.
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    for line in p.stdout:
        f.write(line)
        if line.startswith("[") or "error" in line.lower():
            sys.stdout.write("    " + line)
            sys.stdout.flush()
    rc = p.wait()
wall = time.perf_counter() - t0
ru = resource.getrusage(resource.RUSAGE_CHILDREN)
cpu = ru.ru_utime + ru.ru_stime
json.dump(dict(cmd=cmd, rc=rc, wall_s=wall, cpu_s=cpu,
               foreign_load=max(0.0, busy() - b0 - cpu) / wall), open(out, "w"), indent=1)
sys.exit(rc)
EOF
}

# Taken once: the tree may move on while a long run goes (a commit in between would otherwise
# be printed in the table); '-dirty' marks uncommitted changes to tracked files.
COMMIT="$(git -C "$REPO" rev-parse --short HEAD 2>/dev/null || echo unknown)"
git -C "$REPO" diff --quiet HEAD 2>/dev/null || COMMIT="${COMMIT}-dirty"
log "dataset $DATASET, frames $FRAMES, threads $THREADS, out $OUT, commit $COMMIT"
log "load average before start: $(cut -d' ' -f1-3 /proc/loadavg)"

# ---- peers --------------------------------------------------------------------------------
# The ground truth of the selected frames comes from the peers script (fslam has no export
# command), so the peers run first. A 1-thread GICP run gives ours at 1 thread a like-for-like
# peer; the RGB-D odometry runs only at --threads because it is the slow one.
methods="rgbd,gicp"; [[ $SKIP_RGBD -eq 1 ]] && methods="gicp"
log "peers: Open3D $methods, $THREADS threads (RGB-D odometry: about 0.3 s per frame on idle cores)"
run_measured "peers_t${THREADS}" "$PY" "$PEERS" --dataset "$DATASET" --frames "$FRAMES" \
  --threads "$THREADS" --methods "$methods" --init "$INIT" --tag "_t${THREADS}" --out "$OUT"
if [[ "$THREADS" -ne 1 ]]; then
  log "peers: Open3D gicp, 1 thread"
  run_measured "peers_t1" "$PY" "$PEERS" --dataset "$DATASET" --frames "$FRAMES" \
    --threads 1 --methods gicp --init "$INIT" --tag "_t1" --out "$OUT"
fi
GT="$OUT/groundtruth.txt"
[[ -s "$GT" ]] || { echo "tracking_bench: no ground truth for $DATASET; nothing to evaluate" >&2; exit 1; }

# ---- ours ---------------------------------------------------------------------------------
ours_threads=()
if [[ $SKIP_OURS -eq 1 ]]; then
  log "ours: skipped (--skip-ours)"
elif "$FSLAM" --help 2>/dev/null | grep -Eq '^[[:space:]]+track([[:space:]]|$)'; then
  ours_threads=(1); [[ "$THREADS" -ne 1 ]] && ours_threads+=("$THREADS")
  for t in "${ours_threads[@]}"; do
    log "ours: fslam track, $t thread(s)"
    run_measured "ours_t$t" "$FSLAM" track --dataset "$DATASET" --out "$OUT/ours_t$t.txt" \
      --frames "$FRAMES" --threads "$t" \
      || { log "ours: fslam track failed with $t thread(s), see $OUT/ours_t$t.log"; }
  done
else
  log "ours: $FSLAM has no 'track' subcommand yet; running the peers only"
fi

# ---- evaluation -----------------------------------------------------------------------------
for traj in "$OUT"/ours_t*.txt "$OUT"/rgbd_t*.txt "$OUT"/gicp_t*.txt; do
  [[ -s "$traj" ]] || continue
  name="$(basename "$traj" .txt)"
  "$FSLAM" eval --gt "$GT" --est "$traj" --json "$OUT/eval_$name.json" > "$OUT/eval_$name.log" 2>&1 \
    || log "eval failed for $traj, see $OUT/eval_$name.log"
done

# ---- table ----------------------------------------------------------------------------------
"$PY" - "$OUT" "$FRAMES" "$COMMIT" <<'EOF' | tee "$OUT/summary.txt"
import glob, json, os, re, sys
out, frames, commit = sys.argv[1:4]

def load(path):
    try:
        with open(path) as f:
            return json.load(f)
    except (OSError, ValueError):
        return None

STATS = ("count", "n", "frames", "mean", "median", "p50", "p90", "p95", "p99", "min", "max",
         "std", "total", "sum")

def norm(word):
    word = word.lower().strip("[]():,")
    return word[:-3] if word.endswith("_ms") else word

def ours_timing(log_path, n_frames, run):
    """Median and p99 ms per frame from fslam track's stage summary.

    Accepts a line naming the total, as fslam track prints it
    ('  tracking total  median 20.50 ms   p99 30.20 ms   mean 21.00 ms'), or a table (a header
    naming 'median' and 'p99' columns, values in ms, and a row labelled 'total', 'frame' or
    'per-frame'). Without either, falls back to wall time / frames
    (start-up and image decoding included), marked as such in the notes."""
    try:
        lines = open(log_path).read().splitlines()
    except OSError:
        lines = []
    number = r"[-+]?\d+(?:\.\d+)?"
    header = None
    for line in lines:
        words = [norm(w) for w in re.split(r"[\s|]+", line.strip()) if w]
        words = [w for w in words if w not in ("ms", "")]
        if not words:
            continue
        label = words[0].rstrip(":")
        is_total = label in ("total", "frame", "per-frame", "per_frame") or "total" in words
        if not is_total and "median" in words and "p99" in words:
            # a header; its first word names the label column unless it is a statistic
            header = words if words[0] in STATS else words[1:]
            continue
        if is_total:
            # e.g. fslam's "  tracking total  median 20.50 ms   p99 30.20 ms   mean ..."
            kv = {k: float(v) for k, v in re.findall(r"(median|p99)\D{0,6}?(" + number + ")",
                                                     line.lower())}
            if "median" in kv and "p99" in kv:
                return kv["median"], kv["p99"], "stage summary"
            nums = re.findall(number, line)
            if header and len(nums) >= len(header):
                vals = dict(zip(header, map(float, nums[-len(header):])))
                return vals["median"], vals["p99"], "stage summary"
    if run and n_frames:
        return run["wall_s"] * 1000 / n_frames, None, "wall/frame"
    return None, None, "n/a"

rows = []
peers = {}
for pj in sorted(glob.glob(os.path.join(out, "peers_t*.json"))):
    m = re.search(r"peers(_t\d+)\.json$", pj)
    if not m:
        continue  # peers_tN.run.json
    tag, rep = m.group(1), load(pj)
    for m, rec in rep["methods"].items():
        ev = load(os.path.join(out, "eval_%s%s.json" % (m, tag)))
        label = {"rgbd": "Open3D RGB-D odometry (hybrid)", "gicp": "Open3D GICP 2 cm"}[m]
        pf, pc = rec["per_frame"], rec.get("per_frame_clean")
        # Clean frames only, unless too few of them were clean to stand for the sequence.
        use = pc if pc and pc["count"] >= pf["count"] / 2 else pf
        row = dict(key="%s%s" % (m, tag), label=label, threads=rep["threads"],
                   ate=ev["ate"]["rmse_m"] * 100 if ev else None,
                   med=use["median_ms"], p99=use["p99_ms"],
                   clean="%d/%d" % (pc["count"] if pc else 0, pf["count"]),
                   note="%sall frames %.0f/%.0f ms, reg %.0f ms, fail %d, busy-other %.2f" % (
                       "" if use is pc else "TOO FEW CLEAN FRAMES, ", pf["median_ms"],
                       pf["p99_ms"], rec["timings"]["register"]["median_ms"], rec["failures"],
                       rec.get("foreign_load") or 0.0))
        rows.append(row)
        peers[row["key"]] = row
        n_frames = rep["frame_count"]
ours = []
for lp in sorted(glob.glob(os.path.join(out, "ours_t*.log"))):
    tag = re.search(r"ours(_t\d+)\.log", lp).group(1)
    run = load(os.path.join(out, "ours%s.run.json" % tag))
    ev = load(os.path.join(out, "eval_ours%s.json" % tag))
    med, p99, src = ours_timing(lp, n_frames, run)
    row = dict(key="ours" + tag, label="fslam track", threads=int(tag[2:]),
               ate=ev["ate"]["rmse_m"] * 100 if ev else None, med=med, p99=p99, clean="-",
               note="%s, busy-other %.2f%s" % (src, (run or {}).get("foreign_load") or 0.0,
                                                "" if ev else ", NO TRAJECTORY"))
    rows.append(row)
    ours.append(row)

# ours first, then the peers by method and thread count
order = {"fslam track": 0, "Open3D RGB-D odometry (hybrid)": 1, "Open3D GICP 2 cm": 2}
rows.sort(key=lambda r: (order[r["label"]], r["threads"]))

def f(v, fmt):
    return fmt % v if v is not None else "-"

print("\nTracking benchmark, frames %s, commit %s" % (frames, commit))
print("%-32s %7s %8s %8s %7s %8s  %s" % ("method", "ATE cm", "med ms", "p99 ms", "threads",
                                          "clean", "notes"))
for r in rows:
    print("%-32s %7s %8s %8s %7d %8s  %s" % (r["label"], f(r["ate"], "%.2f"), f(r["med"], "%.1f"),
                                           f(r["p99"], "%.1f"), r["threads"], r["clean"],
                                           r["note"]))
if ours:
    print("\nratios, ours / peer (below 1: ours is more accurate / faster)")
    print("%-16s %-46s %10s %10s" % ("ours", "peer", "ATE ratio", "time ratio"))
    for o in ours:
        for p in peers.values():
            ate = o["ate"] / p["ate"] if o["ate"] is not None and p["ate"] else None
            tim = o["med"] / p["med"] if o["med"] is not None and p["med"] else None
            print("%-16s %-46s %10s %10s" % ("%d thread(s)" % o["threads"],
                  "%s, %d thread(s)" % (p["label"], p["threads"]), f(ate, "%.3f"),
                  f(tim, "%.3f")))
else:
    print("\n(no fslam track trajectory: ratios need one)")
print("\nper-frame time: preprocessing + registration (peers; image decoding excluded), median"
      " and p99 over the clean frames (other processes used < 0.5 core meanwhile);"
      " busy-other: mean cores used by other processes over the whole run (timings suspect"
      " above ~0.1)")
EOF
log "done: $OUT/summary.txt"
