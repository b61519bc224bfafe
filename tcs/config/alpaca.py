"""The ``[alpaca]`` section: where the ASCOM Alpaca front end (``tcs/alpaca``) listens.

Alpaca has no authentication: whoever reaches the HTTP port can move the telescope. So the
front end is off unless the hardware file asks for it (``port`` ≥ 0); the simulated telescope
(``hwconfig/sim.toml``) serves it on 11111, the port ASCOM uses by default, on the TPL2
server's address (127.0.0.1 there). ``tcs-server --alpaca-port N`` overrides the port.

``read_only = true`` makes the port a window, not a hand: every Alpaca call that would move or
change something (slews, park/unpark, MoveAxis, focuser/filter/dome moves, switches, actions,
Tracking, sync …) answers InvalidOperation (0x40B) naming the setting; reads, and the
connection flag (Connect only sets it, it powers nothing), still work. The default is
``false``: the front end is already off unless the file gives it a port, and whoever gives it
one does so for an Alpaca client (NINA, a scheduler) to drive the telescope; the safety
envelope and the make-ready policy (docs/homing-and-make-ready.md) bound what such a client can do. An
observatory that serves Alpaca for displays, dashboards or monitoring only sets it true.
"""

from __future__ import annotations

from dataclasses import dataclass

from tcs.config.schema import setting


@dataclass(frozen=True)
class AlpacaSection:
    port: int = setting(-1, min=-1, max=65535, doc="HTTP port of the Alpaca devices (-1 = not served, "
                                                    "0 = any free port; ASCOM's usual port is 11111)")
    host: str = setting("", doc="address the HTTP server binds to (empty = [server] host)")
    discovery_port: int = setting(32227, min=-1, max=65535,
                                  doc="UDP port answering Alpaca discovery (-1 = no discovery)")
    location: str = setting("", doc="Location of /management/v1/description (free text)")
    server_name: str = setting("tcs Alpaca server", doc="ServerName of /management/v1/description")
    read_only: bool = setting(
        False, doc="true: every Alpaca call that moves or changes something answers InvalidOperation "
                   "(0x40B); reads and Connect/Disconnect work (Alpaca has no authentication: for a "
                   "port that serves displays and monitoring only). Default false: the port itself "
                   "is opt-in, and it is opened for clients that drive the telescope")
