"""The POINTING module (OpenTCI §14): :class:`Pointing` and its TARGET, CURRENT, REFRACTION.

How it works
------------
The module points the telescope at sidereal ICRS (J2000) positions by the spec's three steps —
astrometry with refraction, then the pointing model (:class:`~tcs.pointing.demand.Pipeline`)
— and tracks them by streaming trajectories into the axes
(:class:`~tcs.pointing.tracker.TrackSession`).

Mounts: AZ-ZD (axes AZ and ZD; TARGET/CURRENT have DA and a plain DZ) and RA-DEC (axes HA and
DEC in degrees; DH and DD). A ZD-ZD mount has no POINTING module (not supported), nor has a
telescope without its two main axes.

Units (docs/opentci-notes.md): RA, HA and SIDEREAL_TIME in hours; DEC, PA, the corrections
DA/DZ/DH/DD, TARGETDISTANCE and DOME_DEVIATION in degrees; SLEWINGTIME in seconds.

* **TARGET**: RA (0 ≤ RA < 24) and DEC (−90…90) are written; HA, PA, the model's corrections
  at the target (DA/DZ or DH/DD, in the orientation in use) and SIDEREAL_TIME are computed for
  now. A new TARGET is used by the next TRACK write (also while tracking).
* **CURRENT**: from the encoders: the main axes' REALPOS (including OFFSET) through the
  inverse of the whole pipeline (model inverse, orientation, exact inverse astrometry).
  While tracking with no OFFSET, CURRENT ≈ TARGET; an OFFSET shows as the difference.
* **TRACK** (long-running from 0): 1 normal, 2 orientation chosen to stay inside the limits
  (normal preferred), 3 reverse (negative ZD / Dec beyond the pole), 4 shortest slew; 2 and 4
  read back 1 or 3. Flag 256: the derotator at the active port (MIRROR's position where there
  is a MIRROR, else the first derotator) follows the field rotation
  (:func:`~tcs.pointing.demand.field_angle`). Flag 128: DOME[0] (a rotating dome's slit
  azimuth) is moved to the target's azimuth whenever it deviates by more than DOME_DEVIATION
  (degrees, persisted, default 2); refused with FAILED 5 without a rotating dome or with
  DOME[0] not powered. Refusals and endings: see
  :mod:`tcs.pointing.tracker` (target below ``[pointing] min_altitude`` or outside the axis
  limits: FAILED 9; axes not ready: FAILED 5; the TRACK SET of a tracking that was ended by
  STOP: FAILED 10, by the target setting: FAILED 9 with an event). An ABORT of the TRACK SET
  ends only its wait; tracking goes on until TRACK=0 or STOP.
* **TARGETDISTANCE**: while tracking, the largest distance of the controlled axes from their
  demand: the two main axes together as an angle on the sky (AZ scaled by sin ZD, HA by
  cos Dec), a synchronised derotator by its own angle; otherwise — also from a TRACK write
  until the axes run the new path — the angle on the sky between TARGET and CURRENT (0
  without a target). So a client may poll it right after its TRACK write.
* **SLEWINGTIME**: seconds until the controlled axes reach the demand, the longest of each
  axis's rest-to-rest time over its distance (0 for an axis on its path).
* **REFRACTION** (§14.3): MODE 0 none, 1 defaults (10 °C, 1010 hPa reduced to the site height),
  2 TEMPERATURE/PRESSURE; values persisted, initial values from ``[pointing]``.
* POINTINGPARAMS: :mod:`tcs.pointing.pointing_params`.

Changes of model or refraction re-plan a running tracking at once, in the same orientation.
LOCAL's site and time base are read at every computation (a change applies from the next
refill of the trajectory queues).

What may touch it
-----------------
The event loop only (tree getters/setters, the cabinet's STOP, the telescope's stop).
"""

from __future__ import annotations

import asyncio
import logging
import math
from pathlib import Path
import erfa

from tcs.axes.profile import theoretical_minimum_time
from tcs.errors import ErrorNumber, RangeRefused, TcsError, gather_all
from tcs.model.events import current_cause
from tcs.model.health import ModuleHealth
from tcs.pointing.astrometry import Astrometry, Refraction, Site, TimeBase
from tcs.pointing.demand import Pipeline, Place
from tcs.pointing.envelope import Envelope
from tcs.pointing.model import PointingModel, Sample
from tcs.pointing.orientation import to_normal
from tcs.pointing.pointing_params import PointingParams
from tcs.pointing.storage import DumpHeader
from tcs.pointing.tracker import (FLAG_DEROTATOR, FLAG_DOME, Plan, TrackRequest, TrackSession,
                                  parse_track, plan_track)

log = logging.getLogger(__name__)

__all__ = ["Pointing", "Target", "Current", "RefractionSettings", "make_pointing", "MAIN_AXES"]

MAIN_AXES = {"AZ-ZD": ("AZ", "ZD"), "RA-DEC": ("HA", "DEC")}
_ON_TARGET = 8   # MOTION_STATE bit 3


def _distance(axis, ut1: float) -> float:
    """Demand of a trajectory-running axis (path + OFFSET) minus REALPOS, both at the time the
    drive measured REALPOS (``ut1`` when the axis has not published yet).

    (The axis's own TARGETDISTANCE compares the demand of the next setpoint, a control cycle
    or two ahead, with the last measured position: at tracking rates a fraction of an arcsec.)
    """
    follower = axis.follower
    if follower is None or not len(axis.queue):
        return axis.target_distance
    measured = getattr(axis, "measured_ut1", 0.0) or ut1  # the path where REALPOS was measured
    try:
        d = follower.path_position(measured) - axis.real_position
    except TcsError:        # emptied meanwhile
        return axis.target_distance
    cycle = axis.section.cyclic
    return math.remainder(d, cycle) if cycle else d


def make_pointing(telescope) -> "Pointing | None":
    """The POINTING module of ``telescope``, or None where it has none (ZD-ZD mount, or the
    main axes are not configured)."""
    mount = telescope.config.mount.type
    names = MAIN_AXES.get(mount)
    if names is None:
        return None
    axis1, axis2 = (telescope.axis(n) for n in names)
    if axis1 is None or axis2 is None:
        return None
    return Pointing(telescope, axis1, axis2)


class RefractionSettings:
    """Domain object of POINTING.REFRACTION (§14.3)."""

    def __init__(self, owner: "Pointing", refraction: Refraction):
        self._owner = owner
        self.value = refraction

    @property
    def mode(self) -> int:
        return self.value.mode

    @property
    def temperature(self) -> float:
        return self.value.temperature

    @property
    def pressure(self) -> float:
        return self.value.pressure

    def set_mode(self, value: int) -> None:
        self._set(mode=int(value))

    def set_temperature(self, value: float) -> None:
        self._set(temperature=float(value))

    def set_pressure(self, value: float) -> None:
        self._set(pressure=float(value))

    def _set(self, **change) -> None:
        fields = dict(mode=self.value.mode, temperature=self.value.temperature,
                      pressure=self.value.pressure)
        fields.update(change)
        self.value = Refraction(**fields)   # validates (RANGE)
        self._owner.persist()
        self._owner.model_changed()


class Target:
    """Domain object of POINTING.TARGET: the written RA/DEC and what follows from them now."""

    def __init__(self, owner: "Pointing"):
        self._owner = owner
        self._ra: float | None = None
        self._dec: float | None = None
        #: differential tracking rates, arcsec of RA (not × cos Dec) and of Dec per second
        #: (RTS2's RA_V / DEC_V), from the TRACK write on
        self.ra_v = 0.0
        self.dec_v = 0.0

    @property
    def complete(self) -> bool:
        return self._ra is not None and self._dec is not None

    @property
    def ra(self) -> float:
        return self._ra if self._ra is not None else 0.0

    @property
    def dec(self) -> float:
        return self._dec if self._dec is not None else 0.0

    def set_ra(self, value: float) -> None:
        value = float(value)
        if not 0.0 <= value < 24.0:
            raise RangeRefused(f"TARGET.RA {value} h is outside 0 <= RA < 24")
        self._ra = value

    def set_dec(self, value: float) -> None:
        value = float(value)
        if not -90.0 <= value <= 90.0:
            raise RangeRefused(f"TARGET.DEC {value}° is outside -90…90")
        self._dec = value

    def set_ra_v(self, value: float) -> None:
        self.ra_v = float(value)

    def set_dec_v(self, value: float) -> None:
        self.dec_v = float(value)

    def _now(self):
        """(observed place, corrections) of the target now; None without a target."""
        if not self.complete:
            return None
        p = self._owner
        pipe = p.pipeline()
        d = pipe.demand(self._ra, self._dec, p.utc(), p.orientation_in_use())
        return d.observed, (float(d.axis1[0] - d.ideal1[0]), float(d.axis2[0] - d.ideal2[0]))

    @property
    def ha(self) -> float:
        now = self._now()
        return float(now[0].ha[0]) if now else 0.0

    @property
    def pa(self) -> float:
        now = self._now()
        return float(now[0].pa[0]) if now else 0.0

    @property
    def correction1(self) -> float:
        now = self._now()
        return now[1][0] if now else 0.0

    @property
    def correction2(self) -> float:
        now = self._now()
        return now[1][1] if now else 0.0

    @property
    def sidereal_time(self) -> float:
        return self._owner.sidereal_time


class Current:
    """Domain object of POINTING.CURRENT: where the encoders say the telescope points."""

    def __init__(self, owner: "Pointing"):
        self._owner = owner

    def _place(self) -> Place:
        return self._owner.place()

    @property
    def ra(self) -> float:
        return self._place().ra

    @property
    def dec(self) -> float:
        return self._place().dec

    @property
    def ha(self) -> float:
        return self._place().ha

    @property
    def pa(self) -> float:
        return self._place().pa

    @property
    def correction1(self) -> float:
        return self._place().correction1

    @property
    def correction2(self) -> float:
        return self._place().correction2

    @property
    def sidereal_time(self) -> float:
        return self._owner.sidereal_time


class Pointing(ModuleHealth):
    """Domain object of the POINTING module; see the module docstring.

    Parameters
    ----------
    telescope : the telescope model (config, local, events, store, state_dir, axes,
        ``run_blocking``).
    axis1, axis2 : the main axes (AZ, ZD) or (HA, DEC).
    """

    def __init__(self, telescope, axis1, axis2):
        super().__init__("POINTING", telescope.events, status_sink=telescope.status_sink)
        self.telescope = telescope
        self.config = telescope.config.pointing
        self.mount = telescope.config.mount.type
        self.local = telescope.local
        self.axis1, self.axis2 = axis1, axis2
        self._store = telescope.store
        self.run_blocking = telescope.run_blocking
        directory = (telescope.config.resolve(self.config.model_directory)
                     if self.config.model_directory else Path(telescope.state_dir) / "pointing")
        saved = self._store.get("pointing", {}) or {}
        cfg = self.config
        self._refraction_config = {"mode": cfg.refraction_mode, "temperature": cfg.temperature,
                                   "pressure": cfg.pressure}
        refr = dict(self._refraction_config)
        entry = saved.get("refraction")
        if isinstance(entry, dict) and entry.get("config") == self._refraction_config:
            refr.update(entry.get("value", {}))
        self.refraction = RefractionSettings(self, Refraction(**refr))
        model_state = saved.get("model") or {}
        try:
            model = PointingModel(self.mount, model_state.get("coefficients", {}), self.local.latitude)
        except TcsError as exc:
            log.error("saved pointing model ignored: %s", exc.message)
            model = PointingModel(self.mount, {}, self.local.latitude)
        self.params = PointingParams(self, directory, model, cfg.fit_terms,
                                     model_name=model_state.get("name", ""),
                                     dumpfile=model_state.get("dumpfile", ""))
        self.params.rms_arcsec = float(model_state.get("rms", 0.0))
        self._dome_deviation = float(saved.get("dome_deviation", 2.0))
        self.target = Target(self)
        self.current = Current(self)
        self._session: TrackSession | None = None
        self._astrometry: tuple[tuple, Astrometry] | None = None
        self._pipeline: tuple[tuple, Pipeline] | None = None
        self._place_cache: tuple[tuple, Place] | None = None
        #: the safety envelope (Sun cone, horizon table, keep-outs) on every planned path
        self.envelope = Envelope(telescope.config.envelope, self.mount,
                                 floor=lambda: self.config.min_altitude, astrometry=self.astrometry,
                                 utc=self.utc, ut1_utc=lambda: self.ut1_utc,
                                 model=lambda: self.params.model)
        self.envelope.attach(axis1, axis2)

    # -- time, site, pipeline -------------------------------------------------------------------
    def utc(self) -> float:
        return self.local.utc()

    def ut1(self) -> float:
        return self.local.ut1()

    @property
    def ut1_utc(self) -> float:
        return self.local.ut1_utc

    @property
    def latitude(self) -> float:
        return self.local.latitude

    @property
    def zd_limit(self) -> float:
        """Largest observed zenith distance a target may have (90° − min_altitude)."""
        return 90.0 - self.config.min_altitude

    def astrometry(self) -> Astrometry:
        local = self.local
        key = (local.latitude, local.longitude, local.height, local.tai_utc, local.ut1_utc,
               self.refraction.value)
        if self._astrometry is None or self._astrometry[0] != key:
            astrometry = Astrometry(Site(local.latitude, local.longitude, local.height),
                                    TimeBase(local.tai_utc, local.ut1_utc), self.refraction.value)
            self._astrometry = (key, astrometry)
        return self._astrometry[1]

    def pipeline(self) -> Pipeline:
        """Astrometry + the active model, rebuilt when LOCAL, REFRACTION or the model changed."""
        astrometry = self.astrometry()
        model = self.params.model
        key = (id(astrometry), model)
        if self._pipeline is None or self._pipeline[0] != key:
            self._pipeline = (key, Pipeline(astrometry, model, self.mount))
        return self._pipeline[1]

    @property
    def sidereal_time(self) -> float:
        return float(self.astrometry().sidereal_time(self.utc()))

    def place(self) -> Place:
        """CURRENT: the sky place of the main axes' REALPOS at the time the drives measured it
        (the SYNC of the last readback: every cycle while the axes move, every fifth period at
        rest, ``QUIET_EVERY`` of the control process — each cycle under the idle SYNC, 50 ms
        apart in sim.toml; a readback read a little late — a busy
        service — still gives the place the telescope pointed to then, not a place shifted by
        the sky's turn meanwhile); cached per position and 10 ms."""
        measured = getattr(self.axis1, "measured_ut1", 0.0)
        utc = measured - self.local.ut1_utc if measured else self.utc()
        pipe = self.pipeline()
        key = (self.axis1.real_position, self.axis2.real_position, round(utc, 2), id(pipe))
        if self._place_cache is None or self._place_cache[0] != key:
            self._place_cache = (key, pipe.place(key[0], key[1], utc))
        return self._place_cache[1]

    def orientation_in_use(self) -> bool:
        """Reverse orientation: the tracked one, else where the axes are now."""
        session = self._tracking()
        if session is not None:
            return session.reverse
        return bool(to_normal(self.axis1.real_position, self.axis2.real_position, self.mount)[2])

    # -- TRACK ----------------------------------------------------------------------------------
    def _tracking(self) -> TrackSession | None:
        s = self._session
        return s if s is not None and s.running else None

    @property
    def track(self) -> int:
        s = self._tracking()
        return s.value if s is not None else 0

    def set_track(self, value: int, pa: float = 0.0, target=None):
        """``TRACK``: from 0 an awaitable ending with the tracking; while tracking, at once.
        ``pa``: position angle on the sky added to the derotator's field angle (flag 256).
        ``target``: a moving or fixed target of :mod:`tcs.pointing.targets` (OpenTSI's
        Moon, planets, TLEs) instead of TARGET and its rates; TARGET.RA/DEC then show its
        place now."""
        mode, flags = parse_track(value)
        session = self._tracking()
        if mode == 0:
            if session is not None:
                session.stop(None)
            return None
        if target is not None:
            start = getattr(target, "start", None)
            ra, dec = target.radec(self.astrometry(), max(self.utc(), (start or 0.0) - self.ut1_utc))
            self.target.set_ra(ra % 24.0)
            self.target.set_dec(dec)
            self.target.set_ra_v(0.0)
            self.target.set_dec_v(0.0)
        if not self.target.complete:
            raise TcsError("no target: set TARGET.RA and TARGET.DEC first", ErrorNumber.INVMODE)
        request = TrackRequest(self.target.ra, self.target.dec, mode, flags, float(pa),
                               self.target.ra_v / 3600.0, self.target.dec_v / 3600.0, self.ut1(),
                               target)
        plan = self._plan(request)
        if session is not None:
            session.retarget(plan, current_cause.get())
            return None
        loop = asyncio.get_running_loop()
        result = loop.create_future()
        previous = self._session.task if self._session is not None else None
        self._session = TrackSession(self, plan, result, current_cause.get(), after=previous)
        return result

    def plan_pass(self, satellite, utc: float | None = None):
        """Plan the satellite's pass in progress or next (:meth:`SatelliteTarget.plan`): AZ's
        range and limits decide the cable-wrap turn and the keyhole bridge (AZ-ZD mounts; on
        an equatorial mount the plan gives the times and rates only); a TLE older than
        ``[pointing] tle_max_age`` days is refused (:meth:`PassPlan.refused`)."""
        a1, a2 = self.axis1, self.axis2
        s1, s2 = a1.section, a2.section
        if self.mount == "AZ-ZD":
            rng = (s1.min - a1.offset, s1.max - a1.offset)
            lim1 = (s1.max_velocity, s1.max_acceleration, s1.max_jerk)
            lim2 = (s2.max_velocity, s2.max_acceleration, s2.max_jerk)
        else:
            rng, lim1, lim2 = (-1e9, 1e9), (1e9, 1e9, 1e9), (1e9, 1e9, 1e9)
        return satellite.plan(self.astrometry(), zd_limit=self.zd_limit,
                              utc=self.utc() if utc is None else utc, az_range=rng,
                              az_limits=lim1, zd_limits=lim2,
                              az_current=a1.real_position - a1.offset,
                              max_age=self.config.tle_max_age)

    def plan_for(self, ra: float, dec: float, mode: int) -> Plan:
        """The plan a TRACK of ``mode`` to (ra, dec) would run now (orientation, turn, the
        envelope's route), without starting anything: what a client asks before a slew
        (Alpaca DestinationSideOfPier). Raises as TRACK would (9, 5)."""
        request = TrackRequest(float(ra), float(dec), int(mode), 0, 0.0, self.target.ra_v / 3600.0,
                               self.target.dec_v / 3600.0, self.ut1())
        return self._plan(request)

    def _plan(self, request: TrackRequest, keep_reverse: bool | None = None) -> Plan:
        derotator = port = None
        if request.flags & FLAG_DEROTATOR:
            derotator, port = self.active_derotator()
        dome = self.rotating_dome() if request.flags & FLAG_DOME else None
        return plan_track(request, self.pipeline(), axis1=self.axis1, axis2=self.axis2,
                          derotator=derotator, port=port, dome=dome, ut1=self.ut1(),
                          ut1_utc=self.ut1_utc,
                          zd_limit=self.zd_limit, plan_horizon=self.config.plan_horizon,
                          keep_reverse=keep_reverse, envelope=self.envelope)

    def active_derotator(self):
        """(derotator axis, port) at the active port: MIRROR's position, else the first one."""
        rotators = self.telescope.axis_array("DEROTATOR")
        mirror = self.telescope.axis("MIRROR")
        if mirror is not None:
            position = mirror.real_position
            port = round(position)
            if abs(position - port) > 0.01:
                raise TcsError(f"MIRROR is between ports ({position:.2f}): no active port for "
                               "the derotator", ErrorNumber.INVMODE)
        else:
            port = next((i for i, r in enumerate(rotators) if r is not None), None)
        if port is None or not 0 <= port < len(rotators) or rotators[port] is None:
            raise TcsError(f"TRACK flag 256: no derotator at the active port {port}",
                           ErrorNumber.INVMODE)
        return rotators[port], port

    def rotating_dome(self):
        """DOME[0] of a rotating dome, powered (flag 128); FAILED 5 otherwise."""
        parts = getattr(self.telescope, "dome", None) or []
        rotation = parts[0] if parts else None
        if rotation is None or not getattr(rotation, "cyclic", 0.0):
            raise TcsError("TRACK flag 128: this telescope has no rotating dome (DOME[0])",
                           ErrorNumber.INVMODE)
        if rotation.power_state != 1.0:
            raise TcsError("TRACK flag 128: DOME[0] is not powered", ErrorNumber.INVMODE)
        return rotation

    def model_changed(self) -> None:
        """The model or the refraction changed: re-plan a running tracking (same orientation)."""
        session = self._tracking()
        if session is None:
            return
        try:
            session.retarget(self._plan(session.plan.request, keep_reverse=session.reverse),
                             current_cause.get())
        except TcsError as exc:
            session.stop(exc)

    def session_ended(self, session: TrackSession) -> None:
        if self._session is session:
            self._session = None

    def abort_request(self, cause, awaitable=None) -> None:
        """TPL2 ABORT of the ``TRACK`` SET ``cause``: the tracking it started ends (the axes
        stop with their normal deceleration, RUN=0); a tracking another command started since
        is left alone."""
        session = self._session
        if session is not None and (session.result is awaitable or (cause is not None and session.cause == cause)):
            session.stop(TcsError("aborted", ErrorNumber.TARGETCHANGE))

    def stop(self) -> None:
        """CABINET.STOP: end tracking (its TRACK SET fails with 10)."""
        session = self._tracking()
        if session is not None:
            session.stop(TcsError("stopped by STOP", ErrorNumber.TARGETCHANGE))

    async def close(self) -> None:
        """Service stopping: end tracking and wait for the axes to be released."""
        session = self._session
        if session is not None:
            session.stop(TcsError("the service is stopping", ErrorNumber.INVMODE))
            await asyncio.wait([session.task], timeout=10.0)

    @property
    def tracking_settled(self) -> bool:
        """True while tracking runs on the path of its latest TRACK (the slew may go on)."""
        return bool(self._controlled())

    @property
    def tracktime(self) -> float | None:
        """Seconds of tracking left before the target leaves a limit (the planning horizon
        when it stays inside it that long); None while not tracking on a settled path."""
        session = self._tracking()
        if session is None or not session.settled:
            return None
        until = session.plan.in_limits_until
        if until is None:
            return float(self.config.plan_horizon)
        return max(0.0, until - self.ut1())

    # -- distances ------------------------------------------------------------------------------
    def _controlled(self) -> list:
        """The axes tracking runs, once they run the current plan (before: none, so that
        TARGETDISTANCE and SLEWINGTIME describe the new target, not the old path)."""
        session = self._tracking()
        if session is None or not session.settled:
            return []
        return [lane.axis for lane in session.lanes]

    @property
    def targetdistance(self) -> float:
        axes = self._controlled()
        if axes:
            ut1 = self.ut1()
            a1, a2 = self.axis1, self.axis2
            d1, d2 = _distance(a1, ut1), _distance(a2, ut1)
            if self.mount == "AZ-ZD":
                d1 *= abs(math.sin(math.radians(a2.real_position)))
            else:
                d1 *= math.cos(math.radians(a2.real_position))
            distance = math.hypot(d1, d2)
            for axis in axes[2:]:
                distance = max(distance, abs(_distance(axis, ut1)))
            return distance
        if not self.target.complete:
            return 0.0
        place = self.place()
        sep = erfa.seps(place.ra * math.pi / 12.0, math.radians(place.dec),
                        self.target.ra * math.pi / 12.0, math.radians(self.target.dec))
        return math.degrees(float(sep))

    @property
    def slewingtime(self) -> float:
        axes = self._controlled()
        if axes:
            return max(0.0 if axis.motion_state & _ON_TARGET else
                       theoretical_minimum_time(axis.target_distance, axis.dynamics) for axis in axes)
        if not self.target.complete:
            return 0.0
        d = self.pipeline().demand(self.target.ra, self.target.dec, self.utc(),
                                   self.orientation_in_use())
        out = 0.0
        for axis, demand in ((self.axis1, float(d.axis1[0])), (self.axis2, float(d.axis2[0]))):
            distance = demand - axis.current_position
            if axis.section.cyclic:
                distance = math.remainder(distance, axis.section.cyclic)
            out = max(out, theoretical_minimum_time(distance, axis.dynamics))
        return out

    # -- DOME_DEVIATION -------------------------------------------------------------------------
    @property
    def dome_deviation(self) -> float:
        return self._dome_deviation

    def set_dome_deviation(self, value: float) -> None:
        value = float(value)
        if not 0.0 <= value <= 180.0:
            raise RangeRefused(f"DOME_DEVIATION {value}° is outside 0…180")
        self._dome_deviation = value
        self.persist()

    # -- for POINTINGPARAMS ---------------------------------------------------------------------
    def measure(self) -> Sample:
        """One pointing sample now: the TARGET's ideal position and the axes' REALPOS."""
        if not self.target.complete:
            raise TcsError("SAMPLE needs a TARGET (the star the telescope is centred on)",
                           ErrorNumber.INVMODE)
        for axis in (self.axis1, self.axis2):
            if axis.power_state != 1.0 or axis.referenced < 1.0:
                raise TcsError(f"SAMPLE: {axis.module_name} is not powered and referenced",
                               ErrorNumber.INVMODE)
        a1, a2 = self.axis1, self.axis2
        m1, m2, o1, o2 = a1.real_position, a2.real_position, a1.offset, a2.offset
        utc = self.utc()
        d = self.pipeline().demand(self.target.ra, self.target.dec, utc, self.orientation_in_use())
        ideal1 = float(d.ideal1[0])
        ideal1 = m1 + math.remainder(ideal1 - m1, 360.0)   # on the axis's turn (for the file)
        return Sample(utc, self.target.ra, self.target.dec, ideal1, float(d.ideal2[0]),
                      m1, m2, o1, o2)

    def dump_header(self) -> DumpHeader:
        a = self.astrometry()
        return DumpHeader(self.mount, a.site, a.timebase, a.refraction)

    def check_offsets_resettable(self) -> None:
        for axis in (self.axis1, self.axis2):
            if axis.offset != 0.0 and (axis.power_state != 1.0 or axis.referenced < 1.0):
                raise TcsError(f"CALCULATE=2: {axis.module_name} has an OFFSET but is not "
                               "powered and referenced", ErrorNumber.INVMODE)

    def reset_offsets(self):
        """OFFSET=0 on the main axes that have one; an awaitable ending when reached."""
        waits = [axis.set_offset(0.0) for axis in (self.axis1, self.axis2) if axis.offset != 0.0]
        if not waits:
            return None

        async def run() -> None:
            await gather_all(*waits)

        return run()

    def persist(self) -> None:
        self._store.update(pointing={
            "refraction": {"value": {"mode": self.refraction.mode,
                                     "temperature": self.refraction.temperature,
                                     "pressure": self.refraction.pressure},
                           "config": self._refraction_config},
            "model": self.params.state(),
            "dome_deviation": self._dome_deviation,
        })

    # -- events ---------------------------------------------------------------------------------
    def emit(self, level: str, number: int, text: str = "", cause=None) -> None:
        if self._events is not None:
            self._events.emit(level, self.module_name, number, text, cause)

    def __repr__(self) -> str:  # pragma: no cover - debugging aid
        return f"<Pointing {self.mount} track={self.track}>"

