"""Telescope device (ASCOM ITelescopeV4) over the POINTING module and the telescope's operations.

What maps to what
-----------------
* Coordinates are ICRS J2000 (``EquatorialSystem`` = 2, equJ2000): ``RightAscension`` /
  ``Declination`` are POINTING.CURRENT (the encoders through the inverse pipeline);
  ``Altitude``/``Azimuth`` the observed place of the same encoders with the pointing model
  removed; ``Target…`` are POINTING.TARGET.
* ``SlewToCoordinatesAsync`` / ``SlewToTargetAsync``: POINTING.TARGET, then POINTING.TRACK in
  the orientation that stays inside the limits (normal preferred) — the tracker plans the slew
  and the tracking as one path, so the target is checked against the horizon
  (``[pointing] min_altitude``) and the axis limits before anything moves. As ITelescopeV4
  asks, they need ``Tracking`` True. ``Slewing`` is True until the main axes are on target.
* ``Tracking`` True at rest tracks the place the telescope points at; False is TRACK=0.
* ``SlewToAltAzAsync``: the catalogue object's horizontal position (OpenTSI's
  OBJECT.HORIZONTAL) and the operations' goto; needs ``Tracking`` False.
* ``Park``/``Unpark``/``AtPark``/``SetPark``: the operations' park (the park positions of the
  hardware file, or the ones SetPark saved — shared with OpenTSI's READY=0). Park keeps the
  power on. **Life cycle:** ``AtPark`` is True while the telescope cannot move: parked, or cold
  (a main axis unpowered or unreferenced — a fresh service), or while an ``Unpark`` runs.
  ``Unpark`` is the operator's "make ready" and an asynchronous initiator: it refuses while a
  fault an operator must see is there (a drive fault, a control-process crash, an emergency off:
  InvalidOperation naming it; docs/homing-and-make-ready.md), acknowledges the other latched conditions,
  powers on and references what is not (READY=1)
  in the background and returns at once; ``Slewing`` is True meanwhile (ITelescopeV4's
  completion property), ``AtPark`` too; both go False when the telescope is ready.
  Connecting the telescope moves and powers nothing.
* A slew, park, home or unpark that fails (a drive fault, a limit) is answered once, as a
  DriverError (0x500) with its reason, by the next read of its completion property
  (``Slewing``, ``AtPark``, ``AtHome``). ``Action("AcknowledgeFaults")`` (in
  ``SupportedActions``) acknowledges the latched faults (CABINET.ERROR_STATE=0) without
  powering anything.
* ``FindHome``: the main axes referenced again on their home switches; ``AtHome`` until they move.
* ``PulseGuide``: moves the tracked target by GuideRate × Duration (re-planned at once);
  ``IsPulseGuiding`` for Duration. Guide rates are fixed at half the sidereal rate.
* ``SyncToCoordinates`` / ``SyncToTarget``: a pointing offset — the pointing model's index
  terms (IA/IE, or IH/ID) change so that the current encoders read the given place
  (:meth:`~tcs.model.operations.Operations.sync_to`); refused beyond 10°.
* ``MoveAxis``: axis 0/1 = the main axes, 2 = the derotator at the active port; a rate moves the
  axis at |rate| deg/s in its direction until the limit (tracking ends first), 0 stops it. On an
  alt-az mount axis 1 is altitude: positive raises the tube to the zenith, negative lowers it to
  the horizon limit (``[pointing] min_altitude``). On an equatorial mount the HA and Dec moves
  stop where the telescope would reach that limit too (the bound is computed from the axis
  positions when the move starts: it does not drift with time). Never folded modulo 360°
  (``Axis.move_toward``), and CURRSPEED is left as the operator set it.
* ``SideOfPier``: pierEast (0) in the normal orientation, pierWest (1) in the reverse one.
* ``RightAscensionRate``/``DeclinationRate``: POINTING.TARGET.RA_V/DEC_V (a differential
  rate, from the next slew or tracking start on); only with ``TrackingRate`` sidereal
  (InvalidOperation otherwise, as ITelescopeV4 asks).
* ``TrackingRate``/``TrackingRates``: sidereal (0), lunar (1), solar (2). Lunar and solar are
  not ASCOM's constants: RA_V/DEC_V are the real Moon's / Sun's topocentric motion against
  the stars (DE421, :func:`tcs.pointing.targets.body_rates`, a 10-minute centred difference)
  when tracking starts, at every slew and when the rate is chosen while tracking (then from
  the place being tracked, without a jump); the place pointed at drifts with the body.
  Choosing a rate resets RightAscensionRate/DeclinationRate to 0. King (3) is refused.

Refusals: parked → InvalidWhileParked (0x408); outside the limits or below the horizon, or a
value out of range → InvalidValue (0x401); axes not powered/referenced, an interlock, tracking
in the wrong state → InvalidOperation (0x40B); not connected → NotConnected (0x407).
"""

from __future__ import annotations

import asyncio
import math

import erfa
import numpy as np

from tcs.alpaca.device import Device, axis_ready, need, utc_iso
from tcs.alpaca.protocol import AlpacaRequest, AscomError, Code, not_implemented
from tcs.pointing.orientation import to_normal
from tcs.errors import ErrorNumber, RangeRefused, TcsError
from tcs.pointing.targets import body_rates

SIDEREAL_DEG_S = 360.0 / 86164.0905   # degrees per SI second
GUIDE_RATE = 0.5 * SIDEREAL_DEG_S
SOLAR_TO_SIDEREAL = 1.00273790935
RATE_BODIES = {0: None, 1: "moon", 2: "sun"}   # TrackingRate → body whose motion it follows
TRACK_INSIDE_LIMITS = 2               # POINTING.TRACK mode: the orientation that stays inside
ON_TARGET = 8
SLEW_RULE = ("asynchronous: Slewing True right after until on target (a failure: the next Slewing read "
             "answers it, 0x500)")


#: The rule of the synchronous slews in the generated reference: served (older clients call
#: them), but deprecated for Alpaca and refused by alpyca itself ("Synchronous methods are
#: deprecated, not available via Alpaca"): the documentation's examples use the Async calls.
SYNC_SLEW_RULE = ("synchronous: returns on target (Slewing False right after). Deprecated: alpyca "
                  "refuses it on the client side; call {name}Async and poll Slewing")


class TelescopeDevice(Device):
    TYPE = "telescope"
    NAME = "Telescope"
    INTERFACE_VERSION = 4
    MEMBERS = (
        "alignmentmode", "altitude", "aperturearea", "aperturediameter", "athome", "atpark",
        "azimuth", "canfindhome", "canpark", "canpulseguide", "cansetdeclinationrate",
        "cansetguiderates", "cansetpark", "cansetpierside", "cansetrightascensionrate",
        "cansettracking", "canslew", "canslewaltaz", "canslewaltazasync", "canslewasync",
        "cansync", "cansyncaltaz", "canunpark", "declination", "declinationrate",
        "doesrefraction", "equatorialsystem", "focallength", "guideratedeclination",
        "guideraterightascension", "ispulseguiding", "rightascension", "rightascensionrate",
        "sideofpier", "siderealtime", "siteelevation", "sitelatitude", "sitelongitude",
        "slewing", "slewsettletime", "targetdeclination", "targetrightascension", "tracking",
        "trackingrate", "trackingrates", "utcdate", "axisrates", "canmoveaxis",
        "destinationsideofpier", "abortslew", "findhome", "moveaxis", "park", "pulseguide",
        "setpark", "slewtoaltaz", "slewtoaltazasync", "slewtocoordinates",
        "slewtocoordinatesasync", "slewtotarget", "slewtotargetasync", "synctoaltaz",
        "synctocoordinates", "synctotarget", "unpark")
    STATE = ("altitude", "athome", "atpark", "azimuth", "declination", "ispulseguiding",
             "rightascension", "sideofpier", "siderealtime", "slewing", "tracking", "utcdate")
    PARAMETERS = {
        "get_canmoveaxis": (("Axis", "int"),),
        "get_axisrates": (("Axis", "int"),),
        "get_destinationsideofpier": (("RightAscension", "float"), ("Declination", "float")),
        "put_moveaxis": (("Axis", "int"), ("Rate", "float")),
        "put_pulseguide": (("Direction", "int"), ("Duration", "int")),
        "put_sideofpier": (("SideOfPier", "int"),),
        "put_sitelatitude": (("SiteLatitude", "float"),),
        "put_sitelongitude": (("SiteLongitude", "float"),),
        "put_siteelevation": (("SiteElevation", "float"),),
        "put_utcdate": (("UTCDate", "text"),),
        "put_doesrefraction": (("DoesRefraction", "bool"),),
        "put_tracking": (("Tracking", "bool"),),
        "put_trackingrate": (("TrackingRate", "int"),),
        "put_rightascensionrate": (("RightAscensionRate", "float"),),
        "put_declinationrate": (("DeclinationRate", "float"),),
        "put_guideraterightascension": (("GuideRateRightAscension", "float"),),
        "put_guideratedeclination": (("GuideRateDeclination", "float"),),
        "put_slewsettletime": (("SlewSettleTime", "int"),),
        "put_targetrightascension": (("TargetRightAscension", "float"),),
        "put_targetdeclination": (("TargetDeclination", "float"),),
        "put_slewtocoordinates": (("RightAscension", "float"), ("Declination", "float")),
        "put_slewtocoordinatesasync": (("RightAscension", "float"), ("Declination", "float")),
        "put_synctocoordinates": (("RightAscension", "float"), ("Declination", "float")),
        "put_slewtoaltaz": (("Azimuth", "float"), ("Altitude", "float")),
        "put_slewtoaltazasync": (("Azimuth", "float"), ("Altitude", "float")),
    }
    RULES = {
        "slewtocoordinatesasync": SLEW_RULE,
        "slewtotargetasync": SLEW_RULE,
        "slewtoaltazasync": SLEW_RULE,
        "slewtocoordinates": SYNC_SLEW_RULE.format(name="SlewToCoordinates"),
        "slewtotarget": SYNC_SLEW_RULE.format(name="SlewToTarget"),
        "slewtoaltaz": SYNC_SLEW_RULE.format(name="SlewToAltAz"),
        "abortslew": "synchronous: the motion is stopped at the reply; Slewing True while the axes brake",
        "park": "asynchronous: Slewing True, AtPark False right after until parked (then AtPark True)",
        "unpark": "asynchronous: Slewing True and AtPark True right after until ready, then both False "
                  "(at once when it was only parked)",
        "findhome": "asynchronous: Slewing True, AtHome False right after until at home",
        "moveaxis": "asynchronous: Slewing True right after (a rate) until stopped; 0 stops (Slewing True "
                    "while braking)",
        "pulseguide": "asynchronous: IsPulseGuiding True right after for Duration",
        "tracking": "synchronous: Tracking reads the new value right after (Slewing True while it reaches the place)",
        "synctocoordinates": "synchronous: RightAscension/Declination read the place right after",
        "synctotarget": "synchronous: as SyncToCoordinates",
        "setpark": "synchronous: the park position is saved at the reply",
        "targetrightascension": "synchronous", "targetdeclination": "synchronous",
        "rightascensionrate": "synchronous", "declinationrate": "synchronous",
        "doesrefraction": "synchronous", "trackingrate": "synchronous",
        "sideofpier": "NotImplemented", "sitelatitude": "NotImplemented", "sitelongitude": "NotImplemented",
        "siteelevation": "NotImplemented", "utcdate": "NotImplemented",
        "guideraterightascension": "NotImplemented", "guideratedeclination": "NotImplemented",
        "slewsettletime": "NotImplemented",
    }
    STATE_NAMES = {"altitude": "Altitude", "athome": "AtHome", "atpark": "AtPark", "azimuth": "Azimuth",
                   "declination": "Declination", "ispulseguiding": "IsPulseGuiding",
                   "rightascension": "RightAscension", "sideofpier": "SideOfPier",
                   "siderealtime": "SiderealTime", "slewing": "Slewing", "tracking": "Tracking",
                   "utcdate": "UTCDate"}

    def __init__(self, *args, **kw):
        super().__init__(*args, **kw)
        self._moving_axes: set = set()   # axes a MoveAxis sent towards a limit (speed to restore)
        self._rate = 0                   # TrackingRate: 0 sidereal, 1 lunar, 2 solar

    # -- parts of the model ----------------------------------------------------------------------
    @property
    def ops(self):
        return self.telescope.operations

    @property
    def p(self):
        p = self.telescope.pointing
        if p is None:
            raise AscomError(Code.INVALID_OPERATION, "this telescope has no POINTING module")
        return p

    def _parked(self) -> bool:
        """AtPark: parked, cold (a main axis unpowered or unreferenced) or being unparked."""
        if self.ops.at_park or self.running("unpark"):
            return True
        return any(a.power_state != 1.0 or a.referenced < 1.0 for a in self.ops.main_axes())

    def _not_parked(self, what: str) -> None:
        if self._parked():
            raise AscomError(Code.INVALID_WHILE_PARKED, f"{what}: the telescope is parked or not ready "
                                                        "(Unpark makes it ready)")

    # -- actions ----------------------------------------------------------------------------------
    ACTIONS = ("AcknowledgeFaults",)

    def get_supportedactions(self, r) -> list[str]:
        return list(self.ACTIONS)

    async def put_action(self, r) -> str:
        name = r.text("Action")
        r.text("Parameters")
        if name.lower() != "acknowledgefaults":
            raise AscomError(Code.ACTION_NOT_IMPLEMENTED, f"action {name!r} is not supported "
                                                          f"(SupportedActions: {', '.join(self.ACTIONS)})")
        self._failure = None
        result = self.telescope.cabinet.acknowledge_errors(0)
        if result is not None:   # drive fault resets: wait for them (a few cycles)
            await asyncio.wait_for(asyncio.shield(asyncio.ensure_future(result)), 10.0)
        return "acknowledged"

    # -- capabilities ----------------------------------------------------------------------------
    def get_alignmentmode(self, r) -> int:
        return 0 if self.telescope.config.mount.type == "AZ-ZD" else 1   # algAltAz / algPolar

    def get_canfindhome(self, r) -> bool:
        return True

    def get_canpark(self, r) -> bool:
        return True

    def get_canunpark(self, r) -> bool:
        return True

    def get_cansetpark(self, r) -> bool:
        return True

    def get_canpulseguide(self, r) -> bool:
        return True

    def get_cansetdeclinationrate(self, r) -> bool:
        return True

    def get_cansetrightascensionrate(self, r) -> bool:
        return True

    def get_cansetguiderates(self, r) -> bool:
        return False

    def get_cansetpierside(self, r) -> bool:
        return False

    def get_cansettracking(self, r) -> bool:
        return True

    def get_canslew(self, r) -> bool:
        return True

    def get_canslewasync(self, r) -> bool:
        return True

    def get_canslewaltaz(self, r) -> bool:
        return True

    def get_canslewaltazasync(self, r) -> bool:
        return True

    def get_cansync(self, r) -> bool:
        return True

    def get_cansyncaltaz(self, r) -> bool:
        return False

    def _move_axes(self) -> list:
        p = self.telescope.pointing
        axes = [p.axis1, p.axis2] if p is not None else []
        if p is not None:
            try:
                axes.append(p.active_derotator()[0])
            except Exception:   # no derotator: no tertiary axis
                pass
        return axes

    def _axis_number(self, r) -> int:
        n = r.int("Axis")
        if not 0 <= n <= 2:
            raise AscomError(Code.INVALID_VALUE, f"Axis {n} is not 0, 1 or 2")
        return n

    def get_canmoveaxis(self, r) -> bool:
        return self._axis_number(r) < len(self._move_axes())

    def get_axisrates(self, r) -> list[dict]:
        n = self._axis_number(r)
        axes = self._move_axes()
        if n >= len(axes):
            return []
        return [{"Minimum": 0.0, "Maximum": float(axes[n].section.max_velocity)}]

    # -- where it points --------------------------------------------------------------------------
    def get_rightascension(self, r) -> float:
        self.ops.check_fresh()
        return float(self.p.current.ra)

    def get_declination(self, r) -> float:
        self.ops.check_fresh()
        return float(self.p.current.dec)

    def _altaz(self) -> tuple[float, float]:
        self.ops.check_fresh()  # (no fresh readback: an error, not the last position)
        p = self.p
        place = p.place()
        if p.mount == "AZ-ZD":  # (to_normal of one position, without numpy)
            a1, a2 = float(place.ideal1), float(place.ideal2)
            return (a1 + 180.0 if a2 < 0.0 else a1) % 360.0, 90.0 - abs(a2)
        n1, n2, _rev = to_normal(place.ideal1, place.ideal2, p.mount)
        az, alt = erfa.hd2ae(math.radians(float(n1)), math.radians(float(n2)), math.radians(p.latitude))
        return math.degrees(float(az)) % 360.0, math.degrees(float(alt))

    def get_altitude(self, r) -> float:
        return self._altaz()[1]

    def get_azimuth(self, r) -> float:
        return self._altaz()[0]

    def get_siderealtime(self, r) -> float:
        return float(self.p.sidereal_time)

    def get_equatorialsystem(self, r) -> int:
        return 2   # equJ2000 (ICRS)

    def get_sideofpier(self, r) -> int:
        return 1 if self.p.orientation_in_use() else 0

    def put_sideofpier(self, r) -> None:
        r.int("SideOfPier")
        raise not_implemented("setting SideOfPier")

    def get_destinationsideofpier(self, r) -> int:
        """The side the slew to (ra, dec) will end on: the tracker's own plan (the pier-side
        policy of POINTING.TRACK mode 2, the envelope) when the axes are ready — so that
        SideOfPier reads the same once the slew ended; pierUnknown (-1) for a slew that would
        be refused. Axes not ready: the first orientation inside the limits."""
        ra, dec = self._radec(r, "RightAscension", "Declination")
        p = self.p
        try:
            plan = p.plan_for(ra, dec, TRACK_INSIDE_LIMITS)
        except TcsError as exc:
            if exc.number != ErrorNumber.INVMODE:
                return -1   # pierUnknown: the slew would be refused
        else:
            return 1 if plan.reverse else 0
        d_utc = p.utc()
        pipe = p.pipeline()
        for reverse in (False, True):
            d = pipe.demand(ra, dec, d_utc, reverse)
            if (p.axis2.limits.contains(float(d.axis2[0])) and 90.0 - float(d.observed.zd[0]) >= p.config.min_altitude
                    and self._axis1_reachable(p.axis1, float(d.axis1[0]))):
                return 1 if reverse else 0
        return -1   # pierUnknown: unreachable

    @staticmethod
    def _axis1_reachable(axis, value: float) -> bool:
        cycle = axis.section.cyclic
        if not cycle:
            return axis.limits.contains(value)
        return any(axis.limits.contains(value + k * cycle) for k in range(-3, 4))

    # -- site and time ----------------------------------------------------------------------------
    def get_sitelatitude(self, r) -> float:
        return float(self.telescope.local.latitude)

    def get_sitelongitude(self, r) -> float:
        return float(self.telescope.local.longitude)

    def get_siteelevation(self, r) -> float:
        return float(self.telescope.local.height)

    def put_sitelatitude(self, r) -> None:
        r.float("SiteLatitude")
        raise not_implemented("setting SiteLatitude (the site is the hardware file's and the GPS's)")

    def put_sitelongitude(self, r) -> None:
        r.float("SiteLongitude")
        raise not_implemented("setting SiteLongitude (the site is the hardware file's and the GPS's)")

    def put_siteelevation(self, r) -> None:
        r.float("SiteElevation")
        raise not_implemented("setting SiteElevation (the site is the hardware file's and the GPS's)")

    def get_utcdate(self, r) -> str:
        return utc_iso(self.telescope.local.utc())

    def put_utcdate(self, r) -> None:
        r.text("UTCDate")
        raise not_implemented("setting UTCDate (the time comes from the cabinet clock and GPS)")

    def get_doesrefraction(self, r) -> bool:
        return self.p.refraction.mode != 0

    def put_doesrefraction(self, r) -> None:
        on = r.bool("DoesRefraction")
        refraction = self.p.refraction
        if on != (refraction.mode != 0):
            refraction.set_mode(1 if on else 0)

    # -- rates ------------------------------------------------------------------------------------
    def get_tracking(self, r) -> bool:
        return bool(self.p.track)

    def put_tracking(self, r) -> None:
        on = r.bool("Tracking")
        p = self.p
        if not on:
            if p.track:
                self.ops.stop_tracking()
            return
        self._not_parked("Tracking")
        if p.track:
            return
        place = p.place()
        self._track(place.ra, place.dec, 3 if place.reverse else 1)

    def get_trackingrate(self, r) -> int:
        return self._rate

    def put_trackingrate(self, r) -> None:
        rate = r.int("TrackingRate")
        if rate not in RATE_BODIES:
            raise AscomError(Code.INVALID_VALUE, f"TrackingRate {rate}: sidereal (0), lunar (1) "
                                                 "and solar (2) are supported")
        p = self.p
        self._rate = rate
        session = p._tracking()
        here = session.plan.request.place(p.ut1()) if session is not None else None
        p.target.set_ra_v(0.0)            # the offsets go; a body's rates come in _apply_rate
        p.target.set_dec_v(0.0)
        if here is not None and session.plan.request.target is None:
            ra, dec = (float(x) for x in here)
            p.target.set_ra(ra % 24.0)
            p.target.set_dec(dec)
            self._apply_rate()
            p.set_track(p.track)          # re-planned from where it is, at the new rate

    def get_trackingrates(self, r) -> list[int]:
        return list(RATE_BODIES)

    def _apply_rate(self) -> None:
        """Lunar / solar: RA_V/DEC_V = the body's motion against the stars now."""
        body = RATE_BODIES.get(self._rate)
        if body is None:
            return
        p = self.p
        ra_v, dec_v = body_rates(body, p.astrometry(), p.utc())
        p.target.set_ra_v(ra_v)
        p.target.set_dec_v(dec_v)

    def _sidereal_only(self, what: str, value: float) -> None:
        if self._rate != 0 and value != 0.0:
            raise AscomError(Code.INVALID_OPERATION, f"{what}: an offset only applies to the "
                                                     "sidereal TrackingRate")

    def get_rightascensionrate(self, r) -> float:
        if self._rate != 0:
            return 0.0
        # RA_V: arcsec of RA per SI second → seconds of RA per sidereal second
        return float(self.p.target.ra_v) / 15.0 * SOLAR_TO_SIDEREAL

    def put_rightascensionrate(self, r) -> None:
        value = r.float("RightAscensionRate")
        self._sidereal_only("RightAscensionRate", value)
        if abs(value) > 1000.0:
            raise AscomError(Code.INVALID_VALUE, f"RightAscensionRate {value} is beyond ±1000 s/sidereal s")
        self.p.target.set_ra_v(value * 15.0 / SOLAR_TO_SIDEREAL)

    def get_declinationrate(self, r) -> float:
        return 0.0 if self._rate != 0 else float(self.p.target.dec_v)

    def put_declinationrate(self, r) -> None:
        value = r.float("DeclinationRate")
        self._sidereal_only("DeclinationRate", value)
        if abs(value) > 15000.0:
            raise AscomError(Code.INVALID_VALUE, f"DeclinationRate {value} is beyond ±15000 arcsec/s")
        self.p.target.set_dec_v(value)

    def get_guideraterightascension(self, r) -> float:
        return GUIDE_RATE

    def get_guideratedeclination(self, r) -> float:
        return GUIDE_RATE

    def put_guideraterightascension(self, r) -> None:
        r.float("GuideRateRightAscension")
        raise not_implemented("setting GuideRateRightAscension")

    def put_guideratedeclination(self, r) -> None:
        r.float("GuideRateDeclination")
        raise not_implemented("setting GuideRateDeclination")

    def get_slewsettletime(self, r) -> int:
        return 0

    def put_slewsettletime(self, r) -> None:
        value = r.int("SlewSettleTime")
        if value < 0:
            raise AscomError(Code.INVALID_VALUE, f"SlewSettleTime {value} is negative")
        raise not_implemented("setting SlewSettleTime (the tracker reports on target itself)")

    # -- state ------------------------------------------------------------------------------------
    def get_atpark(self, r) -> bool:
        self.report_failure()
        return self._parked()

    def get_athome(self, r) -> bool:
        self.report_failure()
        return bool(self.ops.at_home)

    def get_ispulseguiding(self, r) -> bool:
        return bool(self.ops.pulse_guiding)

    def get_slewing(self, r) -> bool:
        self.report_failure()
        if self.running("unpark"):   # ITelescopeV4: Unpark completes when Slewing is False
            return True
        self.ops.check_fresh()
        p = self.telescope.pointing
        ops = self.ops
        if self.running("slew") and not (p is not None and p.track):
            # the slew ended (a fault stops the tracking) but its operation has not yet: its
            # failure reaches the next read — never a False that reads as "arrived" before it
            return True
        if p is not None and p.track:
            # on target: every main axis in its window on the current path (the axes' bits can
            # lag a re-plan by a cycle, so the distance to the demand is checked too)
            window = max(p.axis1.section.tolerance, p.axis2.section.tolerance)
            return not (ops.motion_state & ON_TARGET) or p.targetdistance > window
        if ops.running in ("goto", "alpaca-park", "park", "home"):
            return True
        if self._moving_axes:   # a MoveAxis at a rate: slewing from the reply on
            return True
        if any(a.motion_state & 1 for a in self._move_axes()):
            return True
        return False

    # -- targets ----------------------------------------------------------------------------------
    def _radec(self, r, ra_name: str, dec_name: str) -> tuple[float, float]:
        ra, dec = r.float(ra_name), r.float(dec_name)
        need(0.0 <= ra < 24.0, Code.INVALID_VALUE, f"{ra_name} {ra} is outside 0 <= RA < 24")
        need(-90.0 <= dec <= 90.0, Code.INVALID_VALUE, f"{dec_name} {dec} is outside -90…90")
        return ra, dec

    def get_targetrightascension(self, r) -> float:
        t = self.p.target
        need(t.complete, Code.VALUE_NOT_SET, "TargetRightAscension has not been set")
        return float(t.ra)

    def get_targetdeclination(self, r) -> float:
        t = self.p.target
        need(t.complete, Code.VALUE_NOT_SET, "TargetDeclination has not been set")
        return float(t.dec)

    def put_targetrightascension(self, r) -> None:
        value = r.float("TargetRightAscension")
        need(0.0 <= value < 24.0, Code.INVALID_VALUE, f"TargetRightAscension {value} is outside 0…24")
        self.p.target.set_ra(value)

    def put_targetdeclination(self, r) -> None:
        value = r.float("TargetDeclination")
        need(-90.0 <= value <= 90.0, Code.INVALID_VALUE, f"TargetDeclination {value} is outside -90…90")
        self.p.target.set_dec(value)

    # -- slews ------------------------------------------------------------------------------------
    def _track(self, ra: float, dec: float, mode: int) -> None:
        """Point POINTING.TARGET at (ra, dec) and track it; the old target comes back if refused."""
        p = self.p
        target = p.target
        old = (target.ra, target.dec) if target.complete else None
        self._end_moves()
        target.set_ra(ra)
        target.set_dec(dec)
        self._apply_rate()
        try:
            result = p.set_track(mode)
        except Exception:
            if old is not None:
                target.set_ra(old[0])
                target.set_dec(old[1])
            raise
        self.start_operation("slew", result, "the slew")

    def _slew_checks(self, what: str) -> None:
        self._not_parked(what)
        if not self.p.track:
            raise AscomError(Code.INVALID_OPERATION, f"{what} needs Tracking True")

    def put_slewtocoordinatesasync(self, r) -> None:
        ra, dec = self._radec(r, "RightAscension", "Declination")
        self._slew_checks("SlewToCoordinatesAsync")
        self._track(ra, dec, TRACK_INSIDE_LIMITS)

    async def put_slewtocoordinates(self, r) -> None:
        self.put_slewtocoordinatesasync(r)
        await self._until_slewed(r)

    def put_slewtotargetasync(self, r) -> None:
        t = self.p.target
        need(t.complete, Code.INVALID_OPERATION, "no target: set TargetRightAscension and TargetDeclination")
        self._slew_checks("SlewToTargetAsync")
        self._track(t.ra, t.dec, TRACK_INSIDE_LIMITS)

    async def put_slewtotarget(self, r) -> None:
        self.put_slewtotargetasync(r)
        await self._until_slewed(r)

    def put_slewtoaltazasync(self, r) -> None:
        az, alt = r.float("Azimuth"), r.float("Altitude")
        need(0.0 <= az < 360.0, Code.INVALID_VALUE, f"Azimuth {az} is outside 0…360")
        need(-90.0 <= alt <= 90.0, Code.INVALID_VALUE, f"Altitude {alt} is outside -90…90")
        self._not_parked("SlewToAltAzAsync")
        if self.p.track:
            raise AscomError(Code.INVALID_OPERATION, "SlewToAltAzAsync needs Tracking False")
        self.ops.horizontal_demand(az, alt)   # refuses below the horizon / outside the limits
        self._end_moves()
        obj = self.ops.object
        obj.set_az(az)
        obj.set_alt(alt)
        self.start_operation("slew", self.ops.goto_horizontal(), "the slew")

    async def put_slewtoaltaz(self, r) -> None:
        self.put_slewtoaltazasync(r)
        await self._until_slewed(r)

    async def _until_slewed(self, r, timeout: float = 600.0) -> None:
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        await asyncio.sleep(0.05)
        while self.get_slewing(r):
            if loop.time() > deadline:
                raise AscomError(Code.DRIVER_ERROR, "the slew did not end in time")
            await asyncio.sleep(0.05)

    def put_abortslew(self, r) -> None:
        ops = self.ops
        if self.running("unpark"):   # aborting the make-ready: it stops where it is
            self.drop_operation("unpark")
            ops.halt()
            return
        self._not_parked("AbortSlew")
        for key in ("slew", "park", "home"):
            self.drop_operation(key)
        p = self.telescope.pointing
        self._end_moves()
        if p is not None and p.track:
            ops.stop_tracking()
        ops.halt()
        axes = self._move_axes()
        for axis in axes[:2]:   # also a move commanded an instant ago, not yet seen moving
            axis.stop()
        for axis in axes[2:]:
            if axis.motion_state & 1:
                axis.stop()

    def put_moveaxis(self, r) -> None:
        n = self._axis_number(r)
        rate = r.float("Rate")
        self._not_parked("MoveAxis")
        axes = self._move_axes()
        if n >= len(axes):
            raise AscomError(Code.INVALID_VALUE, f"axis {n} cannot be moved")
        axis = axes[n]
        top = float(axis.section.max_velocity)
        need(abs(rate) <= top, Code.INVALID_VALUE, f"Rate {rate} is outside ±{top} deg/s (AxisRates)")
        p = self.telescope.pointing
        if p is not None and p.track and n < 2:
            self.ops.stop_tracking()
        if rate == 0.0:
            axis.stop()
            self._moving_axes.discard(axis)
            return
        axis_ready(axis, "MoveAxis")
        direction, lo, hi = self._move_bounds(n, axis, rate)
        try:
            fut = axis.move_toward(direction, abs(rate), lo=lo, hi=hi, sky=True)   # (+ the envelope)
        except RangeRefused as exc:
            raise AscomError(Code.INVALID_VALUE, f"MoveAxis({n}, {rate:g}): {exc.message}") from None
        self._moving_axes.add(axis)
        fut.add_done_callback(lambda f, a=axis: (self._moving_axes.discard(a), f.cancelled() or f.exception()))

    def _move_bounds(self, n: int, axis, rate: float) -> tuple[int, float | None, float | None]:
        """(drive direction, lowest, highest drive position) of ``MoveAxis(n, rate)``.

        Axis 1 of an alt-az mount is **altitude** (ASCOM): a positive rate raises the
        telescope — towards the zenith (ZD 0) on the side the tube is (normal or reverse
        orientation), where altitude has its end — and a negative rate lowers it down to the
        horizon limit (``[pointing] min_altitude``, the limit SlewToAltAz keeps), never below.
        Both ends are judged on ``CURRPOS`` (the drive position less the axis ``OFFSET``) and
        returned as drive positions (``OFFSET`` + the bound). Every other axis: a positive rate
        increases the axis position, to its software limit (a wrapping axis is not folded
        modulo 360°)."""
        p = self.telescope.pointing
        if n == 1 and p is not None and p.mount == "AZ-ZD" and axis is p.axis2:
            zd = axis.real_position - axis.offset
            side = 1.0 if zd >= 0.0 else -1.0
            if rate > 0:        # up: |ZD| decreases, to the zenith
                return (-1, axis.offset, None) if side > 0 else (1, None, axis.offset)
            limit = p.zd_limit  # down: |ZD| increases, to the horizon limit
            return (1, None, axis.offset + limit) if side > 0 else (-1, axis.offset - limit, None)
        direction = 1 if rate > 0 else -1
        if n < 2 and p is not None and p.mount == "RA-DEC" and axis in (p.axis1, p.axis2):
            bound = self._horizon_bound(axis, direction)
            return (direction, None, bound) if direction > 0 else (direction, bound, None)
        return direction, None, None

    #: sampling step (degrees) of the path a MoveAxis of an equatorial axis would take
    HORIZON_STEP = 0.1

    def _horizon_bound(self, axis, direction: int) -> float | None:
        """Equatorial mount: the axis position (REALPOS frame) where ``MoveAxis`` of ``axis`` in
        ``direction``, the other axis standing, takes the telescope down to the horizon limit
        (``[pointing] min_altitude``), or None when it stays above it up to the software limit.

        The altitude of HA/Dec axis positions does not change with time, so the bound found
        now holds for the whole move: the axis plans its stop to end there (the normal
        deceleration, no overshoot), as the ZD of an alt-az mount stops at ``zd_limit``. The
        path is sampled every :attr:`HORIZON_STEP` through the pointing model (model removed,
        as ``Altitude`` reads) and the crossing refined by bisection. Already below the limit,
        only a direction that raises the telescope is allowed (until it would sink again)."""
        p = self.p
        floor = float(p.config.min_altitude)
        other = p.axis2 if axis is p.axis1 else p.axis1
        here = float(axis.real_position)
        end = float(axis.section.max if direction > 0 else axis.section.min)
        if (end - here) * direction <= 0:
            return None   # (move_toward refuses: at the limit already)
        fixed = float(other.real_position)

        def altitude(positions):
            pos = np.asarray(positions, float)
            still = np.full_like(pos, fixed)
            r1, r2 = (pos, still) if axis is p.axis1 else (still, pos)
            i1, i2 = p.pipeline().model.invert(r1, r2)
            n1, n2, _rev = to_normal(i1, i2, "RA-DEC")
            _az, alt = erfa.hd2ae(np.radians(n1), np.radians(n2), math.radians(p.latitude))
            return np.degrees(alt)

        count = int(abs(end - here) / self.HORIZON_STEP) + 2
        path = np.linspace(here, end, count)
        alt = altitude(path)
        below = alt < floor
        start = 0
        if below[0]:
            if alt[1] <= alt[0]:
                raise AscomError(Code.INVALID_VALUE, f"MoveAxis: the telescope is below the horizon "
                                                     f"limit {floor:g}° and this direction lowers it")
            up = np.nonzero(~below)[0]
            if not up.size:
                return None
            start = int(up[0])
        sinking = np.nonzero(below[start:])[0]
        if not sinking.size:
            return None
        i = start + int(sinking[0])
        above, under = float(path[i - 1]), float(path[i])
        for _ in range(30):   # to ~1e-10 degrees
            mid = 0.5 * (above + under)
            if altitude([mid])[0] >= floor:
                above = mid
            else:
                under = mid
        return above

    def _end_moves(self) -> None:
        for axis in list(self._moving_axes):
            axis.stop()
        self._moving_axes.clear()

    # -- park, home -------------------------------------------------------------------------------
    def put_park(self, r) -> None:
        if self._parked():
            return
        self._end_moves()
        self.start_operation("park", self.ops.park(), "Park")

    def put_unpark(self, r) -> None:
        """Make ready (asynchronous): READY=1 when the telescope is not operational — refused
        (InvalidOperation, naming them) while a fault an operator must see is active or latched
        (a drive fault, a control-process crash, an emergency off: the operator acknowledges
        those, e.g. Action AcknowledgeFaults); other latched conditions it acknowledges
        (:meth:`~tcs.model.operations.Operations.check_make_ready`). AtPark stays True until
        the telescope is ready."""
        if self.running("unpark"):
            return
        ops = self.ops
        try:
            ops.check_make_ready("Unpark")
        except TcsError as exc:
            raise AscomError(Code.INVALID_OPERATION, exc.message) from None
        self._failure = None
        job = ops.unpark()       # raises at once when it cannot start
        self.start_operation("unpark", job, "Unpark")

    def put_setpark(self, r) -> None:
        self.ops.set_park_here()

    def put_findhome(self, r) -> None:
        self._not_parked("FindHome")
        self._end_moves()
        self.start_operation("home", self.ops.find_home(), "FindHome")

    # -- guiding, sync ----------------------------------------------------------------------------
    def put_pulseguide(self, r) -> None:
        direction = r.int("Direction")
        duration = r.int("Duration")
        need(0 <= direction <= 3, Code.INVALID_VALUE, f"Direction {direction} is not 0…3")
        need(0 <= duration <= 3_600_000, Code.INVALID_VALUE, f"Duration {duration} ms is outside 0…3600000")
        self._not_parked("PulseGuide")
        if not self.p.track:
            raise AscomError(Code.INVALID_OPERATION, "PulseGuide needs Tracking True")
        self.ops.pulse_guide(direction, duration / 1000.0, GUIDE_RATE)

    def put_synctocoordinates(self, r) -> None:
        ra, dec = self._radec(r, "RightAscension", "Declination")
        self._not_parked("SyncToCoordinates")
        self._sync(ra, dec)

    def put_synctotarget(self, r) -> None:
        t = self.p.target
        need(t.complete, Code.INVALID_OPERATION, "no target: set TargetRightAscension and TargetDeclination")
        self._not_parked("SyncToTarget")
        self._sync(t.ra, t.dec)

    def _sync(self, ra: float, dec: float) -> None:
        p = self.p
        for axis in (p.axis1, p.axis2):
            if axis.referenced < 1.0:
                raise AscomError(Code.INVALID_OPERATION, f"Sync: {axis.module_name} is not referenced")
        self.ops.sync_to(ra, dec)
        if p.track:   # go on tracking the synced place from where the telescope stands
            p.target.set_ra(ra)
            p.target.set_dec(dec)
            p.set_track(p.track)
