"""SIGTERM while slewing: the pending SET ends with COMMAND FAILED, motion stops, the drives
are switched off, the process exits 0, and what clients wrote is still there after a restart."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

from test_cli_server import connect, free_port


class Client:
    def __init__(self, port: int):
        self.sock = connect(port, timeout=60)
        self.file = self.sock.makefile("rb")
        assert self.file.readline().startswith(b"TPL2 ")
        self.sock.sendall(b'AUTH PLAIN "admin" "admin"\n')
        assert self.file.readline() == b"AUTH OK 0 0\n"

    def send(self, line: str) -> None:
        self.sock.sendall(line.encode() + b"\n")

    def until(self, cmd_id: int, timeout: float = 60.0) -> list[bytes]:
        lines = []
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            line = self.file.readline()
            if not line:
                return lines
            if line.split(b" ", 1)[0] == str(cmd_id).encode():
                lines.append(line.strip())
                if b" COMMAND " in line and not line.strip().endswith(b"COMMAND OK"):
                    return lines
        return lines

    def get(self, obj: str, cmd_id: int = 99) -> bytes:
        self.send(f"{cmd_id} GET {obj}")
        return self.until(cmd_id)[1].split(b"=", 1)[1]

    def close(self) -> None:
        self.file.close()
        self.sock.close()


def start(port: int, env: dict) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "tcs.cli.server", "--port", str(port),
                             "--opentsi-port", "0", "--alpaca-port", "-1", "--web-port", "-1", "--indi-port", "-1"], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)


def test_sigterm_while_slewing(tmp_path):
    env = dict(os.environ, XDG_STATE_HOME=str(tmp_path / "state"))
    port = free_port()
    proc = start(port, env)
    try:
        c = Client(port)
        c.send("1 SET LOCAL.UT1-UTC=0.375;CABINET.POWER=1")
        assert c.until(1)[-1] == b"1 COMMAND COMPLETE"
        c.send("2 SET ZD.REINIT=1")
        c.until(2)
        deadline = time.monotonic() + 30
        while c.get("ZD.REFERENCED") != b"1.0" and time.monotonic() < deadline:
            time.sleep(0.05)
        start_pos = float(c.get("ZD.REALPOS"))
        c.send(f"3 SET ZD.TARGETPOS={start_pos + 40.0}")   # a slew of many seconds
        deadline = time.monotonic() + 30
        while not int(c.get("ZD.MOTION_STATE")) & 1 and time.monotonic() < deadline:
            time.sleep(0.05)
        moving_at = float(c.get("ZD.REALPOS"))
        proc.send_signal(signal.SIGTERM)
        lines = c.until(3)
        assert lines[-1] == b"3 COMMAND FAILED", lines
        c.close()
        assert proc.wait(60) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
        _, err = proc.communicate()
    assert "Traceback" not in err
    stopping = err.index("stopping")
    after = err[stopping:]
    assert "event INFO ZD:23 stopped" in after           # motion brought to rest ...
    assert after.index("ZD:23 stopped") < after.index("event INFO ZD:21 power off")  # ... then off
    assert moving_at < start_pos + 40.0

    proc = start(port, env)                               # state kept across the restart
    try:
        c = Client(port)
        assert c.get("LOCAL.UT1-UTC") == b"0.375"
        c.close()
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(60) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.communicate()


def test_clean_stop_leaves_no_drive_faults(tmp_path):
    """``tcs-sim`` (the drives outlive the server) + ``tcs-server``: SIGTERM with every axis
    powered stops and disables them, then switches the drives' heartbeat consumers off, so
    after a pause longer than their consumer time the next start shows no drive errors."""
    import tomlkit

    from tcs.config.hwconfig import PACKAGE_ROOT
    from test_cli_server import free_port

    doc = tomlkit.parse((PACKAGE_ROOT / "hwconfig" / "sim-remote.toml").read_text())
    port = free_port()
    doc["can"]["port"] = free_port()
    for plc in doc.get("plcs", {}).values():
        plc["port"] = free_port()
    if "gps" in doc:
        doc["gps"]["url"] = f"socket://127.0.0.1:{free_port()}"
    doc["envelope"]["sun_avoidance"] = 0.0   # slews at any hour CI runs (tests/support/service.py)
    hwfile = tmp_path / "remote.toml"
    hwfile.write_text(tomlkit.dumps(doc))
    (tmp_path / "eds").symlink_to(PACKAGE_ROOT / "hwconfig" / "eds")
    env = dict(os.environ, XDG_STATE_HOME=str(tmp_path / "state"))
    sim = subprocess.Popen([sys.executable, "-m", "tcs.cli.sim", "--config", str(hwfile)], env=env,
                           stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)

    def server() -> subprocess.Popen:
        return subprocess.Popen([sys.executable, "-m", "tcs.cli.server", "--config", str(hwfile),
                                 "--port", str(port), "--opentsi-port", "-1", "--alpaca-port", "-1", "--web-port", "-1", "--indi-port", "-1"],
                                env=env, stdout=subprocess.DEVNULL,
                                stderr=subprocess.PIPE, text=True)

    procs = [sim]
    try:
        line = ""
        deadline = time.monotonic() + 60
        while "ready" not in line and time.monotonic() < deadline and sim.poll() is None:
            line = sim.stderr.readline()
        assert "tcs-sim: ready" in line, line
        procs.append(server())
        c = Client(port)
        c.send("1 SET CABINET.POWER=1")
        assert c.until(1)[-1] == b"1 COMMAND COMPLETE"
        assert c.get("CABINET.ERROR_STATE") == b"0"
        c.close()
        procs[-1].send_signal(signal.SIGTERM)
        assert procs[-1].wait(60) == 0
        time.sleep(1.5)  # longer than the drives' heartbeat consumer time (1 s)
        procs.append(server())
        c = Client(port)
        errors = {axis: c.get(f"{axis}.ERROR_STATE")
                  for axis in ("AZ", "ZD", "DEROTATOR[2]", "DEROTATOR[3]", "FOCUS", "FILTER[2]", "MIRROR")}
        assert set(errors.values()) == {b"0"}, errors
        c.close()
        procs[-1].send_signal(signal.SIGTERM)
        assert procs[-1].wait(60) == 0
    finally:
        for proc in procs:
            if proc.poll() is None:
                proc.kill()
            proc.communicate()
