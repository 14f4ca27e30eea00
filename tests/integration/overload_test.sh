#!/usr/bin/env bash
# Overload (issue 23): SESSIONS raw publishers push RAW 640x480 frames into their own maps as fast
# as DDS takes them, a client asks for 640x480 renders back to back, and a probe renders a small
# view every 0.5 s (tests/common/load_main.cpp). The server must stay responsive: the probe's
# renders and `fslam status` answered within seconds during the load, every frame sent tracked
# or reported (a pose, a skip or an error result), a new session served afterwards, resident
# memory under BUDGET_MB, and SIGTERM honoured within 15 s.
#
#   overload_test.sh BIN_DIR REPO_ROOT [SECONDS] [SESSIONS] [BUDGET_MB]
set -uo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/../common/script_support.sh"
BIN="$1" ROOT="$2" LOAD_S="${3:-15}" SESSIONS="${4:-4}" BUDGET_MB="${5:-2500}"
export CYCLONEDDS_URI="file://$ROOT/configs/dds/loopback.xml"
WORK="$(mktemp -d /tmp/fslam_overload.XXXXXX)"
PREFIX="overload$$"
cleanup() { stop_started; rm -rf "$WORK"; }
trap cleanup EXIT
"$BIN/fslam" synth --out "$WORK/seq" --frames 60 --seed 3 >/dev/null 2>&1 || { echo "synth failed"; exit 1; }

check "the server starts" start_server "$WORK/server.log"
# Resident memory every 0.25 s while the server lives.
( while kill -0 "$SERVER" 2>/dev/null; do awk '/VmRSS/ {print $2}' "/proc/$SERVER/status" 2>/dev/null; sleep 0.25; done ) >"$WORK/rss_kb.txt" &
SAMPLER=$!
PIDS+=("$SAMPLER")

timeout $((LOAD_S + 150)) "$BIN/fslam_load" "$PREFIX" "$WORK/seq" "$LOAD_S" "$SESSIONS" \
  --rate 0 --encoding raw --queriers 1 --query-rate 0 >"$WORK/report.json" 2>"$WORK/overload.err" &
LOADER=$!
PIDS+=("$LOADER")
sleep $((LOAD_S / 2))
t0=$(date +%s%N)
"$BIN/fslam" status --prefix "$PREFIX" --seconds 3 >"$WORK/status.txt" 2>&1
status_ms=$(( ($(date +%s%N) - t0) / 1000000 ))
check "fslam status answered during the load (${status_ms} ms)" grep -q "load0" "$WORK/status.txt"
wait "$LOADER"
check "the load tool finished" test $? -eq 0
cat "$WORK/overload.err" | head -5

check "the report holds what was asked" python3 - "$WORK/report.json" "$SESSIONS" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))
sessions = r["sessions"]
ok = len(sessions) == int(sys.argv[2])
for i, s in enumerate(sessions):
    answered = s["tracked"] + s["skipped"] + s["errors"]
    print(f"  session {i}: sent {s['sent']} (refused by flow control {s['refused']}), tracked {s['tracked']}, "
          f"skipped {s['skipped']}, errors {s['errors']}")
    ok = ok and s["sent"] > 0 and answered == s["sent"] and s["tracked"] > 0
probe = sorted(r["probe_ms"])
print(f"  hammer renders: {r['queries']['ok']} answered, {r['queries']['failed']} failed")
if probe:
    print(f"  probe renders: {len(probe)}, p50 {probe[len(probe) // 2]:.0f} ms, max {probe[-1]:.0f} ms, "
          f"failures {r['probe_failures']}")
print(f"  after the load: new session {r['after']['new_session']}, render {r['after']['render_ok']} "
      f"in {r['after']['render_ms']:.0f} ms")
ok = ok and len(probe) > 0 and r["probe_failures"] == 0 and probe[-1] < 5000
ok = ok and r["after"]["new_session"] and r["after"]["render_ok"]
sys.exit(0 if ok else 1)
PY
stop_ms=$(stop_within "$SERVER" 15)
check "SIGTERM honoured within 15 s (${stop_ms} ms)" test "$stop_ms" -lt 15000
wait "$SERVER" 2>/dev/null
peak_kb=$(sort -n "$WORK/rss_kb.txt" | tail -1)
check "peak resident memory $((peak_kb / 1024)) MiB under ${BUDGET_MB} MiB" test "$((peak_kb / 1024))" -lt "$BUDGET_MB"
tail -1 "$WORK/server.log"
stop_started
PIDS=()
exit "$FAILED"
