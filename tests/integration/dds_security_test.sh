#!/usr/bin/env bash
# DDS Security end to end on the loopback network (configs/dds/secure.xml, docs/deployment.md):
# certificates made at test time into a temporary folder by deploy/make_certs.sh (never
# committed); a secure server, a secure client that streams and renders, an observer that may
# query but not stream, and two intruders that listen and try to inject while the client streams:
# a participant without security (the plain loopback profile) and one whose identity and
# documents are signed by a CA the deployment does not trust. The server's frame count at the end
# shows that nothing but the client's frames got in.
#
#   dds_security_test.sh BIN_DIR REPO_ROOT     (exit 77 = skipped)
set -uo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/../common/script_support.sh"
BIN="$1" ROOT="$2"
skip() { echo "SKIPPED: $*"; exit 77; }
command -v openssl >/dev/null || skip "openssl is not installed"
ls /usr/lib/*/libddsc0debian/libdds_security_auth.so* >/dev/null 2>&1 \
  || skip "Cyclone DDS security plugins (libdds_security_*.so of libddsc0debian) not found"

WORK="$(mktemp -d /tmp/fslam_security.XXXXXX)"
PREFIX="sec$$"
cleanup() {
  stop_started
  rm -rf "$WORK"
}
trap cleanup EXIT
as() {  # as IDENTITY COMMAND...: a participant of the secure deployment
  local id="$1"; shift
  env CYCLONEDDS_URI="file://$ROOT/configs/dds/secure.xml" FSLAM_DDS_CERTS="$WORK/certs" \
    FSLAM_DDS_IDENTITY="$id" "$@"
}

bash "$ROOT/deploy/make_certs.sh" "$WORK/certs" --rogue >/dev/null || { echo "make_certs.sh failed"; exit 1; }
"$BIN/fslam" synth --out "$WORK/seq" --frames 15 --seed 4 >/dev/null 2>&1 || { echo "synth failed"; exit 1; }

# Background processes are started without the functions above: a backgrounded function is a
# subshell, and $! would be its PID instead of the program's.
SECURE="CYCLONEDDS_URI=file://$ROOT/configs/dds/secure.xml FSLAM_DDS_CERTS=$WORK/certs"
env $SECURE FSLAM_DDS_IDENTITY=server "$BIN/fslam-server" --prefix "$PREFIX" >"$WORK/server.log" 2>&1 &
SERVER=$!
PIDS+=("$SERVER")
check "the secure server starts" wait_for_line "$WORK/server.log" "serving on"

# Eavesdroppers listen for poses and status while the client streams.
PLAIN="CYCLONEDDS_URI=file://$ROOT/configs/dds/loopback.xml"
ROGUE="CYCLONEDDS_URI=file://$ROOT/configs/dds/secure.xml FSLAM_DDS_CERTS=$WORK/certs/rogue FSLAM_DDS_IDENTITY=intruder"
env $PLAIN "$BIN/fslam_dds_probe" "$PREFIX" 8 >"$WORK/plain_listen.txt" 2>&1 &
PIDS+=($!)
env $ROGUE "$BIN/fslam_dds_probe" "$PREFIX" 8 >"$WORK/rogue_listen.txt" 2>&1 &
PIDS+=($!)
as client "$BIN/fslam" stream --dataset "$WORK/seq" --prefix "$PREFIX" --session s --map room \
  --policy queue --report "$WORK/stream.json" >"$WORK/stream.txt" 2>&1
check "secure client -> server: every pose back" tracked_all "$WORK/stream.json" 15
as client "$BIN/fslam" render --map room --frame 7 --prefix "$PREFIX" --out "$WORK/client.png" \
  >"$WORK/render.txt" 2>&1
check "secure client renders the map" test -s "$WORK/client.png"
as observer "$BIN/fslam" render --map room --frame 7 --prefix "$PREFIX" --out "$WORK/observer.png" \
  >"$WORK/observer_render.txt" 2>&1
check "an observer may query the map" test -s "$WORK/observer.png"
wait "${PIDS[1]}" "${PIDS[2]}"
check "a participant without security gets no poses and no status" \
  grep -qz "poses 0.status 0" "$WORK/plain_listen.txt"
check "a participant with an untrusted identity gets no poses and no status" \
  grep -qz "poses 0.status 0" "$WORK/rogue_listen.txt"

# Injection: each tries to open a session and push five frames.
env $PLAIN "$BIN/fslam_dds_probe" "$PREFIX" 0 plain-session 5 >"$WORK/plain_inject.txt" 2>&1 &
P1=$!
env $ROGUE "$BIN/fslam_dds_probe" "$PREFIX" 0 rogue-session 5 >"$WORK/rogue_inject.txt" 2>&1 &
P2=$!
as observer "$BIN/fslam_dds_probe" "$PREFIX" 0 observer-session 5 >"$WORK/observer_inject.txt" 2>&1
as observer "$BIN/fslam" stream --dataset "$WORK/seq" --frames 0:3 --prefix "$PREFIX" \
  --session observer-stream >"$WORK/observer_stream.txt" 2>&1
wait "$P1" "$P2"
check "no server answers a participant without security" grep -q "open: .*no answer" "$WORK/plain_inject.txt"
check "no server answers an untrusted identity" grep -q "open: .*no answer" "$WORK/rogue_inject.txt"
check "an observer cannot write frames (denied by its permissions)" \
  grep -q "pushed: 0, then push_frame: .*Not Allowed By Security" "$WORK/observer_inject.txt"
check "an observer cannot stream" grep -qi "not allowed by security" "$WORK/observer_stream.txt"

kill -TERM "$SERVER"
wait "$SERVER"
check "the server received the client's 15 frames and nothing else" \
  grep -q "frames received 15, rejected 0" "$WORK/server.log"
if [[ $FAILED -ne 0 ]]; then
  for f in "$WORK"/*.txt; do echo "--- $f"; tail -6 "$f"; done
  echo "--- server"; grep -v "^  \|^[a-z_]*:$" "$WORK/server.log" | tail -15
  exit 1
fi
echo "DDS Security: all checks passed"
