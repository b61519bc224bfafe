"""``tcs-server`` under systemd's notify protocol, with a fake ``NOTIFY_SOCKET``: READY once it
serves, WATCHDOG from the healthy control loop, STATUS lines, STOPPING on SIGTERM."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time

from test_cli_server import connect, free_port


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
    proc = subprocess.Popen([sys.executable, "-m", "tcs.cli.server", "--port", str(port),
                             "--opentsi-port", "0", "--alpaca-port", "0"], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        before_ready = receive_all(sock, "READY=1")
        assert "READY=1" in before_ready, before_ready
        assert before_ready[0].startswith("STATUS=starting")
        assert any(m.startswith("STATUS=serving OpenTCI on 127.0.0.1:") for m in before_ready)
        connect(port).close()  # it serves once READY was sent
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
