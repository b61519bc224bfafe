"""A simulated GPS receiver: GGA, RMC and ZDA sentences once a second on a pty or a TCP port.

How it works
------------
Every ``1 / rate`` seconds (a chain of ``loop.call_at`` — no task, no sleep loop) the receiver
formats one burst — GGA, RMC, ZDA, each with its ``*hh`` XOR checksum and CRLF — from the
injectable ``clock`` (UTC seconds since 1970) and its fixed position, and writes it

* ``mode = "pty"``: to the master side of ``os.openpty()``; :attr:`url` is the slave's path
  (``/dev/pts/N``), which any serial reader opens like a device. Writes never block: when
  nobody reads, the bytes are dropped as on a real line;
* ``mode = "tcp"``: to every client of a listener on 127.0.0.1; :attr:`url` is
  ``socket://127.0.0.1:<port>`` (pyserial's URL for it).

The sentences are formatted here, not with pynmea2, so the reader's parser is tested against
an independent writer.

Fault injection (attributes, effective from the next burst): ``silent`` (nothing is sent),
``garbage`` (noise lines and a truncated sentence around every burst), ``bad_checksums`` (every
checksum wrong), ``fix`` (False: GGA quality 0 and empty position, RMC status V; ZDA still
carries the receiver's clock). :meth:`unplug` closes the pty or drops the TCP clients and stops
listening; in TCP mode :meth:`replug` listens again on the same port.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import random
import time
import tty
from collections.abc import Callable
from datetime import datetime, timezone


def checksum(body: str) -> str:
    """The NMEA checksum of the text between ``$`` and ``*``, as two hex digits."""
    x = 0
    for ch in body.encode("ascii"):
        x ^= ch
    return f"{x:02X}"


def _angle(value: float, degree_digits: int, hemispheres: str) -> tuple[str, str]:
    hemi = hemispheres[0] if value >= 0 else hemispheres[1]
    value = abs(value)
    deg = int(value)
    minutes = (value - deg) * 60.0
    if round(minutes, 4) >= 60.0:
        deg, minutes = deg + 1, 0.0
    return f"{deg:0{degree_digits}d}{minutes:07.4f}", hemi


def burst(t: float, latitude: float, longitude: float, height: float, *, fix: bool = True,
          satellites: int = 9, talker: str = "GP") -> list[str]:
    """The bodies (without ``$`` and checksum) of GGA, RMC and ZDA at UTC ``t``."""
    dt = datetime.fromtimestamp(t, tz=timezone.utc)
    hms = dt.strftime("%H%M%S.") + f"{dt.microsecond // 10000:02d}"
    lat, ns = _angle(latitude, 2, "NS")
    lon, ew = _angle(longitude, 3, "EW")
    if fix:
        gga = f"{talker}GGA,{hms},{lat},{ns},{lon},{ew},1,{satellites:02d},0.9,{height:.1f},M,50.0,M,,"
        rmc = f"{talker}RMC,{hms},A,{lat},{ns},{lon},{ew},0.0,0.0,{dt:%d%m%y},,,A"
    else:
        gga = f"{talker}GGA,{hms},,,,,0,00,,,M,,M,,"
        rmc = f"{talker}RMC,{hms},V,,,,,,,{dt:%d%m%y},,,N"
    zda = f"{talker}ZDA,{hms},{dt:%d},{dt:%m},{dt:%Y},00,00"
    return [gga, rmc, zda]


class SimGps:
    """A receiver at a fixed position.

    Parameters
    ----------
    latitude, longitude, height:
        Degrees north, degrees east, metres above sea level.
    rate:
        Bursts per second (1 Hz like most receivers; tests use more).
    mode:
        ``"pty"`` or ``"tcp"``.
    port:
        TCP port (0: a free one; kept across :meth:`unplug` / :meth:`replug`).
    clock:
        UTC seconds since 1970 for the sentences' time.
    """

    def __init__(self, latitude: float, longitude: float, height: float, *, rate: float = 1.0,
                 satellites: int = 9, mode: str = "pty", port: int = 0,
                 clock: Callable[[], float] = time.time, seed: int = 1):
        if mode not in ("pty", "tcp"):
            raise ValueError(f"mode must be 'pty' or 'tcp', not {mode!r}")
        self.latitude, self.longitude, self.height = latitude, longitude, height
        self.rate = rate
        self.satellites = satellites
        self.mode = mode
        self.port = port
        self.clock = clock
        self.silent = False
        self.garbage = False
        self.bad_checksums = False
        self.fix = True
        self.bursts = 0
        self._rng = random.Random(seed)
        self._master: int | None = None
        self._slave: int | None = None
        self._path = ""
        self._server: asyncio.base_events.Server | None = None
        self._clients: set[asyncio.StreamWriter] = set()
        self._timer: asyncio.TimerHandle | None = None
        self._next = 0.0

    @classmethod
    def from_config(cls, gps, site, *, port: int | None = None, **kwargs) -> SimGps:
        """The receiver a hardware file describes: ``[gps.sim]``, position defaulting to ``[site]``.

        A ``socket://host:port`` URL gives TCP mode on that port (``port`` overrides it; 0 picks
        a free one), anything else a pty — the reader must then open :attr:`url`.
        """
        sim = gps.sim
        lat = sim.latitude if sim and sim.latitude is not None else site.latitude
        lon = sim.longitude if sim and sim.longitude is not None else site.longitude
        height = sim.height if sim and sim.height is not None else site.height
        mode, url_port = "pty", 0
        if gps.url.startswith("socket://"):
            mode = "tcp"
            url_port = int(gps.url.rsplit(":", 1)[1].split("?")[0] or 0)
        return cls(lat, lon, height, rate=sim.rate if sim else 1.0,
                   satellites=sim.satellites if sim else 9, mode=mode,
                   port=url_port if port is None else port, **kwargs)

    @property
    def url(self) -> str:
        """What a reader opens: the pty path, or ``socket://127.0.0.1:<port>``."""
        return self._path if self.mode == "pty" else f"socket://127.0.0.1:{self.port}"

    async def start(self) -> None:
        loop = asyncio.get_running_loop()
        if self.mode == "pty":
            self._master, self._slave = os.openpty()
            tty.setraw(self._slave)          # no echo, no CR/LF translation
            os.set_blocking(self._master, False)
            self._path = os.ttyname(self._slave)
        else:
            await self._listen()
        self._next = loop.time()
        self._tick()

    async def stop(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        await self.unplug()

    async def __aenter__(self) -> SimGps:
        await self.start()
        return self

    async def __aexit__(self, *exc) -> None:
        await self.stop()

    async def unplug(self) -> None:
        """The cable is pulled: the pty disappears / TCP clients are dropped, nothing listens."""
        for fd in (self._master, self._slave):
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._master = self._slave = None
        if self._server is not None:
            self._server.close()
            for w in list(self._clients):
                w.close()
            self._clients.clear()
            await self._server.wait_closed()
            self._server = None

    async def replug(self) -> None:
        """TCP mode: listen again on the same port."""
        if self.mode != "tcp":
            raise RuntimeError("a pty cannot be plugged back in at the same path")
        if self._server is None:
            await self._listen()

    async def _listen(self) -> None:
        self._server = await asyncio.start_server(self._on_client, "127.0.0.1", self.port)
        self.port = self._server.sockets[0].getsockname()[1]

    async def _on_client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self._clients.add(writer)  # the reader side is never read: a GPS only talks

    # ------------------------------------------------------------- emission

    def _tick(self) -> None:
        loop = asyncio.get_running_loop()
        self._next += 1.0 / self.rate
        now = loop.time()
        if self._next < now:  # fell behind (a busy machine): do not burst to catch up
            self._next = now + 1.0 / self.rate
        self._timer = loop.call_at(self._next, self._tick)
        if not self.silent:
            self._send(self._compose())

    def _compose(self) -> bytes:
        lines = []
        for body in burst(self.clock(), self.latitude, self.longitude, self.height, fix=self.fix,
                          satellites=self.satellites):
            cs = checksum(body)
            if self.bad_checksums:
                cs = f"{int(cs, 16) ^ 0x5A:02X}"
            lines.append(f"${body}*{cs}\r\n".encode("ascii"))
        if self.garbage:
            noise = bytes(self._rng.randrange(256) for _ in range(self._rng.randrange(10, 60)))
            lines.insert(0, noise.replace(b"\n", b"") + b"\r\n")
            lines.insert(2, lines[1][: len(lines[1]) // 2] + b"\r\n")   # a truncated sentence
            lines.append(b"$GPXXX,this,is,not,nmea\r\n")
        self.bursts += 1
        return b"".join(lines)

    def _send(self, data: bytes) -> None:
        if self._master is not None:
            try:
                os.write(self._master, data)
            except (BlockingIOError, OSError):
                pass  # nobody reads: the line drops it
        for w in list(self._clients):
            if w.is_closing():
                self._clients.discard(w)
                continue
            if w.transport.get_write_buffer_size() < 65536:
                w.write(data)
