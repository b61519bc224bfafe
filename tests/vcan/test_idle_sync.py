"""The idle SYNC (``[can] idle_sync_period``, tcs.drivers.idle_sync) against simulated drives:
resting drives are told the slower period (0x1006, RPDO deadlines 0x1400:5) before the SYNC
slows, an enable gets the full rate and the drives' full-rate values back before any power
stage is switched on, and a drive that refuses the writes in operational keeps the full rate
for all. Waits for states only; the rates are read from the cycle source's divider and the
drives' own objects."""

from __future__ import annotations

import logging

from cia402_rig import SLOWDOWN, AxisSpec, Rig

from tcs.drivers.drive import DriveState, Progress
from tcs.sim.cia402_drive import SimDriveParams

FULL, IDLE = 0.01, 0.05
WAIT = 30.0
# deadlines: 3 SYNC periods (0x1400:5 in ms), widened with the period
DEADLINE = {"master_loss_timeout": 3 * FULL * SLOWDOWN}


def told(rig: Rig, name: str) -> tuple[int, int]:
    """(0x1006 in µs, RPDO1's deadline 0x1400:5 in ms) as the simulated drive holds them."""
    store = rig.sims[name].store
    return store.get(0x1006, 0), store.get(0x1400, 5)


def full_values() -> tuple[int, int]:
    return round(FULL * SLOWDOWN * 1e6), round(3 * FULL * SLOWDOWN * 1e3)


def idle_values() -> tuple[int, int]:
    return round(IDLE * SLOWDOWN * 1e6), round(3 * IDLE * SLOWDOWN * 1e3)


def test_resting_drives_slow_the_sync_and_an_enable_brings_it_back_first(can_channel):
    axes = {"az": AxisSpec(1, section=DEADLINE), "alt": AxisSpec(2, section=DEADLINE)}
    with Rig(can_channel, axes, idle_sync_period=IDLE) as rig:
        violations = []

        def watch(cycle) -> None:  # no power stage on while a drive holds the idle values
            for name, sim in rig.sims.items():
                if sim.state == "OPERATION ENABLED" and told(rig, name) != full_values():
                    violations.append((name, told(rig, name), rig.system.cycle.divider))
        rig.cycle_hooks.append(watch)
        assert rig.boot_and_start() == {}
        idle = rig.system.idle
        rig.wait(lambda: idle.state == "idle", WAIT, "the idle SYNC")
        assert rig.system.cycle.divider == round(IDLE / FULL)
        assert told(rig, "az") == told(rig, "alt") == idle_values()
        # the drives still report: a fault shows at the slower rate
        assert rig.status("az").state is DriveState.SWITCH_ON_DISABLED

        rig.enable("az")                      # held until the full rate is back
        assert rig.system.cycle.divider == 1 and idle.state in ("tightening", "full")
        rig.wait(lambda: idle.state == "full", WAIT, "every drive back at the full rate")
        assert told(rig, "az") == told(rig, "alt") == full_values()
        rig.drive("az").set_setpoint(0.5)
        rig.wait(lambda: abs(rig.status("az").position - 0.5) < 1e-3, WAIT, "az at 0.5")
        # a homing run and a profile move end, and their results stay for the status: the
        # drive rests again all the same once disabled
        rig.drive("az").start_homing()
        rig.wait(lambda: rig.status("az").homing is Progress.DONE, WAIT, "az homed")
        rig.enable("alt")
        rig.drive("alt").move_to(0.25)
        rig.wait(lambda: rig.status("alt").move is Progress.DONE, WAIT, "alt's move done")

        rig.drive("az").disable()
        rig.drive("alt").disable()
        rig.wait_state("az", DriveState.SWITCH_ON_DISABLED)
        rig.wait_state("alt", DriveState.SWITCH_ON_DISABLED)
        rig.wait(lambda: idle.state == "idle" and idle.entered == 2, WAIT, "idle again")
        assert told(rig, "az") == idle_values()
        assert violations == []
        assert rig.sims["az"].logic.missed_in_row == 0


def test_a_drive_that_refuses_the_writes_keeps_the_full_rate_for_all(can_channel, caplog):
    stiff = SimDriveParams(pdo_timer_in_operational=False)  # PDO parameters in pre-op only
    axes = {"az": AxisSpec(1, section=DEADLINE), "alt": AxisSpec(2, params=stiff, section=DEADLINE)}
    caplog.set_level(logging.WARNING, logger="tcs.drivers.idle_sync")
    with Rig(can_channel, axes, idle_sync_period=IDLE) as rig:
        assert rig.boot_and_start() == {}
        idle = rig.system.idle
        rig.wait(lambda: idle._warned and idle.state == "full", WAIT, "the refusal")
        assert rig.system.cycle.divider == 1 and idle.entered == 0
        assert told(rig, "az") == told(rig, "alt") == full_values()   # az's writes undone
        text = " ".join(r.getMessage() for r in caplog.records)
        assert "idle SYNC not used" in text and "node 2" in text, text
        rig.enable("az", "alt")


def test_no_idle_sync_without_the_setting(can_channel):
    with Rig(can_channel, {"az": AxisSpec(1)}) as rig:
        assert rig.boot_and_start() == {}
        assert not rig.system.idle.enabled
        rig.wait(lambda: rig.system.cycle.stats().cycles > 10, WAIT, "cycles")
        assert rig.system.cycle.divider == 1 and rig.system.idle.state == "full"


def test_at_the_idle_rate_a_late_answer_has_the_longer_cycle_to_come(can_channel):
    """Under the idle SYNC the TPDOs have the same share of the longer cycle as at the full
    rate: a drive answering 1.5 full periods after each SYNC — late for a 10 ms cycle, in time
    for a 50 ms one — is in time at rest. (The wait once stayed ``tpdo_deadline`` × the nominal
    period, and every idle cycle of such a drive counted a TPDO time-out.) At most half the
    cycles may time out: a busy host may delay an answer; the old wait timed out every one."""
    with Rig(can_channel, {"az": AxisSpec(1, section=DEADLINE)}, idle_sync_period=IDLE) as rig:
        assert rig.boot_and_start() == {}
        idle, cycle, sim = rig.system.idle, rig.system.cycle, rig.sims["az"]
        rig.wait(lambda: idle.state == "idle", WAIT, "the idle SYNC")
        sim.params.tpdo_latency = 1.5 * FULL * SLOWDOWN
        start = cycle.stats().cycles
        rig.wait(lambda: cycle.stats().cycles >= start + 2, WAIT, "a cycle with the late answers")
        before = cycle.stats()
        rig.wait(lambda: cycle.stats().cycles >= before.cycles + 20, WAIT, "20 idle cycles")
        after = cycle.stats()
        sim.params.tpdo_latency = 0.0
        assert idle.state == "idle" and cycle.divider == round(IDLE / FULL)
        cycles, timeouts = after.cycles - before.cycles, after.tpdo_timeouts - before.tpdo_timeouts
        assert timeouts < cycles / 2, f"{timeouts} TPDO time-outs in {cycles} idle cycles"
