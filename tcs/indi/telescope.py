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
  tracking. ``TELESCOPE_TRACK_MODE``: TRACK_SIDEREAL, TRACK_SOLAR and TRACK_LUNAR (POINTING.TARGET
  RA_V/DEC_V = the real Sun's / Moon's topocentric motion against the stars, DE421, as Alpaca's
  TrackingRate), TRACK_CUSTOM (``TELESCOPE_TRACK_RATE``: TRACK_RATE_RA is the RA tracking rate,
  15.041…″/s sidereal, so RA_V = sidereal − TRACK_RATE_RA; TRACK_RATE_DE = DEC_V, ″/s). The rate
  applies at once while tracking (re-planned from the place tracked, no jump), else from the
  next slew or tracking start; ``TELESCOPE_TRACK_RATE`` reads the rates in use.
* ``TELESCOPE_MOTION_NS``/``_WE`` with ``TELESCOPE_SLEW_RATE`` (Guide 2× sidereal, Centering
  0.1°/s, Find 1°/s, Max = the axis's maximum): as Alpaca's MoveAxis — tracking ends, the axis
  moves (``Axis.move_toward``, bounded by the limits and the safety envelope: horizon, Sun,
  keep-outs) until Off or abort. North/South is the Dec axis (reversed in the reverse
  orientation) or, alt-az, up to the zenith / down to the horizon limit; West/East is the hour
  angle growing / shrinking, or azimuth growing / shrinking.
* ``TELESCOPE_PARK_POSITION`` (read-only): the park positions (hardware file or SetPark) as
  PARK_AZ/PARK_ALT (alt-az) or PARK_RA (the hour angle, h)/PARK_DEC (equatorial);
  ``TELESCOPE_PARK_OPTION`` PARK_CURRENT makes the present positions the park positions.
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

from tcs.errors import ErrorNumber, RangeRefused, TcsError
from tcs.indi.protocol import Element, Vector
from tcs.indi.server import Device, Refused
from tcs.pointing.orientation import to_normal
from tcs.pointing.targets import body_rates

log = logging.getLogger(__name__)

SIDEREAL_DEG_S = 360.0 / 86164.0905
SIDEREAL_ARCSEC = SIDEREAL_DEG_S * 3600.0   # INDI's TRACK_RATE_RA of sidereal tracking (15.041…)
RATE_BODIES = {"TRACK_SIDEREAL": None, "TRACK_SOLAR": "sun", "TRACK_LUNAR": "moon", "TRACK_CUSTOM": None}
#: TELESCOPE_SLEW_RATE: element, label, deg/s of TELESCOPE_MOTION_NS/_WE (None: the axis's maximum)
SLEW_RATES = (("SLEW_GUIDE", "Guide", 2.0 * 360.0 / 86164.0905), ("SLEW_CENTERING", "Centering", 0.1),
              ("SLEW_FIND", "Find", 1.0), ("SLEW_MAX", "Max", None))
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
        self._rate = "TRACK_SIDEREAL"
        self._custom = (SIDEREAL_ARCSEC, 0.0)   # TELESCOPE_TRACK_RATE for TRACK_CUSTOM
        self.track_mode = add(Vector(d, "TELESCOPE_TRACK_MODE", "Switch", [
            _switch("TRACK_SIDEREAL", "Sidereal", True), _switch("TRACK_SOLAR", "Solar"),
            _switch("TRACK_LUNAR", "Lunar"), _switch("TRACK_CUSTOM", "Custom")], label="Track Mode", state="Ok"))
        self.track_rate = add(Vector(d, "TELESCOPE_TRACK_RATE", "Number", [
            _num("TRACK_RATE_RA", "RA (arcsecs/s)", SIDEREAL_ARCSEC, "%.6f", -16384.0, 16384.0, 0.000001),
            _num("TRACK_RATE_DE", "DE (arcsecs/s)", 0.0, "%.6f", -16384.0, 16384.0, 0.000001)],
            label="Track Rates", state="Idle"))
        self._moving: dict[str, tuple] = {}     # "NS"/"WE" -> (axis, future) of a manual motion
        self._motion_failed: dict[str, str] = {}
        self.motion_ns = add(Vector(d, "TELESCOPE_MOTION_NS", "Switch", [
            _switch("MOTION_NORTH", "North"), _switch("MOTION_SOUTH", "South")],
            label="Motion N/S", group="Motion Control", rule="AtMostOne"))
        self.motion_we = add(Vector(d, "TELESCOPE_MOTION_WE", "Switch", [
            _switch("MOTION_WEST", "West"), _switch("MOTION_EAST", "East")],
            label="Motion W/E", group="Motion Control", rule="AtMostOne"))
        top = min(float(p.axis1.section.max_velocity), float(p.axis2.section.max_velocity))
        self.slew_rate = add(Vector(d, "TELESCOPE_SLEW_RATE", "Switch", [
            _switch(name, f"{label} ({min(speed, top) if speed else top:g}°/s)", name == "SLEW_CENTERING")
            for name, label, speed in SLEW_RATES], label="Slew Rate", group="Motion Control", state="Ok"))
        if equatorial:
            park_elements = [_num("PARK_RA", "HA (hh:mm:ss)", 0.0, "%010.6m", -12.0, 24.0),
                             _num("PARK_DEC", "DEC (dd:mm:ss)", 0.0, "%010.6m", -90.0, 90.0)]
        else:
            park_elements = [_num("PARK_AZ", "AZ D:M:S", 0.0, "%010.6m", 0.0, 360.0),
                             _num("PARK_ALT", "Alt  D:M:S", 0.0, "%010.6m", -90.0, 90.0)]
        self.park_position = add(Vector(d, "TELESCOPE_PARK_POSITION", "Number", park_elements,
                                        label="Park Position", group="Site Management", perm="ro"))
        self.park_option = add(Vector(d, "TELESCOPE_PARK_OPTION", "Switch", [
            _switch("PARK_CURRENT", "Current")], label="Park Options", group="Site Management",
            rule="AtMostOne"))
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
        self._refresh_rates()
        self._refresh_motion()
        self._refresh_park_position()
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
        self._end_motion()
        self._apply_rate()
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
        self._end_motion()
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
        self._end_motion()
        self._apply_rate()
        self._slew_failed = None
        self._slew_mode = "TRACK"
        self._run(p.set_track(3 if place.reverse else 1), "tracking")

    # -- tracking rates ---------------------------------------------------------------------------
    def new_telescope_track_mode(self, values: dict) -> None:
        on = [k for k, v in values.items() if v]
        if len(on) != 1:
            raise Refused("TELESCOPE_TRACK_MODE: exactly one of " + ", ".join(RATE_BODIES))
        self._rate = on[0]
        for e in self.track_mode.elements:
            e.value = e.name == self._rate
        self._replan()
        self.track_mode.state = "Ok"

    def new_telescope_track_rate(self, values: dict) -> None:
        ra = values.get("TRACK_RATE_RA", self._custom[0])
        de = values.get("TRACK_RATE_DE", self._custom[1])
        if abs(ra - SIDEREAL_ARCSEC) > 15000.0 or abs(de) > 15000.0:
            raise Refused(f"TRACK_RATE_RA {ra:g} / TRACK_RATE_DE {de:g}: more than 15000″/s from sidereal")
        self._custom = (float(ra), float(de))
        if self._rate == "TRACK_CUSTOM":
            self._replan()
        self.track_rate.state = "Ok"

    def _apply_rate(self) -> None:
        """POINTING.TARGET.RA_V/DEC_V (arcsec/s against the stars) of the track mode: 0 sidereal,
        the Sun's / Moon's motion now (DE421, as Alpaca's TrackingRate), or the custom rate
        (INDI's TRACK_RATE_RA is the rate of RA tracking: sidereal minus the motion in RA)."""
        p = self.p
        body = RATE_BODIES.get(self._rate)
        if body is not None:
            ra_v, dec_v = body_rates(body, p.astrometry(), p.utc())
        elif self._rate == "TRACK_CUSTOM":
            ra_v, dec_v = SIDEREAL_ARCSEC - self._custom[0], self._custom[1]
        else:
            ra_v, dec_v = 0.0, 0.0
        p.target.set_ra_v(ra_v)
        p.target.set_dec_v(dec_v)

    def _replan(self) -> None:
        """A new rate while tracking: re-planned from the place tracked now (no jump), as
        Alpaca's TrackingRate; otherwise from the next slew or tracking start on."""
        p = self.p
        session = p._tracking()
        here = session.plan.request.place(p.ut1()) if session is not None else None
        if here is None or session.plan.request.target is not None:
            self._apply_rate()
            return
        ra, dec = (float(x) for x in here)
        p.target.set_ra(ra % 24.0)
        p.target.set_dec(dec)
        self._apply_rate()
        p.set_track(p.track)

    def _refresh_rates(self) -> None:
        t = self.p.target
        self.track_rate.element("TRACK_RATE_RA").value = SIDEREAL_ARCSEC - float(t.ra_v)
        self.track_rate.element("TRACK_RATE_DE").value = float(t.dec_v)
        if self.track_rate.state != "Alert":
            self.track_rate.state = "Ok" if self.p.track else "Idle"

    # -- manual motion (INDI's direction keys; Alpaca's MoveAxis) --------------------------------
    def _motion_speed(self, axis) -> float:
        top = float(axis.section.max_velocity)
        for e in self.slew_rate.elements:
            if e.value:
                speed = dict((n, v) for n, _l, v in SLEW_RATES)[e.name]
                return top if speed is None else min(speed, top)
        return min(0.1, top)

    def _motion(self, key: str, vec, values: dict, plus: str, minus: str) -> None:
        a, b = values.get(plus), values.get(minus)
        if a and b:
            raise Refused(f"{vec.name}: one direction at a time")
        old = self._moving.pop(key, None)
        self._motion_failed.pop(key, None)
        if not a and not b:             # both Off: stop
            if old is not None:
                old[0].stop()
            for e in vec.elements:
                e.value = False
            vec.state = "Idle"
            return
        self._not_parked(vec.name)
        p, ops = self.p, self.ops
        north_south = key == "NS"
        axis = p.axis2 if north_south else p.axis1
        if axis.power_state != 1.0 or axis.referenced < 1.0:
            raise Refused(f"{vec.name}: {axis.module_name} is not powered and referenced (UNPARK)")
        if p.track:
            ops.stop_tracking()
        positive = bool(a)               # North / West
        lo = hi = None
        if north_south and p.mount == "AZ-ZD":
            # altitude: North raises the tube to the zenith, South lowers it to the horizon limit
            zd = axis.real_position - axis.offset
            side = 1.0 if zd >= 0.0 else -1.0
            if positive:
                direction, lo, hi = (-1, axis.offset, None) if side > 0 else (1, None, axis.offset)
            else:
                limit = p.zd_limit
                direction, lo, hi = (1, None, axis.offset + limit) if side > 0 else (-1, axis.offset - limit, None)
        elif north_south:
            reverse = bool(p.orientation_in_use())     # the Dec axis turns the other way
            direction = (1 if positive else -1) * (-1 if reverse else 1)
        else:
            direction = 1 if positive else -1          # West: the hour angle / azimuth grows
        try:
            fut = axis.move_toward(direction, self._motion_speed(axis), lo=lo, hi=hi, sky=True)   # + the envelope
        except RangeRefused as exc:
            raise Refused(f"{vec.name}: {exc.message}") from None
        fut.add_done_callback(lambda f: f.cancelled() or f.exception())
        self._moving[key] = (axis, fut)
        vec.element(plus).value, vec.element(minus).value = positive, not positive
        vec.state = "Busy"

    def _refresh_motion(self) -> None:
        for key, vec in (("NS", self.motion_ns), ("WE", self.motion_we)):
            moving = self._moving.get(key)
            if moving is not None and moving[1].done():
                self._moving.pop(key)
                exc = None if moving[1].cancelled() else moving[1].exception()
                if isinstance(exc, TcsError) and exc.number not in (ErrorNumber.TARGETCHANGE, ErrorNumber.MOTIONCHANGE):
                    self._motion_failed[key] = exc.message
                moving = None
            if moving is None:
                for e in vec.elements:
                    e.value = False
                if key in self._motion_failed:
                    vec.state, vec.message = "Alert", self._motion_failed[key]
                elif vec.state != "Alert":
                    vec.state, vec.message = "Idle", None

    def _end_motion(self) -> None:
        for axis, _fut in self._moving.values():
            axis.stop()
        self._moving.clear()

    def new_telescope_motion_ns(self, values: dict) -> None:
        self._motion("NS", self.motion_ns, values, "MOTION_NORTH", "MOTION_SOUTH")

    def new_telescope_motion_we(self, values: dict) -> None:
        self._motion("WE", self.motion_we, values, "MOTION_WEST", "MOTION_EAST")

    def new_telescope_slew_rate(self, values: dict) -> None:
        on = [k for k, v in values.items() if v]
        if len(on) != 1:
            raise Refused("TELESCOPE_SLEW_RATE: exactly one rate")
        for e in self.slew_rate.elements:
            e.value = e.name == on[0]
        self.slew_rate.state = "Ok"

    # -- park position --------------------------------------------------------------------------------
    def _refresh_park_position(self) -> None:
        p = self.p
        parks = {id(a): park for a, park in self.ops.park_positions()}
        if id(p.axis1) not in parks or id(p.axis2) not in parks:
            self.park_position.state = "Idle"
            return
        a1 = parks[id(p.axis1)] - p.axis1.offset
        a2 = parks[id(p.axis2)] - p.axis2.offset
        if p.mount == "AZ-ZD":
            self.park_position.element("PARK_AZ").value = (a1 + 180.0 if a2 < 0.0 else a1) % 360.0
            self.park_position.element("PARK_ALT").value = 90.0 - abs(a2)
        else:
            n1, n2, _rev = to_normal(a1, a2, p.mount)
            self.park_position.element("PARK_RA").value = float(n1) / 15.0
            self.park_position.element("PARK_DEC").value = float(n2)
        self.park_position.state = "Ok"

    def new_telescope_park_option(self, values: dict) -> None:
        if values.get("PARK_CURRENT"):
            self.ops.set_park_here()    # the main axes' positions become the park positions
        self.park_option.state = "Ok"

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
