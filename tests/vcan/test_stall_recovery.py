"""Stall recovery (issue 39 items 6 and 8): a master that stalls mid-slew never makes the drive
jump back or brake harder than the axis's configured stop deceleration.

The TCS's real control stack — :class:`~tcs.axes.axis.Axis` (planner, ``_limit_step``),
:class:`~tcs.axes.control_loop.ControlLoop`, the CiA-402 driver and its cycle — streams a
5°/s slew to a simulated drive over CANopen frames (python-can virtual bus, :mod:`cia402_rig`).
The master's gap is made deterministic by *holding its cycle* (a cycle callback that sleeps g s
once, after the axis made its setpoint: neither SYNC nor RPDO goes out meanwhile, as when the
control process is stopped), while the simulated drive runs on and bridges (extrapolating at
the stream's speed or holding, ``SimDriveParams.bridging``). Motion is judged on the simulated
drive itself (its demand 0x6062 and motor velocity, sampled by a thread; the CSP targets it
latched); waits are for states with generous time-outs, never for durations.
"""

from __future__ import annotations

import contextlib
import dataclasses
import threading
import time

import pytest
from cia402_rig import SLOWDOWN, AxisSpec, Rig

from tcs.axes.axis import Axis
from tcs.axes.control_loop import ControlLoop
from tcs.config.axes import AxisSection
from tcs.drivers.drive import Mode
from tcs.sim.cia402_drive import SimDriveParams

#: The simulated telescope's AZ: 5°/s, 2°/s², jerk 4°/s³, stop deceleration 4°/s²; its drive
#: table 6°/s, 3°/s² (looser), the motor 10°/s, 10°/s².
AXIS = AxisSection(module="AZ", drive="az", min=-200.0, max=200.0, max_velocity=5.0,
                   max_acceleration=2.0, max_jerk=4.0, stop_deceleration=4.0)
STOP_DECEL = 4.0
MOTOR = dict(max_velocity=10.0, max_acceleration=10.0)
STOPPING = ("QUICK STOP ACTIVE", "SWITCH ON DISABLED", "FAULT REACTION ACTIVE", "FAULT")


class Events:
    def publish(self, *args, **kwargs) -> None:  # (the axis's INFO events: not looked at)
        pass

    def __getattr__(self, name):
        return lambda *a, **k: None


class Sampler:
    """(time, demand, motor velocity, state, motor position) of a simulated drive every ~2 ms."""

    def __init__(self, sim):
        self.sim = sim
        self.samples: list[tuple[float, float, float, str]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="test-sampler", daemon=True)

    def _run(self) -> None:
        sim = self.sim
        while not self._stop.is_set():
            with sim.lock:
                lg = sim._now()
                demand = lg.axis.demand()[0]
                self.samples.append((lg.axis.t, demand, lg.axis.v, lg.state.value, lg.axis.x))
            time.sleep(0.002)

    def __enter__(self) -> "Sampler":
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join(5.0)

    def reversal(self) -> float:
        """The largest step back against the slew (positive direction) of the demand while
        the drive follows it (Operation enabled) and of the motor throughout."""
        worst = 0.0
        for values in ([d for _, d, _, s, _ in self.samples if s == "OPERATION ENABLED"],
                       [x for *_, x in self.samples]):
            top = -float("inf")
            for value in values:
                top = max(top, value)
                worst = max(worst, top - value)
        return worst

    def peak_speed(self, window: float, skip=()) -> tuple[float, float, int]:
        """The largest mean speed over ``window`` s (the sim's own clock) of the demand while
        the drive follows it, and of the motor, over windows that overlap none of the
        ``skip`` intervals: (demand, motor, windows judged)."""
        s = [x for x in self.samples if x[3] == "OPERATION ENABLED"]
        best = [0.0, 0.0]
        judged = 0
        j = 0
        for i in range(len(s)):
            while j < len(s) and s[j][0] - s[i][0] < window:
                j += 1
            if j >= len(s):
                break
            if any(a < s[j][0] and s[i][0] < b for a, b in skip):
                continue
            judged += 1
            dt = s[j][0] - s[i][0]
            best[0] = max(best[0], (s[j][1] - s[i][1]) / dt)
            best[1] = max(best[1], (s[j][4] - s[i][4]) / dt)
        return best[0], best[1], judged

    def peak_decel(self, window: float = 0.02, states=None) -> float:
        """The motor's largest deceleration, averaged over ``window`` s (the sim's own clock),
        in ``states`` only (default: all)."""
        s = [x for x in self.samples if states is None or x[3] in states]
        worst, j = 0.0, 0
        for i in range(len(s)):
            while j < len(s) and s[j][0] - s[i][0] < window:
                j += 1
            if j >= len(s):
                break
            t0, _, v0, *_ = s[i]
            t1, _, v1, *_ = s[j]
            if v0 > 0:  # slowing down while moving forwards
                worst = max(worst, (v0 - v1) / (t1 - t0))
        return worst


class LateWake(threading.Event):
    """The cycle runner's sleep to its next SYNC slot, overslept by ``pattern`` (s, repeated;
    empty: on time) — a busy host waking the runner late. The runner sees the lateness (its
    clock is the real one) and the SYNC goes out that late, as it does on a loaded machine."""

    def __init__(self) -> None:
        super().__init__()
        self.pattern: list[float] = []
        self._k = 0

    def wait(self, timeout=None):
        pattern = self.pattern
        if timeout is not None and pattern:
            timeout += pattern[self._k % len(pattern)]
            self._k += 1
        return super().wait(timeout)


class Stand:
    """A rig with one simulated drive driven by a real Axis and ControlLoop."""

    def __init__(self, rig: Rig, mode: Mode):
        self.rig = rig
        system = rig.system
        system.cycle.remove_callback(rig._on_cycle)  # the loop steps the drive, not the rig
        self.drive = system.drives["az"]
        self.axis = Axis("az", AXIS, self.drive, Events(), time.time, rig.can.sync_period)
        self.loop = ControlLoop([self.axis], system.cycle, time.time)
        self.sim = rig.sims["az"]
        self.mode = mode
        self.hold = 0.0       # s the next cycle is held (the master's gap), once
        self.wake = system.cycle._stop = LateWake()  # (the runner's sleep: SYNC jitter)
        system.cycle.add_callback(self._held)

    def _held(self, cycle) -> None:
        if self.hold:
            hold, self.hold = self.hold, 0.0
            start = time.monotonic()
            time.sleep(hold)
            self.held = time.monotonic() - start

    def command(self, kind: str, value) -> None:
        with self.axis._lock:
            self.axis._commands.append((kind, value, None, None))

    def start(self) -> None:
        assert self.rig.boot_and_start() == {}
        self.command("power", True)
        self.rig.wait(lambda: self.axis.power_state == 1.0 and self.drive.status().mode is self.mode,
                      20, "powered in the mode")

    def slew(self, goal: float) -> None:
        self.command("target", goal)
        self.rig.wait(lambda: self.sim.velocity > 4.99, 30, "cruising at 5°/s")

    def gap(self, seconds: float) -> None:
        cycles = self.loop.cycles
        self.hold = seconds * SLOWDOWN
        self.rig.wait(lambda: self.loop.cycles > cycles + 30, 30, "30 cycles after the gap")


def rig_for(can_channel, mode: Mode, bridging: str = "extrapolate", **section) -> Rig:
    name = {Mode.CSP: None, Mode.IP: "vendor-ip-only", Mode.CSV: "vendor-csv-only"}[mode]
    spec = AxisSpec(1, params=SimDriveParams(bridging=bridging, **MOTOR),
                    section=dict(max_velocity=6.0, max_acceleration=3.0,
                                 quick_stop_deceleration=STOP_DECEL, absolute=True,
                                 following_error_window=1.0, following_error_timeout=0.1,
                                 **section))
    if name is not None:
        from pathlib import Path
        eds = str(Path(__file__).parent / "eds" / f"{name}.eds")
        spec.section["eds"] = eds
        spec.sim_eds = eds
    return Rig(can_channel, {"az": spec})


def decel_steps(sim, period: float) -> list[float]:
    """How much each step between two continuous CSP/IP targets the drive latched shrank
    from the one before (units/s²), slowing down only: the TCS's commanded deceleration."""
    recs = list(sim.csp_targets)
    out = []
    for (_, a, _), (_, b, c1), (_, c, c2) in zip(recs, recs[1:], recs[2:]):
        if c1 and c2 and b - a > 0:
            out.append(((b - a) - (c - b)) / period ** 2)
    return out


@pytest.mark.parametrize("mode,bridging,gap", [
    (Mode.CSP, "extrapolate", 0.2), (Mode.CSP, "extrapolate", 0.05), (Mode.CSP, "hold", 0.2),
    (Mode.IP, "extrapolate", 0.2), (Mode.CSV, "extrapolate", 0.2)])
def test_a_short_master_gap_mid_slew_never_pulls_the_drive_back(can_channel, mode, bridging, gap):
    """A gap shorter than the drive's RPDO deadline (0.5 s): no demand reversal, no fault, the
    slew goes on; the TCS never commands more than the stop deceleration (the motor's own
    braking depends on the drive's bridging and the host's other late cycles: the bench)."""
    with rig_for(can_channel, mode, bridging) as rig:
        # (the TCS's commanded deceleration is judged step by step over the nominal period:
        # the setpoints as the axis made them, not moved on by their SYNC's lateness, which
        # makes a step the stream's travel over the real interval — the jittery-SYNC test)
        rig.system.cycle.retime = False
        if rig.system.cycle.kernel_sync:
            # (the kernel's SYNC goes on while the master is held: the drive counts three SYNCs
            # without a setpoint and stops itself — the case of tests/vcan/test_driver_safety,
            # test_stalled_loop_makes_every_drive_quick_stop_by_itself; this test is about a
            # master whose stall stops the SYNC too: thread mode, socketcand)
            pytest.skip("kernel SYNC: a held master is a drive's own stop after three SYNCs")
        stand = Stand(rig, mode)
        stand.start()
        stand.slew(150.0)
        stand.sim.csp_targets.clear()
        with Sampler(stand.sim) as rec:
            time.sleep(0.1)
            stand.gap(gap)
        # the master's silence as it really was: a starved host (an emulated guest at 11x) can
        # stretch the hold towards the RPDO deadline, and then the drive's stop is right
        held = getattr(stand, "held", 0.0)
        if held + 2 * rig.can.sync_period > 0.8 * 0.5 * SLOWDOWN and stand.axis.fault is not None:
            pytest.skip(f"the host stretched the {gap * SLOWDOWN:g} s hold to {held:.2f} s, near the "
                        f"drive's RPDO deadline ({0.5 * SLOWDOWN:g} s): not the case under test")
        assert stand.axis.fault is None and stand.drive.status().fault is None
        assert stand.sim.state == "OPERATION ENABLED" and stand.sim.error_code == 0
        assert stand.axis.resumes >= 1
        # (before: 0.19° for 0.05 s, 0.9° for 0.2 s. A cycle merely one or two periods late on
        # a busy host still sends its setpoint, late: at most two periods' travel back, 0.1°)
        assert rec.reversal() < 0.11, rec.reversal()
        if mode is not Mode.CSV:
            # (+ 2 increments: the drive receives whole increments)
            slack = 2.0 / stand.sim.params.increments_per_unit / rig.can.sync_period ** 2
            assert max(decel_steps(stand.sim, rig.can.sync_period)) <= STOP_DECEL * 1.001 + slack
        rig.wait(lambda: stand.sim.velocity > 4.99, 30, "cruising again")


def test_a_long_master_gap_ends_in_a_controlled_stop(can_channel):
    """A gap longer than the RPDO deadline (0.5 s): the drive's own reaction (quick stop at
    0x6085 = the configured stop deceleration), the TCS then stops the axis; no reversal."""
    with rig_for(can_channel, Mode.CSP) as rig:
        stand = Stand(rig, Mode.CSP)
        stand.start()
        stand.slew(150.0)
        with Sampler(stand.sim) as rec:
            time.sleep(0.1)
            stand.hold = 0.8 * SLOWDOWN
            rig.wait(lambda: stand.sim.state != "OPERATION ENABLED", 30, "the drive's reaction")
            rig.wait(lambda: abs(stand.sim.velocity) < 1e-9, 30, "standstill")
        assert 0x8250 in stand.sim.emcy_sent  # RPDO time-out / SYNC loss
        assert rec.reversal() < 1e-3, rec.reversal()
        # the stop (the cruise before it ripples with the host's own late cycles: the bench)
        assert rec.peak_decel(states=STOPPING) <= STOP_DECEL * 1.01, rec.peak_decel(states=STOPPING)
        rig.wait(lambda: stand.axis.power_state == 0.0 or stand.axis.fault is not None, 30,
                 "the axis gave up")


def test_csv_is_clamped_to_the_axis_limits(can_channel):
    """CSV: the TCS's position loop commands at most the axis's speed (5°/s), never the drive
    table's 6°/s, even when the stream runs ahead of the drive (here by 0.5°)."""
    with rig_for(can_channel, Mode.CSV) as rig:
        stand = Stand(rig, Mode.CSV)
        stand.start()
        stand.slew(150.0)
        drive = stand.drive
        sent = drive.set_setpoint
        with Sampler(stand.sim) as rec:
            drive.set_setpoint = lambda p, v=None: sent(p + 0.5, v)  # the stream jumps ahead
            try:
                rig.wait(lambda: drive.status().following_error > 0.2, 30, "behind the stream")
                rig.wait(lambda: drive.status().following_error < 0.01, 30, "caught up")
            finally:
                drive.set_setpoint = sent
        assert stand.axis.fault is None and drive.status().fault is None
        speeds = [v for _, _, v, *_ in rec.samples]
        assert 4.9 < max(speeds) <= 5.0 * (1 + 1e-6), max(speeds)


#: SYNC lateness, s, one entry per SYNC, repeated (patterns whose length does not divide the
#: 100 ms window: a pattern repeating every 100 ms would look smooth over it): every 7th SYNC
#: 6 ms late; a spread of 0-9 ms; a wake 15 ms late (the slot it was for is skipped: its
#: setpoint goes with the next SYNC, a period and a half late)
JITTER = {"every 7th 6 ms": [0.0] * 6 + [0.006],
          "0-9 ms": [0.0, 0.004, 0.001, 0.009, 0.0, 0.002, 0.006, 0.0, 0.003, 0.008, 0.0, 0.005,
                     0.007],
          "15 ms in 17": [0.0] * 16 + [0.015]}


@contextlib.contextmanager
def cruising(can_channel):
    """(rig, cycle source, stand) of a CSP rig whose runner sends SYNC itself, AZ cruising at
    5°/s towards 150° (skipped with kernel SYNC: the runner does not send it there)."""
    with rig_for(can_channel, Mode.CSP) as rig:
        source = rig.system.cycle
        if source.kernel_sync:
            pytest.skip("kernel SYNC: the runner does not send the SYNC")
        stand = Stand(rig, Mode.CSP)
        stand.start()
        stand.slew(150.0)
        yield rig, source, stand


@pytest.mark.parametrize("jitter", sorted(JITTER))
def test_a_jittery_sync_never_runs_the_demand_above_the_speed_limit(can_channel, jitter):
    """Item 10: SYNCs that go out late (the runner's thread woken late) latch setpoints made for
    the SYNC's slot, and the drive interpolates each over the nominal period from when it got
    it: the setpoints go moved on by the SYNC's lateness, and a slot overrun by less than half
    a period gets its SYNC late rather than skipped. The demand's speed over real time — over
    100 ms windows, as the issue measured it (5.73°/s against 5) — stays within the axis's
    5°/s (before: 5.10-5.12°/s here on an idle host). CSP with the drive's default bridging
    (extrapolation within its RPDO deadline); a drive that holds (IP without a deadline) still
    ripples: docs/motion.md.

    Windows around a SYNC the runner sent more than half a millisecond after it had moved the
    setpoints on (``CycleSource.retime_delays``: the host preempted it in between) and around
    a slot it skipped (``CycleSource.skips``: overran by more than half a period, the stream
    slips a step) are left out — a loaded host's own jitter, not the pattern's; the test is
    skipped when the host left too few windows to judge."""
    with cruising(can_channel) as (rig, source, stand):
        stand.wake.pattern = [late * SLOWDOWN for late in JITTER[jitter]]
        cycles = stand.loop.cycles
        source.retime_delays.clear()
        source.skips.clear()
        with Sampler(stand.sim) as rec:
            rig.wait(lambda: stand.loop.cycles > cycles + 200, 60, "200 jittery cycles")
        stand.wake.pattern = []
        assert stand.axis.fault is None and stand.sim.error_code == 0
        period = rig.can.sync_period
        irregular = [sent for sent, _ in list(source.retime_delays)] + list(source.skips)
        skip = [(sent - period, sent + 6 * period) for sent in irregular]
        demand, motor, judged = rec.peak_speed(0.1 * SLOWDOWN, skip)
        if judged < 50:
            pytest.skip(f"the host preempted the cycle runner between its setpoints and their "
                        f"SYNC {len(skip)} times: {judged} windows left to judge")
        assert demand <= 5.0 * 1.01, (demand, motor, judged)


def test_a_runner_preempted_while_sending_its_setpoints_sends_them_again_moved_on(can_channel):
    """Item 10, a busy host's share: the cycle runner preempted while it sends the held
    setpoints (here the CAN transport's send of the first one holds the thread 3 ms on every
    7th SYNC) sends its SYNC that much later than the lateness it had moved them on by — a
    drive latching them would fall short by 3 ms of travel and make it up in the next line
    (5.10°/s over 100 ms at 5°/s). The runner sees the time it lost, moves them on again and
    sends them again before the SYNC (a drive latches the last it got): the demand stays within
    the axis's 5°/s over every 100 ms window (slots the host itself skipped judged apart)."""
    with cruising(can_channel) as (rig, source, stand):
        transport = source.bus.bus
        send = transport.send
        count = {"syncs": 0, "first": True}
        runner = source._thread

        def preempted_send(msg, timeout=None):
            result = send(msg, timeout)
            if threading.current_thread() is runner:
                if msg.arbitration_id == 0x080:
                    count["syncs"] += 1
                    count["first"] = True
                elif 0x200 <= msg.arbitration_id < 0x580 and count["first"]:
                    count["first"] = False
                    if count["syncs"] % 7 == 3:
                        time.sleep(0.003 * SLOWDOWN)
            return result

        cycles = stand.loop.cycles
        again = source.stats().retimed_again
        source.skips.clear()
        transport.send = preempted_send
        try:
            with Sampler(stand.sim) as rec:
                rig.wait(lambda: stand.loop.cycles > cycles + 200, 60, "200 cycles")
        finally:
            transport.send = send
        assert stand.axis.fault is None and stand.sim.error_code == 0
        assert source.stats().retimed_again - again >= 20
        period = rig.can.sync_period
        skip = [(at - period, at + 6 * period) for at in list(source.skips)]
        demand, motor, judged = rec.peak_speed(0.1 * SLOWDOWN, skip)
        if judged < 50:
            pytest.skip(f"the host skipped {len(skip)} slots: {judged} windows left to judge")
        assert demand <= 5.0 * 1.01, (demand, motor, judged)
