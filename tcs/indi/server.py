"""The INDI server: devices of the model served to INDI clients over TCP (protocol 1.7).

How it works
------------
One asyncio listener (``[indi] port``, loopback unless ``[indi] host`` says otherwise: INDI has
no authentication). Per connection a reader feeds :class:`~tcs.indi.protocol.StreamParser` and
answers each top-level element:

* ``getProperties`` (``device`` absent or ``*`` = every device, as ``indiserver`` chaining asks
  for; ``name`` = one property): the ``def…Vector`` of each matching property; from then on
  the connection receives that device's updates.
* ``new…Vector``: the device's handler for that property runs; a refusal answers the property's
  ``set…Vector`` with state Alert and a ``message`` that carries the TCS's reason; other
  clients are not disturbed.
* anything else (``enableBLOB``, ``pingRequest`` …) is ignored, or answered where INDI asks.

Updates are pushed, not polled by clients: every ``interval`` the server refreshes each device
from the model (:meth:`Device.refresh`) and sends a ``set…Vector`` of every property whose
values, state or message changed to the connections that asked for it. Each connection has a
bounded outbox: updates of one property replace its older unsent one (coalesced by property),
so a slow client costs at most one pending update per property and some messages; a client
that stops reading for ``stall_timeout`` seconds is disconnected. Many clients at once.

What may touch it
-----------------
The service's event loop (``tcs.app.Service``): :func:`start_indi` and :meth:`IndiServer.stop`.
"""

from __future__ import annotations

import asyncio
import collections
import logging

from tcs.errors import TcsError
from tcs.indi.protocol import ProtocolError, StreamParser, Vector, message_xml, parse_new

log = logging.getLogger(__name__)

#: messages (not property updates) kept per connection before the oldest are dropped
MAX_MESSAGES = 64


class Refused(Exception):
    """A request the device does not take: answered Alert with this reason."""


class Device:
    """One INDI device: its properties and what a client's new values do (subclasses)."""

    name = "TCS"

    def __init__(self) -> None:
        self.vectors: dict[str, Vector] = {}

    def add(self, vector: Vector) -> Vector:
        self.vectors[vector.name] = vector
        return vector

    def refresh(self) -> None:
        """Read the model into the properties' values and states (the server's period)."""

    def handle(self, name: str, values: dict) -> None:
        """A client's new values of property ``name``; raises :class:`Refused` (or a
        :class:`~tcs.errors.TcsError`) to answer Alert with its message."""
        raise Refused(f"{self.name}.{name} cannot be written")


class Connection:
    def __init__(self, server: "IndiServer", reader, writer):
        self.server = server
        self.reader, self.writer = reader, writer
        self.devices: set[str] = set()                      # devices it asked for
        self.updates: collections.OrderedDict = collections.OrderedDict()  # (dev, name) -> xml
        self.messages: collections.deque = collections.deque(maxlen=MAX_MESSAGES)
        self.wakeup = asyncio.Event()
        self.peer = writer.get_extra_info("peername")

    def push(self, key, xml: str) -> None:
        self.updates[key] = xml
        self.updates.move_to_end(key)
        self.wakeup.set()

    def say(self, xml: str) -> None:
        self.messages.append(xml)
        self.wakeup.set()

    async def write_loop(self) -> None:
        while True:
            await self.wakeup.wait()
            self.wakeup.clear()
            chunks = list(self.messages)
            self.messages.clear()
            while self.updates:
                chunks.append(self.updates.popitem(last=False)[1])
            if not chunks:
                continue
            try:
                self.writer.write("".join(chunks).encode())
                await asyncio.wait_for(self.writer.drain(), self.server.stall_timeout)
            except (ConnectionError, asyncio.TimeoutError, OSError) as exc:
                # gone, or not reading for stall_timeout: this client ends, nobody else notices
                log.debug("INDI client %s: %s; closing", self.peer, exc.__class__.__name__)
                self.writer.close()
                return


class IndiServer:
    def __init__(self, devices: list[Device], *, interval: float = 0.5, read_only: bool = False,
                 stall_timeout: float = 30.0):
        self.devices = {d.name: d for d in devices}
        self.interval = interval
        self.read_only = read_only
        self.stall_timeout = stall_timeout
        self.connections: set[Connection] = set()
        self._server: asyncio.base_events.Server | None = None
        self._refresh_task: asyncio.Task | None = None
        self._sent: dict = {}
        self._alerts: dict = {}   # (device, property) -> the refusal shown until the next accepted write
        self.port: int | None = None

    async def start(self, host: str, port: int) -> int:
        self._refresh()
        self._server = await asyncio.start_server(self._serve, host, port)
        self.port = self._server.sockets[0].getsockname()[1]
        self._refresh_task = asyncio.ensure_future(self._refresh_loop())
        log.info("INDI devices (%s) on %s:%d", ", ".join(self.devices), host, self.port)
        return self.port

    async def stop(self) -> None:
        if self._refresh_task is not None:
            self._refresh_task.cancel()
        if self._server is not None:
            self._server.close()
        for c in list(self.connections):
            c.writer.close()
        if self._server is not None:
            await self._server.wait_closed()

    # -- updates ----------------------------------------------------------------------------------
    def _refresh(self) -> list[Vector]:
        changed = []
        for device in self.devices.values():
            try:
                device.refresh()
            except Exception:
                log.exception("INDI: refreshing %s failed", device.name)
                continue
            for v in device.vectors.values():
                key = (device.name, v.name)
                if key in self._alerts:
                    v.state, v.message = "Alert", self._alerts[key]
                now = (v.state, v.message, tuple(sorted(v.values().items(), key=lambda kv: kv[0])))
                if self._sent.get(key) != now:
                    self._sent[key] = now
                    changed.append(v)
        return changed

    async def _refresh_loop(self) -> None:
        while True:
            await asyncio.sleep(self.interval)
            self.publish(self._refresh())

    def publish(self, vectors) -> None:
        for v in vectors:
            xml = v.set_xml()
            for c in self.connections:
                if v.device in c.devices:
                    c.push((v.device, v.name), xml)

    # -- a connection ----------------------------------------------------------------------------
    async def _serve(self, reader, writer) -> None:
        c = Connection(self, reader, writer)
        self.connections.add(c)
        writing = asyncio.ensure_future(c.write_loop())
        parser = StreamParser()
        try:
            while True:
                data = await reader.read(65536)
                if not data or writing.done():
                    break
                for element in parser.feed(data):
                    self._answer(c, element)
        except ProtocolError as exc:
            log.info("INDI client %s: %s; closing", c.peer, exc)
        except (ConnectionError, asyncio.IncompleteReadError):
            pass
        finally:
            self.connections.discard(c)
            writing.cancel()
            writer.close()

    def _answer(self, c: Connection, element) -> None:
        tag = element.tag
        if tag == "getProperties":
            device, name = element.get("device"), element.get("name")
            for dev in self.devices.values():
                if device not in (None, "", "*") and device != dev.name:
                    continue
                c.devices.add(dev.name)
                for v in dev.vectors.values():
                    if name and name != v.name:
                        continue
                    c.push((dev.name, v.name, "def"), v.define_xml())
            return
        if tag.startswith("new") and tag.endswith("Vector"):
            self._new(c, element)
            return
        if tag == "pingRequest":
            uid = element.get("uid", "")
            c.say(f'<pingReply uid="{uid}"/>\n')

    def _new(self, c: Connection, element) -> None:
        try:
            _kind, device, name, values = parse_new(element)
        except ValueError as exc:
            c.say(message_xml(element.get("device"), f"refused: {exc}"))
            return
        dev = self.devices.get(device)
        vector = dev.vectors.get(name) if dev is not None else None
        if vector is None:
            c.say(message_xml(device, f"{device}.{name}: no such property"))
            return
        unknown = [k for k in values if vector.element(k) is None]
        try:
            if unknown:
                raise Refused(f"{name} has no element {', '.join(unknown)}")
            if vector.perm == "ro":
                raise Refused(f"{name} is read-only")
            if self.read_only:
                raise Refused(f"{name}: this INDI port is read-only ([indi] read_only)")
            dev.handle(name, values)
            vector.message = None
            self._alerts.pop((device, name), None)
        except (Refused, TcsError) as exc:
            text = getattr(exc, "message", None) or str(exc)
            vector.state = "Alert"
            vector.message = text
            self._alerts[(device, name)] = text
            log.info("INDI %s.%s refused: %s", device, name, text)
        except Exception as exc:  # a bug here: Alert, logged, the service goes on
            log.exception("INDI %s.%s failed", device, name)
            vector.state, vector.message = "Alert", f"internal error: {exc}"
            self._alerts[(device, name)] = vector.message
        self.publish([vector])
        self._sent[(device, name)] = None   # the next refresh sends it again if it changes
