"""A counter that changes whenever state a client can read may have changed.

The TPL2 servers reuse a GET's reply, and the Alpaca devices a state read's value, for the
same request within ``[server] reuse_reply`` (:mod:`tcs.opentci_server.reply_cache`,
:meth:`tcs.alpaca.device.Device.begin`) — only while this counter still has the value it had
before the values were read. Whatever changes readable state outside a read bumps it:

* the control loop's readbacks: in the service as it applies the control process's batches
  (:mod:`tcs.axes.control_process`, its reader thread), or each cycle of a loop running as a
  thread of the service (:mod:`tcs.axes.control_loop`); a lost control process;
* a PLC's poll result and its connection changes (:mod:`tcs.drivers.modbus`); GPS input
  (:mod:`tcs.drivers.gps`);
* every line a TPL2 server writes that is not a GET's reply — a SET's or ABORT's lines, an
  event, a completion, a login (:meth:`tcs.opentci_server.session.Session.send`): a client
  that was told of a change cannot then read the state from before it;
* every Alpaca PUT once it has run (:mod:`tcs.alpaca.server`).

Any thread may bump it; a lost increment between two threads still changes the value.
"""

from __future__ import annotations


class _Epoch:
    value = 0


def bump() -> None:
    """Readable state may have changed: replies kept before now are not used again."""
    _Epoch.value += 1


def current() -> int:
    """The counter's value now."""
    return _Epoch.value


EPOCH = _Epoch  # (``EPOCH.value`` without a call, on the servers' hot path)

__all__ = ["bump", "current", "EPOCH"]
