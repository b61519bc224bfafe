"""Telescope-wide operations: ready/park, the catalogue target, goto, filter and focus verbs.

:class:`Operations` is the part of the telescope model that the OpenTSI tree (and any other
front end that thinks in whole-telescope verbs) binds to; it holds what such clients name —
the catalogue target (:class:`~tcs.pointing.sky_object.SkyObject`), the set-up of the next
verb (:class:`TrackSetup`: filter index, focus position, derotator and dome following,
orientation) — and it computes the summary states they poll. It holds no hardware state of
its own: power, referencing, tracking and positions are the cabinet's, the pointing module's
and the axes'. It is a :class:`~tcs.model.health.ModuleHealth` (``TELESCOPE``) attached to the
cabinet: a verb that fails raises a latched ERROR condition here, so that a client that never
sees a refused SET (pyobs) sees the failure in READY_STATE / STATUS.GLOBAL / STATUS.LIST.

Verbs (each returns an awaitable for a long SET, or raises at once):

* :meth:`set_ready` 1: cabinet power on, then reference what is not referenced (main axes
  first; a failing main axis stops the rest), complete when operational. 0: stop tracking, move
  every axis with a ``park`` position in the hardware file there, power off.
* :meth:`track_object`: ICRS place of the catalogue target → POINTING.TARGET, start tracking
  (POINTING.TRACK with the orientation and the dome/derotator flags from the set-up); complete
  once tracking runs on the new path. An end of that tracking by anything else than TRACK=0 /
  STOP raises the ``tracking`` condition.
* :meth:`goto_horizontal`: the fixed (observed) alt/az of the target through the pointing model,
  on the azimuth turn nearest to where the axis stands, normal orientation — or, when an
  instrumental position was written last, that axis position as it is; complete on arrival.
* :meth:`apply_filter` / :meth:`apply_focus`: the set-up's filter index / focus position.

Summary states: :attr:`ready_state` (−3 local, −2 emergency off, −1 errors block, 0 off,
0 < x < 1 changing, 1.0 powered and referenced) and :attr:`motion_state` (0 at rest; bit 0
moving; while tracking bit 1, and bits 0 and 3 once on target: 11 — never an idle "on target"
or a "limited" bit).

What may touch it: the event loop.
"""

from __future__ import annotations

import asyncio
import logging
import math

import erfa

from tcs.errors import ErrorNumber, RangeRefused, TcsError, gather_all
from tcs.model.health import ERROR, PANIC, ModuleHealth
from tcs.model.events import current_cause
from tcs.pointing.sky_object import SkyObject
from tcs.pointing.targets import BodyTarget

log = logging.getLogger(__name__)

MOVING, TRAJECTORY, ON_TARGET, PARKING = 1, 2, 8, 32
#: Error conditions an operator must see and acknowledge himself (CABINET.ERROR_STATE=0, OpenTSI
#: STATUS.CLEAR, Alpaca Action("AcknowledgeFaults")) before a make-ready (READY=1, Alpaca
#: Unpark) may power and reference the telescope: active or latched, they refuse it. Every
#: other latched condition (a verb that failed, a PLC or the GPS receiver that was lost and
#: came back, warnings) the make-ready acknowledges itself. Any condition with the PANIC bit
#: counts as one of these too. docs/homing-and-make-ready.md keeps the list for operators.
OPERATOR_FAULTS = {
    "emergency_off": "emergency off",
    "drive fault": "drive fault",
    "control process": "control process crashed",
    "drive offline": "drive offline",
    "axis fault": "axis fault",
}
MAIN_AXES = {"AZ-ZD": ("AZ", "ZD"), "RA-DEC": ("HA", "DEC")}


class TrackSetup:
    """How the next verb is carried out (OpenTSI POINTING.SETUP.*); plain settings."""

    def __init__(self) -> None:
        self.derotator_syncmode = 0
        self.derotator_offset = 0.0
        self.dome_syncmode = 0
        self.dome_offset = 0.0
        self.focus_syncmode = 1
        self.focus_position = 0.0
        self.filter_index = 0
        self.optimization = 0
        self.orientation = 0
        self.min_tracktime = 0.0

    def set_derotator_syncmode(self, value: int) -> None:
        self.derotator_syncmode = int(value)

    def set_derotator_offset(self, value: float) -> None:
        self.derotator_offset = float(value)

    def set_dome_syncmode(self, value: int) -> None:
        self.dome_syncmode = int(value)

    def set_dome_offset(self, value: float) -> None:
        self.dome_offset = float(value)

    def set_focus_syncmode(self, value: int) -> None:
        self.focus_syncmode = int(value)

    def set_focus_position(self, value: float) -> None:
        self.focus_position = float(value)

    def set_optimization(self, value: int) -> None:
        self.optimization = int(value)

    def set_orientation(self, value: int) -> None:
        self.orientation = int(value)

    def set_min_tracktime(self, value: float) -> None:
        self.min_tracktime = float(value)

    def track_mode(self) -> int:
        """POINTING.TRACK mode of OpenTCI for this orientation/optimization."""
        if self.orientation == 1:
            return 3
        if self.orientation == 2 or self.optimization:
            return 4 if self.optimization == 2 else 2
        return 1


class Operations(ModuleHealth):
    """Whole-telescope verbs and summary states (see the module docstring)."""

    def __init__(self, telescope):
        super().__init__("TELESCOPE", telescope.events, status_sink=telescope.cabinet.status_sink)
        self.telescope = telescope
        self.object = SkyObject(telescope.config.mount.type)
        self.object.planner = self.pass_plan     # OBJECT.TLE.PASS.* of OpenTSI
        self.setup = TrackSetup()
        self._ready_demand = 0
        self._job: asyncio.Task | None = None
        self._job_kind = ""
        self._closing = False
        self._parked = False          # parked by park() or READY=0 (at_park also checks positions)
        self._guiding_until = 0.0     # loop time a pulse_guide() ends
        self._pass = None             # (key, PassPlan | None, UTC planned) of the TLE
        self._satellite = None

    # -- parts of the model ----------------------------------------------------------------------
    @property
    def cabinet(self):
        return self.telescope.cabinet

    @property
    def pointing(self):
        return self.telescope.pointing

    def main_axes(self) -> list:
        return list(self._main_axes())

    def _main_axes(self) -> list:
        """The main axes, looked up again only when the telescope's axes changed (its list is
        only ever appended to: its length tells)."""
        axes = self.telescope.axes
        key = (id(axes), len(axes))
        cached = getattr(self, "_main_cache", None)
        if cached is None or cached[0] != key:
            names = MAIN_AXES.get(self.telescope.config.mount.type, ())
            cached = self._main_cache = (key, [a for a in (self.telescope.axis(n) for n in names)
                                               if a is not None])
        return cached[1]

    def park_positions(self) -> list[tuple[object, float]]:
        """(axis, park position): the hardware file's, replaced by a SetPark (persisted)."""
        saved = self.telescope.store.get("park", {}) or {}
        out = []
        for a in self.telescope.axes:
            park = saved.get(a.module_name, a.section.park)
            a.park_position = None if park is None else float(park)   # what PARKPOS reads
            if park is not None:
                out.append((a, float(park)))
        return out

    def filter_axis(self, port: int | None = None):
        wheels = self.telescope.axis_array("FILTER")
        if port is not None and 0 <= port < len(wheels) and wheels[port] is not None:
            return wheels[port]
        active = self.active_port()
        if active is not None and 0 <= active < len(wheels) and wheels[active] is not None:
            return wheels[active]
        return next((w for w in wheels if w is not None), None)

    def active_port(self) -> int | None:
        mirror = self.telescope.axis("MIRROR")
        if mirror is None:
            return None
        return int(round(mirror.real_position))

    # -- summary states ------------------------------------------------------------------------
    @property
    def ready(self) -> int:
        return self._ready_demand

    @property
    def ready_state(self) -> float:
        cab = self.cabinet
        if cab.power_state == -1.0:
            return -2.0
        manual = cab.manual_control
        if cab.mode == 0 or (manual.mode and manual.active):
            return -3.0
        if cab.error_state & (PANIC | ERROR):
            return -1.0
        power = max(0.0, float(cab.power_state))
        referenced = float(cab.referenced)
        changing = self._job is not None and not self._job.done()
        axes_on = all(a.power_state == 1.0 for a in self.telescope.axes)
        if not changing:
            if power == 1.0 and referenced >= 1.0 and axes_on:
                return 1.0
            if power == 0.0 and not cab.main_power:
                return 0.0
        return min(0.99, max(0.01, 0.5 * power + 0.5 * power * referenced))

    @property
    def motion_state(self) -> int:
        axes = self.main_axes()
        state = PARKING if self._job_kind == "park" and not self._job.done() else 0
        p = self.pointing
        if p is not None and p.track:
            on_target = p.tracking_settled and all(a.motion_state & ON_TARGET for a in axes)
            return state | TRAJECTORY | MOVING | (ON_TARGET if on_target else 0)
        if (self._job_kind == "goto" and not self._job.done()) or any(a.motion_state & MOVING for a in axes):
            state |= MOVING
        return state

    @property
    def power(self) -> int:
        return 1 if self.cabinet.power_state == 1.0 else 0

    def check_fresh(self) -> None:
        """Raise the ``stale`` error of a main axis without fresh readbacks (drive offline,
        bus lost, control process restarting): the front ends answer their error for it
        (OpenTSI ``FAILED 4``, an Alpaca error), never the last value."""
        for axis in self._main_axes():
            stale = getattr(axis, "stale", None)
            if stale is not None:
                raise stale

    # -- READY -------------------------------------------------------------------------------------
    def operator_faults(self) -> list[str]:
        """The conditions (active or latched) of :data:`OPERATOR_FAULTS` — and any PANIC — of
        the cabinet and its modules, as ``"MODULE: what (text)"``."""
        cab = self.cabinet
        found = []
        for member in (cab, *cab.members()):
            standing = getattr(member, "standing", None)
            if not callable(standing):
                continue
            for name, bits in standing().items():
                if name in OPERATOR_FAULTS or bits & PANIC:
                    what = OPERATOR_FAULTS.get(name, name)
                    fault = getattr(member, "fault", None) if name == "drive fault" else None
                    message = getattr(fault, "message", "") if fault is not None else ""
                    text = f" ({message})" if message else ""
                    found.append(f"{getattr(member, 'module_name', '?')}: {what}{text}")
        return found

    def check_make_ready(self, what: str = "READY=1") -> None:
        """Refuse a make-ready (``what``) while a fault an operator must see is active or
        latched (:data:`OPERATOR_FAULTS`): the error names them and how to acknowledge."""
        if self.cabinet.power_state == -1.0:
            raise TcsError(f"{what} refused: emergency off is active (release it, then acknowledge "
                           "with CABINET.ERROR_STATE=0)", ErrorNumber.INVMODE)
        faults = self.operator_faults()
        if faults:
            raise TcsError(f"{what} refused: {'; '.join(faults)} — an operator acknowledges it first "
                           "(CABINET.ERROR_STATE=0, OpenTSI TELESCOPE.STATUS.CLEAR, Alpaca "
                           "Action AcknowledgeFaults)", ErrorNumber.INVMODE)

    def acknowledge_harmless(self):
        """Acknowledge the latched conditions a make-ready may (none of
        :data:`OPERATOR_FAULTS`: :meth:`check_make_ready` ran before): None, or the awaitable
        of CABINET.ERROR_STATE=0."""
        cab = self.cabinet
        if not cab.error_state & (PANIC | ERROR):
            return None
        return cab.acknowledge_errors(0)

    def set_ready(self, value: int):
        """``READY`` 1 / 0 (long-running; a newer one supersedes the older). READY=1 is the
        make-ready: refused while a fault an operator must see is there
        (:meth:`check_make_ready`); other latched conditions it acknowledges."""
        on = bool(int(value))
        ack = None
        if on:
            self.check_make_ready("READY=1")
            ack = self.acknowledge_harmless()
        self._ready_demand = int(on)
        if on:
            self._parked = False   # READY=1 is OpenTSI's unpark
        return self._start("ready" if on else "park", self._ready_on(ack) if on else self._park_off())

    async def _ready_on(self, ack=None) -> None:
        if ack is not None:
            await ack
        cab = self.cabinet
        if cab.power_state != 1.0 or any(a.power_state != 1.0 for a in self.telescope.axes):
            await cab.set_power(1)   # (ended: the power sequence stops; what is on stays on)
        for _order, axes in cab.reference_plan(False):
            try:
                await gather_all(*(a.reference(False) for a in axes))
            except asyncio.CancelledError:
                # ended (ABORT of its SET, TELESCOPE.STOP, a newer READY): the homing runs it
                # started stop with the drives' normal deceleration; nothing is powered off
                self._stop_started(axes)
                raise

    async def _park_off(self) -> None:
        p = self.pointing
        if p is not None and p.track:
            p.set_track(0)
            await self._until(lambda: not p.track)
        moves, moved = [], []
        for axis, park in self.park_positions():
            if axis.power_state == 1.0 and axis.referenced >= 1.0:
                moves.append((axis, park - axis.offset))
                moved.append(axis)
        if moves:
            try:
                await self._move_main(moves)
            except asyncio.CancelledError:
                # ended before the park position: the moves stop (normal deceleration) and
                # the power stays on (no power-off of a telescope that is not parked)
                self._stop_started(moved)
                raise
        self._parked = True
        # the power-off, once begun, runs to its end (every component off in order): an
        # ABORT or a newer READY ends only the wait for it
        await asyncio.shield(self.cabinet.set_power(0))

    def _stop_started(self, axes, cause=None) -> None:
        """Stop the motion (moves, homing runs) the command ``cause`` (default: the one this
        job runs for) started on ``axes``."""
        cause = current_cause.get() if cause is None else cause
        for axis in axes:
            try:
                axis.abort_request(cause)
            except TcsError as exc:  # a PLC part unreachable: reported by the part itself
                log.warning("%s: stop of an ended command: %s", axis.module_name, exc)

    def abort_request(self, cause, awaitable=None) -> None:
        """TPL2 ABORT of a verb's SET ``cause`` (OpenTSI POINTING.TRACK, USE_PORT, READY):
        what that command started stops with the normal controlled stop — the tracking of
        TRACK=1 ends, the filter wheel, focus or M3 move of TRACK=3/4 or USE_PORT halts. The
        READY/park/goto jobs end by the cancellation of their SET's wait (:meth:`_start`),
        which stops their moves and homing runs (:meth:`_stop_started`)."""
        p = self.pointing
        if p is not None:
            p.abort_request(cause, awaitable)
        wheels = [w for w in self.telescope.axis_array("FILTER") if w is not None]
        others = [self.telescope.axis(n) for n in ("FOCUS", "MIRROR")]
        self._stop_started([a for a in (*wheels, *others) if a is not None], cause)

    # -- POINTING.TRACK verbs --------------------------------------------------------------------
    def stop_tracking(self) -> None:
        p = self.pointing
        if p is not None and p.track:
            p.set_track(0)
        if self._job is not None and self._job_kind == "goto":
            self._job.cancel()

    def track_object(self):
        p = self._need_pointing()
        obj = self.object
        satellite = None
        if obj.kind == "satellite":     # refused at planning (FAILED 9 and its reason as the
            plan = self.pass_plan()     # event), not latched: nothing was started or failed
            if not plan.feasible:
                what = "no pass to follow" if not plan.found else "the pass cannot be followed"
                raise TcsError(f"{what}: {plan.reason}", ErrorNumber.SOFTLIMIT)
            satellite = self._satellite.planned(plan, p.ut1_utc)
        try:
            target = None
            if obj.kind == "body":
                target = BodyTarget(obj.body)
            elif obj.kind == "satellite":
                target = satellite
            else:
                ra, dec = obj.icrs(p.utc())
                ra_v, dec_v = obj.rates_v(dec)     # OBJECT's rates (0 unless written)
                p.target.set_ra(ra)
                p.target.set_dec(dec)
                p.target.set_ra_v(ra_v)
                p.target.set_dec_v(dec_v)
            result = p.set_track(self.setup.track_mode() | self._track_flags(),
                                 pa=self.setup.derotator_offset, target=target)
        except TcsError as exc:
            self._failed("track", exc)
            raise
        if result is not None:
            result.add_done_callback(self._tracking_ended)
        return self._start("track", self._until_tracking(result))

    def pass_plan(self, fresh: bool = False):
        """The :class:`~tcs.pointing.targets.PassPlan` of the TLE's pass in progress or next;
        kept until that pass has set or the TLE changes. No pass to follow (no TLE, two lines
        that are not one element set, an epoch too old, elements SGP4 cannot propagate, no
        pass within 24 h) is a refused plan (FEASIBLE 0, every figure None) whose reason says
        which (re-planned after a minute)."""
        from tcs.pointing.targets import PassPlan
        p = self._need_pointing()
        key = (tuple(self.object.tle[:2]), p.zd_limit, p.mount)
        now = p.utc()
        cached = self._pass
        if cached is not None and cached[0] == key and not fresh and (
                now < (cached[1].set if cached[1].found else cached[2] + 60.0)):
            return cached[1]
        try:
            self._satellite = self.object.satellite()
        except RangeRefused as exc:
            plan = PassPlan.refused(exc.message)
        else:
            plan = p.plan_pass(self._satellite, now)
        self._pass = (key, plan, now)
        return plan

    async def _until_tracking(self, result) -> None:
        p = self.pointing
        await asyncio.sleep(0)
        while not p.tracking_settled:
            if result is not None and result.done():
                result.result()   # its error, or None: ended already
                return
            await asyncio.sleep(0.05)

    def _tracking_ended(self, fut: asyncio.Future) -> None:
        if fut.cancelled():
            return
        exc = fut.exception()            # retrieved in any case (no "never retrieved" noise)
        if self._closing:
            return
        if isinstance(exc, TcsError) and exc.number != ErrorNumber.TARGETCHANGE:
            self._failed("tracking", exc)

    def _track_flags(self) -> int:
        p = self.pointing
        flags = 0
        if self.setup.derotator_syncmode:
            try:
                rotator, _port = p.active_derotator()
                if rotator.power_state == 1.0 and rotator.referenced >= 1.0:
                    flags |= 256
            except TcsError:
                pass
        if self.setup.dome_syncmode:
            try:
                p.rotating_dome()
                flags |= 128
            except TcsError:
                pass
        return flags

    def horizontal_demand(self, az: float, alt: float) -> tuple[float, float]:
        """Axis demands (TARGETPOS) for the observed ``az``/``alt``: pointing model applied,
        normal orientation, the azimuth turn nearest the axis's position."""
        p = self._need_pointing()
        if alt < p.config.min_altitude:
            raise TcsError(f"altitude {alt:.3f}° is below the limit {p.config.min_altitude:g}°",
                           ErrorNumber.SOFTLIMIT)
        a1, a2 = p.axis1, p.axis2
        if p.mount == "AZ-ZD":
            i1, i2 = az, 90.0 - alt
        else:
            ha, dec = erfa.ae2hd(math.radians(az), math.radians(alt), math.radians(p.latitude))
            i1, i2 = math.degrees(math.remainder(float(ha), 2 * math.pi)), math.degrees(float(dec))
        d1, d2 = (float(x) for x in p.pipeline().model.apply(i1, i2))
        cycle = a1.section.cyclic
        if cycle:
            here = a1.current_position
            turns = [d1 + k * cycle for k in range(-3, 4)]
            inside = [t for t in turns if a1.limits.contains(t + a1.offset)]
            if not inside:
                raise TcsError(f"{a1.module_name}: {d1:.3f}° is outside the limits on every turn",
                               ErrorNumber.SOFTLIMIT)
            d1 = min(inside, key=lambda t: abs(t - here))
        for axis, d in ((a1, d1), (a2, d2)):
            if not axis.limits.contains(d + axis.offset):
                raise TcsError(f"{axis.module_name}: {d:.3f}° is outside the limits", ErrorNumber.SOFTLIMIT)
        return d1, d2

    def goto_horizontal(self):
        p = self._need_pointing()
        try:
            obj = self.object
            if obj.goto_frame == "instrumental":
                d1, d2 = obj.instrumental
                if d1 is None or d2 is None:
                    raise TcsError("no position: write both OBJECT.INSTRUMENTAL axes first",
                                   ErrorNumber.INVMODE)
                for axis, d in ((p.axis1, d1), (p.axis2, d2)):
                    if not axis.limits.contains(d + axis.offset):
                        raise TcsError(f"{axis.module_name}: {d:.3f} is outside the limits",
                                       ErrorNumber.SOFTLIMIT)
            elif obj.az is None or obj.alt is None:
                raise TcsError("no position: write OBJECT.HORIZONTAL.AZ and ALT first", ErrorNumber.INVMODE)
            else:
                d1, d2 = self.horizontal_demand(obj.az, obj.alt)
            for axis in (p.axis1, p.axis2):
                if axis.power_state != 1.0 or axis.referenced < 1.0:
                    raise TcsError(f"{axis.module_name} is not powered and referenced", ErrorNumber.INVMODE)
        except TcsError as exc:
            self._failed("goto", exc)
            raise
        # the safety envelope routes the goto; an instrumental position (an engineering place,
        # which may be below the horizon as before) keeps only the Sun cone and the keep-outs
        return self._start("goto", self._goto(p, d1, d2, sky=obj.goto_frame != "instrumental"))

    async def _goto(self, p, d1: float, d2: float, sky: bool = True) -> None:
        if p.track:
            p.set_track(0)
            await self._until(lambda: not p.track)
        try:
            await self._move_main([(p.axis1, d1), (p.axis2, d2)], sky=sky)
        except TcsError as exc:
            self._failed("goto", exc)
            raise
        except asyncio.CancelledError:
            # ended (an ABORT of its SET, TELESCOPE.STOP, a newer verb): the slew it started
            # stops with the normal deceleration; a target a newer command gave is left alone
            cause = current_cause.get()
            for axis in (p.axis1, p.axis2):
                axis.abort_request(cause)
            raise

    def apply_filter(self):
        axis = self.filter_axis()
        if axis is None:
            raise TcsError("no filter wheel", ErrorNumber.INVMODE)
        keys = sorted(axis.positions)
        index = self.setup.filter_index
        if not 0 <= index < len(keys):
            raise RangeRefused(f"filter index {index} is outside 0…{len(keys) - 1}")
        try:
            return axis.set_target(keys[index])
        except TcsError as exc:
            self._failed("filter", exc)
            raise

    def apply_focus(self):
        axis = self.telescope.axis("FOCUS")
        if axis is None:
            raise TcsError("no focus axis", ErrorNumber.INVMODE)
        try:
            return axis.set_target(self.setup.focus_position)
        except TcsError as exc:
            self._failed("focus", exc)
            raise

    # -- filters ---------------------------------------------------------------------------------
    def filter_count(self, axis) -> int:
        return len(axis.positions)

    def set_filter_index(self, value: int) -> None:
        axis = self.filter_axis()
        count = len(axis.positions) if axis is not None else 0
        value = int(value)
        if not 0 <= value < count:
            raise RangeRefused(f"filter index {value} is outside 0…{count - 1}")
        self.setup.filter_index = value

    @property
    def filter_name(self) -> str:
        axis = self.filter_axis()
        if axis is None:
            return ""
        keys = sorted(axis.positions)
        if not 0 <= self.setup.filter_index < len(keys):
            return ""
        key = str(keys[self.setup.filter_index])
        return axis.section.names.get(key, key)

    # -- errors ----------------------------------------------------------------------------------
    def acknowledge_mask(self, mask: int, levels: int = 0xF):
        """Acknowledge the modules whose ERROR_STATE has a bit of ``mask & levels``. Returns
        None, or — when drive faults are being reset — an awaitable that ends when every reset
        ended and fails naming one that did not (as ``CABINET.ERROR_STATE=0``): the client's SET
        completes once the errors are really gone."""
        mask = int(mask) & levels
        if not mask:
            return None
        cab = self.cabinet
        if not (cab.error_state & 0xF & ~mask):
            return cab.acknowledge_errors(0)
        return cab.acknowledge_modules(mask)

    def _failed(self, what: str, exc: TcsError) -> None:
        """A verb failed: a latched ERROR (gone, kept until acknowledged)."""
        name = f"{what} failed"
        self.raise_condition(name, ERROR, exc.message)
        self.clear_condition(name)

    # -- jobs ------------------------------------------------------------------------------------
    def halt(self) -> None:
        """TELESCOPE.STOP: end a READY or goto sequence (not ``stop``: the cabinet's STOP and
        its power-off call ``stop()`` of its modules, and a READY=0 waits for that power-off)."""
        if self._job is not None and not self._job.done():
            self._job.cancel()

    def _start(self, kind: str, coro):
        if self._job is not None and not self._job.done() and self._job_kind in (
                "ready", "park", "goto", "alpaca-park", "home"):
            self._job.cancel()
        self._job = asyncio.get_running_loop().create_task(coro, name=f"TELESCOPE {kind}")
        self._job_kind = kind
        job = self._job

        async def wait() -> None:
            try:
                await asyncio.shield(job)
            except asyncio.CancelledError:
                if job.cancelled():
                    raise TcsError(f"TELESCOPE {kind} was ended", ErrorNumber.TARGETCHANGE) from None
                job.cancel()
                raise
        return wait()

    async def close(self) -> None:
        self._closing = True
        if self._job is not None and not self._job.done():
            self._job.cancel()
            await asyncio.wait([self._job])

    # -- park, home, guiding, sync (the verbs of mount-level clients: ASCOM Alpaca) ------------
    PARK_TOLERANCE = 0.1  # degrees (user units) from the park position that still count as parked

    @property
    def running(self) -> str:
        """The kind of the verb running now ("ready", "park", "goto", "alpaca-park", "home",
        "track"), or "" when none runs."""
        return self._job_kind if self._job is not None and not self._job.done() else ""

    @property
    def at_park(self) -> bool:
        """Parked by :meth:`park` or READY=0, and every parked axis still at its park position."""
        if not self._parked or (self._job is not None and not self._job.done()
                                and self._job_kind in ("park", "alpaca-park")):
            return False
        parks = self.park_positions()
        return bool(parks) and all(abs(a.real_position - park) <= self.PARK_TOLERANCE for a, park in parks)

    def park(self):
        """Stop tracking and move every axis with a park position there (power stays on);
        :attr:`at_park` once arrived. Long-running; refused without a park position."""
        parks = self.park_positions()
        if not parks:
            raise TcsError("no park position: set one in the hardware file or with SetPark", ErrorNumber.INVMODE)
        for axis, _park in parks:
            if axis.power_state != 1.0 or axis.referenced < 1.0:
                raise TcsError(f"{axis.module_name} is not powered and referenced", ErrorNumber.INVMODE)
        self._parked = False
        return self._start("alpaca-park", self._park_move(parks))

    async def _park_move(self, parks) -> None:
        p = self.pointing
        if p is not None and p.track:
            p.set_track(0)
            await self._until(lambda: not p.track)
        await self._move_main([(axis, park - axis.offset) for axis, park in parks])
        self._parked = True

    def unpark(self):
        """Leave the parked state; power on and reference what is not (READY=1) when the
        telescope is not operational. Returns the READY awaitable or None."""
        self._parked = False
        if self.ready_state != 1.0:
            return self.set_ready(1)
        return None

    def set_park_here(self) -> None:
        """SetPark: the main axes' present positions become their park positions (persisted,
        also for OpenTSI's READY=0)."""
        axes = self.main_axes()
        if not axes:
            raise TcsError("no main axes", ErrorNumber.INVMODE)
        saved = dict(self.telescope.store.get("park", {}) or {})
        for axis in axes:
            if axis.referenced < 1.0:
                raise TcsError(f"{axis.module_name} is not referenced", ErrorNumber.INVMODE)
            saved[axis.module_name] = round(float(axis.real_position), 6)
        self.telescope.store.update(park=saved)
        self.park_positions()   # the axes' park_position (OpenTCI PARKPOS) too

    def home_positions(self) -> list[tuple[object, float]]:
        """(main axis, home position): where its drive's homing puts the reference (the home
        offset, 0x607C — the home switch's position in user units), inside the axis limits."""
        out = []
        for axis in self.main_axes():
            drive = self.telescope.config.drives.get(axis.section.drive)
            home = float(drive.homing.offset) if drive is not None else 0.0
            out.append((axis, min(max(home, axis.section.min), axis.section.max)))
        return out

    @property
    def at_home(self) -> bool:
        """The main axes, referenced, stand at their home positions (not while moving there)."""
        if self._job is not None and not self._job.done() and self._job_kind == "home":
            return False
        homes = self.home_positions()
        return bool(homes) and all(a.referenced >= 1.0 and abs(a.real_position - home) <= self.PARK_TOLERANCE
                                   for a, home in homes)

    def find_home(self):
        """Reference the main axes that are not referenced, then move them to their home
        positions (:meth:`home_positions`); tracking ends first. Long-running."""
        homes = self.home_positions()
        for axis, _home in homes:
            if axis.power_state != 1.0:
                raise TcsError(f"{axis.module_name} is not powered", ErrorNumber.INVMODE)

        async def run() -> None:
            p = self.pointing
            if p is not None and p.track:
                p.set_track(0)
                await self._until(lambda: not p.track)
            await gather_all(*(a.reference(False) for a, _h in homes))
            await self._move_main([(a, home - a.offset) for a, home in homes])
        return self._start("home", run())

    async def _move_main(self, targets, sky: bool = False) -> None:
        """TARGETPOS of several axes at once; the two main axes together on the route the safety
        envelope plans (:meth:`tcs.pointing.envelope.Envelope.goto`: around the Sun cone and the
        keep-outs; ``sky``: above the horizon table too), the others as they are."""
        p = self.pointing
        env = getattr(p, "envelope", None) if p is not None else None
        main = {id(p.axis1): None, id(p.axis2): None} if env is not None else {}
        for axis, value in targets:
            if id(axis) in main:
                main[id(axis)] = value
        if env is None or any(v is None for v in main.values()):
            await gather_all(*(axis.set_target(value) for axis, value in targets))
            return
        others = [axis.set_target(value) for axis, value in targets if id(axis) not in main]
        await gather_all(env.goto(p.axis1, p.axis2, main[id(p.axis1)], main[id(p.axis2)], horizon=sky),
                         *others)

    @property
    def pulse_guiding(self) -> bool:
        return asyncio.get_running_loop().time() < self._guiding_until

    def pulse_guide(self, direction: int, seconds: float, rate: float) -> None:
        """Move the tracked target by ``rate`` (degrees/s on the sky) for ``seconds``: direction
        0 north (+Dec), 1 south, 2 east (+RA), 3 west. The tracking is re-planned to the moved
        target at once; :attr:`pulse_guiding` for ``seconds``."""
        p = self._need_pointing()
        if not p.track:
            raise TcsError("pulse guiding needs tracking", ErrorNumber.INVMODE)
        shift = rate * seconds
        ra, dec = p.target.ra, p.target.dec
        if direction in (0, 1):
            dec = dec + (shift if direction == 0 else -shift)
            if not -90.0 <= dec <= 90.0:
                raise RangeRefused("the guided declination passes a pole")
            p.target.set_dec(dec)
        else:
            cos_dec = max(math.cos(math.radians(dec)), 1e-3)
            ra = (ra + (1 if direction == 2 else -1) * shift / 15.0 / cos_dec) % 24.0
            p.target.set_ra(ra)
        p.set_track(p.track)
        loop = asyncio.get_running_loop()
        self._guiding_until = max(self._guiding_until, loop.time()) + seconds

    def sync_to(self, ra: float, dec: float) -> tuple[float, float]:
        """Sync: the telescope points at ICRS ``ra`` (h), ``dec`` (deg) now. Done as a change of
        the pointing model's index terms (IA/IE, or IH/ID), so that POINTING.CURRENT reads that
        place; a running tracking is re-planned (it moves by the difference). Refused in the
        reverse orientation and beyond 10°. Returns the index-term changes (degrees)."""
        p = self._need_pointing()
        if p.orientation_in_use():
            raise TcsError("sync is only done in the normal orientation", ErrorNumber.INVMODE)
        d = p.pipeline().demand(ra, dec, p.utc(), False)
        d1, d2 = float(d.axis1[0]), float(d.axis2[0])
        r1, r2 = p.axis1.real_position, p.axis2.real_position
        e1 = (r1 - d1 + 180.0) % 360.0 - 180.0
        e2 = r2 - d2
        if math.hypot(e1, e2) > 10.0:
            raise RangeRefused(f"sync by {math.hypot(e1, e2):.2f}° is beyond 10°")
        names = ("IA", "IE") if p.mount == "AZ-ZD" else ("IH", "ID")
        changes = (e1, -e2) if p.mount == "AZ-ZD" else (-e1, -e2)
        params = p.params
        for name, change in zip(names, changes):
            params.set_coefficient(name, params.coefficient(name) + change)
        return changes

    def _need_pointing(self):
        p = self.pointing
        if p is None:
            raise TcsError("this telescope has no POINTING module", ErrorNumber.INVMODE)
        return p

    @staticmethod
    async def _until(condition, timeout: float = 30.0) -> None:
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        while not condition():
            if loop.time() > deadline:
                raise TcsError("timed out", ErrorNumber.TIMEOUT)
            await asyncio.sleep(0.05)


__all__ = ["Operations", "TrackSetup"]
