"""The simulator's CAN port survives a receive error (a kernel interface taken down and up:
"Network is down"): its nodes keep hearing the bus, as real drives do, instead of going deaf
and reporting the master's heartbeat lost."""

from __future__ import annotations

import threading
import time
import uuid

import can
from can.interfaces.virtual import VirtualBus

from tcs.sim.can_port import open_port


class FlakyBus(VirtualBus):
    """python-can's virtual bus whose receive fails ``fail`` times (like ENETDOWN)."""

    fail = 0

    def _recv_internal(self, timeout):
        if self.fail:
            self.fail -= 1
            raise can.CanOperationError("Error receiving: Network is down [Error Code 100]")
        return super()._recv_internal(timeout)


def test_receive_error_does_not_deafen_the_port():
    channel = f"tcs-test-{uuid.uuid4().hex[:12]}"
    bus = FlakyBus(channel=channel)
    other = can.Bus(interface="virtual", channel=channel)
    port = open_port(bus)
    heard = threading.Event()
    try:
        port.subscribe(0x77F, lambda cob, data: heard.set())
        bus.fail = 1
        deadline = time.monotonic() + 30
        while bus.fail and time.monotonic() < deadline:
            time.sleep(0.01)  # the receive thread met the error
        assert bus.fail == 0
        deadline = time.monotonic() + 30
        while not heard.is_set() and time.monotonic() < deadline:
            other.send(can.Message(arbitration_id=0x77F, data=[5], is_extended_id=False))
            heard.wait(0.1)
        assert heard.is_set(), "the port stopped receiving after one receive error"
    finally:
        port.release()
        other.shutdown()
        bus.shutdown()
