"""Fixtures for tests that put real CANopen frames on a bus.

``can_channel`` gives the python-can keyword arguments of the bus a test should open (every
party of the test opens its own bus instance with them: on ``virtual`` all buses sharing a
channel name see each other's frames, as nodes on one cable do).

Environment (to run the same tests on a kernel bus, e.g. ``vcan0``):

* ``TCS_CAN_INTERFACE`` — python-can interface name, default ``virtual``;
* ``TCS_CAN_CHANNEL`` — channel; default: a fresh ``tcs-test-<uuid>`` per test for ``virtual``
  (tests cannot hear each other), ``vcan0`` otherwise.

The fixture also makes canopen's notifier shut down without waiting, so teardown is fast.
On a kernel bus every test is on the same cable, whoever runs it: the tests of parallel pytest
workers (and of other pytest runs) take turns, one at a time per channel
(``_one_test_at_a_time_on_a_kernel_bus``).
"""

from __future__ import annotations

import fcntl
import os
import tempfile
import uuid
from pathlib import Path

import canopen
import pytest


@pytest.fixture(autouse=True)
def _one_test_at_a_time_on_a_kernel_bus():
    interface = os.environ.get("TCS_CAN_INTERFACE", "virtual")
    if interface == "virtual":  # a private channel per test, in this process only
        yield
        return
    channel = os.environ.get("TCS_CAN_CHANNEL", "vcan0")
    with open(Path(tempfile.gettempdir()) / f"tcs-test-bus-{channel}.lock", "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes, also if the test dies
        yield


@pytest.fixture
def can_channel(monkeypatch) -> dict:
    """python-can ``can.Bus(**kwargs)`` arguments of a bus private to this test."""
    monkeypatch.setattr(canopen.network.Network, "NOTIFIER_SHUTDOWN_TIMEOUT", 0.0)
    monkeypatch.setattr(canopen.network.Network, "NOTIFIER_CYCLE", 0.05)
    interface = os.environ.get("TCS_CAN_INTERFACE", "virtual")
    channel = os.environ.get("TCS_CAN_CHANNEL")
    if channel is None:
        channel = f"tcs-test-{uuid.uuid4().hex[:12]}" if interface == "virtual" else "vcan0"
    return {"interface": interface, "channel": channel}
