#!/usr/bin/env bash
# kill -9 of the server while it saves (map_files.hpp): a map folder is always a whole version.
# A map is streamed and saved once; then, ROUNDS times, a server loads it, a client asks for
# saves back to back, and the server is killed with SIGKILL at a random moment. After every kill
# the next server must load the map whole (the same Gaussian count), finishing or undoing an
# interrupted save, and no other folder may appear in map_dir. The unit test
# MapFiles.AnInterruptedSaveRecoversAWholeVersion covers each step of the swap deterministically;
# this one checks the server's start-up recovery against real kills.
#
#   save_kill_test.sh BIN_DIR REPO_ROOT [ROUNDS]
set -uo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/../common/script_support.sh"
BIN="$1" ROOT="$2" ROUNDS="${3:-8}"
export CYCLONEDDS_URI="file://$ROOT/configs/dds/loopback.xml"
WORK="$(mktemp -d /tmp/fslam_savekill.XXXXXX)"
PREFIX="savekill$$"
cleanup() { stop_started; rm -rf "$WORK"; }
trap cleanup EXIT
"$BIN/fslam" synth --out "$WORK/seq" --frames 15 --seed 5 >/dev/null 2>&1 || { echo "synth failed"; exit 1; }

count_in() { sed -n "s/.*loaded map 'm' from .* (\([0-9]*\) Gaussians).*/\1/p" "$1"; }

check "the first server starts" start_server "$WORK/server0.log"
"$BIN/fslam" stream --dataset "$WORK/seq" --prefix "$PREFIX" --session s --map m --policy queue \
  --report "$WORK/stream.json" >"$WORK/stream.txt" 2>&1
check "15 frames streamed into m" tracked_all "$WORK/stream.json" 15
kill -TERM "$SERVER"; wait "$SERVER" 2>/dev/null
check "the map is saved at shutdown" test -f "$WORK/maps/m/map.ply"

EXPECTED=""
RECOVERED=0
for round in $(seq 1 "$ROUNDS"); do
  log="$WORK/server$round.log"
  # Each step of the swap widened to 1 s (map_files.cpp fault_pause): most of a save's time is
  # then inside the swap, and most kills land there.
  if ! start_server "$log" 1000; then check "round $round: the server starts" false; cat "$log"; break; fi
  got="$(count_in "$log")"
  [[ -z "$EXPECTED" ]] && EXPECTED="$got"
  check "round $round: map m loaded whole ($got Gaussians, expected $EXPECTED)" test -n "$got" -a "$got" = "$EXPECTED"
  grep -E "interrupted save" "$log" | sed "s/^/  round $round: /"
  grep -qE "interrupted save" "$log" && RECOVERED=$((RECOVERED + 1))
  # The saver ends its running client too when told to: an orphaned save-map would otherwise ask
  # the next server for a save and leave a swap folder behind the final check.
  ( trap 'kill "$client" 2>/dev/null; wait "$client" 2>/dev/null; exit 0' TERM
    for _ in 1 2 3 4 5 6; do
      "$BIN/fslam" save-map --map m --prefix "$PREFIX" >/dev/null 2>&1 &
      client=$!
      wait "$client"
    done ) &
  SAVER=$!
  sleep "$(( RANDOM % 3 + 1 )).$(( RANDOM % 10 ))"
  kill -KILL "$SERVER"; wait "$SERVER" 2>/dev/null
  kill -TERM "$SAVER" 2>/dev/null; wait "$SAVER" 2>/dev/null
  others="$(ls -A "$WORK/maps" | grep -v -E '^(m|\.m\.saving|\.m\.old)$' || true)"
  check "round $round: nothing but m (and its save's hidden leftovers) in map_dir" test -z "$others"
done
start_server "$WORK/final.log"
grep -qE "interrupted save" "$WORK/final.log" && RECOVERED=$((RECOVERED + 1))
echo "$RECOVERED of $ROUNDS kills landed inside a save's swap and were recovered"
check "at least one kill landed inside a swap (else the test proved nothing)" test "$RECOVERED" -ge 1
check "after $ROUNDS kills the map loads whole" test "$(count_in "$WORK/final.log")" = "$EXPECTED"
check "no save leftovers after a clean start's recovery" test ! -e "$WORK/maps/.m.saving" -a ! -e "$WORK/maps/.m.old"
stop_started
PIDS=()
exit "$FAILED"
