"""The simulated telescope's hardware file for the VM stage's checks, printed to stdout:
    python hwfile.py SOURCE.toml [--channel vcan0] [--slowdown N]
``--channel``: the bus becomes socketcan on that kernel interface (tcs-sim puts the drives
there, tcs-server is the master). ``--slowdown N`` (a whole number; the stage passes 5 under
software emulation): the cycle, the heartbeats and their consumer times, SDO, boot,
following-error, enable, fault-reset, mode-switch, master-loss (the drives' RPDO deadline) and
homing time-outs are N times longer, and the following-error windows N times wider (an error
from lateness is speed x lateness), as on a host N times slower — the exchanges are the same,
the clock runs slower (the idle SYNC's period too). ``[server] allow_system_control`` is
switched on (the checks ask for a reboot to see what the hardened unit does with it)."""

import argparse

import tomlkit

p = argparse.ArgumentParser()
p.add_argument("source")
p.add_argument("--channel")
p.add_argument("--slowdown", type=int, default=1)
args = p.parse_args()
doc = tomlkit.parse(open(args.source, encoding="utf-8").read())
can, n = doc["can"], args.slowdown
if args.channel:
    can["interface"], can["channel"] = "socketcan", args.channel
can["sync_period"] = round(float(can.get("sync_period", 0.01)) * n, 3)
if "idle_sync_period" in can:
    can["idle_sync_period"] = round(float(can["idle_sync_period"]) * n, 3)
can["heartbeat_period"] = round(float(can.get("heartbeat_period", 0.1)) * n, 3)
can["boot_timeout"] = round(float(can.get("boot_timeout", 5.0)) * n, 3)
can["sdo_timeout"] = min(10.0, round(float(can.get("sdo_timeout", 0.5)) * n, 3))
for drive in doc.get("drives", {}).values():
    for key, default in (("heartbeat_period", 0.1), ("heartbeat_consumer_timeout", 0.5),
                         ("following_error_timeout", 0.05), ("enable_timeout", 2.0),
                         ("fault_reset_timeout", 1.0), ("mode_switch_timeout", 1.0)):
        drive[key] = round(float(drive.get(key, default)) * n, 3)
    # a position window too: the error a drive sees from frames that come late is speed x
    # lateness, and the lateness is what stretches (a 0.3 s backlog of the emulated
    # simulator at 5 deg/s is 1.5 deg against a window of 1)
    if "following_error_window" in drive:
        drive["following_error_window"] = round(float(drive["following_error_window"]) * n, 6)
    if "master_loss_timeout" in drive:  # (absent: 3 SYNC periods, stretched with the period)
        drive["master_loss_timeout"] = round(float(drive["master_loss_timeout"]) * n, 3)
    if "timeout" in drive.get("homing", {}):
        drive["homing"]["timeout"] = round(float(drive["homing"]["timeout"]) * n, 3)
doc["server"]["allow_system_control"] = True
print(tomlkit.dumps(doc), end="")
