"""A socketcand server: offers an in-process CAN bus to other processes over TCP.

The simulated cabinet (``tcs-sim``) runs its drives on a python-can ``virtual`` bus; this
server bridges that bus to TCP clients speaking socketcand's "rawmode" text protocol — the one
python-can's ``socketcand`` interface (and real CAN-Ethernet gateways) use — so a separate
``tcs-server`` drives the simulated hardware exactly like a remote CAN bus.

Protocol (the part clients use)::

    server: < hi >
    client: < open <bus> >         server: < ok >
    client: < rawmode >            server: < ok >
    client: < send ID LEN B0 B1 … >           (ID hex, 3 digits standard / 8 extended)
    server: < frame ID SEC.USEC HEXDATA >

A frame from a client goes onto the virtual bus and to every *other* client (SocketCAN
semantics: no echo to the sender); every frame of the virtual bus goes to every client.
python-can's client reads the ``< ok >`` of rawmode with a single ``recv``, so frames start to
flow a short moment after it. Malformed or unsupported lines are logged, counted and ignored
(python-can's client cannot parse an ``< error … >`` reply that is not an error frame); the
connection goes on. Threads: one python-can notifier thread hands bus frames to the event loop.

Latency matters: a master's cycle waits for the drives' TPDOs, which cross this bridge. The
sockets have TCP_NODELAY (no Nagle delay on small frames), and the frames the notifier thread
collects while the event loop is busy go out in one write per client (one wake-up of the loop
and one segment for the burst of TPDOs that follows a SYNC, not one per frame).
"""

from __future__ import annotations

import asyncio
import logging
import re
import socket
import threading
import time

import can

from tcs.virtual_can import open_bus

log = logging.getLogger(__name__)

SEND = re.compile(r"send\s+([0-9A-Fa-f]{1,8})\s+([0-9A-Fa-f])((?:\s+[0-9A-Fa-f]{1,2})*)\s*$")
RAWMODE_SETTLE = 0.1  # s between "< ok >" of rawmode and the first frame


def format_frame(msg: can.Message) -> bytes:
    ident = f"{msg.arbitration_id:08X}" if msg.is_extended_id else f"{msg.arbitration_id:03X}"
    ts = msg.timestamp
    return f"< frame {ident} {int(ts)}.{int((ts % 1) * 1e6):06d} {bytes(msg.data).hex().upper()} >".encode()


def parse_send(body: str) -> can.Message | None:
    """The frame of a ``send`` command body, or None when malformed."""
    m = SEND.match(body.strip())
    if not m:
        return None
    ident_text, length = m.group(1), int(m.group(2), 16)
    data = bytes(int(b, 16) for b in m.group(3).split())
    if length != len(data) or length > 8:
        return None
    ident = int(ident_text, 16)
    extended = len(ident_text) > 3
    if (not extended and ident > 0x7FF) or ident > 0x1FFFFFFF:
        return None
    return can.Message(arbitration_id=ident, data=data, is_extended_id=extended)


class _Client(asyncio.Protocol):
    def __init__(self, server: "SocketcandServer"):
        self.server = server
        self.transport: asyncio.Transport | None = None
        self.buffer = ""
        self.raw = False
        self.opened = False

    def connection_made(self, transport) -> None:
        self.transport = transport
        sock = transport.get_extra_info("socket")
        if sock is not None:
            try:
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            except OSError:
                pass
        transport.write(b"< hi >")

    def data_received(self, data: bytes) -> None:
        self.buffer += data.decode("ascii", "replace")
        pos = 0
        while True:  # every complete "< … >" of what arrived (a burst may hold thousands)
            start = self.buffer.find("<", pos)
            end = self.buffer.find(">", start + 1) if start >= 0 else -1
            if start < 0 or end < 0:
                self.buffer = self.buffer[start:] if start >= 0 else ""
                break
            pos = end + 1
            self.command(self.buffer[start + 1:end].strip())
            if self.transport is None:
                return
        if len(self.buffer) > 65536:  # (what is left is one unfinished frame)
            log.warning("socketcand: a client sent 64 KiB without a frame; closing it")
            self.transport.close()

    def command(self, body: str) -> None:
        word = body.split(" ", 1)[0]
        if word == "open":
            self.opened = True
            self.transport.write(b"< ok >")
        elif word == "rawmode" and self.opened:
            self.transport.write(b"< ok >")
            asyncio.get_running_loop().call_later(RAWMODE_SETTLE, self._go_raw)
        elif word == "send" and self.opened:
            msg = parse_send(body)
            if msg is None:
                self.server.refused += 1
                log.warning("socketcand: malformed frame from a client ignored: <%s>", body[:80])
            else:
                self.server.from_client(self, msg)
        else:
            # python-can's client would choke on a reply it cannot parse as a frame: log only
            self.server.refused += 1
            log.warning("socketcand: unsupported command ignored: <%s>", body[:80])

    def _go_raw(self) -> None:
        if self.transport is not None and not self.transport.is_closing():
            self.raw = True

    def connection_lost(self, exc) -> None:
        self.server.clients.discard(self)
        self.transport = None


class SocketcandServer:
    """Bridge between the virtual CAN bus ``channel`` and socketcand clients on ``host:port``."""

    def __init__(self, channel: str, host: str = "127.0.0.1", port: int = 0):
        self.channel = channel
        self.host = host
        self.port = port
        self.clients: set[_Client] = set()
        self._bus: can.BusABC | None = None
        self._notifier: can.Notifier | None = None
        self._server: asyncio.base_events.Server | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self.frames_in = self.frames_out = self.refused = 0
        self._pending: list[can.Message] = []  # bus frames waiting for the loop (notifier thread)
        self._pending_lock = threading.Lock()

    async def start(self) -> int:
        """Open the bridge and listen; returns the bound port."""
        self._loop = asyncio.get_running_loop()
        self._bus = open_bus(interface="virtual", channel=self.channel, receive_own_messages=False)
        self._notifier = can.Notifier(self._bus, [self._on_bus_frame], timeout=0.1)
        self._server = await self._loop.create_server(lambda: self._track(_Client(self)),
                                                      self.host, self.port, reuse_address=True)
        self.port = self._server.sockets[0].getsockname()[1]
        log.info("socketcand server for virtual bus %r on %s:%d", self.channel, self.host, self.port)
        return self.port

    def _track(self, client: _Client) -> _Client:
        self.clients.add(client)
        return client

    def _on_bus_frame(self, msg: can.Message) -> None:  # notifier thread
        loop = self._loop
        if loop is None or msg.is_error_frame:
            return
        with self._pending_lock:
            self._pending.append(msg)
            if len(self._pending) > 1:
                return  # a flush is already scheduled: it takes this frame too
        try:
            loop.call_soon_threadsafe(self._flush)
        except RuntimeError:
            pass

    def _flush(self) -> None:
        with self._pending_lock:
            frames, self._pending = self._pending, []
        if frames:
            self._write(b"".join(format_frame(m) for m in frames), len(frames), None)

    def _to_clients(self, msg: can.Message, sender: _Client | None) -> None:
        self._write(format_frame(msg), 1, sender)

    def _write(self, lines: bytes, count: int, sender: _Client | None) -> None:
        for client in list(self.clients):
            if client is not sender and client.raw and client.transport is not None:
                client.transport.write(lines)
                self.frames_out += count

    def from_client(self, client: _Client, msg: can.Message) -> None:
        self.frames_in += 1
        try:
            self._bus.send(msg)
        except can.CanError as exc:
            log.warning("socketcand: cannot forward frame %03X: %s", msg.arbitration_id, exc)
        msg.timestamp = time.time()
        self._to_clients(msg, client)

    async def stop(self) -> None:
        if self._server is not None:
            self._server.close()
            for client in list(self.clients):
                if client.transport is not None:
                    client.transport.close()
            await self._server.wait_closed()
            self._server = None
        if self._notifier is not None:
            self._notifier.stop()
            self._notifier = None
        if self._bus is not None:
            self._bus.shutdown()
            self._bus = None
