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


def _remote(tmp_path, heartbeat_period: float = 1.0):
    """sim-remote.toml on free ports, and ``tcs-sim`` running it; (file, env, sim process)."""
    doc = tomlkit.parse(REMOTE.read_text())
    doc["can"]["port"] = free_port()
    for plc in doc.get("plcs", {}).values():
        plc["port"] = free_port()
    if "gps" in doc:
        doc["gps"]["url"] = f"socket://127.0.0.1:{free_port()}"
    for drive in doc["drives"].values():
        drive["heartbeat_period"] = heartbeat_period
        drive["heartbeat_consumer_timeout"] = 5.0
    hwfile = tmp_path / "remote.toml"
    hwfile.write_text(tomlkit.dumps(doc))
    (tmp_path / "eds").symlink_to(PACKAGE_ROOT / "hwconfig" / "eds")
    env = dict(os.environ, XDG_STATE_HOME=str(tmp_path / "state"))
    sim = subprocess.Popen([sys.executable, "-m", "tcs.cli.sim", "--config", str(hwfile)], env=env,
                           stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    return hwfile, doc, env, sim


def _wait_ready(sim) -> None:
    line = ""
    deadline = time.monotonic() + 60
    while "ready" not in line and time.monotonic() < deadline and sim.poll() is None:
        line = sim.stderr.readline()
    assert "tcs-sim: ready" in line, line


def _end(*procs) -> None:
    for proc in procs:
        if proc is not None:
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
                try:
                    proc.wait(30)
                except subprocess.TimeoutExpired:
                    proc.kill()
            proc.communicate()


def test_two_servers_started_at_once_one_master(tmp_path):
    """Two tcs-server started in the same instant on one bus both hear a quiet bus; the
    machine-wide bus lock lets exactly one of them become the master."""
    hwfile, doc, env, sim = _remote(tmp_path)
    servers = []
    try:
        _wait_ready(sim)
        for i in range(2):  # each with its own state directory (a shared one is refused first)
            servers.append(subprocess.Popen(
                [sys.executable, "-m", "tcs.cli.server", "--config", str(hwfile), "--port",
                 str(free_port()), "--opentsi-port", "-1", "--alpaca-port", "-1"],
                env=dict(env, XDG_STATE_HOME=str(tmp_path / f"state-{i}")),
                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True))
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and all(p.poll() is None for p in servers):
            time.sleep(0.05)
        refused = [p for p in servers if p.poll() is not None]
        assert len(refused) == 1, "both servers became masters"
        err = refused[0].communicate(timeout=10)[1]
        assert refused[0].returncode == 1 and "another process of this machine is the master" in err, err
        running = next(p for p in servers if p is not refused[0])
        time.sleep(1.0)
        assert running.poll() is None
    finally:
        _end(*servers, sim)


def test_server_drives_the_simulator_in_another_process(tmp_path):
    # Drive heartbeats every 1 s (lost after 1.5 s): starting two more servers during the slew
    # loads this 2-core machine, and the test is not about lost heartbeats.
    hwfile, doc, env, sim = _remote(tmp_path)
    tpl2_port = free_port()
    server = None
    others: list[subprocess.Popen] = []
    try:
        _wait_ready(sim)
        server = subprocess.Popen([sys.executable, "-m", "tcs.cli.server", "--config", str(hwfile),
                                   "--port", str(tpl2_port), "--opentsi-port", "0",
                                   "--alpaca-port", "-1"], env=env,
                                  stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        s = connect(tpl2_port, timeout=60)
        f = s.makefile("rb")
        assert f.readline().startswith(b"TPL2 ")
        s.sendall(b'AUTH PLAIN "admin" "admin"\n')
        assert f.readline() == b"AUTH OK 0 0\n"
        assert command(f, s, 1, "SET CABINET.POWER=1")[-2:] == [b"1 DATA OK CABINET.POWER", b"1 COMMAND COMPLETE"]
        for axis in ("ZD", "AZ"):
            assert command(f, s, 2, f"SET {axis}.REINIT=1")[-1] == b"2 COMMAND COMPLETE"
        for axis in ("ZD", "AZ"):
            deadline = time.monotonic() + 60
            while not command(f, s, 3, f"GET {axis}.REFERENCED")[1].endswith(b"=1.0"):
                assert time.monotonic() < deadline, f"{axis} not referenced"
                time.sleep(0.05)
        start = float(command(f, s, 4, "GET ZD.REALPOS")[1].split(b"=")[1])
        assert command(f, s, 5, f"SET ZD.TARGETPOS={start + 0.5}")[-2:] == [
            b"5 DATA OK ZD.TARGETPOS", b"5 COMMAND COMPLETE"]
        real = float(command(f, s, 6, "GET ZD.REALPOS")[1].split(b"=")[1])
        assert abs(real - (start + 0.5)) < 0.01

        # AZ slews at its configured speed ([axes.az] max_velocity): over socketcand the TPDOs
        # of every cycle arrive in time, so the drive follows without a following error.
        speed = float(doc["axes"]["az"]["max_velocity"])
        start = float(command(f, s, 8, "GET AZ.REALPOS")[1].split(b"=")[1])
        target = start + 30.0
        s.sendall(f"9 SET AZ.TARGETPOS={target}\n".encode())
        # Started by mistake during the slew, on the same bus: a second tcs-server with its own
        # TPL2 port hears the first one (SYNC or heartbeat) and exits before sending a frame; one on the
        # same port exits before opening the bus at all. The slew goes on undisturbed.
        # (each with a state directory of its own: a shared one is refused before all that)
        for port in (free_port(), tpl2_port):
            others.append(subprocess.Popen(
                [sys.executable, "-m", "tcs.cli.server", "--config", str(hwfile), "--port",
                 str(port), "--opentsi-port", "-1", "--alpaca-port", "-1"],
                env=dict(env, XDG_STATE_HOME=str(tmp_path / f"state-{port}")), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True))
        fastest, replies, n = 0.0, [], 10
        deadline = time.monotonic() + 120
        while not (replies and replies[-1].startswith(b"9 COMMAND COMPLETE")):
            assert time.monotonic() < deadline, replies
            s.sendall(f"{n} GET AZ.CURRSPEED\n".encode())
            while True:
                line = f.readline().strip()
                if line.startswith(b"9 "):
                    replies.append(line)
                elif line.startswith(f"{n} DATA INLINE".encode()):
                    fastest = max(fastest, abs(float(line.split(b"=")[1])))
                elif line.startswith(f"{n} COMMAND COMPLETE".encode()):
                    break
            n += 1
            time.sleep(0.05)
        assert b"9 DATA OK AZ.TARGETPOS" in replies, replies
        assert fastest >= 0.99 * speed, (fastest, speed)
        real = float(command(f, s, 8, "GET AZ.REALPOS")[1].split(b"=")[1])
        assert abs(real - target) < 0.01
        (_, err_bus), (_, err_port) = (other.communicate(timeout=60) for other in others)
        assert [other.returncode for other in others] == [1, 1], (err_bus, err_port)
        # (on this machine the bus lock refuses it even before it listens for SYNC)
        assert "refusing to start" in err_bus and "another process of this machine is the master" \
            in err_bus, err_bus
        assert "address already in use" in err_port.lower(), err_port
        assert "booted" not in err_bus + err_port  # never got as far as the drives
        assert command(f, s, 8, "GET AZ.ERROR_STATE")[1].endswith(b"=0")
        s.close()
        f.close()
        server.send_signal(signal.SIGTERM)
        assert server.wait(60) == 0
    finally:
        _end(*others, server, sim)
    assert sim.returncode == 0
