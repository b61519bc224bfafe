"""Issue 41, item 1: every listening port of ``tcs-server`` is taken before any hardware is
touched. With one port busy — the TPL2 port, the OpenTSI port, the Alpaca port, the Alpaca
discovery port (UDP) or the web port — the server ends with status 1 and one line naming the
port's role, its address and the flag or hardware-file key that moves it, having logged
nothing else: no simulated PLC started, no drive booted.

Each server here gets its own free ports (the shipped ``sim.toml`` with its discovery port
moved to a free one), so the test passes beside a running default server."""

from __future__ import annotations

import os
import socket
import subprocess
import sys

import pytest
import tomlkit

from tcs.resources import hwconfig_file


def _free(kind=socket.SOCK_STREAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1" if kind == socket.SOCK_STREAM else "0.0.0.0", 0))
        return s.getsockname()[1]


ROLES = {  # option (None: only the file moves it) → (role, flag, key)
    "--port": ("TPL2 (OpenTCI) port", "--port", "[server] port"),
    "--opentsi-port": ("OpenTSI port", "--opentsi-port", "[server] opentsi_port"),
    "--alpaca-port": ("Alpaca port", "--alpaca-port", "[alpaca] port"),
    "discovery": ("Alpaca discovery port (UDP)", None, "[alpaca] discovery_port"),
    "--web-port": ("web port", "--web-port", "[web] port"),
}


@pytest.mark.parametrize("busy", list(ROLES))
def test_a_busy_port_ends_the_start_before_any_hardware_naming_what_moves_it(tmp_path, busy):
    role, flag, key = ROLES[busy]
    doc = tomlkit.parse(hwconfig_file("sim.toml").read_text())
    udp = busy == "discovery"
    blocker = socket.socket(socket.AF_INET, socket.SOCK_DGRAM if udp else socket.SOCK_STREAM)
    with blocker:
        blocker.bind(("0.0.0.0" if udp else "127.0.0.1", 0))
        if not udp:
            blocker.listen()
        port = blocker.getsockname()[1]
        doc["alpaca"]["discovery_port"] = port if udp else _free(socket.SOCK_DGRAM)
        hwfile = tmp_path / "sim.toml"
        hwfile.write_text(tomlkit.dumps(doc))
        (tmp_path / "eds").symlink_to(hwconfig_file("eds"))
        ports = {option: "0" for option in ROLES if option.startswith("--")}
        if not udp:
            ports[busy] = str(port)
        args = [a for option, value in ports.items() for a in (option, value)]
        env = dict(os.environ, XDG_STATE_HOME=str(tmp_path / "state"))
        proc = subprocess.run([sys.executable, "-m", "tcs.cli.server", "--config", str(hwfile), *args],
                              env=env, capture_output=True, text=True, timeout=120)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 1, proc.stderr
    assert len(lines) == 1, proc.stderr   # nothing started: no PLC, no GPS, no drive
    line = lines[0]
    address = f"0.0.0.0:{port}" if udp else f"127.0.0.1:{port}"
    assert line.startswith(f"tcs-server: cannot start: {role} {address} is in use"), line
    assert "address already in use" in line.lower(), line
    assert line.endswith(f"move it with {flag} or {key} (-1: not served)" if flag and busy != "--port"
                         else f"move it with {flag} or {key}" if flag else f"move it with {key} (-1: not served)"), line
