"""A master that starts while a drive is enabled and moving (a restart after a crash) stops it
in a controlled way — quick stop with the drive's quick-stop deceleration, then disable — before
it reconfigures anything; it never cuts the power at speed (transition 9)."""

from __future__ import annotations

import threading

import pytest
from cia402_rig import SCALE, AxisSpec, Rig

from tcs.drivers.drive import DriveState, Mode
from tcs.sim.cia402_drive import SimDriveParams

QUICK = 2.0   # units/s², the drive's quick-stop deceleration (0x6085)
MOTOR = 20.0  # units/s², what the motor could do: a power cut / brake stops this hard


@pytest.mark.parametrize("option", [2, 6], ids=["605A=2 ends disabled", "605A=6 stays in QSA"])
def test_restart_during_a_move_quick_stops_before_reconfiguring(can_channel, option):
    axes = {"az": AxisSpec(1, params=SimDriveParams(increments_per_unit=SCALE, max_velocity=10.0,
                                                    max_acceleration=MOTOR),
                           section={"default_mode": "pp", "max_velocity": 3.0,
                                    "max_acceleration": 6.0, "quick_stop_deceleration": QUICK,
                                    # the old master's drive does not notice it went away
                                    "heartbeat_consumer_timeout": 30.0})}
    with Rig(can_channel, axes) as rig:
        assert rig.boot_and_start() == {}
        sim = rig.sims["az"]
        with sim.lock:
            sim.store.set(0x605A, 0, option)
            # a drive that does not watch SYNC (0x1006 = 0) and takes no action when the
            # master's messages stop (0x6007 = 0): its profile move outlives the master
            sim.store.set(0x1006, 0, 0)
            sim.store.set(0x6007, 0, 0)
        rig.enable("az")
        rig.drive("az").move_to(90.0)
        rig.wait(lambda: sim.velocity >= 2.9, what="az at speed")

        # The master dies (no SYNC, no RPDO, no heartbeat); the profile move goes on.
        rig.system.stop()
        rig.system.bus.stop_heartbeat()
        assert sim.state == "OPERATION ENABLED" and sim.velocity >= 2.9
        seen = len(sim.logic.transitions)

        # The new master boots it; meanwhile the motor's speed is sampled (model time).
        samples: list[tuple[float, float]] = []
        done = threading.Event()

        def sample() -> None:
            while not done.is_set():
                with sim.lock:
                    logic = sim.logic
                    logic.update(sim.clock())
                    samples.append((logic.axis.t, logic.axis.v))
                done.wait(0.005)

        sampler = threading.Thread(target=sample)
        sampler.start()
        try:
            rig.system.bus.start_heartbeat()
            assert rig.system.boot() == {}
            rig.system.start()
            status = rig.wait_state("az", DriveState.SWITCH_ON_DISABLED)
            rig.wait(lambda: sim.velocity == 0.0, what="az standing still")
        finally:
            done.set()
            sampler.join()

        # Quick stop (11), then Switch on disabled (12: by itself with option 2, by the
        # master's disable voltage at standstill with option 6) — never 9 (power cut at speed).
        assert sim.logic.transitions[seen:][:2] == [11, 12], sim.logic.transitions[seen:]
        assert 9 not in sim.logic.transitions[seen:]
        # It decelerated along its quick-stop ramp, not at what the motor could do.
        decel = [(v1 - v2) / (t2 - t1) for (t1, v1), (t2, v2) in zip(samples, samples[1:])
                 if t2 - t1 > 1e-3]
        assert max(decel) <= QUICK * 1.05, max(decel)
        assert any(v >= 2.9 for _, v in samples)  # it really was still moving at the restart
        assert status.fault is None and status.mode is Mode.PP
        rig.enable("az")  # and it works again for the new master
