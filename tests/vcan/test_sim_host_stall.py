"""The simulated drive on a busy host: its own stall is no silent master, a silent master is.

A master thread of the test sends what the TCS sends in the cyclic phase — RPDO1 (controlword,
target), SYNC every 10 ms, its heartbeat every 50 ms — to a drive enabled in CSP that watches
SYNC (0x1006) and the master's heartbeat (0x1016, 200 ms). A host stall of the simulator is
made by holding its port's lock (no thread of the simulator runs meanwhile, as when the
process is stopped or starved) while the master pauses too, as in the control process where
master and simulated drives share one process. Real time throughout; waits are for states.
"""

from __future__ import annotations

import struct
import threading
import time

import pytest

from tcs.sim import SimDrive, SimDriveParams

from tests.vcan.test_sim_drive import MASTER, NODE, Master, wait_for


class CyclicMaster:
    """The master's cyclic traffic from a thread; ``pause`` holds it, ``silence`` ends SYNC and
    heartbeat for good (a master that died)."""

    def __init__(self, m: Master, target: int = 0):
        self.m = m
        self.target = target
        self.cw = 0x0F
        self.run = threading.Event()
        self.run.set()
        self.silent = threading.Event()
        self.beating = True       # the heartbeat goes on while silent (only SYNC/RPDO stop)
        self._stop = threading.Event()
        self.cycles = 0
        self._thread = threading.Thread(target=self._loop, daemon=True)

    def start(self) -> "CyclicMaster":
        self._thread.start()
        return self

    def _loop(self) -> None:
        last_beat = 0.0
        while not self._stop.is_set():
            if not self.run.is_set():
                self.run.wait(0.05)
                continue
            silent = self.silent.is_set()
            if not silent:
                self.m.send(0x200 + NODE, struct.pack("<Hi", self.cw, self.target))
                self.m.send(0x080, b"")
                self.cycles += 1
            if (not silent or self.beating) and time.monotonic() - last_beat >= 0.05:
                self.m.send(0x700 + MASTER, b"\x05")
                last_beat = time.monotonic()
            time.sleep(0.01)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5.0)


@pytest.fixture
def cyclic(can_channel):
    """An enabled CSP drive under a cyclic master: ``(sim, master, cyclic)``."""
    sim = SimDrive(dict(can_channel), NODE, SimDriveParams())  # the real clock
    m = Master(can_channel)
    sim.start()
    cm = None
    try:
        m.sdo_write(0x1006, 0, 10000, "<I")                   # SYNC every 10 ms: watched
        m.sdo_write(0x1016, 1, (MASTER << 16) | 200, "<I")    # master heartbeat: 200 ms
        m.sdo_write(0x6060, 0, 8, "<b")
        m.send(0x000, bytes([0x01, NODE]))
        wait_for(lambda: sim.nmt_state == 0x05, what="operational")
        cm = CyclicMaster(m).start()
        for cw in (0x06, 0x07, 0x0F):
            cm.cw = cw
            time.sleep(0.05)
        wait_for(lambda: sim.state == "OPERATION ENABLED", 10.0, "operation enabled")
        yield sim, m, cm
    finally:
        if cm is not None:
            cm.stop()
        m.close()
        sim.stop()


def test_a_host_stall_of_the_simulator_is_ridden_out(cyclic):
    sim, m, cm = cyclic
    time.sleep(0.3)                                           # supervision armed
    for _ in range(2):
        cm.run.clear()                                        # the whole process stalls ...
        with sim.lock:                                        # ... the simulator's threads too
            time.sleep(1.0)                                   # > SYNC loss (0.5 s), > 0x1016
        cm.run.set()
        before = cm.cycles
        wait_for(lambda: cm.cycles >= before + 30, 10.0, "30 cycles after the stall")
    assert m.emcy_codes() == [] and sim.error_code == 0
    assert sim.state == "OPERATION ENABLED" and sim.nmt_state == 0x05
    assert sim.host_stalls >= 2


@pytest.mark.parametrize("heartbeat,code,nmt", [(True, 0x8250, 0x05), (False, 0x8130, 0x7F)])
def test_a_silent_master_still_faults_the_drive(cyclic, heartbeat, code, nmt):
    """SYNC stops (heartbeat on): SYNC loss, 0x8250; everything stops: heartbeat lost, 0x8130
    and pre-operational. The simulator runs all the while: a real fault."""
    sim, m, cm = cyclic
    time.sleep(0.3)
    cm.beating = heartbeat
    cm.silent.set()
    wait_for(lambda: code in m.emcy_codes(), 10.0, f"EMCY 0x{code:04X}")
    assert sim.state == "FAULT" and sim.error_code == code
    wait_for(lambda: sim.nmt_state == nmt, 5.0, "NMT state")


def test_a_stall_does_not_move_the_physics_on(can_channel):
    """A profile move stopped by a host stall resumes where it was (no jump)."""
    sim = SimDrive(dict(can_channel), NODE, SimDriveParams(max_velocity=1.0, max_acceleration=10.0))
    m = Master(can_channel)
    sim.start()
    try:
        m.sdo_write(0x6081, 0, 10000, "<I")                   # 1 unit/s
        m.sdo_write(0x6060, 0, 1, "<b")
        for cw in (0x06, 0x07, 0x0F):
            m.controlword(cw)
        m.sdo_write(0x607A, 0, 1000000, "<i")                 # far away: moves for 100 s
        m.controlword(0x1F)
        m.controlword(0x0F)
        wait_for(lambda: sim.position > 0.05, 10.0, "moving")
        with sim.lock:
            before = sim.position
            time.sleep(1.5)
        wait_for(lambda: sim.host_stalls >= 1, 10.0, "the stall noticed")
        # without the stall left out it would stand 1.5 units further at once
        assert sim.position - before < 1.0
    finally:
        m.close()
        sim.stop()
