#!/usr/bin/env bash
# Scale-out over DDS with no broker, across network namespaces this test creates and removes:
# two fslam-server instances (namespaces a and b, map groups 'a-*' and 'b-*') and a client
# (namespace c), joined by veth links to a bridge in a fourth namespace, with addresses the test
# assigns and unicast Cyclone profiles whose Peers are those addresses (the Kubernetes profile's
# shape). The client finds each map's instance in the map directory, streams into a map on one
# instance while it renders a map on the other; an unserved map and an unplaceable new map are
# clear errors; a second claim on a map is refused, and a claim made later gives the map up.
#
#   scaleout_netns_test.sh BIN_DIR     (exit 77 = skipped: not root, or no network namespaces)
set -uo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/../common/script_support.sh"
BIN="$1"
FSLAM="$BIN/fslam"
SERVER="$BIN/fslam-server"
skip() { echo "SKIPPED: $*"; exit 77; }
[[ $(id -u) -eq 0 ]] || skip "needs root to create network namespaces (ip netns add)"
command -v ip >/dev/null || skip "iproute2 (ip) is not installed"

TAG="fs$$"
NS_BR="${TAG}br" NS_A="${TAG}a" NS_B="${TAG}b" NS_C="${TAG}c"
declare -A ADDR=([a]=10.231.0.1 [b]=10.231.0.2 [c]=10.231.0.3)
WORK="$(mktemp -d /tmp/fslam_scaleout.XXXXXX)"
PREFIX="scale$$"

cleanup() {
  stop_started
  for ns in "$NS_A" "$NS_B" "$NS_C" "$NS_BR"; do ip netns del "$ns" 2>/dev/null; done
  rm -rf "$WORK"
}
trap cleanup EXIT

ip netns add "$NS_BR" 2>/dev/null || skip "this machine cannot create network namespaces"
ip -n "$NS_BR" link add br0 type bridge || skip "no bridge support in this kernel"
ip -n "$NS_BR" link set br0 up
for x in a b c; do
  ns="${TAG}$x"
  ip netns add "$ns"
  # The pair is made inside the namespaces: nothing touches this machine's own interfaces.
  ip -n "$ns" link add eth0 type veth peer name "v$x" netns "$NS_BR"
  ip -n "$ns" addr add "${ADDR[$x]}/24" dev eth0
  ip -n "$ns" link set eth0 up
  ip -n "$ns" link set lo up
  ip -n "$NS_BR" link set "v$x" master br0
  ip -n "$NS_BR" link set "v$x" up
  # Unicast discovery on the namespace's address, every namespace a peer.
  cat >"$WORK/dds_$x.xml" <<XML
<CycloneDDS xmlns="https://cdds.io/config">
  <Domain Id="any">
    <General>
      <Interfaces><NetworkInterface address="${ADDR[$x]}"/></Interfaces>
      <AllowMulticast>false</AllowMulticast>
      <MaxMessageSize>65500B</MaxMessageSize>
    </General>
    <Discovery>
      <ParticipantIndex>auto</ParticipantIndex>
      <MaxAutoParticipantIndex>20</MaxAutoParticipantIndex>
      <Peers>
        <Peer address="${ADDR[a]}"/><Peer address="${ADDR[b]}"/><Peer address="${ADDR[c]}"/>
      </Peers>
    </Discovery>
  </Domain>
</CycloneDDS>
XML
done

in_ns() {  # in_ns X COMMAND...: runs in namespace X with its profile
  local x="$1"; shift
  ip netns exec "${TAG}$x" env CYCLONEDDS_URI="file://$WORK/dds_$x.xml" "$@"
}
start_server() {  # start_server X: instance X, map group 'X-*', maps in $WORK/maps_X
  local x="$1"
  # Not through in_ns: a backgrounded function is a subshell, and $! would be its PID.
  ip netns exec "${TAG}$x" env CYCLONEDDS_URI="file://$WORK/dds_$x.xml" "$SERVER" --prefix "$PREFIX" \
    --instance "$x" --map-group "$x-*" --map-dir "$WORK/maps_$x" >"$WORK/server_$x.log" 2>&1 &
  PIDS+=($!)
  eval "PID_$x=$!"
  wait_for_line "$WORK/server_$x.log" "serving on" && return 0
  echo "server $x did not start:"; cat "$WORK/server_$x.log"; return 1
}
stop_server() {  # stop_server X: SIGTERM, wait (it saves its maps and withdraws its claims)
  local pid_var="PID_$1"
  kill -TERM "${!pid_var}" && wait "${!pid_var}" 2>/dev/null
}
client() { in_ns c "$FSLAM" "$@" --prefix "$PREFIX"; }

"$FSLAM" synth --out "$WORK/seq" --frames 30 --seed 3 >/dev/null 2>&1 || { echo "synth failed"; exit 1; }
start_server a || exit 1
start_server b || exit 1

# A map on b, then a stream into a map on a while the client renders the map on b.
client stream --dataset "$WORK/seq" --frames 0:20 --session sb --map b-room --policy queue \
  --report "$WORK/stream_b.json" >"$WORK/stream_b.txt" 2>&1
check "stream 20 frames into b-room (placed on instance b): every pose back" \
  tracked_all "$WORK/stream_b.json" 20
client stream --dataset "$WORK/seq" --frames 0:30 --session sa --map a-room --rate 15 \
  --policy queue --report "$WORK/stream_a.json" >"$WORK/stream_a.txt" 2>&1 &
STREAM_PID=$!
sleep 1
check "render b-room (on b) while a-room streams into a" \
  client render --map b-room --frame 10 --out "$WORK/b_room_10.png"
check "the render is a PNG" test -s "$WORK/b_room_10.png"
wait "$STREAM_PID"
check "stream 30 frames into a-room (placed on instance a): every pose back" \
  tracked_all "$WORK/stream_a.json" 30
check "render a-room (on a)" client render --map a-room --frame 29 --out "$WORK/a_room_29.png"

client maps >"$WORK/maps.txt" 2>&1
cat "$WORK/maps.txt"
check "directory: a-room on a" grep -Eq '^a-room +a ' "$WORK/maps.txt"
check "directory: b-room on b" grep -Eq '^b-room +b ' "$WORK/maps.txt"
check "directory: instance a serves on $PREFIX/a" grep -Eq "^a +$PREFIX/a +a-\\*" "$WORK/maps.txt"

# Clear errors: a map nobody serves, a new map no group takes.
client render --map nowhere --frame 0 --out "$WORK/x.png" >"$WORK/nowhere.txt" 2>&1
check "an unserved map is a clear error" grep -q "no instance on prefix '$PREFIX' serves map 'nowhere'" "$WORK/nowhere.txt"
client stream --dataset "$WORK/seq" --frames 0:2 --session sc --map c-room >"$WORK/c_room.txt" 2>&1
check "a new map no instance creates is a clear error" grep -q "creates new maps of that name" "$WORK/c_room.txt"

# Two instances never both claim a map. Prevention: b refuses to load a copy of a-room while a
# serves it. Resolution: b restarted with that copy in its map dir claims it at start, later than
# a did, and gives it up (the directory lists a alone).
check "save a-room on a" client save-map --map a-room
cp -r "$WORK/maps_a/a-room" "$WORK/maps_b/a-room-copy"
client load-map --map a-room --folder a-room-copy --instance b >"$WORK/load.txt" 2>&1
check "b refuses to serve a map a serves" grep -q "map 'a-room' is served by instance 'a'" "$WORK/load.txt"
stop_server b
rm -rf "$WORK/maps_b/a-room-copy"
cp -r "$WORK/maps_a/a-room" "$WORK/maps_b/a-room"
start_server b || exit 1
wait_for_line "$WORK/server_b.log" "gave up map 'a-room'" 100
check "b gives up a-room, claimed later than a's claim" grep -q "gave up map 'a-room': it is held by instance 'a'" "$WORK/server_b.log"
client maps >"$WORK/maps2.txt" 2>&1
check "directory: a-room held by a alone" bash -c "[[ \$(grep -Ec '^a-room ' $WORK/maps2.txt) == 1 ]] && grep -Eq '^a-room +a ' $WORK/maps2.txt"
check "b still serves b-room after its restart" grep -Eq '^b-room +b ' "$WORK/maps2.txt"

stop_server a
stop_server b
check "a received only a-room's 30 frames" grep -q "frames received 30," "$WORK/server_a.log"
if [[ $FAILED -ne 0 ]]; then
  for f in "$WORK"/*.txt; do echo "--- $f"; tail -5 "$f"; done
  for x in a b; do echo "--- server $x"; grep "^fslam-server: [^ ]* *[^ ]" "$WORK/server_$x.log" | tail -20; done
  exit 1
fi
echo "scale-out over namespaces: all checks passed"
