"""systemd's notify protocol (``Type=notify``): READY, WATCHDOG, STATUS, STOPPING.

A datagram to the AF_UNIX socket named in ``$NOTIFY_SOCKET`` (a leading ``@`` means the
abstract namespace). Without ``$NOTIFY_SOCKET`` every call does nothing, so the service runs
the same by hand. ``WATCHDOG=1`` is sent by :class:`tcs.app.Service` every half
``$WATCHDOG_USEC`` when the control loop ran at all during that half (never from an
independent timer): a loop that is late on a busy host keeps it fed; a dead one (no cycle for
half the watchdog time) lets systemd restart us.
"""

from __future__ import annotations

import logging
import os
import socket

log = logging.getLogger(__name__)


def serving_status(service, host: str, port: int) -> str:
    """The ``STATUS=`` line of a service that serves: every listener it has, e.g.
    ``STATUS=serving OpenTCI on 127.0.0.1:65432, OpenTSI on 127.0.0.1:65433, ASCOM Alpaca on
    http://127.0.0.1:11111, status page on http://127.0.0.1:8088/`` (``service``: a started :class:`tcs.app.Service`)."""
    parts = [f"OpenTCI on {host}:{port}"]
    if getattr(service, "opentsi_server", None) is not None:
        parts.append(f"OpenTSI on {host}:{service.opentsi_port}")
    alpaca = getattr(service, "alpaca_server", None)
    if alpaca is not None:
        parts.append(f"ASCOM Alpaca on http://{alpaca.host}:{alpaca.port}")
    web = getattr(service, "web_server", None)
    if web is not None:
        parts.append(f"status page on http://{web.host}:{web.port}/")
    return "STATUS=serving " + ", ".join(parts)


class Notifier:
    """Sends notify messages; a no-op when the service is not started by systemd."""

    def __init__(self, address: str | None = None):
        address = os.environ.get("NOTIFY_SOCKET") if address is None else address
        self.address = None
        self.sock = None
        if address:
            self.address = "\0" + address[1:] if address.startswith("@") else address
            self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)

    @property
    def enabled(self) -> bool:
        return self.sock is not None

    @staticmethod
    def watchdog_interval() -> float | None:
        """Half of ``$WATCHDOG_USEC`` in seconds (how often to send WATCHDOG=1), or None."""
        usec = os.environ.get("WATCHDOG_USEC")
        pid = os.environ.get("WATCHDOG_PID")
        if not usec or (pid and pid != str(os.getpid())):
            return None
        try:
            return int(usec) / 2e6
        except ValueError:
            return None

    def send(self, *lines: str) -> None:
        if self.sock is None:
            return
        try:
            self.sock.sendto("\n".join(lines).encode(), self.address)
        except OSError as exc:
            log.warning("cannot notify systemd at %s: %s", self.address, exc)

    def close(self) -> None:
        if self.sock is not None:
            self.sock.close()
            self.sock = None
