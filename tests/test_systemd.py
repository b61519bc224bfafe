"""``tcs-server`` under systemd's notify protocol, with a fake ``NOTIFY_SOCKET``: READY once it
serves, WATCHDOG from the healthy control loop, STATUS lines, STOPPING on SIGTERM. The shipped
units pass ``systemd-analyze verify`` and the hardened service scores ≤ 3.0 in ``systemd-analyze
security`` (skipped where systemd-analyze is missing), and ``tools/systemd/install.sh`` run twice
(into a ``DESTDIR``) upgrades in place without touching the hardware file."""

from __future__ import annotations

import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest

from support.venvs import make_venv
from test_cli_server import connect, free_port

REPO = Path(__file__).resolve().parent.parent
SYSTEMD = REPO / "tools" / "systemd"


def receive_all(sock: socket.socket, until: str, timeout: float = 60.0) -> list[str]:
    messages = []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        sock.settimeout(max(0.05, deadline - time.monotonic()))
        try:
            data = sock.recv(4096).decode()
        except socket.timeout:
            break
        messages.extend(data.split("\n"))
        if any(m.startswith(until) for m in messages):
            break
    return messages


def test_notify_sequence_and_watchdog(tmp_path):
    path = str(tmp_path / "notify.sock")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(path)
    port = free_port()
    env = dict(os.environ, NOTIFY_SOCKET=path, WATCHDOG_USEC="200000",
               XDG_STATE_HOME=str(tmp_path / "state"))
    env.pop("WATCHDOG_PID", None)
    # the bundled telescope with every front end, Alpaca without its discovery socket (0.0.0.0)
    config = tmp_path / "sim.toml"
    config.write_text(re.sub(r"(?m)^discovery_port = \d+", "discovery_port = -1",
                             (REPO / "hwconfig" / "sim.toml").read_text()))
    proc = subprocess.Popen([sys.executable, "-m", "tcs.cli.server", "--config", str(config),
                             "--port", str(port), "--opentsi-port", "0", "--alpaca-port", "0", "--web-port", "0", "--indi-port", "0"], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        before_ready = receive_all(sock, "READY=1")
        assert "READY=1" in before_ready, before_ready
        assert before_ready[0].startswith("STATUS=starting")
        # the STATUS line names every port served, and they are the ones that answer
        serving = [m for m in before_ready if m.startswith("STATUS=serving ")]
        assert serving, before_ready
        m = re.fullmatch(rf"STATUS=serving OpenTCI on 127\.0\.0\.1:{port}, OpenTSI on 127\.0\.0\.1:(\d+), "
                         rf"ASCOM Alpaca on http://127\.0\.0\.1:(\d+), "
                         rf"status page on http://127\.0\.0\.1:(\d+)/", serving[0])
        assert m, serving
        connect(port).close()  # it serves once READY was sent
        with connect(int(m[1])) as tsi:
            assert tsi.recv(200).startswith(b"TPL2 ")
        with urllib.request.urlopen(f"http://127.0.0.1:{m[2]}/management/apiversions", timeout=10) as r:
            assert b'"Value": [1]' in r.read()
        with urllib.request.urlopen(f"http://127.0.0.1:{m[3]}/metrics", timeout=10) as r:
            assert b"tcs_build_info" in r.read()
        assert "WATCHDOG=1" in receive_all(sock, "WATCHDOG=1", timeout=30)
        proc.send_signal(signal.SIGTERM)
        after = receive_all(sock, "STOPPING=1", timeout=30)
        assert "STOPPING=1" in after
        assert proc.wait(60) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.communicate()
        sock.close()


def unit_copy(tmp_path, name: str) -> Path:
    """The shipped unit with an ExecStart that exists here (verify checks the binary)."""
    text = (SYSTEMD / name).read_text().replace("/opt/tcs/venv/bin/tcs-server", "/bin/true")
    path = tmp_path / name
    path.write_text(text)
    return path


def test_unit_settings():
    text = (SYSTEMD / "tcs-server.service").read_text()
    settings = [line for line in text.splitlines() if line and not line.startswith("#")]
    assert "RestartPreventExitStatus=2" in settings      # a bad hardware file: no restart loop
    assert not any(s.startswith(("ReadWritePaths=", "LimitMEMLOCK=", "RestrictRealtime="))
                   for s in settings)
    families = next(s for s in settings if s.startswith("RestrictAddressFamilies="))
    assert {"AF_CAN", "AF_INET", "AF_INET6", "AF_UNIX"} <= set(families.split("=")[1].split())
    assert "LimitRTPRIO=50" in settings and "SupplementaryGroups=dialout" in settings
    assert "DeviceAllow=char-ttyUSB rw" in settings
    # a dead server's orphaned control process must have time to stop the axes: "mixed" SIGKILLs
    # it the moment the main process dies (tools/ci/vm/checks/systemd.sh, kill -9 during a slew)
    assert "KillMode=control-group" in settings and "TimeoutStopSec=60" in settings


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze not installed")
def test_units_verify_and_the_service_is_hardened(tmp_path):
    server = unit_copy(tmp_path, "tcs-server.service")
    unit_copy(tmp_path, "tcs-can@.service")
    for unit in (str(server), "tcs-can@can0.service"):
        verify = subprocess.run(["systemd-analyze", "verify", unit], cwd=tmp_path,
                                capture_output=True, text=True, timeout=60)
        assert verify.returncode == 0, verify.stdout + verify.stderr
        assert "tcs" not in verify.stderr, verify.stderr  # no warning about our units
    security = subprocess.run(["systemd-analyze", "security", "--offline=true", "--no-pager",
                               str(server)], capture_output=True, text=True, timeout=60)
    m = re.search(r"Overall exposure level for tcs-server.service: ([0-9.]+)", security.stdout)
    assert m, security.stdout + security.stderr
    assert float(m.group(1)) <= 3.0, security.stdout


@pytest.mark.timeout(900)  # four installs, two package builds: minutes on a loaded machine
def test_install_is_idempotent_and_keeps_the_hardware_file(tmp_path):
    root = tmp_path / "root"
    env = dict(os.environ, DESTDIR=str(root))
    env.pop("VIRTUAL_ENV", None)
    # the dependencies come from this test run's environment (nothing is downloaded); tcs itself
    # is built and installed by install.sh
    make_venv(root / "opt" / "tcs" / "venv")
    install = [str(SYSTEMD / "install.sh")]
    first = subprocess.run(install, env=env, capture_output=True, text=True, timeout=600)
    assert first.returncode == 0, first.stdout + first.stderr
    hwfile = root / "etc" / "tcs" / "tcs.toml"
    assert "installed tcs 0.1.0" in first.stdout and f"installed {hwfile}" in first.stdout
    # the real-cabinet template, not sim.toml and its public admin: no user, refused until tcs-passwd
    text = hwfile.read_text()
    assert "[[users]]\n" not in text and "admin" not in text
    assert oct(hwfile.stat().st_mode & 0o777) == "0o640"
    assert "users: no [[users]]" in first.stderr and "tcs-passwd" in first.stdout
    units = root / "etc" / "systemd" / "system"
    assert (units / "tcs-server.service").is_file() and (units / "tcs-can@.service").is_file()
    # the DESTDIR venv names /opt/tcs, where it is meant to be copied, not the DESTDIR
    script = (root / "opt" / "tcs" / "venv" / "bin" / "tcs-server").read_text()
    assert script.startswith("#!/opt/tcs/venv/bin/python"), script[:80]
    assert str(root) not in (root / "opt" / "tcs" / "venv" / "bin" / "activate").read_text()
    assert "After=tcs-can@can0.service" in (units / "tcs-server.service.d" / "can.conf").read_text()
    assert "BITRATE=1000000" in (root / "etc" / "tcs" / "can-can0.env").read_text()
    # an older install had put sim.toml (public admin/admin) here: the upgrade says so loudly
    hwfile.write_text((SYSTEMD.parent.parent / "hwconfig" / "sim.toml").read_text())
    # the later runs are offline, from a wheelhouse (here: tcs alone, the venv has the rest)
    wheelhouse = tmp_path / "wheelhouse"
    subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(wheelhouse), str(REPO)],
                   check=True, capture_output=True, timeout=600)
    install += ["--wheelhouse", str(wheelhouse)]
    warned = subprocess.run(install, env=env, capture_output=True, text=True, timeout=600)
    assert "WARNING: user 'admin'" in warned.stdout and "PUBLIC password hash" in warned.stdout
    # the operator edits the file; an older install had copied hwconfig/ into the prefix
    hwfile.write_text(text + "\n# edited by the operator\n")
    (root / "opt" / "tcs" / "hwconfig" / "hwconfig").mkdir(parents=True)
    second = subprocess.run(install, env=env, capture_output=True, text=True, timeout=600)
    assert second.returncode == 0, second.stdout + second.stderr
    assert f"kept {hwfile}" in second.stdout
    assert hwfile.read_text().endswith("# edited by the operator\n")
    assert "removed" in second.stdout and not (root / "opt" / "tcs" / "hwconfig").exists()
    assert f"unchanged {units / 'tcs-server.service'}" in second.stdout
    third = subprocess.run(install, env=env, capture_output=True, text=True, timeout=600)
    assert "nothing changed" in third.stdout, third.stdout
    assert "systemctl stop tcs-server" in third.stdout


def test_watchdog_fed_while_the_loop_is_late_withheld_when_it_is_dead(tmp_path):
    """A control loop that runs late (its process held for 0.5 s at a time, as on a busy
    host) keeps the watchdog fed within every WATCHDOG_USEC; one that does not run at all is
    not fed (systemd then restarts the service)."""
    from test_control_process import _children

    path = str(tmp_path / "notify.sock")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(path)
    port = free_port()
    usec = 2.0
    env = dict(os.environ, NOTIFY_SOCKET=path, WATCHDOG_USEC=str(int(usec * 1e6)),
               XDG_STATE_HOME=str(tmp_path / "state"))
    env.pop("WATCHDOG_PID", None)
    proc = subprocess.Popen([sys.executable, "-m", "tcs.cli.server", "--port", str(port),
                             "--opentsi-port", "-1", "--alpaca-port", "-1", "--web-port", "-1", "--indi-port", "-1"], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    child = None
    try:
        assert "READY=1" in receive_all(sock, "READY=1")
        (child,) = _children(proc.pid)

        def pings(seconds: float, hold: float | None) -> list[float]:
            """WATCHDOG=1 arrival times over ``seconds``, the child held ``hold`` s of every
            ``hold + 0.1`` s (None: held all the time)."""
            times = []
            end = time.monotonic() + seconds
            sock.settimeout(0.02)
            running = True
            switch = time.monotonic()
            while time.monotonic() < end:
                now = time.monotonic()
                if hold is None and running:
                    os.kill(child, signal.SIGSTOP)
                    running = False
                elif hold is not None and now >= switch:
                    os.kill(child, signal.SIGSTOP if running else signal.SIGCONT)
                    running = not running
                    switch = now + (hold if not running else 0.1)
                try:
                    data = sock.recv(4096).decode()
                except socket.timeout:
                    continue
                times += [time.monotonic() for m in data.split("\n") if m == "WATCHDOG=1"]
            if hold is not None and not running:
                os.kill(child, signal.SIGCONT)
            return times

        receive_all(sock, "WATCHDOG=1", timeout=30)
        late = pings(8.0, hold=0.5)
        gaps = [b - a for a, b in zip(late, late[1:])]
        assert len(late) >= 4 and max(gaps) < usec, late   # a late loop is alive
        pings(1.5, hold=None)                                 # (the last ping may be on its way)
        dead = pings(3.0, hold=None)
        assert dead == [], dead                               # a dead loop is not fed
    finally:
        if child is not None:
            try:
                os.kill(child, signal.SIGCONT)
            except OSError:
                pass
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(60)
            except subprocess.TimeoutExpired:
                proc.kill()
        proc.communicate()
        sock.close()
