"""Issue 41, item 1: every listening port of ``tcs-server`` is taken before any hardware is
touched. With one port busy — the TPL2 port, the OpenTSI port, the Alpaca port, the Alpaca
discovery port (UDP) or the web port — the server ends with status 1 and one line naming the
port's role, its address and the flag or hardware-file key that moves it, having logged
nothing else: no simulated PLC started, no drive booted.

Each server here (the shipped ``sim.toml``, as ``tcs-server`` runs it with no ``--config``)
gets its own free ports, so the test passes beside a running default server."""

from __future__ import annotations

import os
import socket
import subprocess
import sys

import pytest


def _free(kind=socket.SOCK_STREAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1" if kind == socket.SOCK_STREAM else "0.0.0.0", 0))
        return s.getsockname()[1]


ROLES = {  # option → (role, key)
    "--port": ("TPL2 (OpenTCI) port", "[server] port"),
    "--opentsi-port": ("OpenTSI port", "[server] opentsi_port"),
    "--alpaca-port": ("Alpaca port", "[alpaca] port"),
    "--alpaca-discovery-port": ("Alpaca discovery port (UDP)", "[alpaca] discovery_port"),
    "--web-port": ("web port", "[web] port"),
    "--indi-port": ("INDI port", "[indi] port"),
}


@pytest.mark.parametrize("busy", list(ROLES))
def test_a_busy_port_ends_the_start_before_any_hardware_naming_what_moves_it(tmp_path, busy):
    role, key = ROLES[busy]
    udp = busy == "--alpaca-discovery-port"
    blocker = socket.socket(socket.AF_INET, socket.SOCK_DGRAM if udp else socket.SOCK_STREAM)
    with blocker:
        blocker.bind(("0.0.0.0" if udp else "127.0.0.1", 0))
        if not udp:
            blocker.listen()
        port = blocker.getsockname()[1]
        ports = {option: "0" for option in ROLES}
        ports["--alpaca-discovery-port"] = str(_free(socket.SOCK_DGRAM))
        ports[busy] = str(port)
        args = [a for option, value in ports.items() for a in (option, value)]
        env = dict(os.environ, XDG_STATE_HOME=str(tmp_path / "state"))
        proc = subprocess.run([sys.executable, "-m", "tcs.cli.server", *args],
                              env=env, capture_output=True, text=True, timeout=120)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 1, proc.stderr
    assert len(lines) == 1, proc.stderr   # nothing started: no PLC, no GPS, no drive
    line = lines[0]
    address = f"0.0.0.0:{port}" if udp else f"127.0.0.1:{port}"
    assert line.startswith(f"tcs-server: cannot start: {role} {address} is in use"), line
    assert "address already in use" in line.lower(), line
    assert line.endswith(f"move it with {busy} or {key}" + ("" if busy == "--port" else " (-1: not served)")), line


def test_the_suite_runs_as_beside_a_running_default_server(_default_ports_held):
    """Issue 41, item 2: tests/conftest.py holds the default server's TCP ports while the suite
    runs (or a running server does): none of them can be bound by a test's server. (The UDP
    discovery port is shared by design, SO_REUSEPORT: it is checked where the suite holds it.)"""
    from support.default_ports import DEFAULT_TCP_PORTS

    # Each xdist worker is a session of its own: the ports are held by whichever worker took
    # them first, and released when that worker ends — so each worker checks the ports it holds
    # itself (the first worker holds them all; a port no worker of this run could take is held
    # by a running server, which is the case this guards against anyway).
    held_tcp = [s.getsockname()[1] for s in _default_ports_held if s.type == socket.SOCK_STREAM]
    held_udp = [s.getsockname()[1] for s in _default_ports_held if s.type == socket.SOCK_DGRAM]
    assert set(held_tcp) <= set(DEFAULT_TCP_PORTS)
    for kind, ports, host in ((socket.SOCK_STREAM, held_tcp, "127.0.0.1"),
                              (socket.SOCK_DGRAM, held_udp, "0.0.0.0")):
        for port in ports:
            with socket.socket(socket.AF_INET, kind) as s:
                s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                if kind == socket.SOCK_DGRAM:
                    s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
                with pytest.raises(OSError):
                    s.bind((host, port))


async def test_the_service_holds_its_ports_from_before_the_hardware(tmp_path):
    """The same in the service itself (what tcs-server runs after its first check, and what a
    port taken in between meets): Service.start() ends with the web port's error having
    started no simulator, no drive, no TPL2 listener."""
    from support.service import make_config
    from tcs.app import Service
    from tcs.listeners import PortInUse

    with socket.socket() as blocker:
        blocker.bind(("127.0.0.1", 0))
        blocker.listen()
        port = blocker.getsockname()[1]
        service = Service(make_config(tmp_path / "state"), web_port=port)
        with pytest.raises(PortInUse, match=rf"^web port 127\.0\.0\.1:{port} is in use .*: move it with "
                                            r"--web-port or \[web\] port"):
            await service.start()
    assert service.telescope.peripherals.sims is None and service.telescope.can is None
    assert service.telescope.axes == [] and service.server.port == 0
