"""The Alpaca HTTP server (aiohttp) and its UDP discovery responder.

How it works
------------
:class:`AlpacaServer` is a thin adapter: it turns each HTTP request into an
:class:`~tcs.alpaca.protocol.AlpacaRequest`, asks the device (:mod:`tcs.alpaca.device`) for
the value, and writes the reply — JSON with the transaction ids for a device answer or a device
error, plain text with HTTP 400 for a malformed request. Routes:

* ``/management/apiversions``, ``/management/v1/description``,
  ``/management/v1/configureddevices`` (GET);
* ``/api/v1/{device_type}/{device_number}/{member}`` (GET and PUT);
* ``/setup`` and ``/setup/v1/{device_type}/{device_number}/setup``: small HTML pages with
  each device's live state (no framework: the page is written here).

Any exception a handler lets through becomes an ASCOM driver error (0x500) in an HTTP 200 —
never a 500 — and every request is bounded by a time-out (``request_timeout``), so a client
never hangs. All of it runs on the service's event loop; the control loop runs in its own
thread and is not disturbed by HTTP load (``tools/bench/alpaca_load.py`` measures it).

Discovery (:class:`DiscoveryProtocol`): a UDP socket on ``discovery_port`` (0.0.0.0, to hear
broadcasts; ``SO_REUSEPORT`` so that several Alpaca servers on one host can all answer)
answers ``alpacadiscovery1`` with ``{"AlpacaPort": N}``. When the HTTP server listens on a
loopback address only, only loopback senders get an answer.
"""

from __future__ import annotations

import asyncio
import html
import ipaddress
import json
import logging
import socket
from time import perf_counter
from typing import Any

from aiohttp import web

from tcs import __version__ as TCS_VERSION
from tcs.alpaca.device import Device
from tcs.alpaca.protocol import AlpacaRequest, AscomError, BadRequest, Code, TransactionCounter, reply
from tcs.model.command_stats import CommandStats
from tcs.state_epoch import bump as bump_epoch

log = logging.getLogger(__name__)

DISCOVERY_QUERY = b"alpacadiscovery1"
MAX_BODY = 64 * 1024


def encode_reply(body: dict[str, Any]) -> str:
    """``json.dumps(body)`` of a device reply: the same text, written directly for the common
    case — a value, no error (a third of the JSON cost per status poll)."""
    if len(body) == 5 and body.get("ErrorMessage", 0) == "" and "Value" in body:
        v = body["Value"]
        t = type(v)
        if t is float and v - v == 0.0:  # finite: its repr is its JSON
            text = repr(v)
        elif t is bool:
            text = "true" if v else "false"
        else:
            text = json.dumps(v)
        c, s, n = body["ClientTransactionID"], body["ServerTransactionID"], body["ErrorNumber"]
        if type(c) is int and type(s) is int and type(n) is int:
            return (f'{{"Value": {text}, "ClientTransactionID": {c}, "ServerTransactionID": {s}, '
                    f'"ErrorNumber": {n}, "ErrorMessage": ""}}')
    return json.dumps(body)


class AlpacaServer:
    """The HTTP listener and discovery responder for a list of devices."""

    def __init__(self, devices: list[Device], *, manufacturer: str = "tcs project",
                 server_name: str = "tcs Alpaca server", location: str = "",
                 request_timeout: float = 30.0):
        self.devices = devices
        self._by_key = {(d.TYPE, d.number): d for d in devices}
        self.manufacturer = manufacturer
        self.server_name = server_name
        self.location = location
        self.request_timeout = request_timeout
        self.next_id = TransactionCounter()
        self.port = 0
        self.discovery_port = -1
        self.host = "127.0.0.1"
        #: the requests answered, by HTTP method and result, and their latency (``/metrics``)
        self.command_stats = CommandStats()
        self._runner: web.AppRunner | None = None
        self._discovery: asyncio.DatagramTransport | None = None

    # -- life cycle --------------------------------------------------------------------------------
    def app(self) -> web.Application:
        app = web.Application(client_max_size=MAX_BODY)
        app.router.add_get("/management/apiversions", self._apiversions)
        app.router.add_get("/management/v1/description", self._description)
        app.router.add_get("/management/v1/configureddevices", self._configured)
        app.router.add_route("*", "/api/v1/{type}/{number}/{member}", self._device)
        app.router.add_get("/setup", self._setup_index)
        app.router.add_get("/setup/v1/{type}/{number}/setup", self._setup_device)
        return app

    async def start(self, host: str, port: int, discovery_port: int = -1) -> int:
        """Listen on ``host``:``port`` (0: a free port) and, when ``discovery_port`` ≥ 0, answer
        discovery there; returns the HTTP port."""
        self.host = host
        self._runner = web.AppRunner(self.app(), access_log=None, handle_signals=False)
        await self._runner.setup()
        site = web.TCPSite(self._runner, host, port, reuse_address=True)
        try:
            await site.start()
            addresses = self._runner.addresses
            self.port = addresses[0][1] if addresses else port
            if discovery_port >= 0:
                await self._start_discovery(discovery_port)
        except BaseException:
            await self.stop()
            raise
        log.info("Alpaca devices on http://%s:%d (discovery: %s)", host, self.port,
                 self.discovery_port if self.discovery_port >= 0 else "off")
        return self.port

    async def _start_discovery(self, port: int) -> None:
        loop = asyncio.get_running_loop()
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            if hasattr(socket, "SO_REUSEPORT"):
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
            sock.bind(("0.0.0.0", port))
        except OSError:
            sock.close()
            raise
        transport, _ = await loop.create_datagram_endpoint(
            lambda: DiscoveryProtocol(lambda: self.port, loopback_only=_is_loopback(self.host)), sock=sock)
        self._discovery = transport
        self.discovery_port = sock.getsockname()[1]

    async def stop(self) -> None:
        if self._discovery is not None:
            self._discovery.close()
            self._discovery = None
        if self._runner is not None:
            await self._runner.cleanup()
            self._runner = None

    # -- replies ---------------------------------------------------------------------------------
    def _json(self, body: dict[str, Any]) -> web.Response:
        return web.Response(text=encode_reply(body), content_type="application/json")

    @staticmethod
    def _bad(message: str) -> web.Response:
        return web.Response(status=400, text=message, content_type="text/plain")

    async def _management(self, request: web.Request, value: Any) -> web.Response:
        req = AlpacaRequest("GET", dict(request.query))
        return self._json(reply(req, self.next_id(), value))

    async def _apiversions(self, request: web.Request) -> web.Response:
        return await self._management(request, [1])

    async def _description(self, request: web.Request) -> web.Response:
        return await self._management(request, {
            "ServerName": self.server_name, "Manufacturer": self.manufacturer,
            "ManufacturerVersion": str(TCS_VERSION), "Location": self.location})

    async def _configured(self, request: web.Request) -> web.Response:
        return await self._management(request, [d.configured() for d in self.devices])

    def _find(self, request: web.Request) -> Device:
        kind = request.match_info["type"]
        number = request.match_info["number"]
        if not (number.isascii() and number.isdigit()) or len(number) > 9:
            raise BadRequest(f"device number {number!r} is not a non-negative integer")
        device = self._by_key.get((kind, int(number)))
        if device is None:
            raise BadRequest(f"no {kind} device number {number}")
        return device

    @property
    def connections(self) -> int:
        """The HTTP connections open now."""
        server = self._runner.server if self._runner is not None else None
        return len(server.connections) if server is not None else 0

    async def _device(self, request: web.Request) -> web.Response:
        started = perf_counter()
        method = request.method
        if method not in ("GET", "PUT"):
            self.command_stats.record("OTHER", "bad_request")
            return self._bad(f"method {method} is not allowed (GET or PUT)")
        response, result = await self._answer(request, method)
        self.command_stats.record(method, result, perf_counter() - started)
        return response

    async def _answer(self, request: web.Request, method: str) -> tuple[web.Response, str]:
        """The reply to a device request and its result for the metrics (ok, error, bad_request)."""
        result = "ok"
        try:
            device = self._find(request)
            if method == "GET":
                params = dict(request.query)
            else:
                if request.content_type not in ("application/x-www-form-urlencoded", "multipart/form-data",
                                                "application/octet-stream", ""):
                    raise BadRequest(f"PUT needs a form body (application/x-www-form-urlencoded), "
                                     f"not {request.content_type}")
                try:
                    form = await request.post()
                except (ValueError, UnicodeDecodeError) as exc:
                    raise BadRequest(f"the form body cannot be read: {exc}") from None
                params = {k: v for k, v in form.items() if isinstance(v, str)}
            req = AlpacaRequest(method, params)
            member = request.match_info["member"]
            if member != member.lower():
                raise BadRequest(f"member names are lower case in the URL: {member!r}")
            try:
                try:
                    done, value = device.begin(method, member, req)
                    if not done:  # only what needs awaiting gets a task and the time-out
                        value = await asyncio.wait_for(device.finish(value), self.request_timeout)
                finally:
                    if method != "GET":  # what it changed: no value read before is reused
                        bump_epoch()
                body = reply(req, self.next_id(), value, has_value=(method == "GET" or value is not None))
            except AscomError as exc:
                result = "error"
                body = reply(req, self.next_id(), error=exc)
            except asyncio.TimeoutError:
                result = "error"
                body = reply(req, self.next_id(), error=AscomError(
                    Code.DRIVER_ERROR, f"{member} did not finish within {self.request_timeout:g} s"))
        except BadRequest as exc:
            return self._bad(str(exc)), "bad_request"
        except web.HTTPException:
            raise
        except Exception as exc:  # never a 500: a driver error the client can read
            log.exception("Alpaca %s %s failed", method, request.path)
            result = "error"
            req = AlpacaRequest(method, dict(request.query))
            body = reply(req, self.next_id(), error=AscomError(Code.DRIVER_ERROR, f"internal error: {exc}"))
        return self._json(body), result

    # -- setup pages -----------------------------------------------------------------------------
    async def _setup_index(self, request: web.Request) -> web.Response:
        items = "".join(
            f'<li><a href="/setup/v1/{d.TYPE}/{d.number}/setup">{html.escape(d.NAME)} {d.number}: '
            f'{html.escape(d.name)}</a></li>' for d in self.devices)
        return self._page(self.server_name, f"<ul>{items}</ul>")

    async def _setup_device(self, request: web.Request) -> web.Response:
        try:
            device = self._find(request)
        except BadRequest as exc:
            return self._bad(str(exc))
        rows = [("Connected", str(device.connected))] + device.setup_rows()
        table = "".join(f"<tr><th>{html.escape(k)}</th><td>{html.escape(v)}</td></tr>" for k, v in rows)
        body = (f"<p>{html.escape(device.description)}</p><table>{table}</table>"
                f'<p>Settings live in the hardware file. <a href="/setup">All devices</a></p>')
        return self._page(f"{device.NAME} {device.number}: {device.name}", body, refresh=True)

    @staticmethod
    def _page(title: str, body: str, refresh: bool = False) -> web.Response:
        meta = '<meta http-equiv="refresh" content="2">' if refresh else ""
        text = (f"<!DOCTYPE html><html><head><meta charset=\"utf-8\">{meta}<title>{html.escape(title)}</title>"
                f"</head><body><h1>{html.escape(title)}</h1>{body}</body></html>")
        return web.Response(text=text, content_type="text/html")


def _is_loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return host == "localhost"


class DiscoveryProtocol(asyncio.DatagramProtocol):
    """Answers ``alpacadiscovery1`` datagrams with ``{"AlpacaPort": N}``."""

    def __init__(self, port, loopback_only: bool):
        self._port = port
        self._loopback_only = loopback_only
        self.transport: asyncio.DatagramTransport | None = None

    def connection_made(self, transport) -> None:
        self.transport = transport

    def datagram_received(self, data: bytes, addr) -> None:
        if not data.startswith(DISCOVERY_QUERY) or self.transport is None:
            return
        if self._loopback_only and not _is_loopback(addr[0]):
            return
        self.transport.sendto(json.dumps({"AlpacaPort": self._port()}).encode(), addr)

    def error_received(self, exc: Exception) -> None:  # pragma: no cover - ICMP noise
        log.debug("discovery: %s", exc)
