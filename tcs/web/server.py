"""The read-only web port: a live status page, ``/status.json``, ``/metrics`` (aiohttp).

How it works
------------
:class:`WebServer` runs on the service's event loop, on ``[web]`` host:port (loopback by
default; ``port = -1``: not started). Routes, all GET (HEAD too); anything else on them is
``405``, any other path ``404``; nothing here writes to the model:

* ``/`` — the status page (``tcs/web/static/index.html`` with ``style.css`` and ``app.js``:
  plain files shipped in the package, no build step, nothing fetched from elsewhere);
* ``/events`` — server-sent events: one ``snapshot`` event per new snapshot (every
  ``[web] interval`` s, 4 Hz by default) with the same JSON as ``/status.json``; at most
  :data:`MAX_VIEWERS` at once (then ``503``);
* ``/status.json`` — the newest snapshot (:func:`tcs.web.snapshot.take`);
* ``/metrics`` — the same snapshot in the Prometheus text format (:mod:`tcs.web.metrics`).

One snapshot, one clock: a sampler task takes a snapshot every ``interval`` while a page is
open (once a second otherwise, for the fault and limit counters) and keeps the newest with its
JSON encoding; ``/status.json``, ``/metrics`` and the pages all serve that one (a request
finding it older than ``interval`` takes a new one first). So a scrape costs one snapshot at
most, whatever the number of clients, and the control loop (its own thread or process) is
never touched: the snapshot reads the readbacks the loop already published.
"""

from __future__ import annotations

import asyncio
import json
import logging
import time
from importlib import resources
from typing import Any

from aiohttp import web

from tcs.web import metrics, snapshot

log = logging.getLogger(__name__)

STATIC = ("index.html", "style.css", "app.js")
CONTENT_TYPES = {"html": "text/html", "css": "text/css", "js": "text/javascript"}
IDLE_INTERVAL = 1.0      # s between snapshots while no page is open
KEEPALIVE = 15.0         # s between SSE comments on an otherwise quiet stream
MAX_VIEWERS = 32         # open event streams at most (each costs a connection, not a snapshot)


def _static(name: str) -> bytes:
    return resources.files("tcs.web").joinpath("static", name).read_bytes()


class WebServer:
    """The status page and metrics of one :class:`tcs.app.Service`."""

    def __init__(self, service, interval: float = 0.25):
        self.service = service
        self.interval = float(interval)
        self.host = "127.0.0.1"
        self.port = 0
        self.counters = metrics.Counters()
        self.registry = metrics.make_registry(lambda: self._snap, self.counters)
        self._snap: dict[str, Any] | None = None
        self._json = b"null"
        self._taken = 0.0         # monotonic time of the newest snapshot
        self._seq = 0
        self._new = asyncio.Event()
        self._viewers = 0
        self._closing = False
        self._sampler: asyncio.Task | None = None
        self._runner: web.AppRunner | None = None
        self._files = {name: _static(name) for name in STATIC}
        #: CPU seconds spent taking and encoding snapshots (for the benchmark)
        self.cpu = 0.0
        self.snapshots = 0

    # -- life cycle --------------------------------------------------------------------------
    def app(self) -> web.Application:
        app = web.Application(client_max_size=1024)
        app.router.add_get("/", self._index)
        for name in STATIC[1:]:
            app.router.add_get(f"/{name}", self._file)
        app.router.add_get("/events", self._events)
        app.router.add_get("/status.json", self._status)
        app.router.add_get("/metrics", self._metrics)
        return app

    async def start(self, host: str, port: int) -> int:
        self.host = host
        self.refresh()
        self._runner = web.AppRunner(self.app(), access_log=None, handle_signals=False,
                                     shutdown_timeout=2.0)
        await self._runner.setup()
        site = web.TCPSite(self._runner, host, port, reuse_address=True)
        try:
            await site.start()
        except BaseException:
            await self.stop()
            raise
        addresses = self._runner.addresses
        self.port = addresses[0][1] if addresses else port
        self._sampler = asyncio.get_running_loop().create_task(self._sample(), name="tcs-web-sampler")
        log.info("status page and metrics on http://%s:%d/ (/metrics, /status.json)", host, self.port)
        return self.port

    async def stop(self) -> None:
        self._closing = True
        self._new.set()  # (open event streams end)
        if self._sampler is not None:
            self._sampler.cancel()
            try:
                await self._sampler
            except asyncio.CancelledError:
                pass
            self._sampler = None
        if self._runner is not None:
            await self._runner.cleanup()
            self._runner = None

    # -- snapshots -----------------------------------------------------------------------------
    def refresh(self) -> dict[str, Any]:
        """Take a new snapshot now (event loop), count, encode and publish it."""
        cpu = time.thread_time()
        snap = snapshot.take(self.service)
        self._seq += 1
        snap["seq"] = self._seq
        self.counters.update(snap)
        self._json = json.dumps(snap, separators=(",", ":")).encode()
        self._snap = snap
        self._taken = time.monotonic()
        self.cpu += time.thread_time() - cpu
        self.snapshots += 1
        event, self._new = self._new, asyncio.Event()
        event.set()
        return snap

    def current(self) -> dict[str, Any]:
        """The newest snapshot, taken anew when it is older than ``interval``."""
        if self._snap is None or time.monotonic() - self._taken >= self.interval:
            self.refresh()
        return self._snap

    async def _sample(self) -> None:
        while True:
            await asyncio.sleep(self.interval if self._viewers else IDLE_INTERVAL)
            try:
                if time.monotonic() - self._taken >= self.interval * 0.9:
                    self.refresh()
            except Exception:
                log.exception("status snapshot failed")

    # -- handlers --------------------------------------------------------------------------------
    async def _index(self, request: web.Request) -> web.Response:
        return self._send_file("index.html")

    async def _file(self, request: web.Request) -> web.Response:
        return self._send_file(request.path.lstrip("/"))

    def _send_file(self, name: str) -> web.Response:
        kind = CONTENT_TYPES[name.rsplit(".", 1)[1]]
        return web.Response(body=self._files[name], content_type=kind, charset="utf-8",
                            headers={"Cache-Control": "no-cache"})

    async def _status(self, request: web.Request) -> web.Response:
        self.current()
        return web.Response(body=self._json, content_type="application/json",
                            headers={"Cache-Control": "no-store"})

    async def _metrics(self, request: web.Request) -> web.Response:
        self.current()
        cpu = time.thread_time()
        body = metrics.render(self.registry)
        self.cpu += time.thread_time() - cpu
        return web.Response(body=body, headers={"Content-Type": metrics.CONTENT_TYPE,
                                                "Cache-Control": "no-store"})

    async def _events(self, request: web.Request) -> web.StreamResponse:
        if self._viewers >= MAX_VIEWERS:
            return web.Response(status=503, text=f"{MAX_VIEWERS} status pages are open already; "
                                                 "use /status.json", headers={"Retry-After": "10"})
        response = web.StreamResponse(headers={"Content-Type": "text/event-stream",
                                               "Cache-Control": "no-store",
                                               "X-Accel-Buffering": "no"})
        await response.prepare(request)
        self._viewers += 1
        try:
            self.current()
            sent = -1
            while not self._closing:
                if self._seq != sent:
                    sent = self._seq
                    await response.write(b"event: snapshot\ndata: " + self._json + b"\n\n")
                waiter = self._new
                try:
                    await asyncio.wait_for(waiter.wait(), KEEPALIVE)
                except asyncio.TimeoutError:
                    await response.write(b": keepalive\n\n")
        except ConnectionError:  # (the page was closed)
            pass
        finally:
            self._viewers -= 1
        return response


async def start_web(service) -> WebServer:
    """Listen on ``[web]`` host/port of ``service`` (``service.web_port`` overrides the port)."""
    section = service.config.web
    server = WebServer(service, section.interval)
    await server.start(section.host or "127.0.0.1", service.web_port)
    return server
