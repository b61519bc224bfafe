"""The OpenTCI generic axis (spec §5.1) on PLC axes: the DOME[] parts and the COVERs.

How it works
------------
The PLC runs the motion; the TCS writes a target and a command and reads the state back
(:class:`~tcs.drivers.plc_axis.PlcAxis`, the axis convention of :mod:`tcs.config.plc`).
:class:`PlcAxisModule` serves the same attribute names as the drive-based
:class:`~tcs.axes.axis.Axis`, so the one generic-axis declaration
(:func:`tcs.opentci_server.opentci.axes.axis_members`) serves both. Everything runs on the event
loop: setters validate at once and return an ``asyncio.Future`` for long SETs; the PLC
driver's poll listener (:meth:`PlcAxisModule._on_poll`, once per poll cycle) publishes the
readbacks, emits the change events and resolves the futures. An :class:`AxisGroup` lets one
module move several PLC axes as one (the petals of a mirror cover;
:mod:`tcs.model.plc_axis_group`).

Semantics, where a PLC axis differs from a drive:

``TARGETPOS`` (long)
    Completes when, in a poll read after the PLC accepted the command (``X_command`` back to
    0), the axis stands still with ``at_target`` — i.e. only at the end position. Fails with
    the PLC's fault (7 timeout for a stalled motor, 2 libfail otherwise), 8 limit when it
    stopped short on an end switch, 2 when it stopped short elsewhere, 7 after ``timeout``
    seconds (the axis is then stopped), 4/3 when the PLC is lost, 10 when superseded or
    stopped, 5 when powered off. Opening moves of guarded parts first ask the weather
    interlock (:mod:`tcs.model.interlocks`), which may refuse them (FAILED 1020).
``POWER``
    There is no amplifier to enable: ``POWER_STATE`` is 1.0 while the TCS's power demand is on
    *and* the PLC is connected *and* the axis is not faulted, else 0.0. The demand starts off;
    ``POWER=1`` (or ``CABINET.POWER=1``, which switches every module) needs main power and a
    connected, unfaulted PLC; ``POWER=0`` stops the axis and refuses moves (5 invmode). Both
    complete at once. A PLC that comes back restores ``POWER_STATE`` by itself.
Status while the PLC is unreachable
    ``REALPOS``, ``CURRPOS``, ``POWER``/``POWER_STATE``, ``MOTION_STATE``, ``LIMIT_STATE``,
    ``CURRSPEED`` and ``TARGETDISTANCE`` answer ``FAILED 4`` (``3`` when the PLC hangs), the
    link's number (:attr:`PlcAxisModule.stale`), never the last value polled.
``REFERENCED``
    Always 1.0: PLC axes measure absolute positions (end switches, absolute encoders).
    ``REINIT`` only confirms that with ``EVENT INFO <module>:19``.
``STOP``
    Writes the stop command; pending TARGETPOS/OFFSET fail with 10, a running trajectory ends
    (its RUN completes). ``TARGETPOS`` then reads where the axis came to rest. While the PLC
    is unreachable the stop cannot be delivered: pending SETs still end, and STOP fails with the
    link's number (``FAILED 4``/``3``) and an ``EVENT ERROR``; the driver writes stop to every
    axis of the PLC as soon as the link returns, before anything else, so the aborted move never
    resumes.
``OFFSET``
    Only where allowed (the dome rotation, DOME[0]); elsewhere refused (INVALID). As for a
    drive: added to every positioning request, long SET until on target.
``CURRSPEED``
    Read from the PLC's ``X_speed`` point (0.0 without one); writing is refused (INVALID): the
    PLC sets the speed. ``CURRACC``/``CURRJRK`` read 0.0 (spec §10 allows that for domes); their
    !MIN/!MAX come from the hardware file.
``LIMIT_STATE``
    Bits 0/1 are the closed/open end switches (``closed``/``open`` status bits), bit 7 when one
    is active while the axis is faulted; bits 8/9 when the position is within ``tolerance`` of
    min/max (the closed and the fully open positions). Never on a cyclic axis.
``MOTION_STATE``
    Bit 0 moving (PLC), 1 trajectory, 2 blocked (PLC fault), 3 on target (PLC ``at_target``,
    not while a new command is on its way; on the path within ``track_tolerance`` while a
    trajectory runs).
``ERROR_STATE``
    ERROR while the PLC is unreachable (:mod:`tcs.model.plc_link`) or the axis is faulted. A
    fault also switches the power demand off; ``ERROR_STATE=0`` sends the PLC's reset command
    and forgets the fault once the PLC shows none; then ``POWER=1`` again.

The trajectory of a rotating dome (``TRAJECTORY``) is :mod:`tcs.model.plc_trajectory`.
"""

from __future__ import annotations

import asyncio
import logging
from typing import Callable

from tcs.axes.axis import complete_futures
from tcs.axes.limits import limit_text
from tcs.drivers.modbus import PlcConnectionEvent, PlcSnapshot
from tcs.drivers.plc_axis import AxisState
from tcs.errors import CommunicationError, ErrorNumber, HardwareError, RangeRefused, RequestRefused, TcsError
from tcs.model.events import ERROR, INFO, current_cause
from tcs.model.health import ERROR as ERROR_BIT
from tcs.model.plc_axis_group import AxisGroup, PlcAxisSettings
from tcs.model.plc_link import PlcModule

log = logging.getLogger(__name__)

#: MOTION_STATE and LIMIT_STATE bits (spec §5.1; the same as tcs.axes.axis).
MOVING, TRAJECTORY, BLOCKED, ON_TARGET = 1, 2, 4, 8
HW_MIN, HW_MAX, HW_BLOCKING, SW_MIN, SW_MAX = 1, 2, 128, 256, 512
#: Poll cycles an accepted command may show neither motion nor arrival before it counts as
#: stopped short (a PLC may start the motor a cycle after accepting the command).
START_GRACE = 3


class PlcAxisModule(PlcModule):
    """One generic-axis module (``DOME[n]``, ``COVER``, ``COVER[n]``) on a PLC axis group.

    Parameters
    ----------
    module_name:
        ``DOME[1]``, ``COVER`` …
    group:
        The PLC axes it moves.
    settings:
        Limits and figures (``section`` of the declaration).
    events:
        The telescope's event hub.
    main_power:
        Whether CABINET main power is on (``POWER=1`` needs it).
    offset_allowed:
        Whether ``OFFSET`` may be written (the dome rotation only).
    guarded:
        Whether the weather interlock guards its opening moves.
    """

    #: The PLC runs the motion at its own speed: ``CURRSPEED`` is served read-only.
    speed_writable = False

    discrete = False
    positions: dict = {}
    referenced = 1.0
    current_acc = 0.0
    current_jerk = 0.0
    reference_order = 3  # after the telescope's axes when the cabinet switches power on

    def __init__(self, module_name: str, group: AxisGroup, settings: PlcAxisSettings, *, events=None,
                 main_power: Callable[[], bool] = lambda: True, hw_type: int = 1, status_sink=None,
                 offset_allowed: bool = False, guarded: bool = False):
        super().__init__(module_name, events, hw_type=hw_type, status_sink=status_sink)
        self.group = group
        self.section = settings
        self.main_power = main_power
        self.offset_allowed = offset_allowed
        self.guarded = guarded
        self.interlock = None        # set by the weather interlock that guards it
        self.trajectory = None       # a PlcTrajectory for the dome rotation
        # readbacks
        self.power_state = 0.0
        self.real_position = 0.0
        self.current_speed = 0.0
        self.motion_state = 0
        self.limit_state = 0
        self.offset = 0.0
        self.state: AxisState | None = None
        # demand and motion bookkeeping
        self._power_on = False
        self._fault: TcsError | None = None
        self._ack_pending = False
        self._demand: float | None = None      # TARGETPOS (user frame) once commanded
        self._settle_demand = False            # after STOP: TARGETPOS becomes the rest position
        self._gen = 0                          # generation of the last command written
        self._after: int | None = None         # its poll cycle (None while being written)
        self._seen_moving = False
        self._idle_polls = 0
        self._unsettled = False                # a command not yet reflected by a poll
        self._pending: dict[str, tuple[asyncio.Future, object]] = {}
        self._timer: asyncio.TimerHandle | None = None
        self._tasks: set[asyncio.Task] = set()
        self._remove_poll = None
        self.closing = False                   # moving to closed by the weather interlock

    # ================================================================ life cycle

    def start(self) -> None:
        """Follow the PLC (call on the event loop once its driver runs)."""
        self._remove_poll = self.group.driver.add_poll_listener(self._on_poll)
        self.watch(self.group.driver)
        snap = self.group.driver.snapshot
        if snap.valid:
            self._on_poll(snap)

    async def shutdown(self, timeout: float = 2.0) -> None:
        """Service stopping: stop the axis (unless the weather interlock is closing it), end
        pending SETs (5 invmode), stop following the PLC."""
        if self.trajectory is not None:
            self.trajectory.halt()
        self._fail_motion(TcsError(f"{self.module_name}: the service is stopping", ErrorNumber.INVMODE),
                          run_ok=False)
        if not self.closing and self.plc_connected and (self.state is None or self.state.moving):
            try:
                await asyncio.wait_for(self.group.stop(), timeout)
            except (TcsError, asyncio.TimeoutError) as exc:
                log.warning("%s: stop at shutdown failed: %s", self.module_name, exc)
        self.close()
        tasks = list(self._tasks)
        for task in tasks:
            task.cancel()
        if tasks:
            await asyncio.wait(tasks)

    def close(self) -> None:
        if self._remove_poll is not None:
            self._remove_poll()
            self._remove_poll = None
        self.unwatch()
        self._cancel_timer()

    # ================================================================ readbacks

    @property
    def stale(self) -> CommunicationError | None:
        """The error for readbacks while no fresh PLC poll exists (the PLC unreachable, or
        not polled yet): REALPOS, POWER_STATE, MOTION_STATE … answer it (OpenTCI ``FAILED 4``
        or ``3``, the link's number; OpenTSI the same; Alpaca an error) instead of the last
        value polled, as a drive axis does while its drive is offline."""
        link = self.link_error()
        if link is not None:
            return CommunicationError(self.group.device, f"no fresh data ({link.message})", link.number)
        if not self.group.driver.snapshot.valid:
            return CommunicationError(self.group.device, "no fresh data (not polled yet)", ErrorNumber.NOCON)
        return None

    @property
    def cyclic(self) -> float:
        return self.section.cyclic

    def wrap(self, value: float) -> float:
        """A position of a cyclic axis folded into ``[min, min + cycle)``."""
        c = self.section.cyclic
        return self.section.min + (value - self.section.min) % c if c else value

    @property
    def current_position(self) -> float:
        return self.wrap(self.real_position - self.offset)

    @property
    def target_position(self) -> float:
        if self.trajectory is not None and self.trajectory.running:
            return self.wrap(self.trajectory.path_now())
        if self._demand is not None:
            return self._demand
        return self.wrap((self.state.target if self.state else self.real_position) - self.offset)

    @property
    def target_distance(self) -> float:
        d = self.target_position - self.current_position
        c = self.section.cyclic
        return (d + c / 2) % c - c / 2 if c else d

    @property
    def trajectory_running(self) -> bool:
        return self.trajectory is not None and self.trajectory.running

    # ================================================================ setters

    def _require(self, what: str) -> None:
        if self._fault is not None:
            raise TcsError(f"{self.module_name}: cannot {what}: {self._fault.message}; acknowledge "
                           f"with ERROR_STATE=0 first", self._fault.number)
        link = self.link_error()
        if link is not None:
            raise TcsError(f"{self.module_name}: cannot {what}: {link.message}", link.number)
        if not self._power_on:
            raise TcsError(f"{self.module_name}: cannot {what}: power is off (POWER=1)", ErrorNumber.INVMODE)

    def _future(self) -> asyncio.Future:
        return asyncio.get_running_loop().create_future()

    def set_power(self, value: int):
        """``POWER``: 1 permits motion, 0 stops and forbids it (both complete at once)."""
        return self.power(bool(int(value)))

    def power(self, on: bool):
        if on:
            if not self.main_power():
                raise TcsError(f"{self.module_name}: main power (CABINET.POWER) is off", ErrorNumber.INVMODE)
            link = self.link_error()
            if link is not None:
                raise TcsError(f"{self.module_name}: {link.message}", link.number)
            if self._fault is not None:
                raise TcsError(f"{self.module_name}: {self._fault.message}; acknowledge with "
                               f"ERROR_STATE=0 first", self._fault.number)
            self._power_on = True
        elif self._power_on:
            self._power_on = False
            self._halt(TcsError(f"{self.module_name}: power off", ErrorNumber.INVMODE))
        self._update_power()
        return None

    @property
    def command_pending(self) -> bool:
        """A command (move, STOP) was written that no poll of the PLC has reflected yet."""
        return self._unsettled

    def set_target(self, value: float):
        """``TARGETPOS`` (long): completes at the end position (see the module docstring)."""
        self._require("move")
        value = float(value)
        goal = value + self.offset
        s = self.section
        if not s.cyclic and not s.min - 1e-9 <= goal <= s.max + 1e-9:
            raise RangeRefused(f"{self.module_name}: {value:g} (+ offset {self.offset:g}) is outside "
                               f"[{s.min:g}, {s.max:g}]")
        if self.guarded and self.interlock is not None:
            self.interlock.check_move(self, self.wrap(goal))
        future = self._future()
        if self.trajectory_running:
            self.trajectory.halt()
            self._resolve("run")
        self._hold("target", future)
        self._demand = self.wrap(value) if s.cyclic else value
        self.emit(INFO, ErrorNumber.MOTIONCHANGE, f"moving to {value:g}")
        self._command(goal)
        return future

    def set_offset(self, value: float):
        """``OFFSET`` (long; the dome rotation only)."""
        if not self.offset_allowed:
            raise RequestRefused(f"{self.module_name} takes no OFFSET (only the dome rotation, DOME[0])")
        self._require("apply an offset")
        value = float(value)
        future = self._future()
        self._hold("offset", future)
        base = self.target_position
        self.offset = value
        if self.trajectory_running:
            self.trajectory.offset_changed()
        else:
            self._demand = base
            self._command(base + value)
        return future

    def set_speed(self, value: float) -> None:
        raise RequestRefused(f"{self.module_name}: the PLC runs the motion at its own speed; "
                             "CURRSPEED is read-only here")

    def set_reinit(self, value: int) -> None:
        """``REINIT``: nothing to do — PLC axes are absolute (returns at once)."""
        self.emit(INFO, ErrorNumber.REFERENCE_GOOD, "PLC axes measure absolute positions: referenced")

    def set_stop(self, value: int) -> None:
        self.stop()

    def stop(self) -> None:
        """Stop the axis (returns at once; CABINET.STOP calls it too).

        Raises
        ------
        CommunicationError
            The PLC is unreachable: the stop was not delivered (it is written on reconnect).
        """
        self._halt(TcsError(f"{self.module_name}: stopped", ErrorNumber.TARGETCHANGE))
        if not self.plc_connected:
            error = self.link_error() or CommunicationError(self.group.device, "not connected", ErrorNumber.NOCON)
            text = "STOP not delivered: the PLC is unreachable; stop is written when the link returns"
            self.emit(ERROR, error.number, text)
            raise CommunicationError(self.group.device, text, error.number)

    def set_run(self, value: int):
        """``TRAJECTORY.RUN`` (dome rotation): 1 long until the path ended or was aborted; 0
        aborts, stops the dome and frees the buffers."""
        trajectory = self.trajectory
        if not int(value):
            if trajectory.running:
                trajectory.halt()
                self._resolve("run")
                self._halt(None)
            trajectory.queue.clear()
            return None
        self._require("run a trajectory")
        if len(trajectory.queue) == 0:
            raise TcsError(f"{self.module_name}: the trajectory queue is empty (ADDPOINTS first)",
                           ErrorNumber.NOPOINTS)
        future = self._future()
        for key in ("target", "offset"):
            old = self._pending.pop(key, None)
            if old is not None:
                self._finish(old[0], TcsError(f"{self.module_name}: a trajectory started", ErrorNumber.TARGETCHANGE))
        self._hold("run", future)
        self._demand = None
        self._gen += 1
        self._cancel_timer()
        trajectory.start()
        self.emit(INFO, ErrorNumber.MOTIONCHANGE, "trajectory started")
        return future

    def on_acknowledge(self) -> None:
        """``ERROR_STATE=0``: reset the PLC axis' fault; forget it once the PLC shows none."""
        if self._fault is None:
            return
        if self.state is not None and not self.state.fault:
            self._forget_fault()
        elif self.plc_connected:
            self._ack_pending = True
            self._spawn(self.group.reset(), "fault reset")

    def safety_close(self, reason: TcsError) -> bool:
        """The weather interlock closes this part now, whatever POWER says (the PLC's motors are
        the PLC's); pending SETs fail with ``reason``. Returns whether a move was written."""
        if self.trajectory_running:
            self.trajectory.halt()
        self._fail_motion(reason, run_ok=False)
        if self._fault is not None or not self.plc_connected:
            return False
        if self.state is not None and self.state.closed and not self.state.moving:
            return False
        self.closing = True
        self._demand = self.section.min
        self._command(self.section.min)
        return True

    # ================================================================ commands to the PLC

    def _command(self, goal: float) -> None:
        """Write a move to ``goal`` (PLC frame); pending SETs wait for arrival there."""
        self._gen += 1
        gen = self._gen
        self._after = None
        self._unsettled = True
        self._seen_moving = False
        self._idle_polls = 0
        self._settle_demand = False
        self._cancel_timer()
        self._timer = asyncio.get_running_loop().call_later(self.section.timeout, self._on_timeout, gen)
        self._spawn(self._write(gen, self.group.move(self.wrap(goal))), "move")

    def _halt(self, error: TcsError | None) -> None:
        """Stop: end the trajectory, fail pending TARGETPOS/OFFSET with ``error``, write STOP."""
        if self.trajectory_running:
            self.trajectory.halt()
        if error is not None:
            self._fail_motion(error)
        self.closing = False
        self._gen += 1
        self._after = None
        self._unsettled = True
        self._cancel_timer()
        self._settle_demand = True
        if self.plc_connected:
            self._spawn(self._write(self._gen, self.group.stop()), "stop")

    async def _write(self, gen: int, write) -> None:
        try:
            after = await write
        except TcsError as exc:
            if gen == self._gen:
                self._unsettled = False
                self._settle_demand = False
                self._fail_motion(exc, run_ok=False)
                self.emit(ERROR, exc.number, f"command not taken: {exc.message}")
            return
        if gen == self._gen:
            self._after = after

    def write_track(self, goal: float) -> asyncio.Task:
        """A trajectory's next aim point (PLC frame, no pending SET); returns the write task."""
        gen = self._gen
        return self._spawn(self._write(gen, self.group.move(self.wrap(goal))), "trajectory")

    def _spawn(self, coro, what: str) -> asyncio.Task:
        task = asyncio.get_running_loop().create_task(coro, name=f"{self.module_name} {what}")
        self._tasks.add(task)
        task.add_done_callback(self._task_done)
        return task

    def _task_done(self, task: asyncio.Task) -> None:
        self._tasks.discard(task)
        if not task.cancelled() and task.exception() is not None:
            exc = task.exception()
            if isinstance(exc, TcsError):
                log.info("%s: %s", self.module_name, exc)
            else:
                log.error("%s: %s failed", self.module_name, task.get_name(), exc_info=exc)

    def _on_timeout(self, gen: int) -> None:
        self._timer = None
        if gen != self._gen or not ({"target", "offset"} & self._pending.keys()):
            return
        error = HardwareError(self.group.device, f"move not finished within {self.section.timeout:g} s",
                              ErrorNumber.TIMEOUT)
        self.emit(ERROR, ErrorNumber.TIMEOUT, error.message)
        self._halt(error)

    def _cancel_timer(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    # ================================================================ pending SETs

    def _hold(self, key: str, future: asyncio.Future) -> None:
        old = self._pending.pop(key, None)
        if old is not None:
            self._finish(old[0], TcsError(f"{self.module_name}: target changed", ErrorNumber.TARGETCHANGE))
            self.emit(ERROR, ErrorNumber.TARGETCHANGE, "target changed", old[1])
        self._pending[key] = (future, current_cause.get())

    def abort_request(self, cause, awaitable=None) -> None:
        """TPL2 ABORT of the command ``cause``: if a TARGETPOS, OFFSET or TRAJECTORY.RUN of
        that command still runs here, the part stops (as STOP); else nothing happens."""
        if cause is None or not any(key in self._pending and self._pending[key][1] == cause
                                    for key in ("target", "offset", "run")):
            return
        try:
            self.stop()
        except TcsError:  # PLC unreachable: stop() reported it and writes it on reconnect
            pass

    def cause_of(self, key: str):
        """The command (connection id, command id) of the pending SET ``key``, for its events."""
        entry = self._pending.get(key)
        return entry[1] if entry is not None else None

    def _resolve(self, key: str, error: TcsError | None = None) -> None:
        entry = self._pending.pop(key, None)
        if entry is not None:
            self._finish(entry[0], error)

    @staticmethod
    def _finish(future: asyncio.Future, error: TcsError | None) -> None:
        complete_futures(((future, error),))

    def _fail_motion(self, error: TcsError, run_ok: bool = True) -> None:
        """Fail pending TARGETPOS/OFFSET; RUN completes (STOP) or fails with them."""
        self._resolve("target", error)
        self._resolve("offset", error)
        if self.trajectory_running:
            self.trajectory.halt()
        self._resolve("run", None if run_ok and error.number == ErrorNumber.TARGETCHANGE else error)

    # ================================================================ the PLC's side

    def on_link(self, event: PlcConnectionEvent) -> None:
        if not event.connected:
            error = TcsError(f"{self.module_name}: PLC {event.plc}: {event.message}",
                             event.number or ErrorNumber.NOCON)
            self._fail_motion(error, run_ok=False)
            self._gen += 1
            self._after = None
            self._unsettled = False
            self._settle_demand = False
            self._cancel_timer()
            self.closing = False
        elif self.interlock is not None:
            self.interlock.reconnected(self)  # the driver wrote stop at connect: close again if due
        self._update_power()

    def _on_poll(self, snap: PlcSnapshot) -> None:
        st = self.group.state(snap)
        self.state = st
        self._watch_fault(st)
        self.real_position = st.position
        self.current_speed = st.speed if st.speed is not None else 0.0
        settled = self._after is not None and snap.cycle > self._after and self.group.accepted(snap)
        if settled:
            self._unsettled = False
        if self._settle_demand and settled and not st.moving:
            self._settle_demand = False
            self._demand = self.current_position
        if self.closing and settled and not st.moving:
            self.closing = False
        trajectory = self.trajectory
        if trajectory is not None and trajectory.running:
            trajectory.step(st, snap)
        self._publish(st)
        self._update_power()
        if settled and {"target", "offset"} & self._pending.keys() and not self.trajectory_running:
            self._check_arrival(st)

    def _check_arrival(self, st: AxisState) -> None:
        if st.fault:
            return  # _watch_fault failed them
        if st.moving:
            self._seen_moving = True
            return
        if st.at_target:
            self._cancel_timer()
            self._resolve("target")
            self._resolve("offset")
            return
        self._idle_polls += 1
        if self._seen_moving or self._idle_polls >= START_GRACE:
            at_switch = st.closed or st.open
            error = HardwareError(self.group.device, f"stopped at {st.position:g}, short of the target",
                                  ErrorNumber.LIMIT if at_switch else ErrorNumber.LIBFAIL)
            self.emit(ERROR, error.number, error.message)
            self._cancel_timer()
            self._fail_motion(error, run_ok=False)
            self._demand = self.current_position

    def _watch_fault(self, st: AxisState) -> None:
        if st.fault and self._fault is None:
            if st.stalled:
                self._fault = HardwareError(self.group.device, f"motor stalled at {st.position:g}",
                                            ErrorNumber.TIMEOUT)
            else:
                self._fault = HardwareError(self.group.device, f"PLC reports a fault at {st.position:g}",
                                            ErrorNumber.LIBFAIL)
            self._power_on = False
            self.closing = False
            self.raise_condition("axis fault", ERROR_BIT, self._fault.message)
            self.emit(ERROR, self._fault.number, self._fault.message)
            self._cancel_timer()
            self._fail_motion(self._fault, run_ok=False)
            self._demand = self.current_position
        elif not st.fault and self._fault is not None:
            if self._ack_pending:
                self._forget_fault()
            elif self.conditions().get("axis fault", (0, False))[1]:
                self.clear_condition("axis fault")

    def _forget_fault(self) -> None:
        self._fault = None
        self._ack_pending = False
        if self.conditions().get("axis fault", (0, False))[1]:
            self.clear_condition("axis fault")

    def _publish(self, st: AxisState) -> None:
        s = self.section
        motion = MOVING if st.moving else 0
        if self.trajectory_running:
            motion |= TRAJECTORY
            if self.trajectory.on_path:
                motion |= ON_TARGET
        elif st.at_target and not st.moving and not st.fault and not self._unsettled:
            motion |= ON_TARGET
        limit = 0
        if not s.cyclic:
            limit |= (HW_MIN if st.closed else 0) | (HW_MAX if st.open else 0)
            if limit and st.fault:
                limit |= HW_BLOCKING
            tol = max(s.tolerance, 1e-9)
            limit |= (SW_MIN if st.position <= s.min + tol else 0) | (SW_MAX if st.position >= s.max - tol else 0)
        if st.fault:
            motion |= BLOCKED
        before_motion, before_limit = self.motion_state, self.limit_state
        self.motion_state, self.limit_state = motion, limit
        if (motion ^ before_motion) & (MOVING | TRAJECTORY | BLOCKED):
            self.emit(INFO, ErrorNumber.MOTIONCHANGE, "moving" if motion & MOVING else "stopped")
        if limit != before_limit:
            self.emit(INFO, ErrorNumber.LIMITCHANGE, limit_text(limit))

    def _update_power(self) -> None:
        state = 1.0 if self._power_on and self.plc_connected and self._fault is None else 0.0
        if state != self.power_state:
            self.power_state = state
            self.emit(INFO, ErrorNumber.POWERCHANGE, "power on" if state else "power off")
