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
* **TCS Weather** (sensors or the weather interlock): ``WEATHER_STATUS`` lights —
  ``WEATHER_INTERLOCK`` Ok while the interlock lets the dome and covers open, Alert while it
  refuses (its reason is the property's message), and one light per cause (rain, wind, weather
  unknown); ``WEATHER_PARAMETERS`` the weather sensors among ``SENSOR[]`` (recognised by their
  point's name as for Alpaca's ObservingConditions; wind in km/h as INDI has it).

Each has ``CONNECTION`` (CONNECT powers the focuser, wheel or rotator axis — main power first
when off — as connecting the Alpaca device does; a wheel then references; DISCONNECT changes
nothing) and ``DRIVER_INFO`` with its interface bit (focuser 8, filter 16, rotator 4096, dome
32, weather 128). Status without a fresh readback (a drive offline, a PLC unreachable) is
Alert with that reason, never the last value.

What may touch it
-----------------
The service's event loop, through :class:`~tcs.indi.server.IndiServer`.
"""

from __future__ import annotations

import asyncio
import logging
import math

from tcs.errors import ErrorNumber, TcsError
from tcs.indi.protocol import Element, Vector
from tcs.indi.server import Device, Refused
from tcs.model.equipment_power import power_axis, shielded

log = logging.getLogger(__name__)

MOVING = 1
INTERFACE_FOCUSER, INTERFACE_DOME, INTERFACE_WEATHER, INTERFACE_FILTER = 8, 32, 128, 16
INTERFACE_ROTATOR = 4096
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

        async def watch():
            try:
                await awaitable
            except asyncio.CancelledError:
                raise
            except TcsError as exc:
                if exc.number != ErrorNumber.TARGETCHANGE:   # (superseded: no failure)
                    self._failures[key] = f"{what}: {exc.message}"
            except Exception as exc:  # a bug, not a refusal: logged
                log.exception("INDI %s: %s", self.name, what)
                self._failures[key] = f"{what}: {exc}"
        self._tasks[key] = asyncio.ensure_future(watch())

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


# ------------------------------------------------------------------------------------ builder

def equipment_devices(telescope) -> list[Device]:
    """The devices of everything but the mount, each only where the hardware file has it."""
    out: list[Device] = []
    focus = telescope.axis("FOCUS")
    if focus is not None:
        out.append(FocuserDevice(telescope, focus))
    return out
