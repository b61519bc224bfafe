"""Focuser, FilterWheel, Rotator, Dome and CoverCalibrator devices over the model's axes.

What maps to what
-----------------
* **Focuser** (IFocuserV4): the ``FOCUS`` axis. Absolute; one step = 1 µm of the axis's user
  unit (mm): ``Position`` = round(CURRPOS × 1000), ``MaxStep`` = its upper limit in µm,
  ``Move(Position)`` = TARGETPOS. No temperature compensation (``TempComp`` False, setting it
  True is NotImplemented, as IFocuserV4 asks); ``Temperature`` is not implemented.
* **FilterWheel** (IFilterWheelV3), one per ``FILTER[]`` wheel: slot i = the i-th position of
  the hardware file's ``positions`` (sorted as OpenTSI sorts them), ``Names`` from ``names``;
  ``Position`` is -1 while the wheel moves. Focus offsets are all 0 (none configured).
* **Rotator** (IRotatorV4), one per ``DEROTATOR[]``, the Platform 7 model:
  ``MechanicalPosition`` = REALPOS folded into 0…360; the sky ``Position`` = (±mechanical +
  sync offset) mod 360, − while ``Reverse`` is True. ``Sync(p)`` sets the offset so that
  ``Position`` reads p without moving; writing ``Reverse`` keeps ``Position`` where it is (the
  offset follows). Offset and Reverse are kept per derotator in the state file (they survive a
  restart). ``MoveAbsolute``/``Move`` are in sky degrees, ``MoveMechanical`` in mechanical
  ones; a move goes to the turn of the cyclic axis nearest to where it stands, inside the limits.
* **Dome** (IDomeV3) for ``DOME[]``: ``Azimuth``/``SlewToAzimuth``/``SyncToAzimuth``… on the
  rotation (DOME[0]) when there is one; the shutter is every opening part (slit, flap, roof,
  fold, shells): open when all are at their open end, closed when all are closed. No park or
  home position for a dome in the hardware file: ``CanPark``/``CanFindHome`` False. The dome
  follows the telescope through the tracking (POINTING.TRACK +128), not through ``Slaved``.
* **CoverCalibrator** (ICoverCalibratorV2), one per cover: the cover's axis (closed 0, open at
  its max); no calibrator (``CalibratorState`` NotPresent).

Status without a fresh readback (a drive offline, the PLC of a dome part or cover unreachable)
is an error (the axis's ``stale`` error: a driver error, 0x500), never the last value: positions,
``IsMoving``/``Slewing``/``CoverMoving``; ``ShutterStatus``/``CoverState`` read Error.

PLC modules (dome parts, covers) need their POWER on to move: an Alpaca move switches it on
first (it fails, as InvalidOperation, while CABINET.POWER is off). The weather interlock refuses
opening in bad weather (InvalidOperation, with the interlock's reason).

Life cycle: connecting a Focuser, FilterWheel or Rotator powers on its own axis
(:func:`~tcs.alpaca.device.power_axis`, main power first when it is off; ``Connecting`` True
meanwhile, a fraction of a second) — nothing moves. A filter wheel then references at once (its
slot is unknown until it has: ``Position`` −1 meanwhile, as while moving); a focuser or rotator
references on its first move (:func:`~tcs.alpaca.device.make_ready_then`: ``IsMoving`` True
from the reply through referencing and the move), so that it stands still after Connect. A
``Halt`` then ends the move; the referencing runs to its end (``IsMoving`` True until then).
Every move is an asynchronous initiator whose completion state is set before the reply
(:meth:`~tcs.alpaca.device.Device.start_operation`): right after ``Move``/``MoveAbsolute``/
``MoveMechanical``/``Position=n``/``SlewToAzimuth``/``OpenShutter``/``CloseShutter``/
``OpenCover``/``CloseCover`` the completion read says moving (``IsMoving`` True, ``Position``
-1, ``Slewing`` True, ``ShutterStatus`` opening/closing, ``CoverMoving`` True / ``CoverState``
Moving) until the move ended. ``Halt``/``AbortSlew`` stop the move (the axis decelerates; its
motion bit says moving until it stands); ``HaltCover`` is synchronous: it returns once the
cover stands (``CoverMoving`` False).
"""

from __future__ import annotations

import asyncio
import logging

from tcs.alpaca.device import Device, make_ready_then, need, power_axis, shielded
from tcs.alpaca.protocol import AlpacaRequest, AscomError, Code, not_implemented
from tcs.errors import TcsError

MOVING = 1
log = logging.getLogger(__name__)


# ------------------------------------------------------------------------------------ Focuser

class FocuserDevice(Device):
    TYPE = "focuser"
    NAME = "Focuser"
    INTERFACE_VERSION = 4
    MEMBERS = ("absolute", "ismoving", "maxincrement", "maxstep", "position", "stepsize", "tempcomp",
               "tempcompavailable", "temperature", "halt", "move")
    STATE = ("ismoving", "position", "temperature")
    STATE_NAMES = {"ismoving": "IsMoving", "position": "Position", "temperature": "Temperature"}
    RULES = {
        "move": "asynchronous: IsMoving True right after until at Position — through the referencing of a first "
                "move (a failure: the next IsMoving read, 0x500)",
        "halt": "synchronous: the move is ended at the reply; IsMoving True while the axis brakes, or while "
                "a referencing its first move started runs to its end (the drive's homing is not interrupted)",
        "tempcomp": "synchronous (True: NotImplemented)",
    }
    PARAMETERS = {
        "put_tempcomp": (("TempComp", "bool"),),
        "put_move": (("Position", "int"),),
    }
    STEP = 1000.0   # steps per user unit (µm per mm)

    def __init__(self, number, name, description, telescope, axis, **kw):
        super().__init__(number, name, description, telescope, **kw)
        self.axis = axis

    async def prepare(self) -> None:
        await power_axis(self.telescope, self.axis)

    def needs_preparing(self) -> bool:
        return self.axis.power_state != 1.0

    def get_absolute(self, r) -> bool:
        return True

    def get_ismoving(self, r) -> bool:
        _fresh(self.axis)
        self.report_failure()
        return self.running("move") or bool(self.axis.motion_state & MOVING)

    def get_maxstep(self, r) -> int:
        return int(round(self.axis.section.max * self.STEP))

    def get_maxincrement(self, r) -> int:
        return self.get_maxstep(r)

    def get_position(self, r) -> int:
        _fresh(self.axis)
        return int(round(self.axis.current_position * self.STEP))

    def get_stepsize(self, r) -> float:
        return 1000.0 / self.STEP   # microns

    def get_tempcomp(self, r) -> bool:
        return False

    def put_tempcomp(self, r) -> None:
        if r.bool("TempComp"):
            raise AscomError(Code.NOT_IMPLEMENTED, "no temperature compensation (TempCompAvailable is False)")

    def get_tempcompavailable(self, r) -> bool:
        return False

    def put_halt(self, r) -> None:
        self.halt_operation("move")
        self.axis.stop()

    def put_move(self, r) -> None:
        steps = r.int("Position")
        section = self.axis.section
        lo, hi = int(round(section.min * self.STEP)), int(round(section.max * self.STEP))
        need(lo <= steps <= hi, Code.INVALID_VALUE, f"Position {steps} is outside {lo}…{hi}")
        axis = self.axis
        self.start_operation("move", make_ready_then(self, axis, lambda: axis.set_target(steps / self.STEP)),
                             "Move")


# -------------------------------------------------------------------------------- FilterWheel

class FilterWheelDevice(Device):
    TYPE = "filterwheel"
    NAME = "FilterWheel"
    INTERFACE_VERSION = 3
    MEMBERS = ("focusoffsets", "names", "position")
    RULES = {
        "position": "asynchronous: Position −1 right after until at the slot (a failure: the next Position read, "
                    "0x500); −1 also while it references after Connect",
    }
    PARAMETERS = {
        "put_position": (("Position", "int"),),
    }
    STATE = ("position",)
    STATE_NAMES = {"position": "Position"}

    def __init__(self, number, name, description, telescope, axis, **kw):
        super().__init__(number, name, description, telescope, **kw)
        self.axis = axis

    async def prepare(self) -> None:
        await power_axis(self.telescope, self.axis)

    def needs_preparing(self) -> bool:
        return self.axis.power_state != 1.0

    def _start_connect(self):
        done = super()._start_connect()

        def then(f) -> None:   # connected: reference (its slot is unknown until then)
            axis = self.axis
            if (self.connected and axis.power_state == 1.0 and axis.referenced < 1.0
                    and not self.running("move") and not axis.motion_state & MOVING):
                try:
                    self.start_operation("move", shielded(axis.reference(False)), "referencing")
                except TcsError as exc:   # a fault: its moves say why they are refused
                    log.warning("%s: referencing after connect refused: %s", axis.module_name, exc.message)
        done.add_done_callback(then)
        return done

    def _keys(self) -> list:
        return sorted(self.axis.positions)

    def get_names(self, r) -> list[str]:
        names = self.axis.section.names
        return [str(names.get(str(k), str(k))) for k in self._keys()]

    def get_focusoffsets(self, r) -> list[int]:
        return [0 for _ in self._keys()]

    def get_position(self, r) -> int:
        self.report_failure()
        axis = self.axis
        _fresh(axis)
        if self.running("move") or axis.motion_state & MOVING or axis.referenced < 1.0:
            return -1
        here = axis.real_position   # a discrete axis reads the key of the position it is at
        for i, key in enumerate(self._keys()):
            if abs(float(key) - here) < 1e-6:
                return i
        return -1

    def put_position(self, r) -> None:
        slot = r.int("Position")
        keys = self._keys()
        need(0 <= slot < len(keys), Code.INVALID_VALUE, f"Position {slot} is outside 0…{len(keys) - 1}")
        axis = self.axis
        self.start_operation("move", make_ready_then(self, axis, lambda: axis.set_target(keys[slot])),
                             f"Position={slot}")


# ------------------------------------------------------------------------------------ Rotator

class RotatorDevice(Device):
    TYPE = "rotator"
    NAME = "Rotator"
    INTERFACE_VERSION = 4
    MEMBERS = ("canreverse", "ismoving", "mechanicalposition", "position", "reverse", "stepsize",
               "targetposition", "halt", "move", "moveabsolute", "movemechanical", "sync")
    STATE = ("ismoving", "mechanicalposition", "position")
    STATE_NAMES = {"ismoving": "IsMoving", "mechanicalposition": "MechanicalPosition", "position": "Position"}
    RULES = {
        "move": "asynchronous: IsMoving True right after until there — through the referencing of a first move "
                "(a failure: the next IsMoving read, 0x500)",
        "moveabsolute": "asynchronous: as Move",
        "movemechanical": "asynchronous: as Move",
        "halt": "synchronous: the move is ended at the reply; IsMoving True while the axis brakes, or while "
                "a referencing its first move started runs to its end (the drive's homing is not interrupted)",
        "sync": "synchronous: Position reads the synced angle right after (nothing moves; refused before the "
                "first move has referenced the axis)",
        "reverse": "synchronous: Reverse reads the new value right after; Position unchanged",
    }
    PARAMETERS = {
        "put_reverse": (("Reverse", "bool"),),
        "put_move": (("Position", "float"),),
        "put_moveabsolute": (("Position", "float"),),
        "put_movemechanical": (("Position", "float"),),
        "put_sync": (("Position", "float"),),
    }

    def __init__(self, number, name, description, telescope, axis, **kw):
        super().__init__(number, name, description, telescope, **kw)
        self.axis = axis

    async def prepare(self) -> None:
        await power_axis(self.telescope, self.axis)

    def needs_preparing(self) -> bool:
        return self.axis.power_state != 1.0

    # -- the sync model: sky = (sign × mechanical + offset) mod 360, sign −1 while Reverse --------
    STORE = "alpaca_rotators"

    def _model(self) -> tuple[float, bool]:
        saved = (self.telescope.store.get(self.STORE, {}) or {}).get(self.axis.module_name) or {}
        return float(saved.get("offset", 0.0)), bool(saved.get("reverse", False))

    def _save(self, offset: float, reverse: bool) -> None:
        saved = dict(self.telescope.store.get(self.STORE, {}) or {})
        saved[self.axis.module_name] = {"offset": round(offset % 360.0, 9), "reverse": reverse}
        self.telescope.store.update(**{self.STORE: saved})

    def _sky(self, mechanical: float) -> float:
        offset, reverse = self._model()
        return ((-mechanical if reverse else mechanical) + offset) % 360.0

    def _mechanical(self, sky: float) -> float:
        offset, reverse = self._model()
        return ((-(sky - offset)) if reverse else (sky - offset)) % 360.0

    def get_canreverse(self, r) -> bool:
        return True

    def get_reverse(self, r) -> bool:
        return self._model()[1]

    def put_reverse(self, r) -> None:
        reverse = r.bool("Reverse")
        offset, was = self._model()
        if reverse == was:
            return
        mech = self.get_mechanicalposition(r)
        sky = self._sky(mech)
        self._save(sky - (-mech if reverse else mech), reverse)   # Position stays where it is

    def put_sync(self, r) -> None:
        sky = r.float("Position")
        need(0.0 <= sky < 360.0, Code.INVALID_VALUE, f"Position {sky} is outside 0…360")
        need(self.axis.referenced >= 1.0, Code.INVALID_OPERATION,
             f"Sync: {self.axis.module_name} is not referenced (it references on its first move)")
        _offset, reverse = self._model()
        mech = self.get_mechanicalposition(r)
        self._save(sky - (-mech if reverse else mech), reverse)

    def get_ismoving(self, r) -> bool:
        _fresh(self.axis)
        self.report_failure()
        return self.running("move") or bool(self.axis.motion_state & MOVING)

    def get_mechanicalposition(self, r) -> float:
        _fresh(self.axis)
        return float(self.axis.real_position % 360.0)

    def get_position(self, r) -> float:
        return self._sky(self.get_mechanicalposition(r))

    def get_targetposition(self, r) -> float:
        # the goal of the move a client asked for, from the request on: the axis's own target
        # changes only once the move starts (after powering on and referencing, or the next
        # control cycle), and ASCOM (ConformU) reads TargetPosition right after MoveAbsolute
        goal = getattr(self, "_goal", None)
        if goal is not None and self.running("move"):
            return self._sky(float(goal % 360.0))
        return self._sky(float((self.axis.target_position + self.axis.offset) % 360.0))

    def put_halt(self, r) -> None:
        self.halt_operation("move")
        self.axis.stop()

    def _go(self, angle) -> None:
        """Move to mechanical ``angle`` (a number, or a function giving it once the axis is
        referenced) on the turn nearest to where the axis stands, inside the limits."""
        axis = self.axis
        self._goal = None if callable(angle) else float(angle)   # TargetPosition from now on

        def move():
            goal = self._turn(angle() if callable(angle) else angle)
            return axis.set_target(goal - axis.offset)
        if axis.power_state == 1.0 and axis.referenced >= 1.0:
            self._turn(angle() if callable(angle) else angle)   # refused now, not in the background
        self.start_operation("move", make_ready_then(self, axis, move), "the move")

    def _turn(self, angle: float) -> float:
        axis = self.axis
        here = axis.real_position
        base = here + ((angle - here) % 360.0 + 180.0) % 360.0 - 180.0   # nearest turn
        turns = sorted((base + k * 360.0 for k in range(-2, 3)), key=lambda t: abs(t - here))
        for goal in turns:
            if axis.limits.contains(goal):
                return goal
        raise AscomError(Code.INVALID_VALUE, f"{angle}° cannot be reached inside the limits")

    def put_move(self, r) -> None:
        delta = r.float("Position")
        need(abs(delta) <= 3600.0, Code.INVALID_VALUE, f"relative move {delta}° is beyond ±3600")
        if self.axis.referenced < 1.0:   # relative to where it stands once referenced
            self._go(lambda: self._mechanical((self.get_position(r) + delta) % 360.0))
        else:
            self._go(self._mechanical((self.get_position(r) + delta) % 360.0))

    def put_moveabsolute(self, r) -> None:
        angle = r.float("Position")
        need(0.0 <= angle < 360.0, Code.INVALID_VALUE, f"Position {angle} is outside 0…360")
        self._go(self._mechanical(angle))

    def put_movemechanical(self, r) -> None:
        angle = r.float("Position")
        need(0.0 <= angle < 360.0, Code.INVALID_VALUE, f"Position {angle} is outside 0…360")
        self._go(angle)


# --------------------------------------------------------------------------------------- Dome

SHUTTER_OPEN, SHUTTER_CLOSED, SHUTTER_OPENING, SHUTTER_CLOSING, SHUTTER_ERROR = 0, 1, 2, 3, 4


def _power_up(module, what: str) -> None:
    if module.power_state != 1.0:
        module.power(True)


def _at_min(module) -> bool:
    return module.real_position <= module.section.min + max(module.section.tolerance, 1e-6)


def _at_max(module) -> bool:
    return module.real_position >= module.section.max - max(module.section.tolerance, 1e-6)


def _fresh(part) -> None:
    """Raise the part's ``stale`` error (its PLC unreachable: no fresh readback) — answered as
    an Alpaca error, never the last value polled."""
    stale = getattr(part, "stale", None)
    if stale is not None:
        raise stale


def _opening_state(parts: list, going: dict | None = None) -> int:
    """ShutterState / CoverStatus-like summary of PLC parts: open, closed, opening, closing, error.
    ``going``: part -> goal of the moves an Alpaca client started that have not ended (moving
    from the reply on, before the part's own motion bit says so)."""
    if any(p.motion_state & 4 for p in parts) or any(p.link_error() is not None for p in parts):
        return SHUTTER_ERROR
    going = going or {}
    if going:
        return SHUTTER_OPENING if any(goal >= p.section.max for p, goal in going.items()) else SHUTTER_CLOSING
    moving = [p for p in parts if p.motion_state & MOVING]
    if moving:
        return SHUTTER_OPENING if any(p.target_position > p.current_position for p in moving) else SHUTTER_CLOSING
    if all(_at_max(p) for p in parts):
        return SHUTTER_OPEN
    if all(_at_min(p) for p in parts):
        return SHUTTER_CLOSED
    return SHUTTER_ERROR   # stopped half-way: neither open nor closed


class DomeDevice(Device):
    TYPE = "dome"
    NAME = "Dome"
    INTERFACE_VERSION = 3
    MEMBERS = ("altitude", "athome", "atpark", "azimuth", "canfindhome", "canpark", "cansetaltitude",
               "cansetazimuth", "cansetpark", "cansetshutter", "canslave", "cansyncazimuth",
               "shutterstatus", "slaved", "slewing", "abortslew", "closeshutter", "findhome",
               "openshutter", "park", "setpark", "slewtoaltitude", "slewtoazimuth", "synctoazimuth")
    RULES = {
        "slewtoazimuth": "asynchronous: Slewing True right after until there (a failure: the next Slewing read, 0x500)",
        "openshutter": "asynchronous: ShutterStatus opening (2) right after until open (0); Slewing True meanwhile",
        "closeshutter": "asynchronous: ShutterStatus closing (3) right after until closed (1); Slewing True meanwhile",
        "abortslew": "synchronous: every part is told to stop at the reply; Slewing True while they brake",
        "slaved": "synchronous (True: NotImplemented)",
        "slewtoaltitude": "NotImplemented", "synctoazimuth": "NotImplemented",
    }
    PARAMETERS = {
        "put_slaved": (("Slaved", "bool"),),
        "put_slewtoazimuth": (("Azimuth", "float"),),
        "put_slewtoaltitude": (("Altitude", "float"),),
        "put_synctoazimuth": (("Azimuth", "float"),),
    }
    STATE = ("athome", "atpark", "azimuth", "shutterstatus", "slewing")
    STATE_NAMES = {"athome": "AtHome", "atpark": "AtPark", "azimuth": "Azimuth",
                   "shutterstatus": "ShutterStatus", "slewing": "Slewing"}

    def __init__(self, number, name, description, telescope, rotation, shutters, **kw):
        super().__init__(number, name, description, telescope, **kw)
        self.rotation = rotation
        self.shutters = shutters
        self._goals: dict[int, float] = {}

    def _parts(self) -> list:
        return ([self.rotation] if self.rotation is not None else []) + list(self.shutters)

    def get_canfindhome(self, r) -> bool:
        return False

    def get_canpark(self, r) -> bool:
        return False

    def get_cansetpark(self, r) -> bool:
        return False

    def get_cansetaltitude(self, r) -> bool:
        return False

    def get_cansetazimuth(self, r) -> bool:
        return self.rotation is not None

    def get_cansyncazimuth(self, r) -> bool:
        return False

    def get_cansetshutter(self, r) -> bool:
        return bool(self.shutters)

    def get_canslave(self, r) -> bool:
        return False

    def get_slaved(self, r) -> bool:
        return False

    def put_slaved(self, r) -> None:
        if r.bool("Slaved"):
            raise not_implemented("Slaved (the dome follows through the telescope's tracking)")

    def get_athome(self, r) -> bool:
        return False

    def get_atpark(self, r) -> bool:
        return False

    def get_azimuth(self, r) -> float:
        if self.rotation is None:
            raise not_implemented("Azimuth (this enclosure does not rotate)")
        _fresh(self.rotation)
        return float(self.rotation.current_position % 360.0)

    def _going(self) -> dict:
        return {p: self._goals[i] for i, p in enumerate(self.shutters) if self.running(f"shutter{i}")}

    def get_shutterstatus(self, r) -> int:
        if not self.shutters:
            raise not_implemented("ShutterStatus (no shutter)")
        self.report_failure()
        return _opening_state(self.shutters, self._going())

    def get_slewing(self, r) -> bool:
        for part in self._parts():
            _fresh(part)
        self.report_failure()
        return (self.running("rotation") or bool(self._going())
                or any(p.motion_state & MOVING for p in self._parts()))

    def put_abortslew(self, r) -> None:
        self.drop_operation("rotation")
        for i, _part in enumerate(self.shutters):
            self.drop_operation(f"shutter{i}")
        for part in self._parts():
            part.stop()

    def _shutter(self, open_: bool) -> None:
        if not self.shutters:
            raise not_implemented("OpenShutter/CloseShutter (no shutter)")
        for part in self.shutters:
            _power_up(part, "shutter")
        moves = []
        for part in self.shutters:   # the interlock refuses before anything moves
            goal = part.section.max if open_ else part.section.min
            moves.append((goal, part.set_target(goal)))
        for i, (goal, move) in enumerate(moves):
            self._goals[i] = goal
            self.start_operation(f"shutter{i}", move, "OpenShutter" if open_ else "CloseShutter")

    def put_openshutter(self, r) -> None:
        self._shutter(True)

    def put_closeshutter(self, r) -> None:
        self._shutter(False)

    def put_slewtoazimuth(self, r) -> None:
        az = r.float("Azimuth")
        need(0.0 <= az < 360.0, Code.INVALID_VALUE, f"Azimuth {az} is outside 0…360")
        if self.rotation is None:
            raise not_implemented("SlewToAzimuth (this enclosure does not rotate)")
        _power_up(self.rotation, "rotation")
        self.start_operation("rotation", self.rotation.set_target(az), "SlewToAzimuth")

    def put_slewtoaltitude(self, r) -> None:
        alt = r.float("Altitude")
        need(0.0 <= alt <= 90.0, Code.INVALID_VALUE, f"Altitude {alt} is outside 0…90")
        raise not_implemented("SlewToAltitude")

    def put_synctoazimuth(self, r) -> None:
        az = r.float("Azimuth")
        need(0.0 <= az < 360.0, Code.INVALID_VALUE, f"Azimuth {az} is outside 0…360")
        raise not_implemented("SyncToAzimuth")


# ---------------------------------------------------------------------------- CoverCalibrator

COVER_NOT_PRESENT, COVER_CLOSED, COVER_MOVING, COVER_OPEN, COVER_UNKNOWN, COVER_ERROR = 0, 1, 2, 3, 4, 5


class CoverCalibratorDevice(Device):
    TYPE = "covercalibrator"
    NAME = "CoverCalibrator"
    INTERFACE_VERSION = 2
    MEMBERS = ("brightness", "calibratorchanging", "calibratorstate", "covermoving", "coverstate",
               "maxbrightness", "calibratoroff", "calibratoron", "closecover", "haltcover", "opencover")
    RULES = {
        "opencover": "asynchronous: CoverMoving True, CoverState Moving (2) right after until open (3)",
        "closecover": "asynchronous: CoverMoving True, CoverState Moving (2) right after until closed (1)",
        "haltcover": "synchronous: returns once the cover stands (CoverMoving False right after)",
        "calibratoron": "NotImplemented", "calibratoroff": "NotImplemented",
    }
    PARAMETERS = {
        "put_calibratoron": (("Brightness", "int"),),
    }
    STATE = ("brightness", "calibratorchanging", "calibratorstate", "covermoving", "coverstate")
    STATE_NAMES = {"brightness": "Brightness", "calibratorchanging": "CalibratorChanging",
                   "calibratorstate": "CalibratorState", "covermoving": "CoverMoving",
                   "coverstate": "CoverState"}

    def __init__(self, number, name, description, telescope, cover, **kw):
        super().__init__(number, name, description, telescope, **kw)
        self.cover = cover
        self._goal = 0.0

    def get_calibratorstate(self, r) -> int:
        return 0   # NotPresent

    def get_calibratorchanging(self, r) -> bool:
        return False

    def get_covermoving(self, r) -> bool:
        _fresh(self.cover)
        self.report_failure()
        return self.running("move") or bool(self.cover.motion_state & MOVING)

    def get_coverstate(self, r) -> int:
        self.report_failure()
        state = _opening_state([self.cover], {self.cover: self._goal} if self.running("move") else None)
        return {SHUTTER_OPEN: COVER_OPEN, SHUTTER_CLOSED: COVER_CLOSED, SHUTTER_OPENING: COVER_MOVING,
                SHUTTER_CLOSING: COVER_MOVING}.get(state, COVER_ERROR if self.cover.motion_state & 4
                                                   or self.cover.link_error() is not None else COVER_UNKNOWN)

    def _move(self, open_: bool) -> None:
        _power_up(self.cover, "cover")
        goal = self.cover.section.max if open_ else self.cover.section.min
        move = self.cover.set_target(goal)
        self._goal = goal
        self.start_operation("move", move, "OpenCover" if open_ else "CloseCover")

    def put_opencover(self, r) -> None:
        self._move(True)

    def put_closecover(self, r) -> None:
        self._move(False)

    async def put_haltcover(self, r) -> None:
        """Synchronous: stop, and reply once the cover stands (CoverMoving False)."""
        self.drop_operation("move")
        self.cover.stop()
        loop = asyncio.get_running_loop()
        deadline = loop.time() + 20.0
        while self.cover.motion_state & MOVING or getattr(self.cover, "command_pending", False):
            if loop.time() > deadline:
                raise AscomError(Code.DRIVER_ERROR, "HaltCover: the cover did not stop within 20 s")
            await asyncio.sleep(0.02)

    def put_calibratoron(self, r) -> None:
        r.int("Brightness")
        raise not_implemented("CalibratorOn (no calibrator)")

    def put_calibratoroff(self, r) -> None:
        raise not_implemented("CalibratorOff (no calibrator)")


# ------------------------------------------------------------------------------------ builder

def equipment_devices(telescope, commands, seed: str) -> list[Device]:
    """The devices of everything but the mount, numbered from 0 per type in file order."""
    from tcs.alpaca.site import site_devices
    from tcs.config.modules import OPENING_PARTS

    kw = dict(commands=commands, unique_seed=seed)
    out: list[Device] = []
    focus = telescope.axis("FOCUS")
    if focus is not None:
        out.append(FocuserDevice(0, "FOCUS", "the focus axis (1 step = 1 µm)", telescope, focus, **kw))
    for i, wheel in enumerate(w for w in telescope.axis_array("FILTER") if w is not None):
        out.append(FilterWheelDevice(i, wheel.module_name, f"filter wheel {wheel.module_name}",
                                     telescope, wheel, **kw))
    for i, rot in enumerate(d for d in telescope.axis_array("DEROTATOR") if d is not None):
        out.append(RotatorDevice(i, rot.module_name, f"derotator {rot.module_name}", telescope, rot, **kw))
    dome = telescope.peripherals.dome or []
    if dome and telescope.config.dome is not None:
        kinds = {index: part for index, (part, _section) in telescope.config.dome.parts().items()}
        rotation = dome[0] if kinds.get(0) == "rotation" else None
        shutters = [m for i, m in enumerate(dome) if m is not None and kinds.get(i) in OPENING_PARTS]
        out.append(DomeDevice(0, "DOME", f"{telescope.config.dome.type} dome", telescope, rotation,
                              shutters, **kw))
    for i, cover in enumerate(telescope.peripherals.covers):
        section = telescope.config.covers[i]
        out.append(CoverCalibratorDevice(i, cover.module_name, section.name or cover.module_name,
                                         telescope, cover, **kw))
    out.extend(site_devices(telescope, commands, seed))
    return out
