"""``tcs-server`` when its hardware cannot be reached at start: a CAN interface that cannot be
opened ends the server with one clear line (status 1, no traceback) before anything else is
started; and each lost PLC is warned about once in the log, not once per module it serves (the
modules' events are still sent to clients, logged at INFO)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import tomlkit

from tcs.resources import hwconfig_file

REMOTE = hwconfig_file("sim-remote.toml")
#: every listening port on a free one (sim-remote.toml names the default server's: 65432,
#: 65433, 11111, 8088), so these pass beside a running ``tcs-server``
OWN_PORTS = ["--port", "0", "--opentsi-port", "0", "--alpaca-port", "0", "--alpaca-discovery-port", "-1",
             "--web-port", "0", "--indi-port", "0"]


def _write(tmp_path, doc) -> str:
    hwfile = tmp_path / "unreachable.toml"
    hwfile.write_text(tomlkit.dumps(doc))
    (tmp_path / "eds").symlink_to(hwconfig_file("eds"))
    return str(hwfile)


def test_unreachable_bus_is_one_clean_line(tmp_path):
    doc = tomlkit.parse(REMOTE.read_text())
    can = doc["can"]
    can["interface"] = "socketcan"
    can["channel"] = "tcs-no-such-can"
    for key in ("host", "port"):
        can.pop(key, None)
    doc["plcs"]["dome"]["port"] = 1        # nothing listens on ports 1 and 2
    doc["plcs"]["telescope"]["port"] = 2
    doc.pop("alpaca", None)
    env = dict(os.environ, XDG_STATE_HOME=str(tmp_path / "state"))
    proc = subprocess.run([sys.executable, "-m", "tcs.cli.server", "--config", _write(tmp_path, doc),
                           *OWN_PORTS], env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1, proc.stderr
    assert "Traceback" not in proc.stderr, proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("tcs-server: cannot start: CAN socketcan:tcs-no-such-can: cannot open the bus")
    # with what to do: a kernel without AF_CAN (these machines) names the modules, one with it
    # names the missing interface and its bring-up unit
    assert ("modprobe can can_raw" in last or "`ip link` lists the CAN interfaces" in last
            and "tcs-can@tcs-no-such-can" in last), last
    # the bus is checked first (one master per bus): no PLC was started, so none was lost
    assert not [line for line in proc.stderr.splitlines() if "PLC " in line], proc.stderr


def test_each_lost_plc_is_warned_about_once(tmp_path):
    doc = tomlkit.parse(REMOTE.read_text())
    for key in ("can", "drives", "axes", "simulation", "alpaca"):
        doc.pop(key, None)               # the PLC side alone
    doc["plcs"]["dome"]["port"] = 1        # nothing listens on ports 1 and 2
    doc["plcs"]["telescope"]["port"] = 2
    env = dict(os.environ, XDG_STATE_HOME=str(tmp_path / "state"))
    proc = subprocess.Popen([sys.executable, "-m", "tcs.cli.server", "--config",
                             _write(tmp_path, doc), *OWN_PORTS], env=env,
                            stderr=subprocess.PIPE, text=True)
    lines: list[str] = []
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:  # until both PLCs were found lost
            line = proc.stderr.readline()
            if not line:
                break
            lines.append(line)
            if sum("PLC " in x and ": lost" in x for x in lines) >= 2:
                break
        time.sleep(2.0)  # the modules' reactions, had they been logged as warnings too
    finally:
        proc.send_signal(signal.SIGTERM)
        rest = proc.communicate(timeout=60)[1]
    lines += rest.splitlines()
    assert proc.returncode == 0, "".join(lines)
    warnings = [line for line in lines if "WARNING" in line.split(" ", 2)[:2]]  # (after the time)
    for plc in ("dome", "telescope"):
        # (the weather interlock's own warnings, "weather unknown: PLC dome unreachable", are
        # about the interlock, not the PLC)
        lost = [w for w in warnings if f"PLC {plc}" in w and "weather" not in w]
        assert len(lost) == 1, lost
