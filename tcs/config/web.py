"""The ``[web]`` section: where the read-only status page and the Prometheus metrics listen.

The port (``tcs/web``) serves ``/`` (a live status page), ``/events`` (its server-sent events),
``/status.json`` (the same snapshot for scripts) and ``/metrics`` (Prometheus text format).
Nothing on it can change anything, but it tells whoever reaches it what the telescope does, so
it binds to the loopback address unless the file names another (``host``); ``port = -1``
serves nothing (the default of a hardware file that has no ``[web]``). The simulated telescope
(``hwconfig/sim.toml``) serves it on 8088. ``tcs-server --web-port N`` overrides the port.
"""

from __future__ import annotations

from dataclasses import dataclass

from tcs.config.schema import setting


@dataclass(frozen=True)
class WebSection:
    port: int = setting(-1, min=-1, max=65535, doc="HTTP port of the status page and /metrics "
                                                    "(-1 = not served, 0 = any free port)")
    host: str = setting("127.0.0.1", doc="address the HTTP server binds to (loopback by default: "
                                         "the page is read-only but tells what the telescope does)")
    interval: float = setting(0.25, min=0.05, max=10.0,
                              doc="s between two snapshots pushed to the open status pages (≥ 2 Hz by default)")
