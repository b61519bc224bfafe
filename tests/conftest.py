"""Fixtures shared by every test.

``_no_leaks`` (autouse) fails any test that leaves threads or asyncio tasks behind: servers,
buses, notifiers and simulators must be stopped by the test that started them.

The suite runs in pytest-xdist workers (``-n 6 --dist loadfile``, pyproject.toml): a file runs
on one worker, in order, and its module-scoped service starts once. xdist hands the files out
in collection order, so the longest files are collected first (``SLOW_FIRST``; longest-first
scheduling: a long file handed out last would set the suite's wall time on its own). What a test uses is its
own: free ports, ``tmp_path``, a private virtual CAN channel, ``XDG_STATE_HOME`` in ``tmp_path``
for the processes it starts. A kernel CAN bus is shared: see ``tests/vcan/conftest.py``.

``_default_ports_held`` (session, autouse) holds the default server's ports (``tcs-server``
with no arguments: TPL2 65432, OpenTSI 65433, Alpaca 11111 and its UDP discovery 32227, the
web port 8088) while the suite runs, as a running server would: a test that listens on one of
them fails here as it would beside a running server. Where one is already taken (a server
runs) it is left alone. ``TCS_TESTS_HOLD_DEFAULT_PORTS=0`` does not hold them.
"""

from __future__ import annotations

import asyncio
import os
import socket
import threading
import time

import pytest

#: The files that take longest (their tests' total, a run of the whole suite with
#: ``--durations=0``), longest first; the rest follow in their usual order.
SLOW_FIRST = (
    "test_pointing_module.py", "test_alpaca.py", "test_motion_safety.py",
    "test_control_process.py", "test_motion.py", "test_systemd.py", "test_two_processes.py",
    "test_axes.py", "test_envelope_live.py", "test_envelope.py", "test_busy_host.py", "test_commission.py", "test_vendor_drives.py",
    "test_opentsi.py", "test_server.py", "test_drive_recovery.py", "test_wheel.py",
    "test_enclosure.py", "test_cli_server.py", "test_driver_modes.py",
    "test_conformance_server.py", "test_client.py",
)


#: The ports of ``tcs-server`` with no arguments (hwconfig/sim.toml): TCP, and UDP.
from support.default_ports import DEFAULT_TCP_PORTS, DEFAULT_UDP_PORTS  # noqa: E402


@pytest.fixture(scope="session", autouse=True)
def _default_ports_held():
    held: list[socket.socket] = []
    if os.environ.get("TCS_TESTS_HOLD_DEFAULT_PORTS", "1") != "0":
        for kind, ports, host in ((socket.SOCK_STREAM, DEFAULT_TCP_PORTS, "127.0.0.1"),
                                  (socket.SOCK_DGRAM, DEFAULT_UDP_PORTS, "0.0.0.0")):
            for port in ports:
                sock = socket.socket(socket.AF_INET, kind)
                try:
                    sock.bind((host, port))
                    if kind == socket.SOCK_STREAM:
                        sock.listen()
                except OSError:  # taken already (a running server, another worker): fine
                    sock.close()
                    continue
                held.append(sock)
    yield held
    for sock in held:
        sock.close()


def pytest_collection_modifyitems(session, config, items):
    rank = {name: i for i, name in enumerate(SLOW_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))  # (stable: file order kept)


def _extra_threads(before: set[int]) -> list[threading.Thread]:
    # asyncio_N: the default executor of the test's event loop, which the loop's teardown ends
    return [t for t in threading.enumerate()
            if t.ident not in before and t.is_alive() and not t.name.startswith("asyncio_")]


@pytest.fixture(autouse=True)
def _no_leaked_threads():
    before = {t.ident for t in threading.enumerate()}
    yield
    deadline = time.monotonic() + 3.0
    while _extra_threads(before) and time.monotonic() < deadline:
        time.sleep(0.02)
    leaked = _extra_threads(before)
    assert not leaked, f"test leaked threads: {[t.name for t in leaked]}"


@pytest.fixture(autouse=True)
async def _no_leaked_tasks():
    yield
    current = asyncio.current_task()
    for _ in range(50):
        others = [t for t in asyncio.all_tasks() if t is not current and not t.done()]
        if not others:
            break
        await asyncio.sleep(0.02)
    assert not others, f"test leaked asyncio tasks: {others}"
    # threads of asyncio.to_thread belong to the loop: end them before the thread check
    await asyncio.get_running_loop().shutdown_default_executor()


@pytest.fixture
def state_dir(tmp_path, monkeypatch):
    """A fresh persistent-state directory for the service under test."""
    d = tmp_path / "state"
    monkeypatch.setenv("XDG_STATE_HOME", str(d))
    return d


@pytest.fixture
async def service(tmp_path):
    """The default simulated telescope served on a free port; yields (service, port)."""
    from support.service import start_service

    svc, port = await start_service(tmp_path / "state")
    try:
        yield svc, port
    finally:
        await svc.stop()
