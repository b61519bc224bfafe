"""python-can's in-process ``virtual`` bus, with frame copies that cost a constructor call.

python-can's ``VirtualBus.send`` deep-copies the message for every other bus on the channel
(``copy.deepcopy`` of a ``Message`` and its ``bytearray``, through ``copyreg``): on the
simulated telescope, where the TCS and its simulated drives share one such channel in the
control process, that was a sixth of the process's CPU at idle (1,400 frames a second).
:class:`VirtualBus` makes each copy with the ``Message`` constructor instead: the same fields,
a data buffer of its own, and python-can's rules for the timestamp (the send time unless
``preserve_timestamps``), the channel and ``is_rx``. It registers its queues in python-can's
own channel table, so a bus of either class on one channel hears the other (tests that open
``can.Bus(interface="virtual")`` to listen still do).

:func:`open_bus` is ``can.Bus(**kwargs)``, except that ``interface="virtual"`` gets this
class. :mod:`tcs.drivers.canbus` (the TCS's bus), :mod:`tcs.sim.can_port` (the simulated
nodes' bus) and :mod:`tcs.sim.socketcand_server` (its bridge's side) open their buses through
it; nothing else needs it. A top-level module, as :mod:`tcs.errors`: drivers and simulator
both use it, neither imports the other.
"""

from __future__ import annotations

import queue
import time
from typing import Any

import can
from can.interfaces import virtual

__all__ = ["VirtualBus", "open_bus"]


class VirtualBus(virtual.VirtualBus):
    """python-can's ``virtual`` bus; :meth:`send` copies frames without ``deepcopy``."""

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._check_if_open()
        timestamp = msg.timestamp if self.preserve_timestamps else time.time()
        own = self.queue
        all_sent = True
        for bus_queue in self.channel:
            if bus_queue is own and not self.receive_own_messages:
                continue
            copy = can.Message(timestamp, msg.arbitration_id, msg.is_extended_id,
                               msg.is_remote_frame, msg.is_error_frame, self.channel_id,
                               msg.dlc, bytearray(msg.data), msg.is_fd, bus_queue is not own,
                               msg.bitrate_switch, msg.error_state_indicator)
            try:
                bus_queue.put(copy, block=True, timeout=timeout)
            except queue.Full:
                all_sent = False
        if not all_sent:
            raise can.CanOperationError("Could not send message to one or more recipients")


def open_bus(**kwargs: Any) -> can.BusABC:
    """A python-can bus from ``can.Bus`` keyword arguments (``virtual``: :class:`VirtualBus`)."""
    if kwargs.get("interface") == "virtual":
        options = {k: v for k, v in kwargs.items() if k != "interface"}
        return VirtualBus(**options)
    return can.Bus(**kwargs)
