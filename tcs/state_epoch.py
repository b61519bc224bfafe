"""A counter that changes whenever state a client can read may have changed.

The TPL2 servers keep a GET's reply for the rest of the event-loop pass that made it, so that
the same status GET from many clients in one pass is read once
(:class:`tcs.opentci_server.reply_cache.ReplyCache`); a kept reply is used only while this
counter still has the value it had when the reply was made. Whatever changes readable state
outside a GET bumps it:

* the control process's readbacks, as the service applies them (:mod:`tcs.axes.control_process`,
  its reader thread, once per batch);
* a PLC's poll result (:mod:`tcs.drivers.modbus`);
* every line a TPL2 server writes that is not a GET's reply — a SET's or ABORT's lines, an
  event, a completion, a login (:meth:`tcs.opentci_server.session.Session.send`): a client
  that was told of a change cannot then read the state from before it;
* every Alpaca PUT (:mod:`tcs.alpaca.server`).

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
