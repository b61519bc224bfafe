"""The INDI devices of the equipment: focuser, filter wheels, rotators, dome and weather.

What maps to what
-----------------
Each device exists only where the hardware file has its part, over the same model calls the
Alpaca devices use (:mod:`tcs.alpaca.equipment`), never through them:

* **TCS Focuser** (``FOCUS``): ``ABS_FOCUS_POSITION`` ``FOCUS_ABSOLUTE_POSITION`` in steps of
  1 µm (position = round(CURRPOS × 1000), the axis's limits in µm), ``FOCUS_MAX``,
  ``FOCUS_ABORT_MOTION``. A move powers the axis (not main power), references it on the first
  move, then TARGETPOS — as the Alpaca focuser (:func:`ready_then`). Busy while moving, Ok at the
  target, Alert with the reason when refused or failed.
* **TCS Filter** (one per ``FILTER[]`` wheel; ``TCS Filter 2`` … for more): ``FILTER_SLOT``
  ``FILTER_SLOT_VALUE`` 1 … N (INDI counts from 1) = the hardware file's ``positions`` sorted,
  ``FILTER_NAME`` ``FILTER_SLOT_NAME_1`` … from its ``names`` (read-only: the names are the
  hardware file's). A change powers, references (first time) and moves the wheel.
* **TCS Rotator** (one per ``DEROTATOR[]``; ``TCS Rotator 2`` …): ``ABS_ROTATOR_ANGLE`` ``ANGLE``
  is the sky angle of the Alpaca rotator's model — sky = (±mechanical + sync offset) mod 360,
  − while reversed, shared with Alpaca (the state file's ``alpaca_rotators``): both front ends
  show one angle. ``SYNC_ROTATOR_ANGLE`` sets the offset without moving, ``ROTATOR_REVERSE``
  turns the direction keeping the angle, ``ROTATOR_ABORT_MOTION`` stops. A move goes to the
  turn of the cyclic axis nearest to where it stands, inside the limits.
* **TCS Dome** (``DOME[]``): ``ABS_DOME_POSITION`` ``DOME_ABSOLUTE_POSITION`` = the rotation
  (DOME[0]) in degrees; ``DOME_MOTION`` ``DOME_CW``/``DOME_CCW`` turns it on (increasing /
  decreasing azimuth) until Off or abort, its target kept 90…180° ahead; ``DOME_SHUTTER``
  ``SHUTTER_OPEN``/``SHUTTER_CLOSE`` moves every opening part (slit, flap, roof, fold, shells)
  as the Alpaca dome does — opening refused by the weather interlock with its reason;
  ``DOME_ABORT_MOTION`` stops every part. No ``DOME_PARK``: the hardware file has no park
  position for a dome (Alpaca's CanPark is False too). The dome follows the telescope through
  the TCS's tracking (POINTING.TRACK +128), not through INDI's slaving.
* **TCS Dust Cap** (one per ``COVER``; ``TCS Dust Cap 2`` …): ``CAP_PARK`` PARK closes the
  cover, UNPARK opens it (refused by the weather interlock with its reason), ``CAP_ABORT``
  stops it. No light box: no calibrator is configured (Alpaca's CalibratorState NotPresent).
* **TCS Weather** (sensors or the weather interlock): ``WEATHER_STATUS`` lights —
  ``WEATHER_INTERLOCK`` Ok while the interlock lets the dome and covers open, Alert while it
  refuses (its reason is the property's message), and one light per cause (rain, wind, weather
  unknown); ``WEATHER_PARAMETERS`` the weather sensors among ``SENSOR[]`` (recognised by their
  point's name as for Alpaca's ObservingConditions; wind in km/h as INDI has it).

Each has ``CONNECTION`` (CONNECT powers the focuser, wheel or rotator axis — main power first
when off — as connecting the Alpaca device does; a wheel then references; DISCONNECT changes
nothing) and ``DRIVER_INFO`` with its interface bit (focuser 8, filter 16, rotator 4096, dome
32, weather 128, dust cap 512). Status without a fresh readback (a drive offline, a PLC unreachable) is
Alert with that reason, never the last value.

What may touch it
-----------------
The service's event loop, through :class:`~tcs.indi.server.IndiServer`.
"""

from __future__ import annotations

import asyncio
import inspect
import logging

from tcs.errors import ErrorNumber, TcsError
from tcs.indi.protocol import Element, Vector
from tcs.indi.server import Device, Refused
from tcs.model.equipment_power import power_axis, shielded

log = logging.getLogger(__name__)

MOVING = 1
INTERFACE_FOCUSER, INTERFACE_DOME, INTERFACE_WEATHER, INTERFACE_FILTER = 8, 32, 128, 16
INTERFACE_ROTATOR = 4096
INTERFACE_DUSTCAP = 512
STEP = 1000.0   # focuser steps per mm (1 step = 1 µm)
ROTATOR_STORE = "alpaca_rotators"   # the Alpaca rotator's sync model: one sky angle for both


def _num(name, label, value, fmt, lo, hi, step=0.0):
    return Element(name, label, value, fmt, lo, hi, step)


def _switch(name, label, on=False):
    return Element(name, label, on)


def _version() -> str:
    import tcs
    return str(tcs.__version__)


def names(base: str, count: int) -> list[str]:
    """Device names: ``base`` for the first, ``base 2`` … for more."""
    return [base if i == 0 else f"{base} {i + 1}" for i in range(count)]


def ready_then(telescope, axis, move, device=None):
    """The awaitable of a move of an equipment axis (as Alpaca's ``make_ready_then``):
    ``move()`` at once when the axis is powered and referenced — so that its refusals are the
    request's — else a coroutine that powers the axis (not main power), references it, then
    starts ``move()``. The referencing is kept as ``device.referencing``."""
    if axis.power_state == 1.0 and axis.referenced >= 1.0:
        return move()
    if not telescope.cabinet.main_power:
        raise Refused(f"{axis.module_name}: main power (CABINET.POWER) is off (CONNECT switches it on)")

    async def run():
        await power_axis(telescope, axis, main=False)
        if axis.referenced < 1.0:
            ref = asyncio.ensure_future(axis.reference(False))
            if device is not None:
                device.referencing = ref
            await shielded(ref)
        await shielded(move())
    return run()


class EquipmentDevice(Device):
    """What every equipment device has: CONNECTION, DRIVER_INFO, background operations."""

    INTERFACE = 0

    def __init__(self, telescope, name: str):
        super().__init__()
        self.name = name
        self.telescope = telescope
        self._tasks: dict[str, asyncio.Future] = {}
        self._failures: dict[str, str] = {}
        self.referencing: asyncio.Future | None = None
        d = name
        self.connection = self.add(Vector(d, "CONNECTION", "Switch", [
            _switch("CONNECT", "Connect", True), _switch("DISCONNECT", "Disconnect")],
            label="Connection", group="Main Control", state="Ok"))
        self.info = self.add(Vector(d, "DRIVER_INFO", "Text", [
            Element("DRIVER_NAME", "Name", "tcs"), Element("DRIVER_EXEC", "Exec", "tcs-server"),
            Element("DRIVER_VERSION", "Version", _version()),
            Element("DRIVER_INTERFACE", "Interface", str(self.INTERFACE))],
            label="Driver Info", group="General Info", perm="ro", state="Idle"))

    # -- background operations --------------------------------------------------------------------
    def run(self, key: str, awaitable, what: str) -> None:
        """Run the model's long SET in the background as operation ``key`` (a newer one of the
        same key supersedes it); a failure shows as Alert with its reason."""
        self._failures.pop(key, None)
        old = self._tasks.pop(key, None)
        if old is not None and not old.done():
            old.cancel()
        if awaitable is None:
            return
        # the model's own future (a TARGETPOS) is shielded: an abort ends our waiting, never
        # the SET (it completes or is superseded there); a sequence of ours is cancelled
        inner = shielded(awaitable) if asyncio.isfuture(awaitable) else awaitable

        async def watch():
            try:
                await inner
            except asyncio.CancelledError:
                raise
            except TcsError as exc:
                if exc.number != ErrorNumber.TARGETCHANGE:   # (superseded: no failure)
                    self._failures[key] = f"{what}: {exc.message}"
            except Exception as exc:  # a bug, not a refusal: logged
                log.exception("INDI %s: %s", self.name, what)
                self._failures[key] = f"{what}: {exc}"
        task = asyncio.ensure_future(watch())
        if asyncio.iscoroutine(inner):   # cancelled before it ran: closed, not "never awaited"
            task.add_done_callback(lambda t: t.cancelled() and inspect.getcoroutinestate(inner)
                                   == inspect.CORO_CREATED and inner.close())
        self._tasks[key] = task

    def running(self, key: str) -> bool:
        task = self._tasks.get(key)
        return task is not None and not task.done()

    def halt(self, key: str) -> None:
        task = self._tasks.pop(key, None)
        if task is not None and not task.done():
            task.cancel()
        self._failures.pop(key, None)

    def show(self, vec: Vector, key: str, *, moving: bool, stale=None, done: str = "Ok") -> None:
        """State of a motion property: Alert (no fresh readback, or the operation failed),
        Busy while moving, else ``done``."""
        if stale is not None:
            vec.state, vec.message = "Alert", getattr(stale, "message", str(stale))
        elif key in self._failures:
            vec.state, vec.message = "Alert", self._failures[key]
        elif moving or self.running(key):
            vec.state, vec.message = "Busy", None
        else:
            vec.state, vec.message = done, None

    # -- a client's new values --------------------------------------------------------------------
    def handle(self, name: str, values: dict) -> None:
        handler = getattr(self, "new_" + name.lower(), None)
        if handler is None:
            raise Refused(f"{name} cannot be written")
        handler(values)

    def prepare(self):
        """What CONNECT does besides acknowledging (an awaitable or None)."""
        return None

    def new_connection(self, values: dict) -> None:
        if values.get("CONNECT"):
            self.run("connect", self.prepare(), "connecting")
        self.connection.state = "Busy" if self.running("connect") else "Ok"

    def refresh(self) -> None:
        if self.connection.state == "Busy" and not self.running("connect"):
            failed = self._failures.get("connect")
            self.connection.state, self.connection.message = ("Alert", failed) if failed else ("Ok", None)


def _stale(axis):
    return getattr(axis, "stale", None)


# ------------------------------------------------------------------------------------ Focuser

class FocuserDevice(EquipmentDevice):
    INTERFACE = INTERFACE_FOCUSER

    def __init__(self, telescope, axis, name: str = "TCS Focuser"):
        super().__init__(telescope, name)
        self.axis = axis
        s = axis.section
        lo, hi = round(s.min * STEP), round(s.max * STEP)
        d = self.name
        self.position = self.add(Vector(d, "ABS_FOCUS_POSITION", "Number", [
            _num("FOCUS_ABSOLUTE_POSITION", "Steps", 0.0, "%.f", lo, hi, 1.0)],
            label="Absolute Position"))
        self.maximum = self.add(Vector(d, "FOCUS_MAX", "Number", [
            _num("FOCUS_MAX_VALUE", "Steps", float(hi), "%.f", hi, hi, 1.0)],
            label="Max. Position", group="Main Control", perm="ro", state="Ok"))
        self.abort = self.add(Vector(d, "FOCUS_ABORT_MOTION", "Switch", [_switch("ABORT", "Abort")],
                                     label="Abort Motion", rule="AtMostOne"))

    def prepare(self):
        return power_axis(self.telescope, self.axis)

    def refresh(self) -> None:
        super().refresh()
        axis = self.axis
        stale = _stale(axis)
        if stale is None:
            self.position.element("FOCUS_ABSOLUTE_POSITION").value = float(round(axis.current_position * STEP))
        self.show(self.position, "move", stale=stale, moving=stale is None and bool(axis.motion_state & MOVING),
                  done="Ok" if "move" in self._tasks else "Idle")

    def new_abs_focus_position(self, values: dict) -> None:
        steps = values.get("FOCUS_ABSOLUTE_POSITION")
        if steps is None:
            return
        e = self.position.element("FOCUS_ABSOLUTE_POSITION")
        if steps != round(steps) or not e.min <= steps <= e.max:
            raise Refused(f"FOCUS_ABSOLUTE_POSITION {steps:g} is not a whole step in {e.min:g}…{e.max:g}")
        axis = self.axis
        self.run("move", ready_then(self.telescope, axis, lambda: axis.set_target(steps / STEP), self),
                 "the focuser move")
        self.position.state = "Busy"

    def new_focus_abort_motion(self, values: dict) -> None:
        self.halt("move")
        self.axis.stop()
        self.abort.state = "Ok"


# -------------------------------------------------------------------------------- Filter wheel

class FilterDevice(EquipmentDevice):
    INTERFACE = INTERFACE_FILTER

    def __init__(self, telescope, axis, name: str = "TCS Filter"):
        super().__init__(telescope, name)
        self.axis = axis
        self.keys = sorted(axis.positions)
        labels = axis.section.names
        n = len(self.keys)
        d = self.name
        self.slot = self.add(Vector(d, "FILTER_SLOT", "Number", [
            _num("FILTER_SLOT_VALUE", "Filter", 1.0, "%3.0f", 1.0, float(n), 1.0)],
            label="Filter Slot", group="Filter Wheel"))
        self.names = self.add(Vector(d, "FILTER_NAME", "Text", [
            Element(f"FILTER_SLOT_NAME_{i + 1}", f"Filter#{i + 1}", str(labels.get(str(k), str(k))))
            for i, k in enumerate(self.keys)],
            label="Filter", group="Filter Wheel", perm="ro", state="Ok"))

    def prepare(self):
        axis = self.axis

        async def power_and_reference():   # its slot is unknown until it has referenced
            await power_axis(self.telescope, axis)
            if axis.referenced < 1.0 and not axis.motion_state & MOVING and not self.running("move"):
                self.run("move", axis.reference(False), "referencing")
        return power_and_reference()

    def _slot_here(self) -> int | None:
        axis = self.axis
        if axis.referenced < 1.0 or axis.motion_state & MOVING:
            return None
        here = axis.real_position   # a discrete axis reads the key of the position it is at
        for i, key in enumerate(self.keys):
            if abs(float(key) - here) < 1e-6:
                return i + 1
        return None

    def refresh(self) -> None:
        super().refresh()
        axis = self.axis
        stale = _stale(axis)
        slot = None if stale is not None else self._slot_here()
        if slot is not None and not self.running("move"):
            self.slot.element("FILTER_SLOT_VALUE").value = float(slot)
        self.show(self.slot, "move", stale=stale,
                  moving=stale is None and (bool(axis.motion_state & MOVING) or axis.referenced < 1.0
                                            and "move" in self._tasks),
                  done="Ok" if slot is not None else "Idle")

    def new_filter_slot(self, values: dict) -> None:
        slot = values.get("FILTER_SLOT_VALUE")
        if slot is None:
            return
        n = len(self.keys)
        if slot != round(slot) or not 1 <= slot <= n:
            raise Refused(f"FILTER_SLOT_VALUE {slot:g} is not a slot 1…{n}")
        axis, key = self.axis, self.keys[int(slot) - 1]
        self.run("move", ready_then(self.telescope, axis, lambda: axis.set_target(key), self),
                 f"the change to slot {int(slot)}")
        self.slot.element("FILTER_SLOT_VALUE").value = float(slot)
        self.slot.state = "Busy"


# ------------------------------------------------------------------------------------ Rotator

class RotatorDevice(EquipmentDevice):
    """The sky angle of the Alpaca rotator's model (see the module docstring)."""

    INTERFACE = INTERFACE_ROTATOR

    def __init__(self, telescope, axis, name: str = "TCS Rotator"):
        super().__init__(telescope, name)
        self.axis = axis
        d = self.name
        self.angle = self.add(Vector(d, "ABS_ROTATOR_ANGLE", "Number", [
            _num("ANGLE", "Angle", 0.0, "%.2f", 0.0, 360.0, 0.1)], label="Goto", group="Main Control"))
        self.sync = self.add(Vector(d, "SYNC_ROTATOR_ANGLE", "Number", [
            _num("ANGLE", "Angle", 0.0, "%.2f", 0.0, 360.0, 0.1)], label="Sync", group="Main Control"))
        self.reverse = self.add(Vector(d, "ROTATOR_REVERSE", "Switch", [
            _switch("INDI_ENABLED", "Enabled"), _switch("INDI_DISABLED", "Disabled", True)],
            label="Reverse", group="Main Control", state="Ok"))
        self.abort = self.add(Vector(d, "ROTATOR_ABORT_MOTION", "Switch", [_switch("ABORT", "Abort")],
                                     label="Abort Motion", rule="AtMostOne"))

    def prepare(self):
        return power_axis(self.telescope, self.axis)

    # -- the sync model: sky = (sign × mechanical + offset) mod 360, sign −1 while reversed -----
    def _model(self) -> tuple[float, bool]:
        saved = (self.telescope.store.get(ROTATOR_STORE, {}) or {}).get(self.axis.module_name) or {}
        return float(saved.get("offset", 0.0)), bool(saved.get("reverse", False))

    def _save(self, offset: float, reverse: bool) -> None:
        saved = dict(self.telescope.store.get(ROTATOR_STORE, {}) or {})
        saved[self.axis.module_name] = {"offset": round(offset % 360.0, 9), "reverse": reverse}
        self.telescope.store.update(**{ROTATOR_STORE: saved})

    def _mech_here(self) -> float:
        return float(self.axis.real_position % 360.0)

    def _sky(self, mechanical: float) -> float:
        offset, reverse = self._model()
        return ((-mechanical if reverse else mechanical) + offset) % 360.0

    def _mechanical(self, sky: float) -> float:
        offset, reverse = self._model()
        return ((-(sky - offset)) if reverse else (sky - offset)) % 360.0

    def _turn(self, angle: float) -> float:
        """The drive position of mechanical ``angle`` on the turn nearest to where it stands,
        inside the limits."""
        axis = self.axis
        here = axis.real_position
        base = here + ((angle - here) % 360.0 + 180.0) % 360.0 - 180.0
        for goal in sorted((base + k * 360.0 for k in range(-2, 3)), key=lambda t: abs(t - here)):
            if axis.limits.contains(goal):
                return goal
        raise Refused(f"{angle:g}° (mechanical) cannot be reached inside the limits of {axis.module_name}")

    def refresh(self) -> None:
        super().refresh()
        axis = self.axis
        stale = _stale(axis)
        if stale is None:
            sky = self._sky(self._mech_here())
            self.angle.element("ANGLE").value = sky
            self.sync.element("ANGLE").value = sky
        reverse = self._model()[1]
        self.reverse.element("INDI_ENABLED").value, self.reverse.element("INDI_DISABLED").value = reverse, not reverse
        self.show(self.angle, "move", stale=stale, moving=stale is None and bool(axis.motion_state & MOVING),
                  done="Ok" if "move" in self._tasks else "Idle")

    def new_abs_rotator_angle(self, values: dict) -> None:
        sky = values.get("ANGLE")
        if sky is None:
            return
        if not 0.0 <= sky <= 360.0:
            raise Refused(f"ANGLE {sky:g} is outside 0…360")
        axis = self.axis
        sky %= 360.0

        def move():
            return axis.set_target(self._turn(self._mechanical(sky)) - axis.offset)
        if axis.power_state == 1.0 and axis.referenced >= 1.0:
            self._turn(self._mechanical(sky))   # refused now, not in the background
        self.run("move", ready_then(self.telescope, axis, move, self), "the rotator move")
        self.angle.state = "Busy"

    def new_sync_rotator_angle(self, values: dict) -> None:
        sky = values.get("ANGLE")
        if sky is None:
            return
        if not 0.0 <= sky < 360.0:
            raise Refused(f"ANGLE {sky:g} is outside 0…360")
        if self.axis.referenced < 1.0:
            raise Refused(f"SYNC: {self.axis.module_name} is not referenced (it references on its first move)")
        _offset, reverse = self._model()
        mech = self._mech_here()
        self._save(sky - (-mech if reverse else mech), reverse)
        self.sync.state = "Ok"

    def new_rotator_reverse(self, values: dict) -> None:
        on = values.get("INDI_ENABLED")
        if on is None:
            on = not values.get("INDI_DISABLED", True)
        offset, was = self._model()
        if on != was:
            mech = self._mech_here()
            sky = self._sky(mech)
            self._save(sky - (-mech if on else mech), on)   # the angle stays where it is
        self.reverse.state = "Ok"

    def new_rotator_abort_motion(self, values: dict) -> None:
        self.halt("move")
        self.axis.stop()
        self.abort.state = "Ok"


# --------------------------------------------------------------------------------------- Dome

def _at(part, end: float) -> bool:
    return abs(part.real_position - end) <= max(part.section.tolerance, 1e-6)


class DomeDevice(EquipmentDevice):
    INTERFACE = INTERFACE_DOME
    AHEAD = 90.0   # DOME_MOTION: the target is kept at least this far ahead (and less than 180°)

    def __init__(self, telescope, rotation, shutters, name: str = "TCS Dome"):
        super().__init__(telescope, name)
        self.rotation = rotation
        self.shutters = list(shutters)
        self._motion = 0          # DOME_MOTION direction running: +1 CW, -1 CCW
        self._shutter_goal: bool | None = None
        d = self.name
        if rotation is not None:
            self.position = self.add(Vector(d, "ABS_DOME_POSITION", "Number", [
                _num("DOME_ABSOLUTE_POSITION", "Degrees", 0.0, "%6.2f", 0.0, 360.0, 1.0)],
                label="Absolute Position", group="Main Control"))
            self.motion = self.add(Vector(d, "DOME_MOTION", "Switch", [
                _switch("DOME_CW", "Dome CW"), _switch("DOME_CCW", "Dome CCW")],
                label="Motion", group="Main Control", rule="AtMostOne"))
        else:
            self.position = self.motion = None
        if self.shutters:
            self.shutter = self.add(Vector(d, "DOME_SHUTTER", "Switch", [
                _switch("SHUTTER_OPEN", "Open"), _switch("SHUTTER_CLOSE", "Close")],
                label="Shutter", group="Main Control"))
        else:
            self.shutter = None
        self.abort = self.add(Vector(d, "DOME_ABORT_MOTION", "Switch", [_switch("ABORT", "Abort")],
                                     label="Abort Motion", group="Main Control", rule="AtMostOne"))

    def _parts(self) -> list:
        return ([self.rotation] if self.rotation is not None else []) + self.shutters

    def refresh(self) -> None:
        super().refresh()
        rot = self.rotation
        if rot is not None:
            stale = _stale(rot)
            if stale is None:
                self.position.element("DOME_ABSOLUTE_POSITION").value = float(rot.current_position % 360.0)
                if self._motion and self.running("rotation") and abs(rot.target_distance) < self.AHEAD:
                    self._push_motion()
            moving = stale is None and bool(rot.motion_state & MOVING)
            if self._motion and not self.running("rotation"):
                self._motion = 0
            self.show(self.position, "rotation", stale=stale, moving=moving,
                      done="Ok" if "rotation" in self._tasks else "Idle")
            self.motion.element("DOME_CW").value = self._motion > 0
            self.motion.element("DOME_CCW").value = self._motion < 0
            self.show(self.motion, "rotation", stale=stale, moving=bool(self._motion),
                      done="Idle")
        if self.shutter is not None:
            self._refresh_shutter()

    def _refresh_shutter(self) -> None:
        vec = self.shutter
        stale = next((s for s in (_stale(p) for p in self.shutters) if s is not None), None)
        if stale is None and any(p.motion_state & 4 for p in self.shutters):
            stale = TcsError("a shutter part has a fault", ErrorNumber.INVMODE)
        if stale is not None:
            vec.state, vec.message = "Alert", getattr(stale, "message", str(stale))
            return
        is_open = all(_at(p, p.section.max) for p in self.shutters)
        closed = all(_at(p, p.section.min) for p in self.shutters)
        moving = self.running("shutter") or any(p.motion_state & MOVING for p in self.shutters)
        if moving and self._shutter_goal is not None:
            vec.element("SHUTTER_OPEN").value, vec.element("SHUTTER_CLOSE").value = self._shutter_goal, not self._shutter_goal
        else:
            vec.element("SHUTTER_OPEN").value, vec.element("SHUTTER_CLOSE").value = is_open, closed
        if "shutter" in self._failures:
            vec.state, vec.message = "Alert", self._failures["shutter"]
        elif moving:
            vec.state, vec.message = "Busy", None
        elif is_open or closed:
            vec.state, vec.message = "Ok", None
        else:
            vec.state, vec.message = "Alert", "the shutter stands half-way: neither open nor closed"

    # -- a client's new values --------------------------------------------------------------------
    def _rotation(self, what: str):
        if self.rotation is None:
            raise Refused(f"{what}: this enclosure does not rotate")
        if self.rotation.power_state != 1.0:
            self.rotation.power(True)
        return self.rotation

    def new_abs_dome_position(self, values: dict) -> None:
        az = values.get("DOME_ABSOLUTE_POSITION")
        if az is None:
            return
        if not 0.0 <= az <= 360.0:
            raise Refused(f"DOME_ABSOLUTE_POSITION {az:g} is outside 0…360")
        rot = self._rotation("ABS_DOME_POSITION")
        self._motion = 0
        self.run("rotation", rot.set_target(az % 360.0), "the dome rotation")
        self.position.state = "Busy"

    def _push_motion(self) -> None:
        rot = self.rotation
        goal = (rot.current_position + self._motion * (180.0 - 1.0)) % 360.0
        self.run("rotation", rot.set_target(goal), "the dome rotation")

    def new_dome_motion(self, values: dict) -> None:
        cw, ccw = values.get("DOME_CW"), values.get("DOME_CCW")
        if cw and ccw:
            raise Refused("DOME_MOTION: one direction at a time")
        rot = self._rotation("DOME_MOTION")
        if not cw and not ccw:   # Off: stop
            self._motion = 0
            self.halt("rotation")
            rot.stop()
            self.motion.state = "Idle"
            return
        self._motion = 1 if cw else -1
        try:
            self._push_motion()
        except Exception:
            self._motion = 0
            raise
        self.motion.element("DOME_CW").value, self.motion.element("DOME_CCW").value = bool(cw), bool(ccw)
        self.motion.state = "Busy"

    def new_dome_shutter(self, values: dict) -> None:
        if values.get("SHUTTER_OPEN") and values.get("SHUTTER_CLOSE"):
            raise Refused("DOME_SHUTTER: open or close, not both")
        if values.get("SHUTTER_OPEN"):
            open_ = True
        elif values.get("SHUTTER_CLOSE"):
            open_ = False
        else:
            return
        for part in self.shutters:
            if part.power_state != 1.0:
                part.power(True)
        moves = []
        for part in self.shutters:   # the weather interlock refuses before anything moves
            moves.append(part.set_target(part.section.max if open_ else part.section.min))

        async def all_of():
            await asyncio.gather(*(shielded(m) for m in moves))
        self._shutter_goal = open_
        self.run("shutter", all_of(), "opening the shutter" if open_ else "closing the shutter")
        self.shutter.element("SHUTTER_OPEN").value, self.shutter.element("SHUTTER_CLOSE").value = open_, not open_
        self.shutter.state = "Busy"

    def new_dome_abort_motion(self, values: dict) -> None:
        self._motion = 0
        self.halt("rotation")
        self.halt("shutter")
        for part in self._parts():
            part.stop()
        self.abort.state = "Ok"


# ---------------------------------------------------------------------------------- Dust cap

class DustCapDevice(EquipmentDevice):
    """A mirror cover (``COVER``) as INDI's dust cap: CAP_PARK PARK closes it, UNPARK opens it."""

    INTERFACE = INTERFACE_DUSTCAP

    def __init__(self, telescope, cover, name: str = "TCS Dust Cap"):
        super().__init__(telescope, name)
        self.cover = cover
        self._goal: bool | None = None     # True: closing (PARK)
        self.cap = self.add(Vector(self.name, "CAP_PARK", "Switch", [
            _switch("PARK", "Park"), _switch("UNPARK", "Unpark")], label="Dust Cover", group="Main Control"))
        self.abort = self.add(Vector(self.name, "CAP_ABORT", "Switch", [_switch("ABORT", "Abort")],
                                     label="Abort", group="Main Control", rule="AtMostOne"))

    def refresh(self) -> None:
        super().refresh()
        cover, vec = self.cover, self.cap
        stale = _stale(cover)
        if stale is None and cover.motion_state & 4:
            stale = TcsError(f"{cover.module_name} has a fault", ErrorNumber.INVMODE)
        if stale is not None:
            vec.state, vec.message = "Alert", getattr(stale, "message", str(stale))
            return
        closed, is_open = _at(cover, cover.section.min), _at(cover, cover.section.max)
        moving = self.running("move") or bool(cover.motion_state & MOVING)
        if not (moving and self._goal is not None):
            vec.element("PARK").value, vec.element("UNPARK").value = closed, is_open
        if "move" in self._failures:
            vec.state, vec.message = "Alert", self._failures["move"]
        elif moving:
            vec.state, vec.message = "Busy", None
        elif closed or is_open:
            vec.state, vec.message = "Ok", None
        else:
            vec.state, vec.message = "Alert", "the cover stands half-way: neither open nor closed"

    def new_cap_park(self, values: dict) -> None:
        if values.get("PARK") and values.get("UNPARK"):
            raise Refused("CAP_PARK: PARK or UNPARK, not both")
        if values.get("PARK"):
            close = True
        elif values.get("UNPARK"):
            close = False
        else:
            return
        cover = self.cover
        if cover.power_state != 1.0:
            cover.power(True)
        move = cover.set_target(cover.section.min if close else cover.section.max)   # (the interlock)
        self._goal = close
        self.run("move", move, "closing the cover" if close else "opening the cover")
        self.cap.element("PARK").value, self.cap.element("UNPARK").value = close, not close
        self.cap.state = "Busy"

    def new_cap_abort(self, values: dict) -> None:
        self.halt("move")
        self.cover.stop()
        self.abort.state = "Ok"


# ------------------------------------------------------------------------------------ Weather

#: INDI's weather parameter ← the sensor point names it is read from (as Alpaca's ObservingConditions)
WEATHER = {
    "WEATHER_TEMPERATURE": (("temp_outside", "temperature", "air_temperature"), "Temperature (C)"),
    "WEATHER_PRESSURE": (("pressure", "air_pressure"), "Pressure (hPa)"),
    "WEATHER_HUMIDITY": (("humidity", "relative_humidity"), "Humidity (%)"),
    "WEATHER_WIND_SPEED": (("wind_speed", "windspeed"), "Wind (kph)"),
    "WEATHER_WIND_GUST": (("wind_gust",), "Gust (kph)"),
    "WEATHER_WIND_DIRECTION": (("wind_direction", "winddirection"), "Wind Direction"),
    "WEATHER_DEWPOINT": (("dew_point", "dewpoint"), "Dew Point (C)"),
    "WEATHER_CLOUD_COVER": (("cloud_cover",), "Clouds (%)"),
    "WEATHER_RAIN_RATE": (("rain_rate",), "Rain (mm/h)"),
    "WEATHER_SKY_TEMPERATURE": (("sky_temperature",), "Sky Temperature (C)"),
    "WEATHER_SQM": (("sky_quality",), "SQM (mag/arcsec^2)"),
}
CAUSES = (("WEATHER_RAIN", "rain", "Rain"), ("WEATHER_WIND", "wind", "Wind"),
          ("WEATHER_SENSORS", "unknown", "Weather known"))


def weather_sensors(sensors) -> dict:
    out = {}
    for sensor in sensors:
        point = sensor.point.split(".", 1)[0].lower()
        for key, (points, _label) in WEATHER.items():
            if point in points and key not in out:
                out[key] = sensor
    return out


class WeatherDevice(EquipmentDevice):
    INTERFACE = INTERFACE_WEATHER

    def __init__(self, telescope, sensors: dict, interlock, name: str = "TCS Weather"):
        super().__init__(telescope, name)
        self.sensors = sensors
        self.interlock = interlock
        d = self.name
        lights = []
        if interlock is not None:
            lights.append(Element("WEATHER_INTERLOCK", "Interlock (opening allowed)", "Idle"))
            lights.extend(Element(name, label, "Idle") for name, _cause, label in CAUSES)
        self.status = self.add(Vector(d, "WEATHER_STATUS", "Light", lights, label="Status",
                                      group="Main Control")) if lights else None
        self.parameters = self.add(Vector(d, "WEATHER_PARAMETERS", "Number", [
            _num(key, WEATHER[key][1], 0.0, "%4.2f", -1000.0, 100000.0) for key in sensors],
            label="Parameters", group="Parameters", perm="ro")) if sensors else None

    def refresh(self) -> None:
        super().refresh()
        if self.parameters is not None:
            stale = None
            for key, sensor in self.sensors.items():
                try:
                    value = float(sensor.value)
                except TcsError as exc:
                    stale = exc
                    continue
                if key in ("WEATHER_WIND_SPEED", "WEATHER_WIND_GUST") and (sensor.unit or "").strip() == "m/s":
                    value *= 3.6   # INDI has km/h
                self.parameters.element(key).value = value
            self.parameters.state = "Alert" if stale is not None else "Ok"
            self.parameters.message = getattr(stale, "message", None) if stale is not None else None
        if self.status is not None:
            lock = self.interlock
            lock.evaluate()
            causes = lock.causes()
            self.status.element("WEATHER_INTERLOCK").value = "Alert" if lock.active else "Ok"
            for name, cause, _label in CAUSES:
                self.status.element(name).value = "Alert" if cause in causes else "Ok"
            self.status.state = "Alert" if lock.active else "Ok"
            self.status.message = (lock.reason or None) if lock.active else None


# ------------------------------------------------------------------------------------ builder

def equipment_devices(telescope) -> list[Device]:
    """The devices of everything but the mount, each only where the hardware file has it."""
    out: list[Device] = []
    focus = telescope.axis("FOCUS")
    if focus is not None:
        out.append(FocuserDevice(telescope, focus))
    wheels = [w for w in telescope.axis_array("FILTER") if w is not None]
    for wheel, name in zip(wheels, names("TCS Filter", len(wheels))):
        out.append(FilterDevice(telescope, wheel, name))
    rotators = [d for d in telescope.axis_array("DEROTATOR") if d is not None]
    for rot, name in zip(rotators, names("TCS Rotator", len(rotators))):
        out.append(RotatorDevice(telescope, rot, name))
    dome = telescope.peripherals.dome or []
    if dome and telescope.config.dome is not None:
        from tcs.config.modules import OPENING_PARTS
        kinds = {index: part for index, (part, _section) in telescope.config.dome.parts().items()}
        rotation = dome[0] if kinds.get(0) == "rotation" else None
        shutters = [m for i, m in enumerate(dome) if m is not None and kinds.get(i) in OPENING_PARTS]
        if rotation is not None or shutters:
            out.append(DomeDevice(telescope, rotation, shutters))
    per = telescope.peripherals
    covers = list(per.covers)
    for cover, name in zip(covers, names("TCS Dust Cap", len(covers))):
        out.append(DustCapDevice(telescope, cover, name))
    sensors = weather_sensors(per.sensors)
    if sensors or per.interlock is not None:
        out.append(WeatherDevice(telescope, sensors, per.interlock))
    return out
