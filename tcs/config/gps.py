"""Hardware-file section of the GPS receiver: ``[gps]`` (absent = no GPS module).

::

    [gps]
    url = "/dev/ttyS0"          # or "socket://127.0.0.1:15030", a pty path, "loop://"
    baudrate = 4800
    position_timeout = 3.0      # no validated fix (GGA/RMC/GLL/GNS/PUBX) for this long -> loose (24)
    time_timeout = 3.0          # no validated RMC/ZDA for this long -> time loose (26)
    clock_tolerance = 2.0       # |GPS time - system clock| above this -> time loose, condition

    [gps.sim]                   # only for the simulator (tcs/sim/gps.py)
    rate = 1.0

The reader is :class:`tcs.drivers.gps.GpsReader`; the simulator :class:`tcs.sim.gps.SimGps`.
"""

from __future__ import annotations

from dataclasses import dataclass

from tcs.config.schema import setting


@dataclass(frozen=True)
class GpsSimSection:
    """Parameters of the simulated receiver; position defaults to the ``[site]`` section."""

    latitude: float | None = setting(None, min=-90.0, max=90.0, doc="degrees north")
    longitude: float | None = setting(None, min=-180.0, max=360.0, doc="degrees east")
    height: float | None = setting(None, min=-500.0, max=10000.0, doc="m above sea level")
    rate: float = setting(1.0, min=0.01, max=100.0, doc="sentence bursts per second")
    satellites: int = setting(9, min=0, max=32, doc="satellites reported in GGA")


@dataclass(frozen=True)
class GpsSection:
    url: str = setting(doc="serial device path or pyserial URL of the NMEA stream")
    baudrate: int = setting(4800, min=50, max=4_000_000, doc="serial speed (ignored by socket URLs)")
    position_timeout: float = setting(3.0, min=0.05, max=3600.0,
                                      doc="seconds without a validated fix (GGA, RMC, GLL, GNS or "
                                          "$PUBX,00) before POSITION_LOOSE")
    time_timeout: float = setting(3.0, min=0.05, max=3600.0,
                                  doc="seconds without a validated RMC/ZDA (and fix) before TIME_LOOSE")
    clock_tolerance: float = setting(2.0, min=0.01, max=86400.0,
                                     doc="largest |GPS time - system clock|, s, for the time to be good "
                                         "(NMEA arrives up to ~1 s after the second it names); above it "
                                         "TIME_LOOSE and the condition 'GPS time disagrees with the clock'")
    reopen_min: float = setting(0.5, min=0.0, max=600.0, doc="first delay before reopening the port, s")
    reopen_max: float = setting(10.0, min=0.01, max=3600.0, doc="longest reopen delay, s (doubles up to it)")
    sim: GpsSimSection | None = setting(None, doc="simulator parameters (ignored by the reader)")

    def check(self):
        problems = []
        if not self.url.strip():
            problems.append(("url", "must name the serial port or URL of the receiver"))
        if self.reopen_min > self.reopen_max:
            problems.append(("reopen_min", f"{self.reopen_min} is above reopen_max {self.reopen_max}"))
        return problems
