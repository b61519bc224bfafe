"""POINTING.TRACK: a sidereal target streamed into the axes' trajectory queues (OpenTCI §14).

How it works
------------
Tracking is done with the axes' own TRAJECTORY machinery, exactly as a client would do it
over TPL2: time-stamped points (UT1) are computed ahead, queued with
``axis.queue.add_points`` and run with ``axis.set_run(1)``; the axis's follower intercepts
the moving path with ruckig and then follows it, checking speed, acceleration and jerk.

1. **Plan** (:func:`plan_track`, synchronous, so that a refusal is the SET's reply): the
   target's path over ``plan_horizon`` (coarse samples, 60 s apart) decides the orientation
   and the cable-wrap turn (:func:`~tcs.pointing.orientation.choose_path` for the main axes,
   :func:`choose_turn` for a derotator): the candidate that stays inside the software limits
   the longest, then by mode (2: normal first; 1/3 forced; 4: shortest slew). Refused:
   a target below ``[pointing] min_altitude`` now (FAILED 9), one that needs an axis
   outside its limits in every allowed orientation and turn (FAILED 9), axes not powered
   or not referenced (FAILED 5), no derotator at the active port for flag 256 (FAILED 5).
2. **Start** (:class:`TrackSession`, an asyncio task): ``RUN=0`` on the axes (frees their
   queues, ends whatever ran), points from the last whole ``sample_spacing`` before now to
   ``horizon`` ahead, ``add_points``, ``RUN=1`` with the turn chosen here (``shift`` 0: the
   points are queued on it). Left alone, a cyclic axis's follower would take the turn
   nearest the axis that keeps the queued ~100 s inside the limits, and run into the cable
   wrap later; a TARGETPOS cannot help (it too takes the nearest turn).
3. **Refill**: once per ``sample_spacing`` (or at once when an axis reports) the session
   tops each queue up to ``horizon`` ahead when less than ``refill_below`` remains.
   Every point is checked: observed altitude above the limit, demand + OFFSET inside the
   axis limits. The path is cut before the first point that fails; when the time of the last
   good point comes, the session stops the axes (``RUN=0``) and tracking ends with an event
   ``ERROR POINTING:9`` and FAILED 9 for the TRACK SET.
4. **Dome** (flag 128): once per tick, when DOME[0] (the slit azimuth of a rotating dome)
   is more than POINTING.DOME_DEVIATION from the target's azimuth, it is sent there with
   ``TARGETPOS`` (the spec's step-wise following). Whatever the mount, the slit is put at the
   target's observed azimuth: no dome geometry (telescope off the dome's centre) is modelled.
   A dome that cannot move (power, PLC lost, fault) does not end the tracking: it is reported
   with ``EVENT WARN POINTING:1012`` (once, until it moves again) and retried.
5. **Near the zenith** (AZ-ZD) the azimuth may have to turn faster than it can: the
   follower keeps every setpoint inside the axis's speed/acceleration/jerk limits (it lags,
   ``MOTION_STATE`` bit 4 "limited") and re-intercepts afterwards; the session reports the
   episode with ``EVENT WARN POINTING:1010`` and a WARNING condition, and
   ``EVENT INFO POINTING:1011`` once the axis follows again. Nothing faults.
6. **End**: TRACK=0 (the SET that started tracking answers DATA OK), a STOP or another
   command taking an axis away (FAILED 10), an axis fault or power loss (the axis's number),
   the target setting / an axis limit (FAILED 9). The session then sends ``RUN=0`` to every
   axis still running and emits ``INFO POINTING:1015`` (ended as asked) or
   ``ERROR POINTING:<n>``. An ABORT of the TRACK SET (or a disconnect with
   ABORT_ON_DISCONNECT) ends only the wait, as for the axes' long SETs: tracking goes on
   until TRACK=0 or STOP, and its end is still announced by the events.

The target: POINTING.TARGET (ICRS J2000 with the RA_V/DEC_V rates), or any target of
:mod:`tcs.pointing.targets` given by a front end (``TrackRequest.target``: the Sun, the Moon,
a planet, a planned satellite pass, a fixed alt/az): its observed path goes through the same
pointing model, checks and queues. A satellite pass starts at its rise (the axes wait on the
extrapolated start), uses its own point spacing (0.5 s), is planned over the whole pass
densely (the cable-wrap turn), and its setting ends tracking as asked (1015), not as an error.

A new TARGET or a new TRACK value while tracking re-plans at once (the SET returns
immediately); so do a new pointing model and new refraction settings (same orientation).
Re-planning is ``RUN=0`` and a new ``RUN=1`` on each axis: the follower intercepts the new
path from the moving state, without stopping.

What may touch it
-----------------
The event loop only (the POINTING module calls it); the axes are driven through their public
asyncio-side methods, never from the control-loop thread.
"""

from __future__ import annotations

import asyncio
import logging
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tcs.errors import ErrorNumber, RequestRefused, TcsError
from tcs.model.events import ERROR, INFO, WARN, current_cause
from tcs.model.health import WARNING
from tcs.pointing.demand import Pipeline, field_angle
from tcs.pointing.orientation import AxisRange, choose_path

log = logging.getLogger(__name__)

__all__ = ["TrackRequest", "Plan", "Lane", "plan_track", "parse_track", "choose_turn", "TrackSession",
           "ZENITH_LIMITED", "ZENITH_CLEAR", "DOME_STUCK", "FLAG_DOME", "FLAG_DEROTATOR", "MODE_MASK"]

FLAG_DOME, FLAG_DEROTATOR = 128, 256
MODE_MASK = 0x7F
#: Project events (Appendix B: user numbers from 1000).
ZENITH_LIMITED = 1010
ZENITH_CLEAR = 1011
DOME_STUCK = 1012
#: POINTING's own state changes (not the axes' 23 MOTIONCHANGE / 32 TRAJ_STOP).
TRACKING = 1014               # tracking starts or changes: target, orientation, followers
TRACKING_ENDED = 1015         # tracking ended as asked
_COARSE_STEP = 60.0           # s between the samples of the planning path
_LIMITED_SHARE = 0.95         # of an axis's speed / acceleration: "cannot follow"
_STOP_WAIT = 3.0              # s to wait for RUN=0 answers when ending


@dataclass(frozen=True)
class TrackRequest:
    """What a TRACK write asks for: ICRS target (hours, degrees), mode 1–4, flags 128/256."""

    ra: float
    dec: float
    mode: int
    flags: int = 0
    pa: float = 0.0          # degrees added to the derotator's field angle (flag 256): the
    #                          position angle on the sky (OpenTSI SETUP.DEROTATOR.OFFSET)
    ra_rate: float = 0.0     # differential rates, degrees of RA / Dec per second (RA_V, DEC_V)
    dec_rate: float = 0.0
    epoch: float = 0.0       # UT1 where the target is at (ra, dec)
    #: any other kind of target (tcs.pointing.targets: Sun, Moon, planet, satellite pass,
    #: fixed alt/az); ra/dec are then only its place for display. None: ra/dec and the rates
    target: Any = None

    def observed(self, astrometry, ut1, ut1_utc: float):
        """The observed place to follow at the UT1 times ``ut1`` (array)."""
        if self.target is not None:
            return self.target.observed(astrometry, np.asarray(ut1, float) - ut1_utc)
        return astrometry.observed(*self.place(ut1), np.asarray(ut1, float) - ut1_utc)

    @property
    def start(self) -> float | None:
        """UT1 where the target's path begins (a satellite pass), None: now."""
        return getattr(self.target, "start", None)

    def place(self, ut1):
        """(RA hours, Dec degrees) at the UT1 times ``ut1`` (the rates applied)."""
        if not (self.ra_rate or self.dec_rate):
            return self.ra, self.dec
        dt = np.asarray(ut1, float) - self.epoch
        ra = np.mod(self.ra + self.ra_rate * dt / 15.0, 24.0)
        dec = np.clip(self.dec + self.dec_rate * dt, -90.0, 90.0)
        return ra, dec


@dataclass
class Lane:
    """One axis the session drives; ``role`` is "axis1", "axis2" or "derotator"."""

    axis: Any
    role: str
    port: int | None = None
    start: float = 0.0                 # chosen turn: first value of the planning path
    last: float | None = None          # last queued value (continuity of cyclic paths)
    future: asyncio.Future | None = None


@dataclass
class Plan:
    """The outcome of :func:`plan_track` (what a session needs to start)."""

    request: TrackRequest
    reverse: bool
    lanes: list[Lane]
    slew_time: float
    in_limits_until: float | None      # UT1 where the planning path leaves a limit, if it does
    dome: Any = None                   # DOME[0] to keep at the target's azimuth (flag 128)
    route: Any = None                  # envelope detour (tcs.pointing.envelope.Route) before the intercept

    @property
    def value(self) -> int:
        """POINTING.TRACK as read back: 1 or 3, plus the flags."""
        return (3 if self.reverse else 1) | self.request.flags


def _leading(mask: np.ndarray) -> int:
    bad = np.flatnonzero(~mask)
    return int(bad[0]) if bad.size else int(mask.size)


def choose_turn(path: np.ndarray, minimum: float, maximum: float, cycle: float,
                current: float) -> tuple[np.ndarray, int]:
    """Whole turns added to a continuous path of a cyclic axis: the candidate with the most
    leading samples inside ``[minimum, maximum]``, then the one starting nearest ``current``.

    Returns the shifted path and its number of leading in-limit samples.
    """
    lo, hi = float(path.min()), float(path.max())
    best = None
    for k in range(math.floor((minimum - hi) / cycle) - 1, math.ceil((maximum - lo) / cycle) + 2):
        cand = path + k * cycle
        n = _leading((cand >= minimum) & (cand <= maximum))
        key = (-n, abs(cand[0] - current))
        if best is None or key < best[0]:
            best = (key, cand, n)
    assert best is not None
    return best[1], best[2]


def _ready(axis, what: str) -> None:
    if axis.power_state != 1.0:
        raise TcsError(f"{axis.module_name} is not powered: cannot {what}", ErrorNumber.INVMODE)
    if axis.referenced < 1.0:
        raise TcsError(f"{axis.module_name} is not referenced: cannot {what}", ErrorNumber.INVMODE)


def plan_track(request: TrackRequest, pipeline: Pipeline, *, axis1, axis2, derotator=None,
               port: int | None = None, dome=None, ut1: float, ut1_utc: float, zd_limit: float,
               plan_horizon: float, keep_reverse: bool | None = None, envelope=None) -> Plan:
    """Validate a TRACK request and choose orientation and turns (see the module docstring).

    Parameters
    ----------
    request : target, mode (1–4) and flags.
    pipeline : astrometry + pointing model of the mount.
    axis1, axis2 : the main axes (AZ/ZD or HA/DEC); ``derotator`` with its ``port`` for flag 256.
    dome : DOME[0] for flag 128 (checked by the caller), or None.
    ut1, ut1_utc : now (UT1 seconds) and UT1−UTC.
    zd_limit : largest observed zenith distance allowed (90° − min_altitude).
    plan_horizon : seconds of path checked against the limits.
    keep_reverse : re-planning while tracking: keep this orientation whatever the mode says.
    envelope : the safety envelope (:mod:`tcs.pointing.envelope`): the tracked path is cut
        where it would enter it, the slew onto it is routed around it (or refused, 9).

    Raises
    ------
    TcsError
        9 (softlimit): the target is below the altitude limit, or outside the axis limits in
        every allowed orientation; 5 (invmode): an axis is not powered or not referenced.
    """
    for axis in (axis1, axis2, derotator):
        if axis is not None:
            _ready(axis, "track")
    first = ut1 if request.start is None else max(ut1, request.start)
    end = getattr(request.target, "end", None)
    if end is not None:          # a satellite pass: the whole pass, densely (the cable wrap)
        plan_horizon = max(end - first, 2.0)
        step = max(min(1.0, plan_horizon / 4), plan_horizon / 4000)
    else:
        step = min(_COARSE_STEP, plan_horizon / 4)
    times = first + np.arange(0.0, plan_horizon + step / 2, step)
    obs = request.observed(pipeline.astrometry, times, ut1_utc)
    if obs.zd[0] > zd_limit:
        alt = 90.0 - float(obs.zd[0])
        where = f"{-alt:.2f}° below the horizon" if alt < 0 else f"{alt:.2f}° above the horizon"
        raise TcsError(f"target is {where}, under the altitude limit {90.0 - zd_limit:g}°",
                       ErrorNumber.SOFTLIMIT)
    up = _leading(obs.zd <= zd_limit)
    times = times[:up]
    i1, i2 = pipeline.ideal(obs)
    i1, i2 = np.asarray(i1)[:up], np.asarray(i2)[:up]
    mode = request.mode
    if keep_reverse is not None:
        mode = 3 if keep_reverse else 1
    off1, off2 = axis1.offset, axis2.offset

    def choose(mode):
        return choose_path(
            i1, i2, mode=mode, mount=pipeline.mount,
            axis1_range=AxisRange(axis1.section.min - off1, axis1.section.max - off1),
            axis2_range=AxisRange(axis2.section.min - off2, axis2.section.max - off2),
            current=(axis1.real_position - off1, axis2.real_position - off2),
            speed=(axis1.section.max_velocity, axis2.section.max_velocity))

    chosen = choose(mode)

    def demand(path, n=None):   # the drives' positions of a chosen path: the model applied
        d1, d2 = pipeline.model.apply(path.axis1[:n], path.axis2[:n])
        return np.asarray(d1, float) + off1, np.asarray(d2, float) + off2

    if envelope is not None and mode in (2, 4) and not envelope.judge(
            *demand(chosen, 1), times[:1] - ut1_utc, escape=False).ok:
        try:   # the envelope (a keep-out: the pier) forbids this side: the other one, if it can
            chosen = choose(1 if chosen.reverse else 3)
        except TcsError:
            pass
    lanes = [Lane(axis1, "axis1", start=float(chosen.axis1[0])),
             Lane(axis2, "axis2", start=float(chosen.axis2[0]))]
    in_limits = chosen.in_limits
    slew = chosen.slew_time
    route = None
    if envelope is not None:
        in_limits, route = _envelope_plan(envelope, demand(chosen), times, in_limits, slew,
                                          axis1, axis2, ut1_utc)
        slew = max(slew, route.duration) if route.waypoints else slew
        route = route if route.waypoints else None
    if derotator is not None:
        angle = np.unwrap(field_angle(pipeline.mount, np.asarray(obs.pa)[:up], chosen.axis2,
                                      chosen.reverse, port) + request.pa, period=360.0)
        sec, off = derotator.section, derotator.offset
        current = derotator.real_position - off
        if sec.cyclic:
            angle, n = choose_turn(angle, sec.min - off, sec.max - off, sec.cyclic, current)
        else:
            n = _leading((angle >= sec.min - off) & (angle <= sec.max - off))
        if n == 0:
            raise TcsError(f"{derotator.module_name} cannot follow the field rotation inside its "
                           "limits", ErrorNumber.SOFTLIMIT)
        lanes.append(Lane(derotator, "derotator", port=port, start=float(angle[0])))
        in_limits = min(in_limits, n)
        slew = max(slew, abs(angle[0] - current) / sec.max_velocity)
    until = float(times[in_limits]) if in_limits < times.size else None
    return Plan(request, chosen.reverse, lanes, slew, until, dome, route)


def _envelope_plan(envelope, drives, times, in_limits: int, slew: float, axis1, axis2, ut1_utc: float):
    """The tracked path — ``drives``: the drive positions, model and OFFSET included, as the
    axes will run them (the envelope reads the sky through the model itself) — judged against
    the envelope (refused when it starts inside: 9), and the route of the slew onto it
    (:func:`tcs.pointing.envelope.plan_route`)."""
    from tcs.axes.profile import Setpoint
    from tcs.pointing.envelope import plan_route
    p1, p2 = drives
    j = envelope.judge(p1, p2, times - ut1_utc, escape=False)
    if j.good == 0:
        raise TcsError(f"the target is inside {j.text}", ErrorNumber.SOFTLIMIT)
    arrive = float(times[0]) + slew
    end = (float(np.interp(arrive, times, p1)), float(np.interp(arrive, times, p2)))
    starts = (Setpoint(float(axis1.real_position), float(axis1.current_speed)),
              Setpoint(float(axis2.real_position), float(axis2.current_speed)))
    route = plan_route(envelope, float(times[0]) - ut1_utc, starts, end,
                       (axis1.dynamics, axis2.dynamics),
                       ((axis1.section.min, axis1.section.max), (axis2.section.min, axis2.section.max)))
    return min(in_limits, j.good), route


# ------------------------------------------------------------------------------ the session

@dataclass
class _Points:
    times: np.ndarray
    values: dict[str, np.ndarray] = field(default_factory=dict)


class TrackSession:
    """One tracking, from TRACK≠0 to its end; see the module docstring.

    Parameters
    ----------
    owner : the POINTING module: ``pipeline()``, ``ut1()``, ``ut1_utc``, ``zd_limit``,
        ``config`` (the ``[pointing]`` section), ``emit(level, number, text, cause)``,
        ``raise_condition`` / ``clear_condition``, ``session_ended(session)``.
    plan : from :func:`plan_track`.
    result : the future the TRACK SET awaits (resolved when tracking ended).
    cause : the (connection, command) that started tracking, for its events.
    after : a previous session's task to let finish first.
    """

    def __init__(self, owner, plan: Plan, result: asyncio.Future, cause=None,
                 after: asyncio.Task | None = None):
        self.owner = owner
        self.plan = plan
        self.result = result
        self.cause = cause
        self.lanes: list[Lane] = []
        self._pending: Plan | None = plan
        self._pending_cause = cause
        self._stop: TcsError | None | bool = False    # False: keep going; None: ended as asked
        self._wake = asyncio.Event()
        self._t_end: float | None = None               # UT1 of the last good point
        self._end_reason = ""
        self._last_t: float | None = None              # UT1 of the last queued point
        self._zenith = False
        self._zenith_until = 0.0
        #: the plan's path still in the stretch it starts with (see _check_zenith)
        self._zenith_leaving = True
        self._dome_move: asyncio.Future | None = None
        self._dome_stuck = False
        self._after = after
        self._starting = False
        self.active = True
        self.task = asyncio.get_running_loop().create_task(self._main(), name="pointing-track")

    # -- requests from the POINTING module ----------------------------------------------------
    @property
    def value(self) -> int:
        """TRACK as read back (0 once the session ends)."""
        return self.plan.value if self.active else 0

    @property
    def reverse(self) -> bool:
        return self.plan.reverse

    @property
    def running(self) -> bool:
        """True from the start until an end was asked for or happened."""
        return self.active and self._stop is False

    @property
    def settled(self) -> bool:
        """The axes run the current plan (no re-plan waiting or being started)."""
        return self._pending is None and not self._starting and bool(self.lanes)

    def retarget(self, plan: Plan, cause=None) -> None:
        """A new plan while tracking (new target, mode, flags, model or refraction);
        ``cause``: the command that asked for it (its events carry its id)."""
        self.plan = plan
        self._pending = plan
        self._pending_cause = cause if cause is not None else self.cause
        self._wake.set()

    def stop(self, error: TcsError | None = None) -> None:
        """End tracking: ``None`` as asked (TRACK=0), else with ``error`` (STOP: 10)."""
        if self._stop is False:
            self._stop = error
        self._wake.set()

    def _lane_done(self, fut: asyncio.Future) -> None:
        if not fut.cancelled():
            fut.exception()  # retrieved: only the first lane's error ends tracking (_ended);
            # the others' would be "Future exception was never retrieved" at garbage collection
        self._wake.set()

    # -- the task -------------------------------------------------------------------------------
    async def _main(self) -> None:
        error: TcsError | None = None
        try:
            if self._after is not None:
                await asyncio.wait([self._after])
            while True:
                if self._stop is not False:
                    error = self._stop
                    break
                if self._pending is not None:
                    plan, self._pending = self._pending, None
                    self._starting = True
                    try:
                        await self._start(plan, self._pending_cause)
                    finally:
                        self._starting = False
                    continue
                ended = [lane for lane in self.lanes if lane.future is not None and lane.future.done()]
                if ended:
                    error = self._ended(ended[0])
                    break
                now = self.owner.ut1()
                if self._t_end is not None and now >= self._t_end:
                    error = self._planned_end()
                    break
                self._refill(now)
                self._watch_zenith(now)
                self._sync_dome(now)
                timeout = self.owner.config.sample_spacing
                if self._t_end is not None:
                    timeout = min(timeout, max(0.0, self._t_end - now))
                try:
                    await asyncio.wait_for(self._wake.wait(), timeout)
                except TimeoutError:
                    pass
                self._wake.clear()
        except asyncio.CancelledError:
            error = TcsError("tracking cancelled", ErrorNumber.TARGETCHANGE)
            raise
        except TcsError as exc:
            error = exc
        except Exception as exc:  # a bug must end tracking visibly, not silently
            log.exception("tracking failed")
            error = TcsError(f"tracking failed: {exc!r}", ErrorNumber.INTERNAL)
        finally:
            await self._finish(error)

    async def _finish(self, error: TcsError | None) -> None:
        self.active = False
        lanes = self.lanes or self.plan.lanes   # (a start that failed half-way: all of them)
        running = [lane.axis for lane in lanes if lane.future is None or not lane.future.done()]
        await self._run0(running)
        if self._zenith:
            self.owner.clear_condition("zenith")
        if error is None:
            self.owner.emit(INFO, TRACKING_ENDED, "tracking ended", self.cause)
        else:
            self.owner.emit(ERROR, error.number, f"tracking ended: {error.message}", self.cause)
        if not self.result.done():
            if error is None:
                self.result.set_result(None)
            else:
                self.result.set_exception(error)
        self.owner.session_ended(self)

    async def _run0(self, axes) -> None:
        """``RUN=0`` on ``axes``; waits (bounded) for the buffers to be free."""
        futures = []
        for axis in axes:
            try:
                futures.append(asyncio.ensure_future(axis.set_run(0)))
            except TcsError as exc:
                log.warning("RUN=0 on %s refused: %s", axis.module_name, exc.message)
        if futures:
            done, pending = await asyncio.wait(futures, timeout=_STOP_WAIT)
            for f in pending:
                f.cancel()
            for f in done:
                if not f.cancelled() and f.exception() is not None:
                    log.warning("RUN=0 failed: %s", f.exception())

    # -- starting and re-planning ---------------------------------------------------------------
    async def _start(self, plan: Plan, cause) -> None:
        owner = self.owner
        new_axes = {id(lane.axis) for lane in plan.lanes}
        # detach the old lanes first: their RUN futures end now and are not "the end"
        old, self.lanes = self.lanes, []
        for lane in old:
            if lane.future is not None:
                lane.future.remove_done_callback(self._lane_done)
        await self._run0([lane.axis for lane in old if id(lane.axis) not in new_axes])
        await self._run0([lane.axis for lane in plan.lanes])
        if getattr(owner, "envelope", None) is not None:
            plan = await self._detour(plan)   # the envelope's detour, then the intercept from its end
            if plan is None:
                return                         # interrupted: TRACK=0, STOP or a newer plan
        self._t_end, self._end_reason, self._last_t = None, "", None
        self._zenith_leaving = True
        lanes = [Lane(lane.axis, lane.role, lane.port, lane.start) for lane in plan.lanes]
        points = self._points(plan, lanes, owner.ut1(), first=True)
        if points.times.size < 2:
            raise self._planned_end() or TcsError("the pass is over", ErrorNumber.SOFTLIMIT)
        now = owner.ut1()
        for lane in lanes:
            lane.axis.queue.add_points(points.times, points.values[lane.role], now)
        self._last_t = float(points.times[-1])
        try:
            for lane in lanes:
                lane.future = lane.axis.set_run(1, shift=0.0)   # the points are on the chosen turn
                self.lanes.append(lane)
                lane.future.add_done_callback(self._lane_done)
        except TcsError:
            await self._run0([lane.axis for lane in lanes])
            raise
        await self._taken(lanes)
        self._check_zenith(points)
        ra_text = f"RA {plan.request.ra:.6f} h, Dec {plan.request.dec:+.5f}°"
        if plan.request.target is not None:
            ra_text = f"{plan.request.target.describe()} ({ra_text} now)"
        owner.emit(INFO, TRACKING,
                   f"tracking {ra_text}, {'reverse' if plan.reverse else 'normal'} orientation"
                   + (f", {lanes[2].axis.module_name} follows the field" if len(lanes) > 2 else ""),
                   cause)

    async def _detour(self, plan: Plan) -> Plan | None:
        """Re-plan from where the axes stand now and run the safety envelope's detour, if the
        plan has one (TARGETPOS moves through its waypoints); again from its end, until the
        slew onto the path is direct. TRACK=0, STOP or a newer plan meanwhile stop the axes
        (the normal controlled stop, as an ABORT of the moves) and return None."""
        owner = self.owner
        for _ in range(3):
            plan = owner._plan(plan.request, keep_reverse=plan.reverse)
            if self._pending is None:
                self.plan = plan
            if plan.route is None:
                return plan
            axes = (plan.lanes[0].axis, plan.lanes[1].axis)
            route = asyncio.ensure_future(owner.envelope.run_route(plan.route, *axes))
            while not route.done():
                self._wake.clear()
                waiter = asyncio.ensure_future(self._wake.wait())
                await asyncio.wait([route, waiter], return_when=asyncio.FIRST_COMPLETED)
                waiter.cancel()
                if not route.done() and (self._stop is not False or self._pending is not None):
                    route.cancel()
                    for axis in axes:   # the moves this task started: the normal controlled stop
                        axis.abort_request(current_cause.get())
                    await asyncio.wait([route])
                    self._wake.set()
                    return None
            route.result()    # (a failed move ends the tracking with its error)
        return plan

    @staticmethod
    async def _taken(lanes: list[Lane]) -> None:
        """Wait (a few control cycles at most) until every axis runs the new trajectory, so
        that its MOTION_STATE is the new run's when the start is announced."""
        for _ in range(200):
            if all(lane.future.done() or lane.axis.follower.state.value in ("intercepting", "following")
                   for lane in lanes):
                return
            await asyncio.sleep(lanes[0].axis.dt)

    # -- points ---------------------------------------------------------------------------------
    def _points(self, plan: Plan, lanes: list[Lane], now: float, first: bool = False) -> _Points:
        """Points from the grid time after the last queued one (or just before ``now``) to
        ``horizon`` ahead, cut before the first one that breaks a limit."""
        cfg = self.owner.config
        req = plan.request
        dt = getattr(req.target, "spacing", None) or cfg.sample_spacing
        if first or self._last_t is None:
            t0 = math.floor(now / dt) * dt
            if req.start is not None and req.start > t0:      # a pass that rises later
                t0 = math.ceil(req.start / dt) * dt
        else:
            t0 = self._last_t + dt
        t1 = max(now, t0) + cfg.horizon
        # room: points already passed count as free (add_points drops them) — counting them as
        # taken starved the refill of a queue filled in one go (a satellite's 0.5 s points in a
        # 120-point buffer: "ran out of points" 58 s into the pass)
        free = min(lane.axis.queue.capacity if first else lane.axis.queue.free_points_at(now)
                   for lane in lanes)
        n = int(math.floor((t1 - t0) / dt + 1e-9)) + 1
        n = max(0, min(n, free - 4))
        times = t0 + dt * np.arange(n)
        if self._t_end is not None:
            times = times[times <= self._t_end]
        out = _Points(times)
        if times.size == 0:
            for lane in lanes:
                out.values[lane.role] = np.zeros(0)
            return out
        pipe = self.owner.pipeline()
        d = pipe.demand_observed(req.observed(pipe.astrometry, times, self.owner.ut1_utc), plan.reverse)
        ok = d.zd <= self.owner.zd_limit
        reason = np.where(ok, "", "set")
        for lane in lanes:
            if lane.role == "axis1":
                raw = d.axis1
            elif lane.role == "axis2":
                raw = d.axis2
            else:
                raw = field_angle(pipe.mount, d.observed.pa, d.axis2, plan.reverse, lane.port) + req.pa
            sec = lane.axis.section
            if sec.cyclic or lane.role != "axis2":
                ref = lane.start if lane.last is None else lane.last
                raw = np.unwrap(np.concatenate(([ref], raw)), period=360.0)[1:]
            out.values[lane.role] = raw
            off = lane.axis.offset
            inside = (raw + off >= sec.min) & (raw + off <= sec.max)
            reason = np.where((reason == "") & ~inside, lane.axis.module_name, reason)
            ok &= inside
        envelope = getattr(self.owner, "envelope", None)
        if envelope is not None and "axis2" in out.values:   # the safety envelope: stop before it
            j = envelope.judge(out.values["axis1"] + lanes[0].axis.offset,
                               out.values["axis2"] + lanes[1].axis.offset,
                               times - self.owner.ut1_utc, escape=False)
            if not j.ok:
                self._envelope_text = j.text
                reason = np.where((reason == "") & (np.arange(times.size) >= j.good), "envelope", reason)
                ok[j.good:] = False
        good = _leading(ok)
        if good < times.size:
            # the path ends at its last good point: in this batch, else the last one queued
            # (a refill whose first point is past the set: not now, while points remain)
            if good:
                self._t_end = float(times[good - 1])
            elif not first and self._last_t is not None:
                self._t_end = self._last_t
            else:
                self._t_end = float(now)
            bad = str(reason[good])
            self._end_reason = bad if bad in ("set", "envelope") else f"limit:{bad}"
            out.times = times[:good]
            for key in out.values:
                out.values[key] = out.values[key][:good]
        for lane in lanes:
            if out.times.size:
                lane.last = float(out.values[lane.role][-1])
        return out

    def _refill(self, now: float) -> None:
        lanes = self.lanes
        if not lanes or self._last_t is None:
            return
        if self._t_end is not None and self._last_t >= self._t_end:
            return
        remaining = min(lane.axis.queue.remaining(now) for lane in lanes)
        if remaining >= self.owner.config.refill_below:
            return
        points = self._points(self.plan, lanes, now)
        if points.times.size == 0:
            return
        for lane in lanes:
            lane.axis.queue.add_points(points.times, points.values[lane.role], now)
        self._last_t = float(points.times[-1])
        self._check_zenith(points)

    # -- endings --------------------------------------------------------------------------------
    def _planned_end(self) -> TcsError | None:
        if self._end_reason == "set" and getattr(self.plan.request.target, "ends_normally", False):
            return None          # a satellite pass that set as planned: tracking ended as asked
        if self._end_reason == "envelope":
            return TcsError(f"stopped before {getattr(self, '_envelope_text', 'the envelope')}",
                            ErrorNumber.SOFTLIMIT)
        if self._end_reason.startswith("limit:"):
            name = self._end_reason.split(":", 1)[1]
            return TcsError(f"{name} would leave its software limits", ErrorNumber.SOFTLIMIT)
        return TcsError(f"the target set below the altitude limit "
                        f"{90.0 - self.owner.zd_limit:g}°", ErrorNumber.SOFTLIMIT)

    def _ended(self, lane: Lane) -> TcsError:
        """Why an axis's trajectory ended by itself (not by this session's RUN=0)."""
        fut = lane.future
        name = lane.axis.module_name
        if fut.cancelled():
            return TcsError(f"{name}: trajectory cancelled", ErrorNumber.TARGETCHANGE)
        exc = fut.exception()
        if isinstance(exc, TcsError):  # (the axis's own errors name it already)
            text = exc.message if exc.message.startswith(f"{name}:") else f"{name}: {exc.message}"
            return TcsError(text, exc.number)
        if exc is not None:
            return TcsError(f"{name}: {exc!r}", ErrorNumber.INTERNAL)
        reason = getattr(lane.axis.follower, "end_reason", None)
        if reason == "end":
            if self._t_end is not None:
                return self._planned_end()
            return TcsError(f"{name}: trajectory ran out of points", ErrorNumber.INTERNAL)
        return TcsError(f"{name}: trajectory stopped (STOP, TARGETPOS or RUN=0)",
                        ErrorNumber.TARGETCHANGE)

    # -- the dome -------------------------------------------------------------------------------
    def _sync_dome(self, now: float) -> None:
        """DOME[0] to the target's azimuth when it deviates by more than DOME_DEVIATION."""
        dome = self.plan.dome
        if dome is None or (self._dome_move is not None and not self._dome_move.done()):
            return
        req = self.plan.request
        if req.start is not None and now < req.start:
            now = req.start
        az = float(np.atleast_1d(req.observed(self.owner.pipeline().astrometry, now, self.owner.ut1_utc).az)[0])
        if abs(math.remainder(dome.current_position - az, 360.0)) <= self.owner.dome_deviation:
            return
        try:
            self._dome_move = asyncio.ensure_future(dome.set_target(az))
        except TcsError as exc:
            self._dome_trouble(exc)
            return
        self._dome_move.add_done_callback(self._dome_done)

    def _dome_done(self, fut: asyncio.Future) -> None:
        if fut.cancelled():
            return
        exc = fut.exception()
        if exc is None:
            self._dome_stuck = False
        elif isinstance(exc, TcsError):
            self._dome_trouble(exc)

    def _dome_trouble(self, exc: TcsError) -> None:
        if not self._dome_stuck and self.active:
            self._dome_stuck = True
            self.owner.emit(WARN, DOME_STUCK, f"the dome does not follow: {exc.message}", self.cause)

    # -- near the zenith ------------------------------------------------------------------------
    def _check_zenith(self, points: _Points) -> None:
        """Report when the azimuth path needs more speed or acceleration than the axis has:
        a passage through the zenith keyhole *while tracking*. A path that starts in the
        keyhole — tracking switched on at the zenith park position (Alpaca's Tracking=True
        there tracks the zenith), then a slew elsewhere — is not one: its first stretch, up to
        the first sample the axis can follow, is what the axes slew (intercept) over anyway,
        so it raises nothing (it latched a warning after every normal slew out of the park)."""
        lane = next((ln for ln in self.lanes if ln.role == "axis1"), None)
        if lane is None or self.owner.pipeline().mount != "AZ-ZD" or points.times.size < 3:
            return
        x, t = points.values["axis1"], points.times
        v = np.diff(x) / np.diff(t)
        a = np.diff(v) / np.diff(t[:-1])
        sec = lane.axis.section
        fast = np.abs(v) > _LIMITED_SHARE * sec.max_velocity
        hard = np.abs(a) > _LIMITED_SHARE * sec.max_acceleration
        bad = np.concatenate((fast[:-1] | hard, fast[-1:]))   # per interval of the samples
        if self._zenith_leaving:
            followable = np.flatnonzero(~bad)
            if followable.size == 0:
                return                     # still leaving the keyhole the path started in
            self._zenith_leaving = False
            bad[:followable[0]] = False
        if not bad.any():
            return
        idx = np.flatnonzero(bad)
        self._zenith_until = max(self._zenith_until, float(t[idx[-1] + 1]))
        if not self._zenith:
            self._zenith = True
            text = (f"near the zenith {lane.axis.module_name} needs {np.abs(v).max():.3g}°/s, "
                    f"{np.abs(a).max() if a.size else 0.0:.3g}°/s² (limits {sec.max_velocity:g}°/s, "
                    f"{sec.max_acceleration:g}°/s²): it follows within its limits and lags")
            self.owner.raise_condition("zenith", WARNING, text)
            self.owner.emit(WARN, ZENITH_LIMITED, text, self.cause)

    def _watch_zenith(self, now: float) -> None:
        if not self._zenith or now < self._zenith_until:
            return
        lane = next((ln for ln in self.lanes if ln.role == "axis1"), None)
        if lane is not None and lane.axis.motion_state & 16:   # still limited / chasing
            return
        self._zenith = False
        self.owner.clear_condition("zenith")
        self.owner.emit(INFO, ZENITH_CLEAR, f"{lane.axis.module_name if lane else 'axis'} follows "
                                            "the path again", self.cause)


def parse_track(value: int) -> tuple[int, int]:
    """Split a TRACK value into (mode 0–4, flags); RANGE for anything else."""
    value = int(value)
    mode, flags = value & MODE_MASK, value & ~MODE_MASK
    if mode > 4 or flags & ~(FLAG_DOME | FLAG_DEROTATOR) or value < 0:
        raise RequestRefused(f"TRACK {value}: modes are 0-4, flags 128 (dome) and 256 (derotator)",
                             keyword="RANGE")
    return mode, flags

