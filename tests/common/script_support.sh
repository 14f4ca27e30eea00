# Shared by the script tests in tests/integration (sourced): a check that records a failure and
# goes on, so that one run shows every broken check, and the end of the processes a test started
# (by the PIDs it recorded in PIDS, never by name).
FAILED=0
PIDS=()

# check NAME COMMAND...: runs COMMAND; prints ok or FAILED with NAME.
check() {
  local name="$1"; shift
  if "$@"; then echo "ok: $name"; else echo "FAILED: $name"; FAILED=1; fi
}

# SIGTERM to every recorded process, then wait for each (servers save and withdraw on the way out).
stop_started() {
  local pid
  for pid in "${PIDS[@]}"; do kill -TERM "$pid" 2>/dev/null; done
  for pid in "${PIDS[@]}"; do wait "$pid" 2>/dev/null; done
}

# start_server LOG [PAUSE_MS [SERVER ARGS...]]: fslam-server on $PREFIX with its maps in $WORK/maps
# ($BIN, $PREFIX and $WORK are the script's), each step of a save's swap widened to PAUSE_MS
# (map_files.cpp fault_pause; 0 = none), with any further arguments; $SERVER is its PID, recorded
# in PIDS; true once it serves.
start_server() {
  local log="$1" pause="${2:-0}"
  shift $(($# >= 2 ? 2 : 1))
  FSLAM_FAULT_SAVE_PAUSE_MS="$pause" "$BIN/fslam-server" --prefix "$PREFIX" --map-dir "$WORK/maps" "$@" >"$log" 2>&1 &
  SERVER=$!
  PIDS+=("$SERVER")
  wait_for_line "$log" "serving on"
}

# stop_within PID SECONDS: SIGTERM, then wait up to SECONDS for PID to exit; prints the
# milliseconds it took, false when it was still running.
stop_within() {
  local t0 i
  t0=$(date +%s%N)
  kill -TERM "$1" 2>/dev/null
  for i in $(seq $(( $2 * 10 ))); do kill -0 "$1" 2>/dev/null || break; sleep 0.1; done
  echo $(( ($(date +%s%N) - t0) / 1000000 ))
  ! kill -0 "$1" 2>/dev/null
}

# wait_for_line FILE TEXT [TENTHS]: until FILE holds TEXT (default 20 s); false when it never does.
wait_for_line() {
  local i
  for i in $(seq 1 "${3:-200}"); do grep -q "$2" "$1" 2>/dev/null && return 0; sleep 0.1; done
  return 1
}

# tracked_all REPORT N: the JSON report of `fslam stream --report REPORT` says all N frames were
# sent and tracked (none skipped, in error or unanswered).
tracked_all() {
  python3 - "$1" "$2" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))
n = int(sys.argv[2])
sys.exit(0 if r.get("frames_sent") == n and r.get("tracked") == n else 1)
PY
}
