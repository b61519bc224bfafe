"""``tcs-server`` as a process: the default simulated telescope, overrides, a bad hardware
file refused with a clear message, and a clean exit on SIGTERM/SIGINT."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
from pathlib import Path
import sys
import time

import pytest


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start(tmp_path, *args) -> subprocess.Popen:
    env = dict(os.environ, XDG_STATE_HOME=str(tmp_path / "state"), PYTHONUNBUFFERED="1")
    return subprocess.Popen([sys.executable, "-m", "tcs.cli.server", *args], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def connect(port: int, timeout: float = 30.0) -> socket.socket:
    deadline = time.monotonic() + timeout
    while True:
        try:
            return socket.create_connection(("127.0.0.1", port), timeout=10)
        except OSError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.1)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_serves_the_simulated_telescope_and_stops_cleanly(tmp_path, sig):
    port = free_port()
    proc = start(tmp_path, "--port", str(port), "--opentsi-port", "0", "--alpaca-port", "-1", "--web-port", "-1", "--indi-port", "-1")
    try:
        s = connect(port)
        f = s.makefile("rb")
        assert f.readline().startswith(b"TPL2 2.1 CONN ")
        s.sendall(b'AUTH PLAIN "admin" "admin"\n1 GET CONFIG.MOUNT\n')
        assert f.readline() == b"AUTH OK 0 0\n"
        assert [f.readline() for _ in range(3)][1] == b'1 DATA INLINE CONFIG.MOUNT="AZ-ZD"\n'
        proc.send_signal(sig)
        assert proc.wait(30) == 0
        rest = f.read()  # (returns when the server closed the connection)
        # an event of the start-up (GPS time good) may still come before the close
        assert all(line.startswith(b"0 EVENT ") for line in rest.splitlines()), rest
        s.close()
        f.close()
    finally:
        if proc.poll() is None:
            proc.kill()
        out, err = proc.communicate()
    assert "Traceback" not in err
    assert "TPL2 server listening on 127.0.0.1:" in err


def test_a_second_server_on_the_same_state_directory_is_refused(tmp_path):
    """Two simulated telescopes started by one user from sim.toml would share
    ~/.local/state/tcs/sim (state, status list, pointing model, accounts): the second one is
    refused, naming the directory and the holder; once the first ends, the directory is free."""
    port = free_port()
    first = start(tmp_path, "--port", str(port), "--opentsi-port", "-1", "--alpaca-port", "-1", "--web-port", "-1", "--indi-port", "-1")
    try:
        connect(port).close()
        second = start(tmp_path, "--port", str(free_port()), "--opentsi-port", "-1", "--alpaca-port", "-1", "--web-port", "-1", "--indi-port", "-1")
        _, err = second.communicate(timeout=120)
        assert second.returncode == 1, err
        assert "Traceback" not in err
        assert f"the state directory {tmp_path / 'state' / 'tcs' / 'sim'} is in use by another " \
               f"tcs-server (pid {first.pid})" in err, err
        first.send_signal(signal.SIGTERM)
        assert first.wait(60) == 0
        third = start(tmp_path, "--port", str(port), "--opentsi-port", "-1", "--alpaca-port", "-1", "--web-port", "-1", "--indi-port", "-1")
        try:
            connect(port, timeout=120).close()
        finally:
            third.send_signal(signal.SIGTERM)
            assert third.wait(60) == 0
    finally:
        if first.poll() is None:
            first.kill()
        first.communicate()


def test_a_folder_named_tcs_in_the_working_directory_shadows_nothing(tmp_path):
    """tcs-server started where a folder ``tcs/sim`` exists (the state directory's parent, as
    ``XDG_STATE_HOME=$PWD`` makes it, or a clone's parent): its control process found
    ``tcs.sim`` there and could not start the simulated drives."""
    (tmp_path / "tcs" / "sim").mkdir(parents=True)
    port = free_port()
    env = dict(os.environ, XDG_STATE_HOME=str(tmp_path / "state"), PYTHONUNBUFFERED="1")
    proc = subprocess.Popen([str(Path(sys.executable).parent / "tcs-server"), "--port", str(port),
                             "--opentsi-port", "-1", "--alpaca-port", "-1", "--web-port", "-1", "--indi-port", "-1"], cwd=tmp_path, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        s = connect(port, timeout=120)
        f = s.makefile("rb")
        f.readline()
        s.sendall(b'AUTH PLAIN "admin" "admin"\n')
        assert f.readline() == b"AUTH OK 0 0\n"
        deadline = time.monotonic() + 120
        while True:  # the drives (in the control process) boot after the port is open
            s.sendall(b"1 GET AZ.REALPOS\n")
            lines = [f.readline()]
            while not lines[-1].startswith((b"1 COMMAND COMPLETE", b"1 COMMAND FAILED")):
                lines.append(f.readline())
            if any(line.startswith(b"1 DATA INLINE AZ.REALPOS=") for line in lines):
                break
            assert time.monotonic() < deadline and proc.poll() is None, lines
            time.sleep(0.5)
        f.close()
        s.close()
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(60) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
        _, err = proc.communicate()
    assert "Traceback" not in err, err


def test_bad_hardware_file_is_refused_with_a_clear_message(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('[server]\nport = "high"\n[site]\nlatitude = 123\n[nonsense]\n')
    proc = start(tmp_path, "--config", str(bad))
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 2
    assert f"{bad}: server.port: must be an integer" in err
    assert f"{bad}: site.latitude: 123.0 is out of range" in err
    assert f"{bad}: nonsense: unknown key" in err
    assert "Traceback" not in err


def test_port_in_use_is_a_clear_error(tmp_path):
    with socket.socket() as blocker:
        blocker.bind(("127.0.0.1", 0))
        blocker.listen()
        port = blocker.getsockname()[1]
        proc = start(tmp_path, "--port", str(port), "--opentsi-port", "0", "--alpaca-port", "-1", "--web-port", "-1", "--indi-port", "-1")
        out, err = proc.communicate(timeout=60)
    assert proc.returncode == 1
    assert "Traceback" not in err and "address already in use" in err.lower()


STAMP = r"^\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z (DEBUG|INFO|WARNING|ERROR|CRITICAL) "


def test_a_log_started_by_hand_has_timestamps_and_quiet_logins(tmp_path):
    """Issue 25: a server started by hand logged without time stamps, and every login (one per
    tcs-client call) was an INFO line. Now each line starts with the local time, a login is
    DEBUG (not shown at the default INFO) and a failed login stays a WARNING. The time is UTC,
    as in CABINET.STATUS.LOG[]."""
    import re

    port = free_port()
    proc = start(tmp_path, "--port", str(port), "--opentsi-port", "-1", "--alpaca-port", "-1", "--web-port", "-1", "--indi-port", "-1")
    try:
        for password, answer in (("admin", b"AUTH OK 0 0\n"), ("wrong", b"AUTH FAILED\n")):
            s = connect(port)
            f = s.makefile("rb")
            assert f.readline().startswith(b"TPL2 2.1 CONN ")
            s.sendall(f'AUTH PLAIN "admin" "{password}"\n'.encode())
            assert f.readline() == answer
            s.close()
            f.close()
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(30) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
        out, err = proc.communicate()
    lines = [line for line in err.splitlines() if line.strip()]
    assert lines and all(re.match(STAMP, line) for line in lines), err
    assert not any("logged in as admin" in line for line in lines), err
    assert any(re.match(STAMP + r"tcs\.opentci_server\.session: .*failed login as 'admin'", line)
               for line in lines), err


def test_under_journald_lines_leave_the_time_to_the_journal(tmp_path):
    """systemd's journal stamps every line itself: when stderr is the stream $JOURNAL_STREAM
    names (its device:inode), the lines are ``LEVEL name: message``; the variable inherited by
    a process whose stderr goes elsewhere does not count."""
    code = ("import logging; from tcs.cli.server import setup_logging; setup_logging('INFO'); "
            "logging.getLogger('tcs.x').info('hello')")
    log = tmp_path / "stderr.log"
    with open(log, "w") as stream:
        st = os.fstat(stream.fileno())
        env = dict(os.environ, JOURNAL_STREAM=f"{st.st_dev}:{st.st_ino}")
        subprocess.run([sys.executable, "-c", code], env=env, stderr=stream, check=True, timeout=60)
    assert log.read_text() == "INFO tcs.x: hello\n"
    elsewhere = subprocess.run([sys.executable, "-c", code], env=env, stderr=subprocess.PIPE,
                               text=True, check=True, timeout=60)
    assert elsewhere.stderr.endswith(" INFO tcs.x: hello\n") and elsewhere.stderr[:2] == "20"
