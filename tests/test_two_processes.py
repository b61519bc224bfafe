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
    doc["envelope"]["sun_avoidance"] = 0.0   # slews at any hour CI runs (tests/support/service.py)
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
                 str(free_port()), "--opentsi-port", "-1", "--alpaca-port", "-1", "--web-port", "-1", "--indi-port", "-1"],
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
                                   "--alpaca-port", "-1", "--web-port", "-1", "--indi-port", "-1"], env=env,
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
                 str(port), "--opentsi-port", "-1", "--alpaca-port", "-1", "--web-port", "-1", "--indi-port", "-1"],
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
        # near the configured speed (a late cycle's step is cut to the limit, so a loaded
        # machine reads a little less; a following-error stop would fail the SET above)
        assert fastest >= 0.8 * speed, (fastest, speed)
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


def _sample_drives(drives: dict, samples: dict, stop) -> None:
    """(thread) Every ~2 ms: (time, motor velocity, demanded velocity, the hardest
    acceleration of the drive's own reference) of each simulated drive."""
    while not stop.is_set():
        for name, drive in drives.items():
            with drive.lock:
                drive.logic.update(drive.clock())
                axis = drive.logic.axis
                samples[name].append((axis.t, axis.v, axis.demand()[1],
                                      max(abs(seg.a) for seg in axis.reference.segments)))
        time.sleep(0.002)


def _max_deceleration(samples: list[tuple[float, float]], after: float, window: float = 0.02) -> float:
    """The largest mean deceleration (speed lost per second) over any ``window`` s after
    ``after``; ``samples`` are (time, velocity)."""
    points = [p for p in samples if p[0] >= after]
    worst, j = 0.0, 0
    for i, (t0, v0) in enumerate(points):
        j = max(j, i)
        while j < len(points) and points[j][0] - t0 < window:
            j += 1
        if j == len(points):
            break
        t1, v1 = points[j]
        worst = max(worst, (abs(v0) - abs(v1)) / (t1 - t0))
    return worst


def test_killed_control_process_drives_stop_at_the_stop_deceleration(tmp_path):
    """Two-process rig, the simulated drives in this process (sampled here): kill -9 of the
    control process with AZ and ZD at full speed. Every drive ramps down at no more than its
    axis's configured stop deceleration (not at the motor's limit); the service starts a new
    control process, the client stays connected, the axes read fresh, nothing moves until
    commanded, the error stays until acknowledged, and then the axis moves again."""
    import asyncio
    import threading

    from tcs.config import load_config
    from tcs.sim.cabinet import SimCabinet
    from test_control_process import _children

    doc = tomlkit.parse(REMOTE.read_text())
    doc["can"]["port"] = free_port()
    for plc in doc.get("plcs", {}).values():
        plc["port"] = free_port()
    if "gps" in doc:
        doc["gps"]["url"] = f"socket://127.0.0.1:{free_port()}"
    for drive in doc["drives"].values():
        drive["heartbeat_period"] = 1.0
        drive["heartbeat_consumer_timeout"] = 5.0
    doc["envelope"]["sun_avoidance"] = 0.0   # slews at any hour CI runs (tests/support/service.py)
    hwfile = tmp_path / "remote.toml"
    hwfile.write_text(tomlkit.dumps(doc))
    (tmp_path / "eds").symlink_to(PACKAGE_ROOT / "hwconfig" / "eds")
    config = load_config(hwfile)
    env = dict(os.environ, XDG_STATE_HOME=str(tmp_path / "state"))

    loop = asyncio.new_event_loop()
    runner = threading.Thread(target=loop.run_forever, name="sim-loop", daemon=True)
    runner.start()
    cabinet = SimCabinet(config)
    server = None
    stop_sampling = threading.Event()
    try:
        asyncio.run_coroutine_threadsafe(cabinet.start(), loop).result(60)
        axes = {a.module: a for a in config.axes.values() if a.module in ("AZ", "ZD")}
        drives = {m: cabinet.drives[config.drives[a.drive].node_id] for m, a in axes.items()}
        tpl2_port = free_port()
        server = subprocess.Popen([sys.executable, "-m", "tcs.cli.server", "--config", str(hwfile),
                                   "--port", str(tpl2_port), "--opentsi-port", "-1",
                                   "--alpaca-port", "-1", "--web-port", "-1", "--indi-port", "-1"], env=env,
                                  stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        s = connect(tpl2_port, timeout=60)
        f = s.makefile("rb")
        assert f.readline().startswith(b"TPL2 ")
        s.sendall(b'AUTH PLAIN "admin" "admin"\n')
        assert f.readline() == b"AUTH OK 0 0\n"
        assert command(f, s, 1, "SET CABINET.POWER=1")[-1] == b"1 COMMAND COMPLETE"

        def num(cmd_id: int, name: str) -> float | None:
            line = command(f, s, cmd_id, f"GET {name}")[1]
            try:
                return float(line.split(b"=")[1])
            except (IndexError, ValueError):  # FAILED 4: stale
                return None

        def wait(what: str, predicate, timeout: float = 60.0) -> None:
            deadline = time.monotonic() + timeout
            while not predicate():
                assert time.monotonic() < deadline, what
                time.sleep(0.05)

        for axis in ("ZD", "AZ"):
            assert command(f, s, 2, f"SET {axis}.POWER=1")[-1] == b"2 COMMAND COMPLETE"
            assert command(f, s, 3, f"SET {axis}.REINIT=1")[-1] == b"3 COMMAND COMPLETE"
        for axis in ("ZD", "AZ"):
            # (generous: homing searches of two axes on a loaded host; once not done in 60 s in CI)
            wait(f"{axis} referenced", lambda: num(4, f"{axis}.REFERENCED") == 1.0, 180.0)
        az, zd = num(5, "AZ.REALPOS"), num(5, "ZD.REALPOS")
        s.sendall(f"10 SET AZ.TARGETPOS={az + 150.0}\n11 SET ZD.TARGETPOS={zd - 90.0 if zd > 0 else zd + 90.0}\n".encode())
        for axis in ("AZ", "ZD"):
            top = axes[axis].max_velocity
            wait(f"{axis} at full speed: " + str(command(f, s, 7, f"GET {axis}.CURRSPEED;{axis}.ERROR_STATE;"
                                                        f"{axis}.MOTION_STATE;CABINET.STATUS.LIST")),
                 lambda: abs(num(6, f"{axis}.CURRSPEED") or 0) >= 0.95 * top)

        samples = {m: [] for m in drives}
        sampler = threading.Thread(target=_sample_drives, args=(drives, samples, stop_sampling), daemon=True)
        sampler.start()
        (child,) = _children(server.pid)
        time.sleep(0.05)
        killed = drives["AZ"].clock()
        os.kill(child, signal.SIGKILL)
        wait("every drive at rest", lambda: all(
            len(samples[m]) > 10 and samples[m][-1][0] > killed + 0.5 and samples[m][-1][1] == 0.0
            and samples[m][-1][2] == 0.0
            for m in drives), 30)
        stop_sampling.set()
        sampler.join(5)
        for axis, section in axes.items():
            limit = section.stop_deceleration
            at_kill = [abs(v) for t, v, _, _ in samples[axis] if t <= killed]
            assert at_kill and at_kill[-1] >= 0.8 * section.max_velocity, (axis, at_kill[-3:])
            rest = next(t for t, v, d, _ in samples[axis] if t > killed and v == 0.0 and d == 0.0)
            # the stop as a whole: from the start of the drive's own ramp (its reference is no
            # longer the last CSP line) to rest no harder than the stop deceleration (old: the
            # drive held its last setpoint and the motor braked at its own limit). The ramp
            # starts from the motor's speed, which wobbles around the last CSP steps (5.09
            # against a demand of 4.78 was seen; the 0.25 s check below judges the motor), so
            # the demand just before the ramp is not where it starts
            ramp_start = next(((t, abs(d)) for t, _, d, a in samples[axis] if t >= killed and a > 0), None)
            assert ramp_start is not None, (axis, "the drive ran no ramp of its own")
            t_top, v_top = ramp_start
            mean = v_top / (rest - t_top)
            # and over any 0.25 s once the motor is back on the ramp: on a loaded host the CSP
            # steps before the kill come unevenly and the motor may run above the demand (3.41
            # against a demand of 3.23 and a limit of 3 was seen); settling onto the ramp from
            # there is the motor's position loop, not the stop
            on_ramp = next((t for t, v, d, _ in samples[axis] if t >= t_top and abs(v) <= abs(d) * 1.02 + 1e-3),
                           t_top)
            worst = _max_deceleration([(t, v) for t, v, _, _ in samples[axis]], on_ramp, 0.25)
            # the ramp the drive ran: 0x6085, capped at the axis's stop deceleration
            ramp = max(abs(a) for t, _, _, a in samples[axis] if t > killed)
            assert mean <= 1.05 * limit and worst <= 1.25 * limit and ramp <= limit * (1 + 1e-6), (
                axis, mean, worst, ramp, limit,
                [(round(t - killed, 3), round(v, 3), round(d, 3))
                 for t, v, d, _ in samples[axis] if t >= killed][::10][:60])

        # a new control process takes the drives over; this client stays connected
        deadline = time.monotonic() + 120
        while _children(server.pid) in ([], [child]):
            assert time.monotonic() < deadline and server.poll() is None, "no new control process"
            time.sleep(0.1)
        wait("fresh readbacks", lambda: num(20, "AZ.REALPOS") is not None, 120)
        wait("fresh readbacks", lambda: num(21, "ZD.REALPOS") is not None, 60)
        for axis in ("AZ", "ZD"):
            assert num(22, f"{axis}.POWER_STATE") == 0.0
            assert int(num(23, f"{axis}.ERROR_STATE")) != 0        # latched until acknowledged
        still = {m: d.logic.axis.x for m, d in drives.items()}
        time.sleep(1.0)
        for m, d in drives.items():                                  # nothing moves
            with d.lock:
                d.logic.update(d.clock())
                assert d.logic.axis.x == still[m] and d.logic.axis.v == 0.0
        assert command(f, s, 24, "SET CABINET.ERROR_STATE=0")[-1] == b"24 COMMAND COMPLETE"
        wait("acknowledged", lambda: num(25, "AZ.ERROR_STATE") == 0.0)
        # commanded again: power, reference (the new control process starts unreferenced;
        # ZD's homing is where it stands), a move
        assert command(f, s, 26, "SET ZD.POWER=1")[-1] == b"26 COMMAND COMPLETE"
        assert command(f, s, 27, "SET ZD.REINIT=1")[-1] == b"27 COMMAND COMPLETE"
        wait("ZD referenced", lambda: num(4, "ZD.REFERENCED") == 1.0)
        real = num(28, "ZD.REALPOS")
        lines = command(f, s, 29, f"SET ZD.TARGETPOS={real + 1.0}")
        assert lines[-2:] == [b"29 DATA OK ZD.TARGETPOS", b"29 COMMAND COMPLETE"], lines
        s.close()
        f.close()
        server.send_signal(signal.SIGTERM)
        assert server.wait(60) == 0
    finally:
        stop_sampling.set()
        _end(server)
        asyncio.run_coroutine_threadsafe(cabinet.stop(), loop).result(60)
        loop.call_soon_threadsafe(loop.stop)
        runner.join(10)
