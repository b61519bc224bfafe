"""The INDI Telescope device ("TCS Telescope") over the POINTING module and the operations.

What maps to what
-----------------
* ``EQUATORIAL_EOD_COORD`` (RA hours, DEC degrees) is **JNow** as INDI defines it: the apparent
  place, equinox and equator of date (precession, nutation, aberration, light deflection) —
  converted exactly from and to the TCS's ICRS J2000 (``POINTING.CURRENT`` / ``TARGET``) with
  ERFA: ICRS → CIRS (``atci13``) → equinox-based RA (minus the equation of the origins), and
  back. Reading: where the telescope points (the encoders through the inverse pipeline).
  Writing: what ``ON_COORD_SET`` says — ``TRACK`` slews and tracks, ``SLEW`` slews and stops
  tracking once on target, ``SYNC`` is a pointing offset (the pointing model's index terms,
  :meth:`~tcs.model.operations.Operations.sync_to`). State Busy while slewing, Ok on target,
  Alert with the TCS's reason when refused (horizon, Sun, limits, not ready) or when it failed.
* ``HORIZONTAL_COORD`` (AZ, ALT degrees): read, the observed place of the encoders; writing it
  slews there (the operations' horizontal goto) with tracking off.
* ``TELESCOPE_ABORT_MOTION``: stops tracking and every move (the operations' halt).
* ``TELESCOPE_PARK`` PARK/UNPARK: the operations' park (the hardware file's park positions) and
  make-ready (``unpark``: powers and references, the TCS's make-ready policy applies).
* ``TELESCOPE_TRACK_STATE``: TRACK_ON tracks the place the telescope points at, TRACK_OFF ends
  tracking. ``TELESCOPE_TRACK_MODE``: sidereal only in this version (others refused).
* ``TELESCOPE_TIMED_GUIDE_NS``/``_WE`` (ms) with ``GUIDE_RATE`` (fraction of sidereal, 0.5):
  pulses that move the tracked target by rate × time (:meth:`Operations.pulse_guide`).
* ``TELESCOPE_PIER_SIDE`` (equatorial mounts): PIER_EAST in the normal orientation, PIER_WEST
  in the reverse one; read-only.
* ``GEOGRAPHIC_COORD`` (LAT, LONG east 0…360, ELEV m), ``TIME_UTC`` (ISO UTC, OFFSET 0),
  ``TELESCOPE_INFO``, ``DRIVER_INFO`` (interface bits: telescope 1, guider 4): read-only — the
  site and the clock belong to the TCS.
* ``CONNECTION``: the TCS is always connected to its hardware; CONNECT answers Ok, DISCONNECT
  is acknowledged and changes nothing for other clients.

What may touch it
-----------------
The service's event loop, through :class:`~tcs.indi.server.IndiServer`.
"""

from __future__ import annotations

import asyncio
import logging
import math
import time

import erfa

from tcs.errors import TcsError
from tcs.indi.protocol import Element, Vector
from tcs.indi.server import Device, Refused
from tcs.pointing.orientation import to_normal

log = logging.getLogger(__name__)

SIDEREAL_DEG_S = 360.0 / 86164.0905
GUIDE_RATE = 0.5                       # of the sidereal rate
TRACK_INSIDE_LIMITS = 2                # POINTING.TRACK: the orientation that stays inside
ON_TARGET = 8
INTERFACE_TELESCOPE, INTERFACE_GUIDER = 1, 4
# guide pulse directions of Operations.pulse_guide (ASCOM's numbers)
NORTH, SOUTH, EAST, WEST = 0, 1, 2, 3


def _tt(utc: float, tai_utc: float) -> tuple[float, float]:
    return erfa.DJM0, (utc + tai_utc + 32.184) / 86400.0 + 40587.0


def icrs_to_jnow(ra_h: float, dec_d: float, utc: float, tai_utc: float) -> tuple[float, float]:
    """ICRS J2000 (hours, degrees) → apparent place of date, equinox-based (hours, degrees)."""
    t1, t2 = _tt(utc, tai_utc)
    ri, di, eo = erfa.atci13(math.radians(ra_h * 15.0), math.radians(dec_d), 0.0, 0.0, 0.0, 0.0, t1, t2)
    ra = erfa.anp(ri - eo)
    return math.degrees(ra) / 15.0, math.degrees(di)


def jnow_to_icrs(ra_h: float, dec_d: float, utc: float, tai_utc: float) -> tuple[float, float]:
    """The inverse of :func:`icrs_to_jnow`."""
    t1, t2 = _tt(utc, tai_utc)
    eo = erfa.eo06a(t1, t2)
    rc, dc, _eo = erfa.atic13(erfa.anp(math.radians(ra_h * 15.0) + eo), math.radians(dec_d), t1, t2)
    return math.degrees(erfa.anp(rc)) / 15.0, math.degrees(dc)


def _num(name, label, value, fmt, lo, hi, step=0.0):
    return Element(name, label, value, fmt, lo, hi, step)


def _switch(name, label, on=False):
    return Element(name, label, on)


class TelescopeDevice(Device):
    def __init__(self, telescope, name: str = "TCS Telescope"):
        super().__init__()
        self.name = name
        self.telescope = telescope
        self.tasks: set[asyncio.Task] = set()
        self._coord_mode = "TRACK"
        self._slew_mode: str | None = None     # SLEW/TRACK of the running slew
        self._slew_failed: str | None = None
        self._guiding_until = {"NS": 0.0, "WE": 0.0}
        p = self.p
        equatorial = p.mount == "RA-DEC"
        add, d = self.add, self.name
        self.connection = add(Vector(d, "CONNECTION", "Switch", [
            _switch("CONNECT", "Connect", True), _switch("DISCONNECT", "Disconnect")],
            label="Connection", group="Main Control", state="Ok"))
        self.info = add(Vector(d, "DRIVER_INFO", "Text", [
            Element("DRIVER_NAME", "Name", "tcs"), Element("DRIVER_EXEC", "Exec", "tcs-server"),
            Element("DRIVER_VERSION", "Version", _version()),
            Element("DRIVER_INTERFACE", "Interface", str(INTERFACE_TELESCOPE | INTERFACE_GUIDER))],
            label="Driver Info", group="General Info", perm="ro", state="Idle"))
        self.eq = add(Vector(d, "EQUATORIAL_EOD_COORD", "Number", [
            _num("RA", "RA (hh:mm:ss)", 0.0, "%010.6m", 0.0, 24.0),
            _num("DEC", "DEC (dd:mm:ss)", 0.0, "%010.6m", -90.0, 90.0)],
            label="Eq. Coordinates"))
        self.coord_set = add(Vector(d, "ON_COORD_SET", "Switch", [
            _switch("SLEW", "Slew"), _switch("TRACK", "Track", True), _switch("SYNC", "Sync")],
            label="On Set", state="Ok"))
        self.horizontal = add(Vector(d, "HORIZONTAL_COORD", "Number", [
            _num("AZ", "AZ D:M:S", 0.0, "%010.6m", 0.0, 360.0),
            _num("ALT", "Alt  D:M:S", 0.0, "%010.6m", -90.0, 90.0)], label="Horizontal Coordinates"))
        self.abort = add(Vector(d, "TELESCOPE_ABORT_MOTION", "Switch", [_switch("ABORT", "Abort")],
                                label="Abort Motion", rule="AtMostOne"))
        self.park = add(Vector(d, "TELESCOPE_PARK", "Switch", [
            _switch("PARK", "Park(ed)"), _switch("UNPARK", "UnPark(ed)")], label="Parking", group="Site Management"))
        self.track_state = add(Vector(d, "TELESCOPE_TRACK_STATE", "Switch", [
            _switch("TRACK_ON", "On"), _switch("TRACK_OFF", "Off", True)], label="Tracking"))
        self.track_mode = add(Vector(d, "TELESCOPE_TRACK_MODE", "Switch", [
            _switch("TRACK_SIDEREAL", "Sidereal", True)], label="Track Mode", state="Ok"))
        self.guide_ns = add(Vector(d, "TELESCOPE_TIMED_GUIDE_NS", "Number", [
            _num("TIMED_GUIDE_N", "North (ms)", 0.0, "%.f", 0.0, 60000.0, 100.0),
            _num("TIMED_GUIDE_S", "South (ms)", 0.0, "%.f", 0.0, 60000.0, 100.0)],
            label="Guide N/S", group="Guide"))
        self.guide_we = add(Vector(d, "TELESCOPE_TIMED_GUIDE_WE", "Number", [
            _num("TIMED_GUIDE_W", "West (ms)", 0.0, "%.f", 0.0, 60000.0, 100.0),
            _num("TIMED_GUIDE_E", "East (ms)", 0.0, "%.f", 0.0, 60000.0, 100.0)],
            label="Guide E/W", group="Guide"))
        self.guide_rate = add(Vector(d, "GUIDE_RATE", "Number", [
            _num("GUIDE_RATE_WE", "W/E Rate", GUIDE_RATE, "%.2f", GUIDE_RATE, GUIDE_RATE),
            _num("GUIDE_RATE_NS", "N/S Rate", GUIDE_RATE, "%.2f", GUIDE_RATE, GUIDE_RATE)],
            label="Guiding Rate", group="Guide", perm="ro", state="Ok"))
        if equatorial:
            self.pier = add(Vector(d, "TELESCOPE_PIER_SIDE", "Switch", [
                _switch("PIER_WEST", "West (pointing east)"), _switch("PIER_EAST", "East (pointing west)")],
                label="Pier Side", group="Site Management", perm="ro"))
        else:
            self.pier = None
        self.geo = add(Vector(d, "GEOGRAPHIC_COORD", "Number", [
            _num("LAT", "Lat (dd:mm:ss)", 0.0, "%010.6m", -90.0, 90.0),
            _num("LONG", "Lon (dd:mm:ss)", 0.0, "%010.6m", 0.0, 360.0),
            _num("ELEV", "Elevation (m)", 0.0, "%g", -200.0, 10000.0)],
            label="Scope Location", group="Site Management", perm="ro", state="Ok"))
        self.time = add(Vector(d, "TIME_UTC", "Text", [
            Element("UTC", "UTC Time", ""), Element("OFFSET", "UTC Offset", "0.00")],
            label="UTC", group="Site Management", perm="ro", state="Ok"))
        self.scope_info = add(Vector(d, "TELESCOPE_INFO", "Number", [
            _num("TELESCOPE_APERTURE", "Aperture (mm)", 0.0, "%g", 0.0, 100000.0),
            _num("TELESCOPE_FOCAL_LENGTH", "Focal Length (mm)", 0.0, "%g", 0.0, 1000000.0),
            _num("GUIDER_APERTURE", "Guider Aperture (mm)", 0.0, "%g", 0.0, 100000.0),
            _num("GUIDER_FOCAL_LENGTH", "Guider Focal Length (mm)", 0.0, "%g", 0.0, 1000000.0)],
            label="Scope Properties", group="Options", perm="ro", state="Ok"))

    # -- the model --------------------------------------------------------------------------------
    @property
    def p(self):
        p = self.telescope.pointing
        if p is None:
            raise Refused("this telescope has no POINTING module")
        return p

    @property
    def ops(self):
        return self.telescope.operations

    def _now(self) -> tuple[float, float]:
        local = self.telescope.local
        return local.utc(), local.tai_utc

    def _run(self, coro, what: str) -> None:
        """Run a long operation of the model in the background; its failure shows as Alert."""
        if coro is None:
            return

        async def watch():
            try:
                await coro
            except asyncio.CancelledError:
                raise
            except TcsError as exc:
                self._slew_failed = f"{what}: {exc.message}"
            except Exception as exc:  # logged: a bug, not a refusal
                log.exception("INDI %s", what)
                self._slew_failed = f"{what}: {exc}"
        task = asyncio.ensure_future(watch())
        self.tasks.add(task)
        task.add_done_callback(self.tasks.discard)

    def _fresh(self) -> bool:
        try:
            self.ops.check_fresh()
            return True
        except TcsError:
            return False

    def _on_target(self) -> bool:
        p = self.p
        window = max(p.axis1.section.tolerance, p.axis2.section.tolerance)
        return bool(self.ops.motion_state & ON_TARGET) and p.targetdistance <= window

    def refresh(self) -> None:
        p, ops = self.p, self.ops
        utc, tai_utc = self._now()
        fresh = self._fresh()
        tracking = bool(p.track)
        if fresh:
            cur = p.current
            ra, dec = icrs_to_jnow(float(cur.ra), float(cur.dec), utc, tai_utc)
            self.eq.element("RA").value, self.eq.element("DEC").value = ra, dec
            az, alt = self._altaz()
            self.horizontal.element("AZ").value, self.horizontal.element("ALT").value = az, alt
        if not fresh:
            self.eq.state = self.horizontal.state = "Alert"
            self.eq.message = "no fresh readback of the main axes"
        elif self._slew_failed:
            self.eq.state, self.eq.message = "Alert", self._slew_failed
        elif tracking and not self._on_target():
            self.eq.state, self.eq.message = "Busy", None
        elif ops.running in ("goto", "park", "home", "alpaca-park") or ops.motion_state & 1 and not tracking:
            self.eq.state, self.eq.message = "Busy", None
        else:
            self.eq.state, self.eq.message = ("Ok" if tracking or self._slew_mode else "Idle"), None
        if fresh and self.horizontal.state == "Alert":
            self.horizontal.state = "Idle"
        if self._slew_mode == "SLEW" and tracking and self._on_target():
            self._slew_mode = None
            ops.stop_tracking()      # INDI's SLEW: there, then no tracking
            tracking = False
        self.track_state.element("TRACK_ON").value = tracking
        self.track_state.element("TRACK_OFF").value = not tracking
        self.track_state.state = "Busy" if tracking else "Idle"
        parked = bool(ops.at_park)
        self.park.element("PARK").value, self.park.element("UNPARK").value = parked, not parked
        running = ops.running
        self.park.state = "Busy" if running in ("park", "unpark", "ready") else ("Ok" if parked else "Idle")
        now = time.monotonic()
        for key, vec in (("NS", self.guide_ns), ("WE", self.guide_we)):
            vec.state = "Busy" if now < self._guiding_until[key] and ops.pulse_guiding else "Idle"
            if vec.state == "Idle":
                for e in vec.elements:
                    e.value = 0.0
        if self.pier is not None and fresh:
            reverse = bool(p.orientation_in_use())
            self.pier.element("PIER_WEST").value, self.pier.element("PIER_EAST").value = reverse, not reverse
            self.pier.state = "Ok"
        local = self.telescope.local
        self.geo.element("LAT").value = float(local.latitude)
        self.geo.element("LONG").value = float(local.longitude) % 360.0
        self.geo.element("ELEV").value = float(local.height)
        self.time.element("UTC").value = time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(utc))

    def _altaz(self) -> tuple[float, float]:
        p = self.p
        place = p.place()
        if p.mount == "AZ-ZD":
            a1, a2 = float(place.ideal1), float(place.ideal2)
            return (a1 + 180.0 if a2 < 0.0 else a1) % 360.0, 90.0 - abs(a2)
        n1, n2, _rev = to_normal(place.ideal1, place.ideal2, p.mount)
        az, alt = erfa.hd2ae(math.radians(float(n1)), math.radians(float(n2)), math.radians(p.latitude))
        return math.degrees(float(az)) % 360.0, math.degrees(float(alt))

    # -- a client's new values --------------------------------------------------------------------
    def handle(self, name: str, values: dict) -> None:
        handler = getattr(self, "new_" + name.lower(), None)
        if handler is None:
            raise Refused(f"{name} cannot be written")
        handler(values)

    def new_connection(self, values: dict) -> None:
        self.connection.state = "Ok"   # always connected to its hardware

    def new_on_coord_set(self, values: dict) -> None:
        on = [k for k, v in values.items() if v]
        if len(on) != 1:
            raise Refused("ON_COORD_SET: exactly one of SLEW, TRACK, SYNC")
        self._coord_mode = on[0]
        for e in self.coord_set.elements:
            e.value = e.name == on[0]
        self.coord_set.state = "Ok"

    def _not_parked(self, what: str) -> None:
        if self.ops.at_park:
            raise Refused(f"{what}: the telescope is parked (TELESCOPE_PARK UNPARK first)")

    def new_equatorial_eod_coord(self, values: dict) -> None:
        ra = values.get("RA", self.eq.element("RA").value)
        dec = values.get("DEC", self.eq.element("DEC").value)
        if not (0.0 <= ra < 24.0 and -90.0 <= dec <= 90.0):
            raise Refused(f"RA {ra:g} h / DEC {dec:g}° is outside 0…24 h / −90…90°")
        utc, tai_utc = self._now()
        ra_c, dec_c = jnow_to_icrs(ra, dec, utc, tai_utc)
        p, ops = self.p, self.ops
        if self._coord_mode == "SYNC":
            self._not_parked("SYNC")
            for axis in (p.axis1, p.axis2):
                if axis.referenced < 1.0:
                    raise Refused(f"SYNC: {axis.module_name} is not referenced")
            ops.sync_to(ra_c, dec_c)
            if p.track:
                p.target.set_ra(ra_c)
                p.target.set_dec(dec_c)
            self.eq.state = "Ok"
            return
        self._not_parked(self._coord_mode)
        target = p.target
        old = (target.ra, target.dec) if target.complete else None
        target.set_ra(ra_c)
        target.set_dec(dec_c)
        try:
            result = p.set_track(TRACK_INSIDE_LIMITS)
        except Exception:
            if old is not None:
                target.set_ra(old[0])
                target.set_dec(old[1])
            raise
        self._slew_failed = None
        self._slew_mode = self._coord_mode
        self._run(result, "the slew")
        self.eq.state = "Busy"

    def new_horizontal_coord(self, values: dict) -> None:
        az = values.get("AZ", self.horizontal.element("AZ").value)
        alt = values.get("ALT", self.horizontal.element("ALT").value)
        if not (0.0 <= az <= 360.0 and -90.0 <= alt <= 90.0):
            raise Refused(f"AZ {az:g}° / ALT {alt:g}° is outside 0…360 / −90…90")
        self._not_parked("HORIZONTAL_COORD")
        ops = self.ops
        if self.p.track:
            ops.stop_tracking()
        ops.horizontal_demand(az % 360.0, alt)   # refuses below the horizon / outside the limits
        obj = ops.object
        obj.set_az(az % 360.0)
        obj.set_alt(alt)
        self._slew_failed = None
        self._slew_mode = None
        self._run(ops.goto_horizontal(), "the slew")
        self.horizontal.state = "Busy"

    def new_telescope_abort_motion(self, values: dict) -> None:
        ops = self.ops
        for task in list(self.tasks):
            task.cancel()
        self._slew_mode = None
        if self.telescope.pointing is not None and self.p.track:
            ops.stop_tracking()
        ops.halt()
        self.abort.state = "Ok"
        self.eq.state = "Idle"

    def new_telescope_park(self, values: dict) -> None:
        ops = self.ops
        if values.get("PARK"):
            self._slew_mode = None
            self._run(ops.park(), "Park")
        elif values.get("UNPARK"):
            self._run(ops.unpark(), "Unpark")
        self.park.state = "Busy"

    def new_telescope_track_state(self, values: dict) -> None:
        p, ops = self.p, self.ops
        if values.get("TRACK_OFF") and not values.get("TRACK_ON"):
            if p.track:
                ops.stop_tracking()
            self._slew_mode = None
            return
        if not values.get("TRACK_ON"):
            return
        self._not_parked("TRACK_ON")
        if p.track:
            return
        place = p.place()
        p.target.set_ra(place.ra)
        p.target.set_dec(place.dec)
        self._slew_failed = None
        self._slew_mode = "TRACK"
        self._run(p.set_track(3 if place.reverse else 1), "tracking")

    def new_telescope_track_mode(self, values: dict) -> None:
        if not values.get("TRACK_SIDEREAL", False) or any(v for k, v in values.items() if k != "TRACK_SIDEREAL"):
            raise Refused("only sidereal tracking is served over INDI in this version")

    def _guide(self, vec, values: dict, key: str, plus: str, minus: str, d_plus: int, d_minus: int) -> None:
        ops = self.ops
        if not self.p.track:
            raise Refused("guide pulses need tracking (TELESCOPE_TRACK_STATE TRACK_ON)")
        a, b = values.get(plus, 0.0), values.get(minus, 0.0)
        if a and b:
            raise Refused(f"{vec.name}: one direction at a time")
        ms = a or b
        if not 0.0 <= ms <= 60000.0:
            raise Refused(f"{vec.name}: {ms:g} ms is outside 0…60000")
        if ms == 0:
            return
        ops.pulse_guide(d_plus if a else d_minus, ms / 1000.0, GUIDE_RATE * SIDEREAL_DEG_S)
        for e in vec.elements:
            e.value = values.get(e.name, 0.0)
        self._guiding_until[key] = time.monotonic() + ms / 1000.0
        vec.state = "Busy"

    def new_telescope_timed_guide_ns(self, values: dict) -> None:
        self._guide(self.guide_ns, values, "NS", "TIMED_GUIDE_N", "TIMED_GUIDE_S", NORTH, SOUTH)

    def new_telescope_timed_guide_we(self, values: dict) -> None:
        self._guide(self.guide_we, values, "WE", "TIMED_GUIDE_W", "TIMED_GUIDE_E", WEST, EAST)


def _version() -> str:
    import tcs
    return str(tcs.__version__)
