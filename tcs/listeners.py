"""Every port the service listens on, taken before any hardware is touched.

How it works
------------
:func:`listeners` lists the service's listening ports — the TPL2 (OpenTCI) port and its
TLS-only twin, the OpenTSI port, the Alpaca HTTP port and its UDP discovery port, the status
page's web port, the INDI port — each with its role and the command-line flag and hardware-file key that move
it (:class:`Listener`). :class:`Reservation` binds each of them (the way the front ends will,
``SO_REUSEADDR``; discovery with ``SO_REUSEPORT`` as Alpaca servers share it) and holds them
while the drives boot and the PLCs connect; :meth:`Reservation.release` lets one go just before
its front end binds it for good (``tcs-server`` checks them all once even before it loads the
service: :func:`check_free`). A port that cannot be bound raises :class:`PortInUse`, whose
message names the role, the address and what moves it::

    web port 127.0.0.1:8088 is in use ([Errno 98] Address already in use; another tcs-server
    or another program has it): move it with --web-port or [web] port (-1: not served)

:func:`port_error` turns the OSError of a late bind (a port taken between the check and the
start) into the same message. Only :mod:`tcs.app` uses this module.
"""

from __future__ import annotations

import asyncio
import errno
import os
import socket
from dataclasses import dataclass

from tcs.errors import TcsError


class PortInUse(TcsError):
    """A listening port of the service cannot be bound; the message says which and what moves it."""


@dataclass(frozen=True)
class Listener:
    """One listening port: ``role`` (``"web port"``), where, and what moves it."""

    role: str
    host: str
    port: int
    flag: str          # the tcs-server option ("" when there is none)
    key: str           # the hardware-file key
    udp: bool = False

    @property
    def address(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{host or '*'}:{self.port}"

    @property
    def remedy(self) -> str:
        where = f"{self.flag} or {self.key}" if self.flag else self.key
        return f"move it with {where} (-1: not served)" if self.role != "TPL2 (OpenTCI) port" \
            else f"move it with {where}"


def port_error(listener: Listener, exc: OSError) -> PortInUse:
    """The error to report for ``exc`` raised while binding ``listener``."""
    # (asyncio words its bind errors at length: the system's own text for a system error)
    reason = f"[Errno {exc.errno}] {os.strerror(exc.errno)}" if exc.errno and exc.errno > 0 else str(exc)
    what, hint = "cannot be bound", ""
    if exc.errno == errno.EADDRINUSE:
        what, hint = "is in use", "; another tcs-server or another program has it"
    elif exc.errno == errno.EACCES:
        what = "may not be bound by this user"
    elif exc.errno == errno.EADDRNOTAVAIL:
        what = "is not an address of this machine"
    return PortInUse(f"{listener.role} {listener.address} {what} ({reason}{hint}): {listener.remedy}")


def listeners(service) -> list[Listener]:
    """The listening ports a :class:`tcs.app.Service` will open (those with a port ≥ 0)."""
    return planned(service.config, service.host, service.port, service.opentsi_port,
                   service.alpaca_port, service.web_port, service.alpaca_discovery_port,
                   getattr(service, "indi_port", None))


def planned(config, host: str | None = None, port: int | None = None, opentsi_port: int | None = None,
            alpaca_port: int | None = None, web_port: int | None = None,
            alpaca_discovery_port: int | None = None, indi_port: int | None = None) -> list[Listener]:
    """The listening ports of a service of ``config`` with these overrides (``None``: the
    file's; the options of ``tcs-server``)."""
    def pick(value, default):
        return default if value is None else value

    server_host = host or config.server.host
    out = [Listener("TPL2 (OpenTCI) port", server_host, pick(port, config.server.port),
                    "--port", "[server] port")]
    if config.server.tls_cert and config.server.tls_key and config.server.tls_port:
        out.append(Listener("TPL2 TLS port", server_host, config.server.tls_port, "", "[server] tls_port"))
    if pick(opentsi_port, config.server.opentsi_port) >= 0:
        out.append(Listener("OpenTSI port", server_host, pick(opentsi_port, config.server.opentsi_port),
                            "--opentsi-port", "[server] opentsi_port"))
    if pick(alpaca_port, config.alpaca.port) >= 0:
        out.append(Listener("Alpaca port", config.alpaca.host or server_host,
                            pick(alpaca_port, config.alpaca.port), "--alpaca-port", "[alpaca] port"))
        discovery = pick(alpaca_discovery_port, config.alpaca.discovery_port)
        if discovery >= 0:
            out.append(Listener("Alpaca discovery port (UDP)", "0.0.0.0", discovery,
                                "--alpaca-discovery-port", "[alpaca] discovery_port", udp=True))
    if pick(web_port, config.web.port) >= 0:
        out.append(Listener("web port", config.web.host or "127.0.0.1", pick(web_port, config.web.port),
                            "--web-port", "[web] port"))
    if pick(indi_port, config.indi.port) >= 0:
        out.append(Listener("INDI port", host or config.indi.host, pick(indi_port, config.indi.port),
                            "--indi-port", "[indi] port"))
    return out


def check_free(wanted: list[Listener]) -> None:
    """Bind each port of ``wanted`` once and let it go again (no event loop; what
    ``tcs-server`` does first, before it even loads the service): raises :class:`PortInUse`
    for the first that cannot be bound. The service then takes them for good
    (:class:`Reservation`)."""
    for listener in wanted:
        if listener.port == 0:
            continue
        try:
            if listener.udp:
                _bind_udp(listener.host, listener.port).close()
                continue
            infos = socket.getaddrinfo(listener.host or None, listener.port, type=socket.SOCK_STREAM,
                                       flags=socket.AI_PASSIVE)
            for family, kind, proto, _name, address in {info for info in infos}:
                try:
                    sock = socket.socket(family, kind, proto)
                except OSError:
                    continue  # a family this host lacks (as asyncio's create_server skips it)
                with sock:
                    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                    if family == socket.AF_INET6 and hasattr(socket, "IPPROTO_IPV6"):
                        sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)
                    sock.bind(address)
        except OSError as exc:
            raise port_error(listener, exc) from None


class Reservation:
    """The bound (not yet listening) sockets of some :class:`Listener` s, held until released."""

    def __init__(self) -> None:
        self._held: dict[str, list] = {}

    async def take(self, wanted: list[Listener]) -> None:
        """Bind every port of ``wanted`` (port 0 needs no reservation); raises
        :class:`PortInUse` for the first that cannot be bound, having released the others."""
        loop = asyncio.get_running_loop()
        try:
            for listener in wanted:
                if listener.port == 0:
                    continue
                try:
                    if listener.udp:
                        self._held[listener.role] = [_bind_udp(listener.host, listener.port)]
                    else:  # as the front ends bind (asyncio's create_server: every address of host)
                        server = await loop.create_server(asyncio.Protocol, listener.host or None,
                                                          listener.port, reuse_address=True,
                                                          start_serving=False)
                        self._held[listener.role] = [server]
                except OSError as exc:
                    raise port_error(listener, exc) from None
        except BaseException:
            self.release_all()
            raise

    def release(self, role: str) -> None:
        for held in self._held.pop(role, ()):
            held.close()

    def release_all(self) -> None:
        for role in list(self._held):
            self.release(role)


def _bind_udp(host: str, port: int) -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        if hasattr(socket, "SO_REUSEPORT"):
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
        sock.bind((host, port))
    except OSError:
        sock.close()
        raise
    return sock
