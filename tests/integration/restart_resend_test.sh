#!/usr/bin/env bash
# The server restarted while a client waits for an answer (issue 23, docs/protocol.md
# "Resending"): a client asks for a save; the server is killed with SIGKILL in the middle of it;
# a new server starts on the same map folder. The client library sees the new server's reader
# match, sends the request again with the same id, and gets its answer from the new server: the
# call succeeds within its timeout, and the map folder holds one whole version.
#
#   restart_resend_test.sh BIN_DIR REPO_ROOT
set -uo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/../common/script_support.sh"
BIN="$1" ROOT="$2"
export CYCLONEDDS_URI="file://$ROOT/configs/dds/loopback.xml"
WORK="$(mktemp -d /tmp/fslam_resend.XXXXXX)"
PREFIX="resend$$"
cleanup() { stop_started; rm -rf "$WORK"; }
trap cleanup EXIT
"$BIN/fslam" synth --out "$WORK/seq" --frames 15 --seed 6 >/dev/null 2>&1 || { echo "synth failed"; exit 1; }


check "the first server starts" start_server "$WORK/server1.log"
"$BIN/fslam" stream --dataset "$WORK/seq" --prefix "$PREFIX" --session s --map m --policy queue \
  --report "$WORK/stream.json" >"$WORK/stream.txt" 2>&1
check "15 frames streamed into m" tracked_all "$WORK/stream.json" 15
kill -TERM "$SERVER"; wait "$SERVER" 2>/dev/null
check "the map is saved at shutdown" test -f "$WORK/maps/m/map.ply"

# Each step of this server's save swap takes 2 s, so the kill below lands inside the save.
check "a second server loads m (saves paused 2 s per step)" start_server "$WORK/server2.log" 2000
"$BIN/fslam" save-map --map m --prefix "$PREFIX" --timeout 60 >"$WORK/save.txt" 2>&1 &
SAVER=$!
PIDS+=("$SAVER")
saving() { local i; for i in $(seq 100); do [[ -e "$WORK/maps/.m.saving" ]] && return 0; sleep 0.1; done; return 1; }
check "the save started on the second server (its staging folder exists)" saving
kill -KILL "$SERVER"; wait "$SERVER" 2>/dev/null
killed_at=$(date +%s.%N)
t0=$SECONDS
check "a third server starts on the same folder" start_server "$WORK/server3.log"
wait "$SAVER"
rc=$?
echo "save-map after the restart: exit $rc in $((SECONDS - t0)) s: $(tr '\n' ' ' <"$WORK/save.txt")"
check "the waiting save-map succeeded (answered by the new server)" test "$rc" -eq 0
# Only the new server was alive after the kill, so a map folder written after it is its save.
check "the new server saved m on the resent request (folder written after the kill)" \
  python3 -c "import os, sys; sys.exit(os.stat('$WORK/maps/m/map.ply').st_mtime <= $killed_at)"
check "one whole version of m remains, no leftovers" test -f "$WORK/maps/m/map.ply" -a ! -e "$WORK/maps/.m.saving" -a ! -e "$WORK/maps/.m.old"
stop_started
PIDS=()
exit "$FAILED"
