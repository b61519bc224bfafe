"""Fixtures for tests that put real CANopen frames on a bus.

``can_channel`` gives the python-can keyword arguments of the bus a test should open (every
party of the test opens its own bus instance with them: on ``virtual`` all buses sharing a
channel name see each other's frames, as nodes on one cable do).

Environment (to run the same tests on a kernel bus, e.g. ``vcan0``):

* ``TCS_CAN_INTERFACE`` — python-can interface name, default ``virtual``;
* ``TCS_CAN_CHANNEL`` — channel; default: a fresh ``tcs-test-<uuid>`` per test for ``virtual``
  (tests cannot hear each other), ``vcan0`` otherwise.

On a kernel bus every pytest-xdist worker gets a cable of its own: worker ``gwN`` uses the
channel's number plus N (``vcan0`` → ``vcan0``, ``vcan1``, ``vcan2`` with ``-n 3``; create them
with ``tools/ci/vcan-up.sh vcan0 vcan1 vcan2``), so the SDO, NMT and PDO traffic of one worker's
drives never reaches another's (a missing interface fails the test, naming the command). On its
channel a test still takes a lock (``_one_test_at_a_time_on_a_kernel_bus``), so other pytest runs
on the same machine take turns with it.

The fixture also makes canopen's notifier shut down without waiting, so teardown is fast.
"""

from __future__ import annotations

import fcntl
import os
import re
import tempfile
import uuid
from pathlib import Path

import canopen
import pytest


def _nth_channel(n: int) -> str:
    """``TCS_CAN_CHANNEL`` (default ``vcan0``) with its number raised by ``n``."""
    match = re.fullmatch(r"(.*?)(\d*)", os.environ.get("TCS_CAN_CHANNEL", "vcan0"))
    return f"{match[1]}{int(match[2] or 0) + n}"


def kernel_channel() -> str:
    """This worker's kernel channel: ``gwN`` gets the N-th after ``TCS_CAN_CHANNEL``."""
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")
    return _nth_channel(int(worker[2:]) if worker.startswith("gw") else 0)


@pytest.fixture(autouse=True)
def _one_test_at_a_time_on_a_kernel_bus():
    interface = os.environ.get("TCS_CAN_INTERFACE", "virtual")
    if interface == "virtual":  # a private channel per test, in this process only
        yield
        return
    channel = kernel_channel()
    if interface == "socketcan" and not Path(f"/sys/class/net/{channel}").exists():
        workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
        names = " ".join(_nth_channel(n) for n in range(workers))
        pytest.fail(f"no CAN interface {channel} for this pytest worker (one per worker): "
                    f"tools/ci/vcan-up.sh {names}", pytrace=False)
    with open(Path(tempfile.gettempdir()) / f"tcs-test-bus-{channel}.lock", "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes, also if the test dies
        yield


@pytest.fixture
def can_channel(monkeypatch) -> dict:
    """python-can ``can.Bus(**kwargs)`` arguments of a bus private to this test."""
    # (the join returns once the reader ends, one NOTIFIER_CYCLE; not waiting at all closed the
    # socket under a reader still in recv: EBADF warnings in a slow guest's tests/vcan)
    monkeypatch.setattr(canopen.network.Network, "NOTIFIER_SHUTDOWN_TIMEOUT", 2.0)
    monkeypatch.setattr(canopen.network.Network, "NOTIFIER_CYCLE", 0.05)
    interface = os.environ.get("TCS_CAN_INTERFACE", "virtual")
    if interface == "virtual":
        channel = os.environ.get("TCS_CAN_CHANNEL") or f"tcs-test-{uuid.uuid4().hex[:12]}"
    else:
        channel = kernel_channel()
    return {"interface": interface, "channel": channel}
