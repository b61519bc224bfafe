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

The failure shapes of real receivers (issue 43): ``cold`` (a cold start: no fix, ZDA and RMC
dated 1999-08-22), ``quality`` (6 dead reckoning, 7 manual, 8 a Garmin in simulator mode —
sent with RMC status A), ``date_offset`` (−1024 weeks: week-rollover firmware; a few seconds:
a receiver whose time disagrees with the clock), ``corrupt`` (one field out of range in a
checksummed GGA), ``mixed_binary`` (UBX bytes before each sentence on the same line, as a
u-blox sending UBX and NMEA on one port), ``kinds`` (which sentences: a GGA-less receiver
sends RMC/GLL/GNS/ZDA; ``$PUBX,00``), ``gga_every`` (GGA only every n-th burst) and
``talkers`` (one GGA per constellation, ``$GPGGA`` and ``$GLGGA`` with their own counts).
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


def _fields(dt: datetime) -> tuple[str, str, str]:
    hms = dt.strftime("%H%M%S.") + f"{dt.microsecond // 10000:02d}"
    return hms, f"{dt:%d%m%y}", f"{dt:%d},{dt:%m},{dt:%Y}"


#: GGA quality -> the NMEA 2.3 mode indicator a receiver sends with it in RMC, GLL and GNS.
QUALITY_MODE = {0: "N", 1: "A", 2: "D", 3: "P", 4: "R", 5: "F", 6: "E", 7: "M", 8: "S"}


def burst(t: float, latitude: float, longitude: float, height: float, *, fix: bool = True,
          satellites: int = 9, talker: str = "GP", kinds: tuple[str, ...] = ("GGA", "RMC", "ZDA"),
          quality: int = 1, cold: bool = False, date_offset: float = 0.0,
          corrupt: str = "", talkers: tuple[tuple[str, int], ...] = ()) -> list[str]:
    """The bodies (without ``$`` and checksum) of one burst at UTC ``t``.

    ``kinds`` picks the sentences in order (GGA, RMC, GLL, GNS, ZDA, GSV, PUBX for ``$PUBX,00``).
    ``quality`` is the GGA quality of a fix (6 dead reckoning, 8 simulator: with RMC status A
    and mode E/S, as such receivers send). ``cold``: a cold start — no fix, the receiver's
    clock at 1999-08-22 plus the time of day. ``date_offset`` is added to the dates and times
    sent (−1024 weeks: week-rollover firmware). ``corrupt``: one field out of range in an
    otherwise checksummed fix ("latitude" 95.5°, "height" 99999 m, "hemisphere" missing,
    "minutes" ≥ 60). ``talkers``: ``(talker, satellites)`` pairs, one GGA each, instead of one.
    """
    sent = t + date_offset
    if cold:
        sent = datetime(1999, 8, 22, tzinfo=timezone.utc).timestamp() + t % 86400
        fix = False
    dt = datetime.fromtimestamp(sent, tz=timezone.utc)
    hms, ddmmyy, zda_date = _fields(dt)
    lat, ns = _angle(latitude, 2, "NS")
    lon, ew = _angle(longitude, 3, "EW")
    alt = f"{height:.1f}"
    if corrupt == "latitude":
        lat = "9530.0000"
    elif corrupt == "height":
        alt = "99999.0"
    elif corrupt == "hemisphere":
        ns = ""
    elif corrupt == "minutes":
        lat = lat[:2] + "75" + lat[4:]
    q = quality if fix else 0
    mode = QUALITY_MODE.get(q, "N")
    status = "A" if fix else "V"
    out = []
    for kind in kinds:
        if kind == "GGA":
            for tk, sats in (talkers or ((talker, satellites),)):
                if fix:
                    out.append(f"{tk}GGA,{hms},{lat},{ns},{lon},{ew},{q},{sats:02d},0.9,{alt},M,50.0,M,,")
                else:
                    out.append(f"{tk}GGA,{hms},,,,,0,00,,,M,,M,,")
        elif kind == "RMC":
            out.append(f"{talker}RMC,{hms},{status},{lat},{ns},{lon},{ew},0.0,0.0,{ddmmyy},,,{mode}" if fix
                       else f"{talker}RMC,{hms},V,,,,,,,{ddmmyy},,,N")
        elif kind == "GLL":
            out.append(f"{talker}GLL,{lat},{ns},{lon},{ew},{hms},{status},{mode}" if fix
                       else f"{talker}GLL,,,,,{hms},V,N")
        elif kind == "GNS":
            out.append(f"{talker}GNS,{hms},{lat},{ns},{lon},{ew},{mode}{mode},{satellites:02d},0.9,{alt},50.0,,"
                       if fix else f"{talker}GNS,{hms},,,,,NN,00,,,,,")
        elif kind == "PUBX":
            nav = "G3" if fix and q == 1 else "D3" if fix and q == 2 else "DR" if fix and q == 6 else "NF"
            out.append(f"PUBX,00,{hms},{lat},{ns},{lon},{ew},{height + 50.0:.3f},{nav},2.1,2.0,0.007,77.52,"
                       f"0.007,,0.92,1.19,0.77,{satellites},0,0" if fix
                       else f"PUBX,00,{hms},0000.00000,N,00000.00000,E,0.000,NF,5303302,3750001,0.000,0.00,"
                            "0.000,,99.99,99.99,99.99,0,0,0")
        elif kind == "GSV":
            out.append(f"{talker}GSV,1,1,{satellites + 3:02d}")
        elif kind == "ZDA":
            out.append(f"{talker}ZDA,{hms},{zda_date},00,00")
    return out


#: UBX NAV-PVT-like binary that a u-blox receiver sends on the same port as its NMEA: the next
#: sentence follows it on the same "line" (no newline in between).
UBX_BLOB = bytes([0xB5, 0x62, 0x01, 0x07, 0x5C, 0x00]) + bytes(range(0x30, 0x70)) + b"\x24\x00\xff\x2a"


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
        #: Failure shapes of real receivers (effective from the next burst): see :func:`burst`.
        self.kinds: tuple[str, ...] = ("GGA", "RMC", "ZDA")
        self.quality = 1            # 6 dead reckoning, 7 manual, 8 simulator mode
        self.cold = False           # cold start: no fix, clock at 1999-08-22
        self.date_offset = 0.0      # -1024 weeks: week-rollover firmware; seconds: a wrong clock
        self.corrupt = ""           # "latitude", "height", "hemisphere", "minutes"
        self.mixed_binary = False   # UBX bytes before every sentence on the same line
        self.gga_every = 1          # GGA only every n-th burst
        self.talkers: tuple[tuple[str, int], ...] = ()   # one GGA per (talker, satellites)
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
        kinds = self.kinds
        if self.gga_every > 1 and self.bursts % self.gga_every:
            kinds = tuple(k for k in kinds if k != "GGA")
        for body in burst(self.clock(), self.latitude, self.longitude, self.height, fix=self.fix,
                          satellites=self.satellites, kinds=kinds, quality=self.quality, cold=self.cold,
                          date_offset=self.date_offset, corrupt=self.corrupt, talkers=self.talkers):
            cs = checksum(body)
            if self.bad_checksums:
                cs = f"{int(cs, 16) ^ 0x5A:02X}"
            line = f"${body}*{cs}\r\n".encode("ascii")
            lines.append(UBX_BLOB + line if self.mixed_binary else line)
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
