"""The ``[alpaca]`` section: where the ASCOM Alpaca front end (``tcs/alpaca``) listens.

Alpaca has no authentication: whoever reaches the HTTP port can move the telescope. So the
front end is off unless the hardware file asks for it (``port`` ≥ 0); the simulated telescope
(``hwconfig/sim.toml``) serves it on 11111, the port ASCOM uses by default, on the TPL2
server's address (127.0.0.1 there). ``tcs-server --alpaca-port N`` overrides the port.
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
