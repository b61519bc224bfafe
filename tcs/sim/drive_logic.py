"""The CiA-402 application of the simulated drive: objects ↔ state machine ↔ modes ↔ physics.

Pure logic with time passed in: the node calls :meth:`DriveLogic.update` with its clock's
time before every access (SDO, PDO, SYNC, poll), and the write hooks installed on the object
store carry the master's commands in. Outputs are the live objects (statusword, positions …,
read through the store) and EMCY messages through the ``emcy`` callback.

Units: the wire is in increments (positions), increments/s, increments/s²; the physics in
user units. ``increments per unit`` = 0x608F:1 / 0x608F:2 × 0x6091:1 / 0x6091:2, and the
position actual value is ``(x − zero) × increments per unit`` where ``zero`` is the physical
position that reads 0 (moved by homing; back to 0 at NMT reset node).

Behaviour chosen where CiA-402 leaves it to the vendor (the driver can rely on it):

* Modes 1 PP, 3 PV, 6 HM, 7 IP, 8 CSP, 9 CSV (0 = none), restricted to those 0x6502 offers. A write of another mode to 0x6060 is aborted
  with 0x06090030. A mode change takes effect at once (0x6061 reads it back) except while a
  homing run is in progress: then it waits until the run has ended.
* Entering Operation enabled holds the current position (PP, CSP, HM) or ramps to the
  target velocity 0x60FF (PV). In CSP the target arriving with the next SYNC is interpolated
  to linearly over the interpolation period 0x60C2 (then held); a target far from the actual
  position makes the motor run at its limits and usually ends in a following-error fault.
* Leaving the powered states (transitions 5, 8, 9, 10, 12 with option 0) engages the brake:
  the motor stops with its maximum deceleration.
* Quick stop (11) ramps with 0x6084 (0x605A = 1, 5), 0x6085 (2, 6) or the motor's maximum
  deceleration (3, 4, 7, 8); options 1–4 then go to Switch on disabled (12), 5–8 stay in
  Quick stop active; option 0 disables at once.
* Faults (transition 13): EMCY with the code, 0x603F = code, error register 0x1001, history
  0x1003. Fault reaction 0x605E: 1 = ramp with 0x6084, 2 = with 0x6085, 0 = brake at once;
  over-current and encoder faults always disable at once. Then Fault (14). A rising edge of
  controlword bit 7 in Fault → Switch on disabled (15) and EMCY 0x0000; a fault already active
  is not reported again.
* Hardware limit switches: entering one while the power stage is on (outside a homing run
  that searches for it) is the fault 0x8612 "position limit" (reaction as above). Standing on
  an active limit switch, the drive accepts motion only away from it: targets toward it are
  held at the actual position and statusword bit 11 "internal limit" is set; bit 7
  "warning" is set while any limit switch is active.
* Software limits 0x607D (increments; both 0 = off): PP and CSP targets beyond them are
  clamped to them and bit 11 is set; in PV the drive stops with 0x6085 at the limit.
* Following error: |demand − actual| > 0x6065 for longer than 0x6066 ms in PP/CSP/HM →
  fault 0x8611 (0x6065 = 0xFFFFFFFF switches the check off). Bit 13 shows |error| > window.
* IP (7): like CSP, with the interpolation data record 0x60C1:1 as the target, only while
  controlword bit 4 "enable IP" is set (statusword bit 12 = IP active); a record received
  without it is ignored (counted in ``ip_ignored``), and clearing bit 4 while moving stops
  with 0x6085. Linear interpolation only (0x60C0 = 0).
* CSV (9): from every SYNC the motor follows the target velocity 0x60FF with its maximum
  acceleration (the master closes the position loop); a velocity above 0x607F (or the
  motor's) is clamped with statusword bit 11 "internal limit", as drives do (no EMCY);
  towards an active limit switch or beyond a software limit the velocity is 0. No following
  error in CSV (the drive has no position demand).
* CSP, IP, CSV: synchronous RPDOs missing at :data:`RPDO_TIMEOUT_SYNCS` consecutive SYNCs while
  enabled in these modes → the abort connection reaction 0x6007 with code 0x8250 "RPDO time-out"
  (:meth:`DriveLogic.connection_lost`: 0 none, 1 fault — the EDS default —, 2 disable
  voltage, 3 quick stop per 0x605A; 2 and 3 send the code by EMCY as a warning). The node
  applies the same reaction when SYNC stops (0x1006), when an RPDO misses its deadline
  (event timer 0x1400:5, watched in real time by the node) or NMT takes it out of
  operational. Until then the drive *bridges* the missing setpoints (CSP, IP) as
  ``SimDriveParams.bridging`` says: ``"extrapolate"`` (default) — with a deadline set the
  demand goes on at the setpoint stream's speed (the travel of its last
  :data:`TREND_SETPOINTS` setpoints over the real time between the SYNCs that latched them: a
  drive that synchronizes its cycle to SYNC measures those intervals; never faster than the
  last interval's, so a stream slowing to a stop is not bridged past it — capped at the motor's
  speed; no braking at
  the motor's limit before the reaction starts), bounded by the deadline and the software
  limits — or ``"hold"`` — the demand stays at the last setpoint (the motor brakes at its own
  limit, as a drive whose interpolator runs dry). CSV keeps the last target velocity. So a
  lost master ends in a ramp at 0x6085 (0x6007 = 3, 0x605A = 2). The first setpoint after a
  gap is latched like any other: a line from wherever the demand is to it (a stale setpoint
  made before the gap would pull the demand back: the master must not send one).
* Disable operation (transition 5) ramps down with the profile deceleration when 0x605C = 1,
  brakes at once when 0. Every SYNC without a fresh
  RPDO while enabled in CSP counts in ``rpdo_missed``. The velocity offset 0x60B1 is accepted
  and ignored (the model's position loop needs no feed-forward).
* Statusword bit 12 in CSP = 1 "drive follows the command"; PP bit 12 = set-point
  acknowledge (until bit 4 is cleared), bit 10 = target reached (within 0x6067, at rest);
  PV bit 10 = at the target velocity, bit 12 = speed 0; HM bits 13/12/10 per CiA-402.
"""

from __future__ import annotations

import collections
import math
from collections.abc import Callable
from fractions import Fraction

from tcs.sim import homing as hm
from tcs.sim.cia402_states import POWERED, STATUS_BITS, VOLTAGE, State, step
from tcs.sim.drive_params import SimDriveParams
from tcs.sim.drive_physics import Axis, Event, Threshold, hold, linear_profile, position_profile, \
    stop_profile, velocity_profile
from tcs.sim.object_store import ABORT_STATE, ABORT_VALUE_RANGE, ObjectStore, SdoAbort

S = State
MODE_NONE, MODE_PP, MODE_PV, MODE_HM, MODE_IP, MODE_CSP, MODE_CSV = 0, 1, 3, 6, 7, 8, 9
SUPPORTED_MODES = frozenset({MODE_NONE, MODE_PP, MODE_PV, MODE_HM, MODE_IP, MODE_CSP, MODE_CSV})
#: Modes fed by a synchronous RPDO every SYNC (missing RPDOs: the 0x6007 reaction).
STREAMING_MODES = frozenset({MODE_IP, MODE_CSP, MODE_CSV})
#: Modes whose position demand is watched for a following error (0x6065/0x6066).
FE_MODES = frozenset({MODE_PP, MODE_CSP, MODE_HM, MODE_IP})

EMCY_RESET = 0x0000
EMCY_OVERCURRENT = 0x2310
EMCY_ENCODER = 0x7305
EMCY_HEARTBEAT = 0x8130
EMCY_PDO_LENGTH = 0x8210
EMCY_RPDO_TIMEOUT = 0x8250
EMCY_FOLLOWING_ERROR = 0x8611
EMCY_POSITION_LIMIT = 0x8612
#: Faults after which the power stage is switched off at once (no stopping ramp).
IMMEDIATE_FAULTS = frozenset({EMCY_OVERCURRENT, EMCY_ENCODER})
#: Consecutive SYNCs without an RPDO (enabled in CSP) that fault the drive.
RPDO_TIMEOUT_SYNCS = 3
#: A CSP/IP drive bridges a missing setpoint at the speed of its last this many setpoints (their
#: travel over the real time between the SYNCs that latched the first and the last)
TREND_SETPOINTS = 4

SW_MIN, SW_MAX = "software limit min", "software limit max"
_MAX_EVENTS_PER_UPDATE = 100000


def error_register_bits(code: int) -> int:
    """0x1001 bits for an error code: 0 generic + 1 current / 2 voltage / 3 temperature / 4 comm."""
    reg = 0x01
    group = code >> 12
    if group == 0x2:
        reg |= 0x02
    elif group == 0x3:
        reg |= 0x04
    elif group == 0x4:
        reg |= 0x08
    elif code >> 8 in (0x81, 0x82):
        reg |= 0x10
    return reg


class DriveLogic:
    """The drive application of one simulated CiA-402 node.

    Parameters
    ----------
    store:
        The node's objects (hooks are installed here).
    params:
        The physical axis.
    t:
        Current time (s) of the node's clock.
    emcy:
        ``emcy(code, error_register)``: called for every EMCY the drive sends.
    """

    def __init__(self, store: ObjectStore, params: SimDriveParams, t: float,
                 emcy: Callable[[int, int], None]):
        self.store, self.params, self._emcy = store, params, emcy
        self.sw = hm.Switches(params.negative_limit_switch, params.positive_limit_switch,
                              params.home_switch, params.home_switch_active_below,
                              params.index_pulse_spacing)
        self.axis = Axis(x=params.position, t=t, max_velocity=params.max_velocity,
                         max_acceleration=params.max_acceleration)
        self.state = S.SWITCH_ON_DISABLED  # transitions 0 and 1 happen at boot
        self.zero = 0.0
        #: methods 35/37: the physical place that reads the home offset (an absolute encoder)
        self.absolute_home = (params.position if params.absolute_home is None
                              else params.absolute_home)
        self.controlword = 0
        self.mode = MODE_NONE
        self.mode_request = MODE_NONE
        self.homing: hm.Homing | None = None
        self.pp_target: int | None = None      # increments
        self.pp_pending: int | None = None
        self.setpoint_ack = False
        self.internal_limit = False
        self.alarm_reason: str | None = None
        self.missed_in_row = 0
        #: the last streamed setpoints (CSP/IP), units, with the time of the SYNC that latched
        #: each (the stream's speed for bridging: TREND_SETPOINTS)
        self._goals: collections.deque[tuple[float, float]] = collections.deque(maxlen=TREND_SETPOINTS)
        self.rpdo_missed = 0
        self.ip_ignored = 0                    # IP records received without enable-IP (bit 4)
        self.rpdo_deadlines: dict[int, float] = {}  # RPDO → deadline, s (set by the node)
        self.transitions: list[int] = []       # the transition numbers taken, for tests
        self._ipu: float | None = None
        self._install_defaults()
        self._install_hooks()
        self._refresh_watch()

    # -- set-up ------------------------------------------------------------------------------
    def _install_defaults(self) -> None:
        st, p = self.store, self.params
        frac = Fraction(p.increments_per_unit).limit_denominator(1000)
        st.set(0x608F, 1, frac.numerator)
        st.set(0x608F, 2, frac.denominator)
        st.set(0x6091, 1, 1)
        st.set(0x6091, 2, 1)
        ipu = p.increments_per_unit
        st.set(0x607F, 0, round(p.max_velocity * ipu))
        st.set(0x6081, 0, round(p.max_velocity * ipu / 2))
        st.set(0x6083, 0, round(p.max_acceleration * ipu / 2))
        st.set(0x6084, 0, round(p.max_acceleration * ipu / 2))
        st.set(0x6085, 0, round(p.max_acceleration * ipu))
        st.set(0x6099, 1, round(p.max_velocity * ipu / 5))
        st.set(0x6099, 2, round(p.max_velocity * ipu / 50))
        st.set(0x609A, 0, round(p.max_acceleration * ipu / 2))
        self.install_identity()

    def install_identity(self) -> None:
        """0x1018 from the parameters (also after an NMT reset communication)."""
        for sub, value in enumerate(self.params.identity, start=1):
            self.store.set(0x1018, sub, int(value))

    def _install_hooks(self) -> None:
        st = self.store
        st.on_write(0x6040, lambda sub, v: self.on_controlword(v))
        st.on_write(0x6060, lambda sub, v: self._on_mode(v))
        st.on_write(0x60FF, lambda sub, v: self._on_target_velocity(v))
        st.on_write(0x6098, self._check_homing_method)
        st.on_write(0x608F, self._check_scaling)
        st.on_write(0x6091, self._check_scaling)
        st.on_write(0x1003, self._on_error_history)
        st.on_read(0x6041, lambda sub: self.statusword())
        st.on_read(0x6061, lambda sub: self.mode)
        st.on_read(0x6064, lambda sub: self.to_inc(self.axis.x))
        st.on_read(0x6062, lambda sub: self.to_inc(self.axis.demand()[0]))
        st.on_read(0x606C, lambda sub: round(self.axis.v * self.ipu()))
        st.on_read(0x60F4, lambda sub: self.to_inc(self.axis.demand()[0]) - self.to_inc(self.axis.x))
        st.on_read(0x60FD, lambda sub: self.digital_inputs())

    # -- conversions -------------------------------------------------------------------------
    def ipu(self) -> float:
        """Increments per user unit from 0x608F and 0x6091 (cached; scaling writes clear it)."""
        if self._ipu is None:
            st = self.store
            self._ipu = (st.get(0x608F, 1) / st.get(0x608F, 2)) * (st.get(0x6091, 1) / st.get(0x6091, 2))
        return self._ipu

    def to_inc(self, x: float) -> int:
        return round((x - self.zero) * self.ipu())

    def to_phys(self, inc: float) -> float:
        return self.zero + inc / self.ipu()

    def _profile_limits(self) -> tuple[float, float, float]:
        """Profile velocity, acceleration, deceleration in units, capped by the motor."""
        st, ipu, p = self.store, self.ipu(), self.params
        vmax = min(st.get(0x6081, 0), st.get(0x607F, 0)) / ipu
        return (min(vmax, p.max_velocity), min(st.get(0x6083, 0) / ipu, p.max_acceleration),
                min(st.get(0x6084, 0) / ipu, p.max_acceleration))

    def _decel(self, which: str) -> float:
        st, ipu, amax = self.store, self.ipu(), self.params.max_acceleration
        value = {"profile": st.get(0x6084, 0), "quick": st.get(0x6085, 0)}.get(which)
        if value is None or value <= 0:
            return amax
        return min(value / ipu, amax)

    def _software_limits(self) -> tuple[float, float] | None:
        lo, hi = self.store.get(0x607D, 1), self.store.get(0x607D, 2)
        if lo == 0 and hi == 0:
            return None
        return lo, hi

    # -- the power state machine -------------------------------------------------------------
    def on_controlword(self, cw: int) -> None:
        """The master wrote 0x6040 (SDO or RPDO)."""
        prev, self.controlword = self.controlword, cw
        new, number = step(self.state, cw, prev, self.store.get(0x605A, 0))
        if number:
            self._enter(new, number)
        if self.state is not S.OPERATION_ENABLED:
            return
        rising, falling = cw & ~prev, prev & ~cw
        if self.mode == MODE_PP:
            if rising & 0x10:
                self._new_setpoint(cw)
            if falling & 0x10:
                self.setpoint_ack = False
        elif self.mode == MODE_IP:
            if falling & 0x10 and not self._at_rest():  # IP disabled while moving: stop
                ax = self.axis
                ax.set_reference(stop_profile(ax.t, ax.x, ax.v, self._decel("quick")))
        elif self.mode == MODE_HM:
            if rising & 0x10 and not cw & 0x100:
                self._start_homing()
            if falling & 0x10 and self.homing is not None:
                self.homing.interrupt()
                self._refresh_watch()
        if (rising | falling) & 0x100:
            self._on_halt(bool(cw & 0x100))

    def _enter(self, new: State, number: int) -> None:
        old = self.state
        self.state = new
        self.transitions.append(number)
        ax = self.axis
        if new is S.OPERATION_ENABLED:
            self.missed_in_row = 0
            self.internal_limit = False
            if number != 16 or self.mode != MODE_PV:
                ax.set_reference(hold(ax.t, ax.x) if ax.v == 0
                                 else stop_profile(ax.t, ax.x, ax.v, self._decel("quick")))
            self.pp_target, self.pp_pending, self.setpoint_ack = None, None, False
            self._apply_mode_request()
            if self.mode == MODE_PV:
                self._on_target_velocity(self.store.get(0x60FF, 0))
        elif new is S.QUICK_STOP_ACTIVE:
            option = self.store.get(0x605A, 0)
            self._abort_homing(error=False)
            if option == 0:
                self._brake()
                self.state = S.SWITCH_ON_DISABLED
                self.transitions.append(12)
            else:
                dec = self._decel("profile" if option in (1, 5) else "quick" if option in (2, 6) else "max")
                self._ramp_down(dec, "quick_stop")
        elif new is S.SWITCH_ON_DISABLED and number == 15:
            self.store.set(0x603F, 0, 0)
            self.store.set(0x1001, 0, 0)
            self._emcy(EMCY_RESET, 0)
        elif old in POWERED and new not in POWERED:
            self._abort_homing(error=False)
            if number == 5 and self._option(0x605C, 0) == 1:
                ax = self.axis  # disable operation option 1: ramp down, then the brake
                ax.set_reference(stop_profile(ax.t, ax.x, ax.v, self._decel("profile")))
                self.alarm_reason, ax.alarm = None, None
            else:
                self._brake()
        self._refresh_watch()

    def _brake(self) -> None:
        ax = self.axis
        ax.set_reference(stop_profile(ax.t, ax.x, ax.v, self.params.max_acceleration))
        self.alarm_reason, ax.alarm = None, None

    def _ramp_down(self, dec: float, reason: str) -> None:
        ax = self.axis
        profile = stop_profile(ax.t, ax.x, ax.v, dec)
        ax.set_reference(profile)
        self.alarm_reason = reason
        ax.alarm = max(profile.end_time, ax.t)

    def fault(self, code: int) -> bool:
        """Raise a fault (transition 13); False if a fault is already active."""
        if self.state in (S.FAULT, S.FAULT_REACTION_ACTIVE):
            return False
        st = self.store
        reg = error_register_bits(code)
        st.set(0x603F, 0, code)
        st.set(0x1001, 0, reg)
        history = [st.get(0x1003, i) for i in range(1, 9)]
        history = [code] + history[:7]
        for i, value in enumerate(history, start=1):
            st.set(0x1003, i, value)
        st.set(0x1003, 0, min(8, st.get(0x1003, 0) + 1))
        self._emcy(code, reg)
        powered = self.state in POWERED
        self._abort_homing(error=True)
        self.transitions.append(13)
        self.setpoint_ack = False
        reaction = st.get(0x605E, 0)
        if powered and code not in IMMEDIATE_FAULTS and reaction in (1, 2):
            self.state = S.FAULT_REACTION_ACTIVE
            self._ramp_down(self._decel("profile" if reaction == 1 else "quick"), "fault_reaction")
        else:
            self.state = S.FAULT
            self.transitions.append(14)
            self._brake()
        self._refresh_watch()
        return True

    def _option(self, index: int, default: int) -> int:
        """An option code object, or ``default`` when the EDS has no such object."""
        try:
            return self.store.get(index, 0)
        except KeyError:
            return default

    def connection_lost(self, code: int | None) -> None:
        """The master is gone (RPDOs or SYNC missing, NMT left operational): react per 0x6007
        while the power stage is on (0 none, 1 fault ``code``, 2 disable voltage, 3 quick stop)."""
        if self.state is not S.OPERATION_ENABLED:
            return
        option = self._option(0x6007, 1)
        if option == 1:
            self.fault(code if code is not None else EMCY_RPDO_TIMEOUT)
            return
        if option not in (2, 3):
            return
        if code is not None:
            self._emcy(code, self.store.get(0x1001, 0))
        if option == 2:
            self._enter(S.SWITCH_ON_DISABLED, 9)
        else:
            self._enter(S.QUICK_STOP_ACTIVE, 11)

    # -- modes -------------------------------------------------------------------------------
    def _on_mode(self, mode: int) -> None:
        if mode not in SUPPORTED_MODES:
            raise SdoAbort(ABORT_VALUE_RANGE, f"mode {mode} not supported")
        self.mode_request = mode
        self._apply_mode_request()

    def _apply_mode_request(self) -> None:
        if self.mode_request == self.mode:
            return
        if self.homing is not None and self.homing.moving:
            return
        old, self.mode = self.mode, self.mode_request
        self.homing = None
        ax = self.axis
        if self.state is S.OPERATION_ENABLED:
            self.pp_target, self.pp_pending, self.setpoint_ack = None, None, False
            self.missed_in_row = 0
            if self.mode == MODE_PV:
                self._on_target_velocity(self.store.get(0x60FF, 0))
            elif ax.v == 0 and ax.locked:
                ax.set_reference(hold(ax.t, ax.x))
            elif self.mode not in (MODE_CSP, MODE_IP):
                ax.set_reference(stop_profile(ax.t, ax.x, ax.v, self._decel("profile")))
            else:
                ax.set_reference(hold(ax.t, ax.demand()[0]))
            self.alarm_reason, ax.alarm = None, None
        self._refresh_watch()

    def _limit_blocks(self, direction: float) -> bool:
        """Whether an active limit switch forbids motion in ``direction``."""
        x = self.axis.x
        return (direction < 0 and self.sw.active(hm.NEG, x)) or (direction > 0 and self.sw.active(hm.POS, x))

    def _clamp_target(self, target: int) -> int:
        """Clamp a position target to the software limits and away from active limit switches."""
        limits = self._software_limits()
        self.internal_limit = False
        if limits is not None:
            lo, hi = limits
            if not lo <= target <= hi:
                target = max(lo, min(hi, target))
                self.internal_limit = True
        actual = self.to_inc(self.axis.x)
        if self._limit_blocks(target - actual):
            self.internal_limit = True
            target = actual
        return target

    def _new_setpoint(self, cw: int) -> None:
        target = self.store.get(0x607A, 0)
        if cw & 0x40:  # relative
            base = self.pp_target if self.pp_target is not None else self.to_inc(self.axis.x)
            target += base
        target = self._clamp_target(target)
        ax = self.axis
        moving = not self._at_rest()
        if cw & 0x20 or not moving or self.pp_target is None:
            self.pp_target, self.pp_pending = target, None
            if not cw & 0x100:
                self._plan_pp()
        elif self.pp_pending is None:
            self.pp_pending = target
            self.alarm_reason = "pp"
            ax.alarm = max(ax.reference.end_time, ax.t)
        else:
            return  # buffer full: no acknowledge
        self.setpoint_ack = True

    def _plan_pp(self) -> None:
        ax = self.axis
        vmax, acc, dec = self._profile_limits()
        ax.set_reference(position_profile(ax.t, ax.x, ax.v, self.to_phys(self.pp_target), vmax, acc, dec))

    def _on_target_velocity(self, value: int) -> None:
        if self.state is not S.OPERATION_ENABLED or self.mode != MODE_PV or self.controlword & 0x100:
            return
        vmax, acc, dec = self._profile_limits()
        v = value / self.ipu()
        v = max(-self.params.max_velocity, min(self.params.max_velocity, v))
        v = max(-self.store.get(0x607F, 0) / self.ipu(), min(self.store.get(0x607F, 0) / self.ipu(), v))
        self.internal_limit = False
        if self._limit_blocks(v) or self._beyond_software_limit(v):
            v, self.internal_limit = 0.0, True
        ax = self.axis
        ax.set_reference(velocity_profile(ax.t, ax.x, ax.v, v, acc, dec))

    def _beyond_software_limit(self, direction: float) -> bool:
        limits = self._software_limits()
        if limits is None:
            return False
        actual = self.to_inc(self.axis.x)
        return (direction < 0 and actual <= limits[0]) or (direction > 0 and actual >= limits[1])

    def _on_halt(self, halted: bool) -> None:
        ax = self.axis
        if self.mode == MODE_HM and halted and self.homing is not None:
            self.homing.interrupt()
        elif self.mode in (MODE_PP, MODE_PV) and halted:
            ax.set_reference(stop_profile(ax.t, ax.x, ax.v, self._decel("profile")))
            self.alarm_reason, ax.alarm = None, None
        elif self.mode == MODE_PP and self.pp_target is not None:
            self._plan_pp()
        elif self.mode == MODE_PV:
            self._on_target_velocity(self.store.get(0x60FF, 0))
        self._refresh_watch()

    # -- homing ------------------------------------------------------------------------------
    def _check_homing_method(self, sub: int, method: int) -> None:
        if method != 0 and method not in hm.SUPPORTED_METHODS:
            raise SdoAbort(ABORT_VALUE_RANGE, f"homing method {method} not supported")
        if self.homing is not None and self.homing.moving:
            raise SdoAbort(ABORT_STATE, "homing in progress")

    def _start_homing(self) -> None:
        st, ipu, p = self.store, self.ipu(), self.params
        method = st.get(0x6098, 0)
        fast = min(st.get(0x6099, 1) / ipu, p.max_velocity)
        slow = min(st.get(0x6099, 2) / ipu, p.max_velocity)
        acc = min(st.get(0x609A, 0) / ipu, p.max_acceleration)
        if method not in hm.SUPPORTED_METHODS:
            self.homing = hm.Homing(self.axis, self.sw, 35, 0, 0, 0)
            self.homing.state = "error"
            return
        self.homing = hm.Homing(self.axis, self.sw, method, fast, slow, acc, self.absolute_home)
        self.alarm_reason = "homing"
        self._after_homing_step()

    def _after_homing_step(self) -> None:
        h = self.homing
        if h is None:
            return
        if h.state == "done" and h.home_position is not None and self.alarm_reason == "homing":
            # The latched home point reads the home offset from now on.
            self.zero = h.home_position - self.store.get(0x607C, 0) / self.ipu()
            self.alarm_reason = None
        if not h.moving:
            self.alarm_reason = None
            self._apply_mode_request()
        self._refresh_watch()

    def _abort_homing(self, error: bool) -> None:
        h = self.homing
        if h is not None and h.moving:
            h.state = "error" if error else "interrupted"
            if self.alarm_reason == "homing":
                self.alarm_reason, self.axis.alarm = None, None

    # -- time --------------------------------------------------------------------------------
    def update(self, t: float) -> None:
        """Advance the drive to time ``t`` (s), handling everything that happens on the way."""
        for _ in range(_MAX_EVENTS_PER_UPDATE):
            event = self.axis.advance(t)
            if event is None:
                return
            self._on_event(event)

    def _on_event(self, ev: Event) -> None:
        if ev.kind == "following_error":
            if self.state in POWERED and self.mode in FE_MODES:
                self.fault(EMCY_FOLLOWING_ERROR)
            return
        if ev.kind == "alarm":
            reason, self.alarm_reason = self.alarm_reason, None
            if reason == "homing" and self.homing is not None:
                self.alarm_reason = "homing"
                self.homing.on_event(ev)
                self._after_homing_step()
            elif reason == "pp" and self.pp_pending is not None:
                self.pp_target, self.pp_pending = self.pp_pending, None
                if not self.controlword & 0x100:
                    self._plan_pp()
            elif reason == "quick_stop" and self.state is S.QUICK_STOP_ACTIVE:
                if 1 <= self.store.get(0x605A, 0) <= 4:
                    self.state = S.SWITCH_ON_DISABLED
                    self.transitions.append(12)
                    self._brake()
            elif reason == "fault_reaction" and self.state is S.FAULT_REACTION_ACTIVE:
                self.state = S.FAULT
                self.transitions.append(14)
                self._brake()
            self._refresh_watch()
            return
        name = ev.threshold.name
        homing_runs = self.homing is not None and self.homing.state == "running"
        if name in (hm.NEG, hm.POS):
            entering = self.sw.active(name, self.axis.x)
            if homing_runs:
                self.homing.on_event(ev)
                self._after_homing_step()
            elif entering and self.state in (S.OPERATION_ENABLED, S.QUICK_STOP_ACTIVE):
                self.fault(EMCY_POSITION_LIMIT)
        elif name in (hm.HOME, hm.INDEX):
            if homing_runs:
                self.homing.on_event(ev)
                self._after_homing_step()
        elif name in (SW_MIN, SW_MAX):
            outward = (name == SW_MAX) == ev.upward
            if outward and self.state is S.OPERATION_ENABLED and self.mode in (MODE_PV, MODE_CSV):
                ax = self.axis
                ax.set_reference(stop_profile(ax.t, ax.x, ax.v, self._decel("quick")))
                self.internal_limit = True
        self._refresh_watch()

    def _refresh_watch(self) -> None:
        """What the axis must watch now: switches, homing signals, limits, following error."""
        ax = self.axis
        th = self.sw.limit_thresholds()
        if self.homing is not None and self.homing.state == "running":
            th += self.homing.thresholds()
        limits = self._software_limits()
        if limits is not None and self.mode in (MODE_PV, MODE_CSV) and self.state is S.OPERATION_ENABLED:
            th += [Threshold(SW_MIN, self.to_phys(limits[0])), Threshold(SW_MAX, self.to_phys(limits[1]))]
        ax.thresholds = th
        window = self.store.get(0x6065, 0)
        if self.state in POWERED and self.mode in FE_MODES and window != 0xFFFFFFFF:
            ax.fe_window = max(window, 1) / self.ipu()
            ax.fe_timeout = self.store.get(0x6066, 0) / 1000.0
        else:
            ax.fe_window = 0.0

    # -- SYNC --------------------------------------------------------------------------------
    def on_sync(self, fresh_rpdo: bool) -> None:
        """A SYNC (after :meth:`update` to its time and after applying the synchronous RPDOs)."""
        if self.state is not S.OPERATION_ENABLED or self.mode not in STREAMING_MODES:
            self.missed_in_row = 0
            self._goals.clear()
            return
        if self.mode == MODE_IP and not self.controlword & 0x10:
            # IP not enabled (controlword bit 4): the interpolation data record is ignored
            self.missed_in_row = 0
            self._goals.clear()
            if fresh_rpdo and self.store.get(0x60C1, 1) != self.to_inc(self.axis.x):
                self.ip_ignored += 1
            return
        if not fresh_rpdo:
            self.rpdo_missed += 1
            self.missed_in_row += 1
            if self.missed_in_row >= RPDO_TIMEOUT_SYNCS:
                self.connection_lost(EMCY_RPDO_TIMEOUT)
            return
        self.missed_in_row = 0
        if self.mode == MODE_CSV:
            self._csv_velocity(self.store.get(0x60FF, 0))
            return
        record = self.store.get(0x60C1, 1) if self.mode == MODE_IP else self.store.get(0x607A, 0)
        target = self._clamp_target(record)
        ax = self.axis
        value, exponent = self.store.get(0x60C2, 1), self.store.get(0x60C2, 2)
        period = value * 10.0 ** exponent
        start, goal = ax.demand()[0], self.to_phys(target)
        trend = 0.0
        if self._goals and period > 0:
            # (the stream's travel over the real time since the oldest of the last setpoints
            # latched, which a drive synchronized to SYNC measures: per nominal period, a late
            # SYNC's setpoint — moved on by its lateness — bridged at the increment of a longer
            # interval, an early one's at a shorter: 5.2°/s over 100 ms against a 5°/s stream
            # with SYNCs 0-9 ms late; over the last interval alone, one SYNC that went out a
            # little later than its setpoint was made for doubled the speed of a short one)
            # (and never faster than the last interval's: a stream that slows down to a stop
            # is not bridged past it at its speed of three setpoints before)
            t0, g0 = self._goals[0]
            t1, g1 = self._goals[-1]
            top = self.params.max_velocity
            if ax.t > t0:
                trend = (goal - g0) / (ax.t - t0)
                last = (goal - g1) / (ax.t - t1) if ax.t > t1 else trend
                trend = 0.0 if trend * last <= 0 else math.copysign(min(abs(trend), abs(last)), trend)
                trend = max(-top, min(top, trend))
        self._goals.append((ax.t, goal))
        ax.set_reference(linear_profile(ax.t, start, goal, period, self._bridge(goal, trend), trend))

    def _bridge(self, goal: float, v: float) -> float:
        """How long the CSP demand goes on, after reaching ``goal``, at the setpoint stream's
        speed ``v`` (its last setpoints' travel over the real time between their SYNCs) when
        the next setpoints do not come: the RPDO deadline (0x1400:5; the drive then stops per
        0x6007 at 0x6085), never past a software limit; 0 (hold the last setpoint) without one.

        The stream's speed, not the last line's: the line from the demand where the SYNC found
        it to the new setpoint also takes up the lateness of that SYNC; bridging at its speed
        fed each SYNC's lateness into the next line's start (a gap of more than two periods
        more than doubled it: the demand swung ±0.6° around a 0.4°/s path and the motor
        faulted with a following error on a loaded machine)."""
        deadline = max(self.rpdo_deadlines.values(), default=0.0)
        if deadline <= 0 or v == 0 or self.params.bridging == "hold":
            return 0.0
        limits = self._software_limits()
        if limits is not None:
            edge = self.to_phys(limits[1] if v > 0 else limits[0])
            deadline = min(deadline, max(0.0, (edge - goal) / v))
        return deadline

    def _csv_velocity(self, value: float) -> None:
        """CSV: follow the target velocity (increments/s) from this SYNC on, with the motor's
        acceleration; above 0x607F (or the motor) it is clamped and bit 11 set; towards an
        active limit switch or beyond a software limit it is 0."""
        ipu, p, ax = self.ipu(), self.params, self.axis
        v = value / ipu
        vmax = p.max_velocity
        limit = self.store.get(0x607F, 0)
        if limit > 0:
            vmax = min(vmax, limit / ipu)
        self.internal_limit = False
        if abs(v) > vmax:
            v, self.internal_limit = (vmax if v > 0 else -vmax), True
        if self._limit_blocks(v) or self._beyond_software_limit(v):
            v, self.internal_limit = 0.0, True
        amax = p.max_acceleration
        ax.set_reference(velocity_profile(ax.t, ax.x, ax.v, v, amax, amax))

    # -- outputs -----------------------------------------------------------------------------
    def _at_rest(self) -> bool:
        ax = self.axis
        return ax.v == 0 and ax.locked and ax.t >= ax.reference.end_time and ax.reference.segments[-1].v0 == 0

    def resting(self) -> bool:
        """Nothing happens here until a command comes: power stage off, the motor still, no
        homing running and no alarm due (the simulated drive's poll may then slow down)."""
        homing = self.homing
        return (self.state not in POWERED and self.axis.alarm is None and self._at_rest()
                and (homing is None or homing.state != "running"))

    def digital_inputs(self) -> int:
        x = self.axis.x
        return (int(self.sw.active(hm.NEG, x)) | int(self.sw.active(hm.POS, x)) << 1
                | int(self.sw.active(hm.HOME, x)) << 2)

    def statusword(self) -> int:
        sw = STATUS_BITS[self.state] | 0x0200
        if self.state in VOLTAGE:
            sw |= 0x0010
        x = self.axis.x
        on_limit = self.sw.active(hm.NEG, x) or self.sw.active(hm.POS, x)
        if on_limit:
            sw |= 0x0080
        if self.internal_limit or on_limit:
            sw |= 0x0800
        if self.state is S.QUICK_STOP_ACTIVE and self._at_rest():
            sw |= 0x0400
        if self.state is not S.OPERATION_ENABLED:
            return sw
        ax = self.axis
        fe = abs(ax.following_error) * self.ipu() > self.store.get(0x6065, 0)
        if self.mode == MODE_PP:
            if self.setpoint_ack:
                sw |= 0x1000
            if fe:
                sw |= 0x2000
            if self._at_rest() and self.pp_pending is None:
                target = self.pp_target
                if target is None or self.controlword & 0x100 or \
                        abs(self.to_inc(ax.x) - target) <= self.store.get(0x6067, 0):
                    sw |= 0x0400
        elif self.mode == MODE_PV:
            v_ref = ax.reference.segments[-1].v0
            if ax.t >= ax.reference.end_time and abs(ax.v - v_ref) * self.ipu() < 1:
                sw |= 0x0400
            if ax.v == 0:
                sw |= 0x1000
        elif self.mode == MODE_HM:
            sw |= 0x0400 if self.homing is None else self.homing.status_bits()
        elif self.mode == MODE_CSP:
            sw |= 0x1000
            if fe:
                sw |= 0x2000
        elif self.mode == MODE_IP:
            if self.controlword & 0x10:
                sw |= 0x1000  # IP active
            if fe:
                sw |= 0x2000
        elif self.mode == MODE_CSV:
            sw |= 0x1000  # drive follows the command value
        return sw

    # -- object checks -----------------------------------------------------------------------
    def _check_scaling(self, sub: int, value: int) -> None:
        if self.state in POWERED:
            raise SdoAbort(ABORT_STATE, "scaling changes only while disabled")
        self._ipu = None  # recomputed from the stored value at the next use

    def _on_error_history(self, sub: int, value: int) -> None:
        if sub != 0 or value != 0:
            raise SdoAbort(ABORT_VALUE_RANGE, "only 0 may be written to 0x1003:0")
        for i in range(1, 9):
            self.store.set(0x1003, i, 0)
