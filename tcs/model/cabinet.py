"""CABINET: main power, referencing of all axes, STOP, the combined error state (spec §6).

:class:`Cabinet` is the domain object of the CABINET module and a
:class:`~tcs.model.health.ModuleHealth` of its own (conditions not belonging to one module:
emergency off, UPS, fans …). It holds two lists that may grow after construction
(:meth:`attach`): ``axes`` (generic axes) and ``modules`` (every other domain object with an
``ERROR_STATE``; those with ``power(on)`` / ``stop()`` take part in POWER and STOP).

POWER (long-running; ``set_power`` returns an awaitable)
    1: main power on (``main_power`` becomes True — individual ``<axis>.POWER`` needs it —
    and the optional ``main_switch(True)`` hook runs), then every component in a safe order,
    one after the other: the axes sorted by ``reference_order`` (main axes first), then the
    other modules with ``power``. ``POWER_STATE`` stays 0 until all are on, then 1. The first
    component that fails ends the SET with its number (``FAILED n``) and an event
    ``CABINET:n``; main power stays on, ``POWER_STATE`` 0.
    0: STOP everything, then power off in reverse order; a component that fails does not keep
    the others (nor main power) on; the first failure is reported at the end.
    A newer POWER supersedes a running one (the older SET fails with 10 targetchange); STOP
    and emergency off (5 invmode) end it too. ``POWERCHANGE`` (21) events mark every change
    of main power or ``POWER_STATE``. ``POWER_STATE`` is −1 while emergency off is active
    (:meth:`set_emergency_off`, for a PLC input).

REINIT (returns at once; referencing runs in the background)
    0: reference the axes whose ``REFERENCED`` < 1; 1: all of them (``reference(force=True)``).
    Axes run in groups of equal ``reference_order``, lowest first, the axes of a group in
    parallel. **Safety rule:** when an axis of a main group (order < 2: ZD/DEC, AZ/HA) fails,
    the groups after it are not started (a telescope whose main axes are not known should not
    move its other mechanisms unattended); a failure in a later group does not stop the
    remaining ones. Events ``CABINET:18`` at the start, ``:19`` when all asked for are
    referenced, ``:20`` (ERROR) naming the failed and the skipped axes, ``:20`` (INFO) when
    STOP ended it. Needs main power on and no POWER sequence running (else 5 invmode);
    a REINIT while one runs is refused with BUSY.

STOP (returns at once)
    Ends a running POWER or REINIT sequence (the POWER SET fails with 10), then calls
    ``stop()`` of every axis and module. A module whose stop raises does not keep the others
    from stopping.

ERROR_STATE
    The OR of the cabinet's own conditions and every module's ``error_state``; every change
    of that OR emits ``CABINET:15`` (the cabinet follows the modules' own ERRORCHANGE events
    on the event hub). Writing 0 acknowledges every module, the cabinet, and resets the
    ``Count`` column of CABINET.STATUS.LIST.

MANUAL_CONTROL
    Our cabinets have no hand paddle: ``MODE`` (key switch) and ``SELECTION`` read 0,
    ``ACTIVE`` is a flag clients may set (it completes at once, with a MANUALCONTROL (16)
    event when it changes) and ``BRIGHTNESS`` is stored (persisted) for a paddle that may come.
    The effective manual control, ``MODE`` AND ``ACTIVE``, is therefore always off.

``MODE`` is 1 (remote operation permitted): there is no local/remote key switch either.

Threads: everything runs on the event loop except condition reports and event emission,
which ModuleHealth and the event hub make thread-safe.
"""

from __future__ import annotations

import asyncio
import inspect
import logging
import threading
import time
from typing import Any, Awaitable, Callable

from tcs.config import HwConfig
from tcs.errors import ErrorNumber, RangeRefused, RequestRefused, TcsError
from tcs.model.cabinet_info import CabinetSetup, DriveDiagnostics, loop_figure
from tcs.model.events import ERROR, INFO
from tcs.model.health import ERROR as ERROR_BIT
from tcs.model.health import PANIC, ModuleHealth
from tcs.model.log_buffer import LogBuffer
from tcs.model.state_store import StateStore
from tcs.model.status_list import StatusList

log = logging.getLogger(__name__)

#: Groups with a lower ``reference_order`` are the main axes (see REINIT's safety rule).
MAIN_AXES_ORDER = 2


class _Job:
    """A background sequence (POWER or REINIT) that STOP or a newer request may end."""

    def __init__(self, kind: str, task: asyncio.Task, result: asyncio.Future | None):
        self.kind = kind
        self.task = task
        self.result = result
        self.reason: TcsError | None = None

    def cancel(self, reason: TcsError) -> None:
        if self.reason is None:
            self.reason = reason
        self.task.cancel()


class ManualControl:
    """CABINET.MANUAL_CONTROL without a paddle (see the module docstring)."""

    mode = 0
    selection = 0

    def __init__(self, store: StateStore, events=None):
        self._store = store
        self._events = events
        self.active = 0
        saved = store.get("cabinet_manual_control", {}) or {}
        self.brightness = float(saved.get("brightness", 1.0))

    def set_active(self, value: int) -> None:
        value = int(value)
        if value != self.active:
            self.active = value
            if self._events is not None:
                self._events.emit(INFO, "CABINET", ErrorNumber.MANUALCONTROL,
                                  "manual control enabled" if value else "manual control disabled")

    def set_brightness(self, value: float) -> None:
        self.brightness = float(value)
        self._store.update(cabinet_manual_control={"brightness": self.brightness})


class Cabinet(ModuleHealth):
    """Domain object of the CABINET module.

    Parameters
    ----------
    config:
        The hardware file (``[cabinet]`` and the drives' identities for SETUP).
    store:
        Persistent state (STATUS.LIST, MANUAL_CONTROL.BRIGHTNESS).
    events:
        The telescope's event hub.
    modules, axes:
        Initial members (copied into lists that :meth:`attach` extends).
    log_buffer:
        The ring of STATUS.LOG[]; by default one of ``[cabinet] log_lines`` lines.
    clock:
        Wall clock for STATUS.LIST ages.
    """

    mode = 1

    def __init__(self, config: HwConfig, store: StateStore, events, modules=(), axes=(),
                 log_buffer: LogBuffer | None = None, clock: Callable[[], float] = time.time):
        self.status_list = StatusList(store, clock=clock)
        super().__init__("CABINET", events, hw_type=config.cabinet.hw_type, status_sink=self.status_list)
        self.axes: list[Any] = []
        self.modules: list[Any] = []
        self._members: tuple[Any, ...] = ()  # axes then modules, each once (see attach)
        self._health_members: tuple[ModuleHealth, ...] = ()  # their ERROR_STATE is pushed here
        self._members_error = 0   # OR of the _health_members' ERROR_STATE (kept current)
        self._other_members: tuple[Any, ...] = ()  # members that are not ModuleHealth: read each time
        self._members_lock = threading.Lock()
        self.setup = CabinetSetup(config)
        self.manual_control = ManualControl(store, events)
        self.log_buffer = log_buffer if log_buffer is not None else LogBuffer(config.cabinet.log_lines)
        #: Optional ``async main_switch(on)``: the contactor behind main power (a PLC coil).
        self.main_switch: Callable[[bool], Awaitable[None]] | None = None
        #: Optional ``loop_stats()`` -> mapping/object with cycles, late, missed, max_lateness.
        self.loop_stats: Callable[[], Any] | None = None
        self._main_power = False
        self._power_state = 0.0
        self._power_demand = 0
        self._emergency = False
        self._jobs: list[_Job] = []
        self._published = 0
        self._publish_lock = threading.Lock()
        self._batch = False
        self._unsubscribe = events.subscribe(self._on_event) if events is not None else None
        self.attach(modules=modules, axes=axes)
        self._drives: list[DriveDiagnostics] | None = None

    # -- members ----------------------------------------------------------------------------------
    def attach(self, *, modules=(), axes=()) -> None:
        """Add modules and axes; a ModuleHealth without a status sink gets the STATUS.LIST."""
        for m in axes:
            if m is not self and m not in self.axes:
                self.axes.append(m)
                self._connect_sink(m)
        for m in modules:
            if m is not self and m not in self.modules:
                self.modules.append(m)
                self._connect_sink(m)
        seen, members = set(), []
        for m in (*self.axes, *self.modules):
            if m is not self and id(m) not in seen:
                seen.add(id(m))
                members.append(m)
        self._members = tuple(members)
        self._health_members = tuple(m for m in members if isinstance(m, ModuleHealth))
        self._other_members = tuple(m for m in members if not isinstance(m, ModuleHealth))
        for m in self._health_members:
            m.on_error_state = self._member_error_changed
        self._member_error_changed()

    def _member_error_changed(self) -> None:
        """A member's ERROR_STATE changed (any thread, under that member's lock)."""
        with self._members_lock:
            state = 0
            for m in self._health_members:
                state |= m.error_state
            self._members_error = state

    def _connect_sink(self, module: Any) -> None:
        if isinstance(module, ModuleHealth) and module._status_sink is None:
            module._status_sink = self.status_list

    @property
    def status_sink(self) -> StatusList:
        """The ``status_sink`` to give every ModuleHealth (callable, plus ``acknowledged(device)``)."""
        return self.status_list

    def members(self) -> list[Any]:
        """Axes then modules, each once, never the cabinet (as of the last :meth:`attach`)."""
        return list(self._members)

    def power_order(self) -> list[Any]:
        """Components in the order they are switched on (reversed for off)."""
        axes = sorted(self.axes, key=lambda a: getattr(a, "reference_order", MAIN_AXES_ORDER))
        others = [m for m in self.modules if m not in axes and m is not self
                  and callable(getattr(m, "power", None))]
        return [a for a in axes if a is not self] + others

    # -- lifecycle ----------------------------------------------------------------------------------
    async def start(self) -> None:
        """On the event loop: write STATUS.LIST from here, capture the ``tcs`` log."""
        self.status_list.bind_loop()
        self.log_buffer.install("tcs")

    async def close(self) -> None:
        """End running sequences (5 invmode), write STATUS.LIST, stop capturing the log.
        Does not switch or stop hardware: the telescope's shutdown does that."""
        tasks = self._cancel_jobs(TcsError("the service is stopping", ErrorNumber.INVMODE))
        if tasks:
            await asyncio.wait(tasks)
        if self._unsubscribe is not None:
            self._unsubscribe()
            self._unsubscribe = None
        self.status_list.unbind_loop()
        self.log_buffer.remove()

    # -- power ----------------------------------------------------------------------------------------
    @property
    def main_power(self) -> bool:
        """True while main power is on (individual ``<axis>.POWER`` needs it)."""
        return self._main_power

    @property
    def power(self) -> int:
        """The last demanded POWER (0/1)."""
        return self._power_demand

    @property
    def power_state(self) -> float:
        return -1.0 if self._emergency else self._power_state

    def set_power(self, value: int) -> Awaitable[None]:
        """``CABINET.POWER``: the awaitable ends when every component reached the state."""
        on = bool(int(value))
        if on and self._emergency:
            raise TcsError("emergency off is active: release it before switching power on",
                           ErrorNumber.INVMODE)
        kinds = ("POWER",) if on else ("POWER", "REINIT")
        previous = self._cancel_jobs(TcsError("superseded by a newer CABINET.POWER",
                                              ErrorNumber.TARGETCHANGE), kinds)
        self._power_demand = int(on)
        job = self._start_job("POWER", lambda: self._power_sequence(on, previous), result=True)
        return job.result  # type: ignore[return-value]

    async def _power_sequence(self, on: bool, previous: list[asyncio.Task]) -> None:
        if previous:
            await asyncio.wait(previous)
        if on:
            await self._power_on()
        else:
            await self._power_off()

    async def _power_on(self) -> None:
        if self.main_switch is not None:
            await self.main_switch(True)
        self._set_power(True, self._power_state, "main power on, switching the components on")
        for component in self.power_order():
            try:
                await _maybe_await(component.power(True))
            except asyncio.CancelledError:
                raise
            except Exception as exc:
                err = _as_tcs_error(exc, component, "power on")
                self._emit(ERROR, err.number, f"power on stopped at {_name(component)}: {err}")
                raise err from exc
        self._set_power(True, 1.0, "power on")

    async def _power_off(self) -> None:
        self._set_power(self._main_power, 0.0, "switching power off")
        self.stop_motion()
        first: TcsError | None = None
        for component in reversed(self.power_order()):
            try:
                await _maybe_await(component.power(False))
            except asyncio.CancelledError:
                raise
            except Exception as exc:
                err = _as_tcs_error(exc, component, "power off")
                self._emit(ERROR, err.number, f"power off of {_name(component)} failed: {err}")
                first = first or err
        if self.main_switch is not None:
            try:
                await self.main_switch(False)
            except TcsError as exc:
                self._emit(ERROR, exc.number, f"main power off failed: {exc}")
                first = first or exc
        self._set_power(False, 0.0, "power off")
        if first is not None:
            raise first

    def _set_power(self, main: bool, state: float, text: str) -> None:
        if (main, state) != (self._main_power, self._power_state):
            self._main_power, self._power_state = main, state
            self._emit(INFO, ErrorNumber.POWERCHANGE, text)

    def set_emergency_off(self, active: bool, text: str = "emergency off") -> None:
        """An emergency-off input changed (PLC): −1 POWER_STATE, everything stopped, PANIC."""
        if active and not self._emergency:
            self._emergency = True
            self._cancel_jobs(TcsError(text, ErrorNumber.INVMODE))
            self.stop_motion()
            self._power_demand = 0
            self._main_power, self._power_state = False, 0.0
            self.raise_condition("emergency_off", PANIC, text)
            self._emit(ERROR, ErrorNumber.POWERCHANGE, text)
        elif not active and self._emergency:
            self._emergency = False
            self.clear_condition("emergency_off")
            self._emit(INFO, ErrorNumber.POWERCHANGE, "emergency off released; main power is off")

    # -- referencing --------------------------------------------------------------------------------
    @property
    def referenced(self) -> float:
        """Mean of the axes' REFERENCED (1.0 without axes)."""
        if not self.axes:
            return 1.0
        total = 0.0
        for axis in self.axes:
            try:
                total += min(1.0, max(0.0, float(axis.referenced)))
            except Exception:
                log.debug("REFERENCED of %s unreadable", _name(axis), exc_info=True)
        return total / len(self.axes)

    def set_reinit(self, value: int) -> None:
        """``CABINET.REINIT``: start referencing in the background (see the module docstring)."""
        if self._running("REINIT"):
            raise RequestRefused("referencing is already running (STOP ends it)", keyword="BUSY")
        if self._emergency or not self._main_power:
            raise TcsError("main power is off", ErrorNumber.INVMODE)
        if self._running("POWER"):
            raise TcsError("power is being switched; REINIT when CABINET.POWER has completed",
                           ErrorNumber.INVMODE)
        force = bool(int(value))
        plan = self.reference_plan(force)
        if not plan:
            self._emit(INFO, ErrorNumber.REFERENCE_GOOD, "all components are referenced")
            return
        names = ", ".join(_name(a) for _, axes in plan for a in axes)
        self._emit(INFO, ErrorNumber.REFERENCE_EXECUTE, f"referencing {names}")
        self._start_job("REINIT", lambda: self._reference_all(plan, force, names), result=False)

    def reference_plan(self, force: bool) -> list[tuple[int, list[Any]]]:
        """The axes REINIT references, as (reference_order, axes) groups, lowest order first."""
        groups: dict[int, list[Any]] = {}
        for axis in self.axes:
            if force or _referenced(axis) < 1.0:
                groups.setdefault(int(getattr(axis, "reference_order", MAIN_AXES_ORDER)), []).append(axis)
        return [(order, groups[order]) for order in sorted(groups)]

    async def _reference_all(self, plan: list[tuple[int, list[Any]]], force: bool, names: str) -> None:
        failed: list[str] = []
        skipped: list[str] = []
        main_failed = False
        for order, axes in plan:
            if main_failed:
                skipped.extend(_name(a) for a in axes)
                continue
            results = await asyncio.gather(*(_reference(a, force) for a in axes), return_exceptions=True)
            for axis, result in zip(axes, results):
                if isinstance(result, BaseException):
                    failed.append(f"{_name(axis)}: {_as_tcs_error(result, axis, 'referencing')}")
                    main_failed |= order < MAIN_AXES_ORDER
        if failed or skipped:
            text = "referencing failed: " + "; ".join(failed)
            if skipped:
                text += "; not started: " + ", ".join(skipped)
            self._emit(ERROR, ErrorNumber.REFERENCE_BAD, text)
        else:
            self._emit(INFO, ErrorNumber.REFERENCE_GOOD, f"referenced {names}")

    # -- STOP -------------------------------------------------------------------------------------------
    def set_stop(self, value: int) -> None:
        """``CABINET.STOP``: returns at once."""
        self.stop()

    def stop(self) -> None:
        """End POWER/REINIT sequences (10 targetchange), then stop every axis and module."""
        self._cancel_jobs(TcsError("stopped by CABINET.STOP", ErrorNumber.TARGETCHANGE))
        undelivered = self.stop_motion()
        if undelivered is not None:  # CABINET.STOP answers FAILED n: one part did not get it
            raise undelivered

    def stop_motion(self) -> TcsError | None:
        """Call ``stop()`` of every axis and module (all of them, whatever fails); returns the
        first stop that could not be delivered (a PLC unreachable: 4/3), else None."""
        undelivered: TcsError | None = None
        for member in self.members():
            stop = getattr(member, "stop", None)
            if not callable(stop):
                continue
            try:
                stop()
            except TcsError as exc:
                log.warning("STOP of %s failed: %s", _name(member), exc)
                undelivered = undelivered or exc
            except Exception:
                log.exception("STOP of %s failed", _name(member))
        return undelivered

    # -- ERROR_STATE ------------------------------------------------------------------------------------
    @property
    def error_state(self) -> int:
        state = self._error_state | self._members_error
        for member in self._other_members:
            try:
                state |= int(getattr(member, "error_state", 0) or 0)
            except Exception:
                log.debug("ERROR_STATE of %s unreadable", _name(member), exc_info=True)
        return state

    def acknowledge_errors(self, value: int):
        """``CABINET.ERROR_STATE=0``: acknowledge every module, the cabinet and the list's counts;
        long-running while drive fault resets are under way (completes when they ended)."""
        if value != 0:
            raise RangeRefused("only 0 (acknowledge) may be written to ERROR_STATE")
        self._batch = True
        try:
            resets = self._acknowledge(self.members())
        finally:
            self._batch = False
        super().acknowledge_errors(0)
        self.status_list.acknowledged(None)
        self._publish("acknowledged")
        return _all_reset(resets) if resets else None

    def acknowledge_modules(self, mask: int):
        """Acknowledge only the modules whose ERROR_STATE has a bit of ``mask`` (OpenTSI's
        STATUS.CLEAR by severity); None, or an awaitable as :meth:`acknowledge_errors` returns."""
        resets = self._acknowledge([m for m in self.members()
                                    if int(getattr(m, "error_state", 0) or 0) & mask])
        return _all_reset(resets) if resets else None

    @staticmethod
    def _acknowledge(members) -> list:
        """ERROR_STATE=0 of each of ``members``; the drive axes' fault resets under way (an
        axis's acknowledge is long-running: complete when every reset ended, fail — why — when
        one did not reset)."""
        resets = []
        for member in members:
            ack = getattr(member, "acknowledge_errors", None)
            if callable(ack):
                try:
                    result = ack(0)
                    if inspect.isawaitable(result):
                        resets.append(result)
                except Exception:
                    log.exception("acknowledging %s failed", _name(member))
        return resets

    def _changed(self, before: int, text: str) -> None:  # ModuleHealth hook
        self._publish(text)

    def _on_event(self, event) -> None:
        if event.number == ErrorNumber.ERRORCHANGE and event.source != self.module_name and not self._batch:
            self._publish(f"{event.source}: {event.text}", event.cause)

    def _publish(self, text: str, cause=None) -> None:
        """Emit CABINET:15 when the combined ERROR_STATE changed since the last one."""
        after = self.error_state
        with self._publish_lock:
            before, self._published = self._published, after
        if after != before and self._events is not None:
            level = ERROR if after & (PANIC | ERROR_BIT) > before & (PANIC | ERROR_BIT) else INFO
            self._events.emit(level, self.module_name, ErrorNumber.ERRORCHANGE, text, cause=cause)

    # -- STATUS, CORE ----------------------------------------------------------------------------------
    def clear_status(self, value: int) -> None:
        """``CABINET.STATUS.CLEAR=-1``."""
        self.status_list.clear(value)

    def core_drives(self) -> list[DriveDiagnostics]:
        """``CORE.DRIVE[]``: one element per axis (fixed when the tree is built)."""
        if self._drives is None or len(self._drives) != len(self.axes):
            self._drives = [DriveDiagnostics(a) for a in self.axes]
        return self._drives

    def loop_figure(self, name: str) -> float:
        return loop_figure(self.loop_stats, name)

    # -- jobs -------------------------------------------------------------------------------------------
    def _running(self, kind: str) -> bool:
        return any(j.kind == kind and not j.task.done() for j in self._jobs)

    def job_running(self, kind: str) -> bool:
        """A ``POWER`` or ``REINIT`` sequence is running (front ends wait for it, not supersede it)."""
        return self._running(kind)

    def _start_job(self, kind: str, factory: Callable[[], Awaitable[None]], result: bool) -> _Job:
        loop = asyncio.get_running_loop()
        job = _Job(kind, None, loop.create_future() if result else None)  # type: ignore[arg-type]
        job.task = loop.create_task(_run(factory), name=f"CABINET {kind}")
        # the done callback runs in this (the command's) context: its events name the command
        job.task.add_done_callback(lambda _task: self._job_done(job))
        if job.result is not None:  # the client's ABORT cancels the wait: end the sequence too
            job.result.add_done_callback(lambda f: job.task.cancel() if f.cancelled() else None)
        self._jobs = [j for j in self._jobs if not j.task.done()] + [job]
        return job

    def _job_done(self, job: _Job) -> None:
        """Turn the task's outcome into the SET's result (also when cancelled before it ran)."""
        exc: BaseException | None
        if job.task.cancelled():
            exc = job.reason or TcsError(f"CABINET {job.kind} ended", ErrorNumber.TARGETCHANGE)
            if job.kind == "REINIT":
                self._emit(INFO, ErrorNumber.REFERENCE_BAD, "referencing stopped")
        else:
            exc = job.task.exception()
            if exc is not None and not isinstance(exc, TcsError):
                log.error("CABINET %s failed", job.kind, exc_info=exc)
                exc = TcsError(f"CABINET {job.kind} failed: {exc!r}", ErrorNumber.INTERNAL)
        if job.result is not None and not job.result.done():
            if exc is None:
                job.result.set_result(None)
            else:
                job.result.set_exception(exc)

    def _cancel_jobs(self, reason: TcsError, kinds=("POWER", "REINIT")) -> list[asyncio.Task]:
        victims = [j for j in self._jobs if j.kind in kinds and not j.task.done()]
        for job in victims:
            job.cancel(reason)
        return [j.task for j in victims]

    def _emit(self, level: str, number: int, text: str) -> None:
        if self._events is not None:
            self._events.emit(level, self.module_name, number, text)


def _name(member: Any) -> str:
    return str(getattr(member, "module_name", type(member).__name__))


def _referenced(axis: Any) -> float:
    try:
        return float(axis.referenced)
    except Exception:
        return 0.0


async def _run(factory: Callable[[], Awaitable[None]]) -> None:
    await factory()  # created here: a job cancelled before it ran leaves no coroutine behind


async def _reference(axis: Any, force: bool) -> None:
    await _maybe_await(axis.reference(force))


async def _maybe_await(value: Any) -> None:
    if inspect.isawaitable(value):
        await value


def _as_tcs_error(exc: BaseException, member: Any, what: str) -> TcsError:
    if isinstance(exc, TcsError):
        return exc
    if isinstance(exc, asyncio.CancelledError):
        return TcsError(f"{_name(member)}: {what} cancelled", ErrorNumber.TARGETCHANGE)
    log.error("%s of %s failed: %r", what, _name(member), exc)
    return TcsError(f"{_name(member)}: {what} failed: {exc!r}", ErrorNumber.INTERNAL)


__all__ = ["Cabinet", "ManualControl", "MAIN_AXES_ORDER"]


async def _all_reset(resets: list) -> None:
    """``CABINET.ERROR_STATE=0``'s wait for the axes' fault resets: done when all ended; a reset
    that failed fails the acknowledge with its reason (it used to answer done while an
    ``AZ.ERROR_STATE`` stayed 2)."""
    results = await asyncio.gather(*resets, return_exceptions=True)
    errors = [r for r in results if isinstance(r, BaseException)]
    if errors:
        first = errors[0]
        text = "; ".join(getattr(e, "message", str(e)) for e in errors)
        raise TcsError(f"not every error was reset: {text}",
                       getattr(first, "number", ErrorNumber.LIBFAIL))
