#!/bin/bash
# VM stage, in the guest (root, in the project, guest venv active): the two-process stack over
# kernel CAN. tcs-sim serves the simulated drives on vcan0 (and its PLCs and GPS over TCP),
# tcs-server is the master on the same vcan0 with interface "socketcan" (SYNC from the kernel's
# broadcast manager); through TPL2: power, referencing, a slew, and tracking a star.
set -u
. "$(dirname "$0")/lib.sh"
ch=${1:-vcan0}
work=$(mktemp -d)
tools/ci/vcan-up.sh "$ch" >/dev/null; check vcan-up $? "$ch"
# (eds/ next to the file: the hardware file names its EDS relative to itself)
hwfile --channel "$ch" > "$work/stack.toml"; ln -s "$PWD/hwconfig/eds" "$work/eds"
export XDG_STATE_HOME=$work/state
grep -A5 '^\[can\]' "$work/stack.toml"; echo "(slowdown $SLOWDOWN)"
# every TCS heartbeat (0x77F), SYNC and EMCY on the bus, time-stamped: why a drive faulted
candump -t A -L "$ch,77F:7FF,080:7FF,080:780" > "$work/candump.log" 2>&1 &
dump=$!
step "tcs-sim: the drives on $ch"
tcs-sim --config "$work/stack.toml" 2> "$work/sim.log" &
sim=$!
# (until it is ready or has ended: a refused hardware file ends it at once, with status 2)
wait_for 600 sh -c "grep -q 'tcs-sim: ready' '$work/sim.log' || ! kill -0 $sim 2>/dev/null"
grep -q 'tcs-sim: ready' "$work/sim.log"; check tcs-sim-ready $? "$(grep 'ready' "$work/sim.log" || tail -5 "$work/sim.log")"
step "tcs-server: master on $ch (socketcan)"
t=$(date +%s.%N)
tcs-server --config "$work/stack.toml" --opentsi-port -1 --alpaca-port -1 2> "$work/server.log" &
server=$!
server_up() { value LOCAL.UT1 >/dev/null || ! kill -0 "$server" 2>/dev/null; }
wait_for 600 server_up; value LOCAL.UT1 >/dev/null
check tcs-server-serving $? "after $(since "$t") s$(kill -0 "$server" 2>/dev/null || echo "; it ended: $(tail -3 "$work/server.log")")"
client get CABINET.CORE.CYCLE.CYCLES CABINET.CORE.CYCLE.MISSED 2>&1 | tr '\n' ' '; echo
step "power, referencing"
client set CABINET.POWER=1 | tail -1; rc=${PIPESTATUS[0]}; check power-on "$rc"
if [ "$rc" != 0 ]; then  # nothing after this can work: say why, keep the logs, stop
  step "power-on failed: the logs' errors"
  grep -E 'WARNING|ERROR|lost|stall' "$work/server.log" | tail -25
  grep -E 'WARNING|ERROR|lost|stall|NMT|fault' "$work/sim.log" | tail -25
  grep -c . "$work/candump.log"; tail -5 "$work/candump.log"
  kill -TERM "$server" "$sim"; wait "$server" "$sim"; kill "$dump"
  mkdir -p /run-share/out && cp "$work"/*.log /run-share/out/ 2>/dev/null
  summary stack; exit
fi
client set CABINET.REINIT=1 | tail -1; check reinit "${PIPESTATUS[0]}"
# (one tcs-client polling over one connection: a client started every second cost the guest
# a vCPU of interpreter start-ups and starved the telescope it watched)
client wait --quiet --timeout 290 --interval 2 'CABINET.REFERENCED>=1' >/dev/null 2>&1
check referenced $? "REFERENCED=$(value CABINET.REFERENCED)"
step "slew"
t=$(date +%s.%N)
client set AZ.TARGETPOS=40 ZD.TARGETPOS=30 | tail -1; rc=${PIPESTATUS[0]}
check slew "$rc" "$(since "$t") s; AZ.REALPOS=$(value AZ.REALPOS) ZD.REALPOS=$(value ZD.REALPOS)"
step "track a star (west of the meridian, dec 10)"
lst=$(value POINTING.CURRENT.SIDEREAL_TIME)
ra=$(awk -v l="$lst" 'BEGIN { r = l - 0.5; if (r < 0) r += 24; printf "%.4f", r }')
client set POINTING.TARGET.RA="$ra" POINTING.TARGET.DEC=10 | tail -1
# (a TRACK from 0 answers only when the tracking ends, OpenTCI 2.5: started without waiting,
# then POINTING.TARGETDISTANCE is watched until it is small)
t=$(date +%s.%N)
client set --no-wait POINTING.TRACK=1 | tail -1; rc=${PIPESTATUS[0]}
[ "$rc" = 0 ] && client wait --quiet --timeout 290 --interval 2 'POINTING.TARGETDISTANCE<0.01' >/dev/null 2>&1; rc=$?
check track-start "$rc" "$(since "$t") s to the path; RA $ra (LST $lst)"
sleep 20
dist=$(value POINTING.TARGETDISTANCE); az1=$(value AZ.REALPOS); sleep 5; az2=$(value AZ.REALPOS)
track=$(value POINTING.TRACK)
awk -v d="$dist" 'BEGIN { exit !(d != "" && d + 0 < 0.01) }' && [ "$track" = 1 ] && [ "$az1" != "$az2" ]
check tracking $? "TARGETDISTANCE=$dist deg, AZ $az1 -> $az2, TRACK=$track"
client set POINTING.TRACK=0 | tail -1; check track-stop "${PIPESTATUS[0]}"
step "bus and errors"
ip -s link show "$ch" | sed -n '3,6p'
client get CABINET.ERROR_STATE CABINET.CORE.CYCLE.CYCLES CABINET.CORE.CYCLE.MISSED CABINET.CORE.CYCLE.LATE 2>&1 | tr '\n' ' '; echo
lost=$(grep -c '0x8130\|heartbeat of the TCS lost' "$work/server.log")
check no-heartbeat-loss "$([ "$lost" = 0 ] && echo 0 || echo 1)" "$lost lines about the TCS heartbeat lost"
kill -TERM "$server"; wait "$server"; check server-stop $? "exit status"
kill -TERM "$sim"; wait "$sim"; kill "$dump"
grep -E 'WARNING|ERROR' "$work/server.log" | head -20
mkdir -p /run-share/out && cp "$work"/*.log /run-share/out/ 2>/dev/null
summary stack
