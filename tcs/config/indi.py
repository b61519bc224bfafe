"""The ``[indi]`` section: where the INDI devices listen (``tcs/indi``).

INDI has no authentication: the port binds to the loopback address unless ``host`` names
another, and ``read_only = true`` serves the properties without taking any client's writes.
``port = -1`` (the default) serves nothing; 7624 is INDI's own port (that of ``indiserver``:
run the TCS on another one, e.g. 7625, when an ``indiserver`` on the same host chains it with
``indiserver @127.0.0.1:7625``). ``tcs-server --indi-port N`` overrides the port.
"""

from __future__ import annotations

from dataclasses import dataclass

from tcs.config.schema import setting


@dataclass(frozen=True)
class IndiSection:
    port: int = setting(-1, min=-1, max=65535, doc="TCP port of the INDI devices (-1 = not served, "
                                                    "0 = any free port; INDI's own is 7624)")
    host: str = setting("127.0.0.1", doc="address the INDI port binds to (loopback by default: INDI "
                                         "has no authentication)")
    read_only: bool = setting(False, doc="serve the properties but refuse every client's write "
                                         "(answered Alert with the reason)")
    interval: float = setting(0.5, min=0.05, max=10.0,
                              doc="s between two refreshes of the devices pushed to the clients")
