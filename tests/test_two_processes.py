"""``tcs-sim`` and ``tcs-server`` as two processes: the server drives the simulated cabinet over
socketcand like real hardware and moves an axis. Also: the remote hardware file differs from the
default one only in its bus settings."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
import tomllib

import tomlkit

from tcs.config import DEFAULT_CONFIG
from tcs.config.hwconfig import PACKAGE_ROOT
from test_cli_server import connect, free_port

REMOTE = PACKAGE_ROOT / "hwconfig" / "sim-remote.toml"


def test_remote_file_differs_only_in_bus_settings():
    local = tomllib.loads(DEFAULT_CONFIG.read_text())
    remote = tomllib.loads(REMOTE.read_text())
    assert local.pop("can")["interface"] == "virtual"
    assert remote.pop("can")["interface"] == "socketcand"
    assert local == remote


def command(f, s, cmd_id: int, text: str, timeout: float = 60.0) -> list[bytes]:
    s.sendall(f"{cmd_id} {text}\n".encode())
    lines = []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        line = f.readline()
        if not line:
            break
        if line.split(b" ", 1)[0] == str(cmd_id).encode():
            lines.append(line.strip())
            if line.startswith(f"{cmd_id} COMMAND ".encode()) and not line.strip().endswith(b"OK"):
                break
    return lines


def test_server_drives_the_simulator_in_another_process(tmp_path):
    doc = tomlkit.parse(REMOTE.read_text())
    can_port, tpl2_port = free_port(), free_port()
    doc["can"]["port"] = can_port
    for plc in doc.get("plcs", {}).values():
        plc["port"] = free_port()
    if "gps" in doc:
        doc["gps"]["url"] = f"socket://127.0.0.1:{free_port()}"
    hwfile = tmp_path / "remote.toml"
    hwfile.write_text(tomlkit.dumps(doc))
    (tmp_path / "eds").symlink_to(PACKAGE_ROOT / "hwconfig" / "eds")
    env = dict(os.environ, XDG_STATE_HOME=str(tmp_path / "state"))
    sim = subprocess.Popen([sys.executable, "-m", "tcs.cli.sim", "--config", str(hwfile)], env=env,
                           stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    server = None
    try:
        line = ""
        deadline = time.monotonic() + 60
        while "ready" not in line and time.monotonic() < deadline and sim.poll() is None:
            line = sim.stderr.readline()
        assert "tcs-sim: ready" in line, line
        server = subprocess.Popen([sys.executable, "-m", "tcs.cli.server", "--config", str(hwfile),
                                   "--port", str(tpl2_port), "--opentsi-port", "0"], env=env,
                                  stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        s = connect(tpl2_port, timeout=60)
        f = s.makefile("rb")
        assert f.readline().startswith(b"TPL2 ")
        s.sendall(b'AUTH PLAIN "admin" "admin"\n')
        assert f.readline() == b"AUTH OK 0 0\n"
        assert command(f, s, 1, "SET CABINET.POWER=1")[-2:] == [b"1 DATA OK CABINET.POWER", b"1 COMMAND COMPLETE"]
        assert command(f, s, 2, "SET ZD.REINIT=1")[-1] == b"2 COMMAND COMPLETE"
        for _ in range(200):
            if command(f, s, 3, "GET ZD.REFERENCED")[1].endswith(b"=1.0"):
                break
            time.sleep(0.05)
        start = float(command(f, s, 4, "GET ZD.REALPOS")[1].split(b"=")[1])
        assert command(f, s, 5, f"SET ZD.TARGETPOS={start + 0.5}")[-2:] == [
            b"5 DATA OK ZD.TARGETPOS", b"5 COMMAND COMPLETE"]
        real = float(command(f, s, 6, "GET ZD.REALPOS")[1].split(b"=")[1])
        assert abs(real - (start + 0.5)) < 0.01
        s.close()
        f.close()
        server.send_signal(signal.SIGTERM)
        assert server.wait(60) == 0
    finally:
        for proc in (server, sim):
            if proc is not None:
                if proc.poll() is None:
                    proc.send_signal(signal.SIGTERM)
                    try:
                        proc.wait(30)
                    except subprocess.TimeoutExpired:
                        proc.kill()
                proc.communicate()
    assert sim.returncode == 0
