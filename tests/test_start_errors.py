"""``tcs-server`` when its hardware cannot be reached at start: a CAN interface that cannot be
opened ends the server with one clear line (status 1, no traceback), and each lost PLC is
warned about once in the log, not once per module it serves (the modules' events are still
sent to clients, logged at INFO)."""

from __future__ import annotations

import os
import subprocess
import sys

import tomlkit

from tcs.config.hwconfig import PACKAGE_ROOT

REMOTE = PACKAGE_ROOT / "hwconfig" / "sim-remote.toml"


def test_unreachable_bus_and_plcs_give_clean_short_messages(tmp_path):
    doc = tomlkit.parse(REMOTE.read_text())
    can = doc["can"]
    can["interface"] = "socketcan"
    can["channel"] = "tcs-no-such-can"
    for key in ("host", "port"):
        can.pop(key, None)
    doc["plcs"]["dome"]["port"] = 1        # nothing listens on ports 1 and 2
    doc["plcs"]["telescope"]["port"] = 2
    hwfile = tmp_path / "unreachable.toml"
    hwfile.write_text(tomlkit.dumps(doc))
    (tmp_path / "eds").symlink_to(PACKAGE_ROOT / "hwconfig" / "eds")
    env = dict(os.environ, XDG_STATE_HOME=str(tmp_path / "state"))
    proc = subprocess.run([sys.executable, "-m", "tcs.cli.server", "--config", str(hwfile),
                           "--port", "0"], env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1, proc.stderr
    assert "Traceback" not in proc.stderr, proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("tcs-server: cannot start: CAN socketcan:tcs-no-such-can: cannot open the bus")
    warnings = [line for line in proc.stderr.splitlines() if line.startswith("WARNING")]
    for plc in ("dome", "telescope"):
        # (the weather interlock's own warnings, "weather unknown: PLC dome unreachable", are
        # about the interlock, not the PLC)
        lost = [w for w in warnings if f"PLC {plc}" in w and "weather" not in w]
        assert len(lost) == 1, lost
