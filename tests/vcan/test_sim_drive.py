"""The simulated CiA-402 drive, tested as a master sees it: real CANopen frames on a bus.

The master is plain canopen (``Network`` + ``RemoteNode`` with the drive's EDS) and raw
python-can frames — not the TCS driver. Physics runs on a fake clock the tests advance, so
motion takes no real time; waits are for frames and states, with generous deadlines.
"""

from __future__ import annotations

import struct
import threading
import time

import canopen
import pytest

from tcs.sim import DEFAULT_EDS, SimDrive, SimDriveParams, start_sim_drives
from tcs.sim.can_port import POLL_PERIOD, REST_POLL_PERIOD
from tcs.sim.cia402_drive import LIVELY_FOR
from cia402_rig import SLOWDOWN

NODE = 5
MASTER = 1
IPU = 10000.0


class FakeClock:
    """An injectable clock the test moves by hand."""

    def __init__(self, t: float = 1000.0):
        self.t = t

    def __call__(self) -> float:
        return self.t

    def advance(self, dt: float) -> None:
        self.t += dt


def wait_for(predicate, timeout: float = 5.0, what: str = "condition"):
    deadline = time.monotonic() + timeout * SLOWDOWN  # (cia402_rig: a slow host's factor)
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.002)
    raise AssertionError(f"timed out waiting for {what}")


class Master:
    """A raw canopen master: RemoteNode for SDO/PDO configuration and a frame recorder."""

    def __init__(self, channel: dict, node_id: int = NODE):
        self.network = canopen.Network()
        self.network.connect(**channel)
        self.node = self.network.add_node(node_id, str(DEFAULT_EDS))
        self.node.sdo.RESPONSE_TIMEOUT = 2.0 * SLOWDOWN
        self.node_id = node_id
        self.frames: list[tuple[int, bytes]] = []
        self.stamps: list[tuple[int, float]] = []
        self._lock = threading.Lock()
        for cob in (0x80 + node_id, 0x180 + node_id, 0x280 + node_id, 0x380 + node_id,
                    0x480 + node_id, 0x700 + node_id):
            self.network.subscribe(cob, self._record)

    def _record(self, cob: int, data: bytearray, timestamp: float) -> None:
        with self._lock:
            self.frames.append((cob, bytes(data)))
            self.stamps.append((cob, timestamp))

    def received(self, cob: int) -> list[bytes]:
        with self._lock:
            return [d for c, d in self.frames if c == cob]

    def clear(self) -> None:
        with self._lock:
            self.frames.clear()
            self.stamps.clear()

    def emcy_codes(self) -> list[int]:
        return [struct.unpack_from("<H", d)[0] for d in self.received(0x80 + self.node_id)]

    def wait_frames(self, cob: int, count: int = 1, timeout: float = 5.0) -> list[bytes]:
        return wait_for(lambda: (f := self.received(cob)) and len(f) >= count and f, timeout,
                        f"{count} frame(s) 0x{cob:03X}")

    def send(self, cob: int, data: bytes) -> None:
        self.network.send_message(cob, data)

    def sdo_write(self, index: int, sub: int, value: int, fmt: str) -> None:
        self.node.sdo.download(index, sub, struct.pack(fmt, value))

    def sdo_read(self, index: int, sub: int, fmt: str) -> int:
        return struct.unpack(fmt, self.node.sdo.upload(index, sub))[0]

    def abort_code(self, fn) -> int:
        with pytest.raises(canopen.SdoAbortedError) as info:
            fn()
        return info.value.code

    def statusword(self) -> int:
        return self.sdo_read(0x6041, 0, "<H")

    def controlword(self, value: int) -> None:
        self.sdo_write(0x6040, 0, value, "<H")

    def close(self) -> None:
        self.network.disconnect()


@pytest.fixture
def clock():
    return FakeClock()


@pytest.fixture
def rig(can_channel, clock):
    """``make(params) -> (sim, master)`` on one bus; everything stopped afterwards."""
    made = []

    def make(params: SimDriveParams | None = None, start: bool = True):
        sim = SimDrive(dict(can_channel), NODE, params or SimDriveParams(), clock=clock)
        made.append(sim)
        master = Master(can_channel)
        made.append(master)
        if start:
            sim.start()
        return sim, master

    yield make
    for thing in reversed(made):
        thing.stop() if isinstance(thing, SimDrive) else thing.close()


def enable(master: Master, mode: int) -> None:
    master.sdo_write(0x6060, 0, mode, "<b")
    for cw in (0x06, 0x07, 0x0F):
        master.controlword(cw)
    assert master.statusword() & 0x6F == 0x27
    assert master.sdo_read(0x6061, 0, "<b") == mode


# --------------------------------------------------------------------------- NMT, heartbeat, SDO
def test_boot_up_heartbeat_and_nmt_states(rig):
    sim, m = rig(SimDriveParams(boot_delay=0.05), start=False)
    sim.start()
    assert m.wait_frames(0x700 + NODE)[0] == b"\x00"        # boot-up
    m.sdo_write(0x1017, 0, 20, "<H")
    assert m.wait_frames(0x700 + NODE, 4)[-1] == b"\x7f"    # heartbeats in pre-operational
    for command, state in ((0x01, 0x05), (0x02, 0x04), (0x80, 0x7F)):
        m.send(0x000, bytes([command, NODE]))
        m.clear()
        assert m.wait_frames(0x700 + NODE, 2)[-1] == bytes([state])
    m.node.sdo.RESPONSE_TIMEOUT = 0.3
    m.send(0x000, bytes([0x02, 0]))                         # broadcast stop: no SDO in stopped
    wait_for(lambda: sim.nmt_state == 0x04)
    with pytest.raises(canopen.SdoCommunicationError):
        m.node.sdo.upload(0x1000, 0)
    m.send(0x000, bytes([0x82, NODE]))                      # reset communication
    wait_for(lambda: b"\x00" in m.received(0x700 + NODE)[-3:], what="boot-up after reset")
    m.node.sdo.RESPONSE_TIMEOUT = 2.0
    assert m.sdo_read(0x1017, 0, "<H") == 0                 # communication objects at defaults


def test_identity_and_strings_by_sdo(rig):
    sim, m = rig(SimDriveParams(identity=(0xABC, 0x00402001, 0x00010000, 4242)))
    assert m.node.sdo[0x1018][1].raw == 0x00000ABC
    assert m.node.sdo[0x1018][2].raw == 0x00402001
    assert m.node.sdo[0x1018][3].raw == 0x00010000
    assert m.node.sdo[0x1018][4].raw == 4242
    assert m.node.sdo[0x1000].raw == 0x00020192
    assert m.node.sdo[0x1008].raw == "TCS simulated servo drive"   # segmented upload
    assert m.node.sdo[0x608F][1].raw == 10000 and m.node.sdo[0x6091][2].raw == 1


def test_sdo_aborts(rig):
    sim, m = rig()
    assert m.abort_code(lambda: m.node.sdo.upload(0x1234, 0)) == 0x06020000
    assert m.abort_code(lambda: m.node.sdo.upload(0x1018, 9)) == 0x06090011
    assert m.abort_code(lambda: m.sdo_write(0x6041, 0, 1, "<H")) == 0x06010002
    assert m.abort_code(lambda: m.sdo_write(0x6040, 0, 1, "<I")) == 0x06070012    # too long
    assert m.abort_code(lambda: m.sdo_write(0x6060, 0, 2, "<b")) == 0x06090030    # mode 2
    assert m.abort_code(lambda: m.sdo_write(0x6098, 0, 7, "<b")) == 0x06090030    # method 7
    # A PDO mapping longer than 64 bits.
    m.sdo_write(0x1800, 1, 0x80000000 | (0x180 + NODE), "<I")
    m.sdo_write(0x1A00, 0, 0, "<B")
    for sub, obj in enumerate((0x60640020, 0x606C0020, 0x60F40020), start=1):
        m.sdo_write(0x1A00, sub, obj, "<I")
    assert m.abort_code(lambda: m.sdo_write(0x1A00, 0, 3, "<B")) == 0x06040042
    # Not mappable / wrong direction.
    m.sdo_write(0x1A00, 0, 0, "<B")
    assert m.abort_code(lambda: m.sdo_write(0x1A00, 1, 0x60650020, "<I")) == 0x06040041
    assert m.abort_code(lambda: m.sdo_write(0x1600, 1, 0x60410010, "<I")) in (0x06040041, 0x08000022)
    # PDO parameters cannot change in operational.
    m.send(0x000, bytes([0x01, NODE]))
    wait_for(lambda: sim.nmt_state == 0x05)
    assert m.abort_code(lambda: m.sdo_write(0x1801, 2, 5, "<B")) == 0x08000022
    # Refused SDO.
    sim.set_refuse_sdo(True)
    assert m.abort_code(lambda: m.node.sdo.upload(0x1000, 0)) == 0x08000020
    sim.set_refuse_sdo(False)
    assert m.sdo_read(0x1000, 0, "<I") == 0x00020192


def test_remap_tpdo_in_pre_operational_and_sync_transmission(rig, clock):
    sim, m = rig(SimDriveParams(position=1.5))
    tpdo = m.node.tpdo
    tpdo.read()
    tpdo[1].clear()
    tpdo[1].add_variable(0x6041)
    tpdo[1].add_variable(0x606C)
    tpdo[1].trans_type = 2               # every 2nd SYNC
    tpdo[1].enabled = True
    tpdo[1].save()
    m.node.tpdo.read()
    assert [v.index for v in m.node.tpdo[1].map] == [0x6041, 0x606C]
    m.send(0x000, bytes([0x01, NODE]))
    wait_for(lambda: sim.nmt_state == 0x05)
    for _ in range(4):
        m.send(0x080, b"")
        wait_for(lambda: sim.sync_count >= _ + 1)
    frames = m.wait_frames(0x180 + NODE, 2)
    assert len(m.received(0x180 + NODE)) == 2
    status, velocity = struct.unpack("<Hi", frames[0])
    assert status & 0x4F == 0x40 and velocity == 0
    pos = struct.unpack("<ii", m.wait_frames(0x280 + NODE, 4)[0])[0]   # TPDO2 untouched: every SYNC
    assert pos == 0                                                    # velocity 0x606C
    # TPDO3 (event) came when the node went operational: digital inputs + error code.
    inputs, error = struct.unpack("<IH", m.wait_frames(0x380 + NODE)[0])
    assert (inputs, error) == (0, 0)


# --------------------------------------------------------------------------- state machine
def test_state_machine_walk_quick_stop_and_fault_reset(rig):
    sim, m = rig()
    assert m.statusword() & 0x4F == 0x40                         # switch on disabled
    m.controlword(0x06)
    assert m.statusword() & 0x6F == 0x21                         # 2: ready to switch on
    m.controlword(0x07)
    assert m.statusword() & 0x6F == 0x23                         # 3: switched on
    m.controlword(0x0F)
    assert m.statusword() & 0x6F == 0x27                         # 4: operation enabled
    m.controlword(0x07)
    assert m.statusword() & 0x6F == 0x23                         # 5
    m.controlword(0x0F)
    m.controlword(0x02)                                          # 11, then 12 (option 2)
    assert m.statusword() & 0x4F == 0x40
    m.sdo_write(0x605A, 0, 6, "<h")                              # stay in quick stop active
    for cw in (0x06, 0x0F, 0x02):
        m.controlword(cw)
    assert m.statusword() & 0x6F == 0x07
    m.controlword(0x0F)
    assert m.statusword() & 0x6F == 0x27                         # 16
    sim.inject_fault("overcurrent")
    assert m.statusword() & 0x4F == 0x08                         # 13, 14
    m.controlword(0x00)
    assert m.statusword() & 0x4F == 0x08                         # no edge, still fault
    m.controlword(0x80)
    assert m.statusword() & 0x4F == 0x40                         # 15, never further
    m.controlword(0x8F)
    assert m.statusword() & 0x4F == 0x40                         # bit 7 held: enabling refused
    assert sim.logic.transitions == [2, 3, 4, 5, 4, 11, 12, 2, 4, 11, 16, 13, 14, 15]


def test_mode_display_follows_allowed_switches(rig):
    sim, m = rig()
    for mode in (1, 3, 6, 8):
        m.sdo_write(0x6060, 0, mode, "<b")
        assert m.sdo_read(0x6061, 0, "<b") == mode


# --------------------------------------------------------------------------- CSP over PDOs
def csp_cycle(m: Master, clock: FakeClock, sim: SimDrive, cw: int, target: int, period: float):
    """One CSP cycle: RPDO1 (controlword, target), the period passes, SYNC; returns TPDO1."""
    before = len(m.received(0x180 + NODE))
    m.send(0x200 + NODE, struct.pack("<Hi", cw, target))
    clock.advance(period)
    m.send(0x080, b"")
    frames = m.wait_frames(0x180 + NODE, before + 1)
    return struct.unpack("<Hi", frames[before])


def start_csp(m: Master, sim: SimDrive) -> None:
    m.sdo_write(0x6060, 0, 8, "<b")
    m.send(0x000, bytes([0x01, NODE]))
    wait_for(lambda: sim.nmt_state == 0x05)


def test_csp_follows_a_ramp(rig, clock):
    sim, m = rig(SimDriveParams(position=2.0))
    start_csp(m, sim)
    period = 0.01
    pos = 20000
    for cw in (0x06, 0x07, 0x0F):
        status, actual = csp_cycle(m, clock, sim, cw, pos, period)
    assert status & 0x6F == 0x27 and status & 0x1000 and actual == 20000
    speed = 0.5 * IPU                                  # 0.5 unit/s ramp
    errors = []
    for k in range(1, 101):
        status, actual = csp_cycle(m, clock, sim, 0x0F, round(pos + speed * period * k), period)
        errors.append(round(pos + speed * period * (k - 1)) - actual)
    assert status & 0x6F == 0x27 and not status & 0x2000
    assert abs(errors[-1]) <= 2                        # steady state: the previous cycle's target
    assert max(abs(e) for e in errors) < 0.5 ** 2 / (2 * 5.0) * IPU + 60   # start transient only
    assert sim.rpdo_missed == 0 and sim.error_code == 0
    assert abs(sim.position - (2.0 + 0.5 * 0.99)) < 1e-3


def test_csp_following_error_faults(rig, clock):
    sim, m = rig()
    start_csp(m, sim)
    for cw in (0x06, 0x07, 0x0F):
        csp_cycle(m, clock, sim, cw, 0, 0.01)
    for _ in range(20):                                   # a 3-unit jump: far beyond 5 units/s²
        status, actual = csp_cycle(m, clock, sim, 0x0F, 30000, 0.01)
        if status & 0x08:
            break
    assert status & 0x4F in (0x08, 0x0F)
    assert m.wait_frames(0x80 + NODE)[0][:3] == bytes([0x11, 0x86, 0x01])    # EMCY 0x8611
    assert sim.error_code == 0x8611
    assert m.sdo_read(0x603F, 0, "<H") == 0x8611


def test_csp_missing_rpdos_fault_with_rpdo_timeout(rig, clock):
    sim, m = rig()
    start_csp(m, sim)
    for cw in (0x06, 0x07, 0x0F):
        csp_cycle(m, clock, sim, cw, 0, 0.01)
    for k in range(3):
        before = len(m.received(0x180 + NODE))
        clock.advance(0.01)
        m.send(0x080, b"")
        m.wait_frames(0x180 + NODE, before + 1)
    assert sim.rpdo_missed == 3
    assert m.wait_frames(0x80 + NODE)[0][:2] == bytes([0x50, 0x82])
    assert sim.state == "FAULT"


# --------------------------------------------------------------------------- profile position, limits
def test_profile_position_move_and_limit_switch(rig, clock):
    sim, m = rig(SimDriveParams(positive_limit_switch=3.0))
    enable(m, 1)
    m.sdo_write(0x607A, 0, 20000, "<i")
    m.controlword(0x1F)                                     # new set-point
    assert m.statusword() & 0x1000                          # acknowledged
    m.controlword(0x0F)
    assert not m.statusword() & 0x0400                      # moving
    clock.advance(60.0)
    assert m.statusword() & 0x0400                          # target reached
    assert m.sdo_read(0x6064, 0, "<i") == 20000
    # Now into the positive limit switch at 3.0.
    m.sdo_write(0x607A, 0, 50000, "<i")
    m.controlword(0x1F)
    m.controlword(0x0F)
    clock.advance(60.0)
    assert m.statusword() & 0x4F == 0x08
    wait_for(lambda: 0x8612 in m.emcy_codes(), what="EMCY 0x8612")
    assert m.sdo_read(0x60FD, 0, "<I") & 0x02                 # positive limit switch active
    assert sim.physical_position >= 3.0
    # Reset, re-enable: further out is refused (internal limit), back in is allowed.
    m.controlword(0x00)
    m.controlword(0x80)
    wait_for(lambda: 0x0000 in m.emcy_codes(), what="EMCY 0x0000")
    enable(m, 1)
    m.sdo_write(0x607A, 0, 60000, "<i")
    m.controlword(0x1F)
    m.controlword(0x0F)
    clock.advance(10.0)
    assert m.statusword() & 0x0800 and m.statusword() & 0x6F == 0x27
    m.sdo_write(0x607A, 0, 10000, "<i")
    m.controlword(0x1F)
    m.controlword(0x0F)
    clock.advance(60.0)
    assert m.sdo_read(0x6064, 0, "<i") == 10000
    assert m.sdo_read(0x60FD, 0, "<I") == 0


def test_software_limit_clamps_target(rig, clock):
    sim, m = rig()
    m.sdo_write(0x607D, 1, -10000, "<i")
    m.sdo_write(0x607D, 2, 15000, "<i")
    enable(m, 1)
    m.sdo_write(0x607A, 0, 40000, "<i")
    m.controlword(0x1F)
    m.controlword(0x0F)
    clock.advance(30.0)
    assert m.sdo_read(0x6064, 0, "<i") == 15000
    assert m.statusword() & 0x0800


# --------------------------------------------------------------------------- homing
HOMING_CASES = [
    # method, params, home point (physical units), expected direction of the last search
    (17, dict(position=0.3, negative_limit_switch=-2.0), -2.0),
    (18, dict(position=0.3, positive_limit_switch=2.5), 2.5),
    (1, dict(position=0.3, negative_limit_switch=-2.25, index_pulse_spacing=1.0), -2.0),
    (2, dict(position=0.3, positive_limit_switch=2.25, index_pulse_spacing=1.0), 2.0),
    (19, dict(position=0.3, home_switch=1.2), 1.2),
    (19, dict(position=1.7, home_switch=1.2), 1.2),             # starts on the switch
    (21, dict(position=0.3, home_switch=-1.2, home_switch_active_below=True), -1.2),
    (33, dict(position=0.3, index_pulse_spacing=0.25), 0.25),
    (34, dict(position=0.3, index_pulse_spacing=0.25), 0.5),
    (35, dict(position=0.3), 0.3),
    (37, dict(position=0.3), 0.3),
]


@pytest.mark.parametrize("method,params,home", HOMING_CASES)
def test_homing_methods(rig, clock, method, params, home):
    sim, m = rig(SimDriveParams(**params))
    m.sdo_write(0x6098, 0, method, "<b")
    m.sdo_write(0x6099, 1, 20000, "<I")                     # 2 units/s
    m.sdo_write(0x6099, 2, 2000, "<I")                      # 0.2 units/s
    m.sdo_write(0x609A, 0, 100000, "<I")                    # 10 units/s²
    m.sdo_write(0x607C, 0, 1234, "<i")
    enable(m, 6)
    assert m.statusword() & 0x3400 == 0x0400                # not started
    m.controlword(0x1F)
    if method not in (35, 37):
        assert m.statusword() & 0x3400 == 0x0000            # running: it takes time
        clock.advance(0.05)
        assert m.statusword() & 0x3400 == 0x0000
    clock.advance(100.0)
    assert m.statusword() & 0x3400 == 0x1400                # homing attained, target reached
    x = sim.physical_position
    assert m.sdo_read(0x6064, 0, "<i") == round((x - home) * IPU) + 1234
    m.controlword(0x0F)
    assert m.statusword() & 0x3400 == 0x1400


def test_homing_error_on_unexpected_limit_switch(rig, clock):
    # Method 19 expects a positive home switch; there is none, the axis meets the limit.
    sim, m = rig(SimDriveParams(position=0.0, positive_limit_switch=1.0))
    m.sdo_write(0x6098, 0, 19, "<b")
    m.sdo_write(0x6099, 1, 20000, "<I")
    enable(m, 6)
    m.controlword(0x1F)
    clock.advance(100.0)
    assert m.statusword() & 0x3400 == 0x2400                # error at rest
    assert m.statusword() & 0x6F == 0x27                    # drive still enabled (no fault)


# --------------------------------------------------------------------------- heartbeat consumer, faults
def test_heartbeat_consumer_fault(rig):
    sim, m = rig()
    m.sdo_write(0x1016, 1, (MASTER << 16) | 200, "<I")
    m.send(0x000, bytes([0x01, NODE]))
    enable(m, 1)
    time.sleep(0.3)                       # monitoring starts with the first heartbeat only
    assert sim.state == "OPERATION ENABLED" and m.emcy_codes() == []
    m.send(0x700 + MASTER, b"\x05")       # one heartbeat, then silence
    wait_for(lambda: 0x8130 in m.emcy_codes(), what="EMCY 0x8130")
    assert sim.state == "FAULT" and sim.nmt_state == 0x7F   # CiA-301: back to pre-operational
    assert m.sdo_read(0x1001, 0, "<B") & 0x11 == 0x11      # generic + communication


def test_a_resting_drive_slows_the_poll_and_a_command_brings_its_rate_back(rig):
    """The bus's poll slows while its drive rests (issue 27: the idle simulated telescope's
    wake-ups); an SDO request, an enable, a power stage on keep or bring the full rate."""
    sim, m = rig()
    m.send(0x000, bytes([0x01, NODE]))
    wait_for(lambda: sim.port.poll_period == REST_POLL_PERIOD, what="the resting poll")
    assert m.statusword() & 0x4F == 0x40                  # an SDO request: full rate again
    assert sim.port.poll_period == POLL_PERIOD
    wait_for(lambda: sim.port.poll_period == REST_POLL_PERIOD, what="the resting poll again")
    enable(m, 1)
    time.sleep(LIVELY_FOR + 0.5)                          # powered: never the resting rate
    assert sim.state == "OPERATION ENABLED" and sim.port.poll_period == POLL_PERIOD
    m.controlword(0x06)                                   # power stage off: rests again
    wait_for(lambda: sim.port.poll_period == REST_POLL_PERIOD, what="the resting poll after disable")


def test_a_resting_drive_still_notices_a_silent_master(rig):
    sim, m = rig()
    m.sdo_write(0x1016, 1, (MASTER << 16) | 300, "<I")
    m.send(0x000, bytes([0x01, NODE]))
    beating = threading.Event()
    beating.set()

    def beat():
        while beating.is_set():
            m.send(0x700 + MASTER, b"\x05")
            time.sleep(0.05)

    beater = threading.Thread(target=beat, daemon=True)
    beater.start()
    try:
        wait_for(lambda: sim.port.poll_period == REST_POLL_PERIOD, what="the resting poll")
        assert m.emcy_codes() == []
    finally:
        beating.clear()
        beater.join()
    wait_for(lambda: 0x8130 in m.emcy_codes(), what="EMCY 0x8130 at the resting rate")
    assert sim.state == "FAULT" and sim.nmt_state == 0x7F


@pytest.mark.parametrize("kind,code", [("overcurrent", 0x2310), ("following_error", 0x8611),
                                       ("encoder", 0x7305)])
def test_injected_fault_gives_emcy_and_reset_emcy(rig, kind, code):
    sim, m = rig()
    enable(m, 8)
    sim.inject_fault(kind)
    frame = m.wait_frames(0x80 + NODE)[0]
    assert struct.unpack_from("<HB", frame) == (code, m.sdo_read(0x1001, 0, "<B"))
    assert m.statusword() & 0x4F in (0x08, 0x0F)
    assert m.sdo_read(0x1003, 1, "<I") == code
    m.controlword(0x80)
    wait_for(lambda: 0x0000 in m.emcy_codes(), what="EMCY 0x0000")
    assert m.sdo_read(0x603F, 0, "<H") == 0


def test_dead_node_sends_and_answers_nothing(rig):
    sim, m = rig()
    m.sdo_write(0x1017, 0, 20, "<H")
    m.wait_frames(0x700 + NODE, 2)
    sim.set_responding(False)
    time.sleep(0.2)                       # frames already on their way arrive
    m.clear()
    m.node.sdo.RESPONSE_TIMEOUT = 0.2
    with pytest.raises(canopen.SdoCommunicationError):
        m.node.sdo.upload(0x1000, 0)
    sim.inject_fault("overcurrent")
    time.sleep(0.1)
    assert m.received(0x700 + NODE) == [] and m.received(0x80 + NODE) == []
    sim.set_responding(True)
    m.node.sdo.RESPONSE_TIMEOUT = 2.0
    assert m.sdo_read(0x603F, 0, "<H") == 0x2310
    m.wait_frames(0x700 + NODE, 1)


def test_several_drives_share_one_bus(can_channel, clock):
    sims = start_sim_drives(dict(can_channel), {2: SimDriveParams(), 3: SimDriveParams(position=1.0)},
                            clock=clock)
    master = Master(can_channel, node_id=3)
    try:
        assert master.sdo_read(0x6064, 0, "<i") == 10000
        assert sorted(sims) == [2, 3] and sims[2].position == 0.0
    finally:
        master.close()
        sims.stop()


def test_event_tpdo_timer_inhibit_and_change(rig):
    sim, m = rig()
    m.sdo_write(0x1802, 5, 50, "<H")                      # event timer 50 ms
    m.sdo_write(0x1802, 3, 300, "<H")                     # inhibit 30 ms
    m.send(0x000, bytes([0x01, NODE]))
    m.wait_frames(0x380 + NODE, 4)                        # the timer keeps them coming
    sim.inject_fault("encoder")
    wait_for(lambda: any(d[4:6] == b"\x05\x73" for d in m.received(0x380 + NODE)),
             what="TPDO3 with error code 0x7305")
    times = [t for c, t in m.stamps if c == 0x380 + NODE]
    assert min(b - a for a, b in zip(times, times[1:])) >= 0.03 - 0.002


def test_reset_node_restores_defaults_and_boots_again(rig):
    sim, m = rig()
    m.sdo_write(0x6081, 0, 1234, "<I")
    m.sdo_write(0x1017, 0, 20, "<H")
    enable(m, 1)
    m.clear()
    m.send(0x000, bytes([0x81, NODE]))
    wait_for(lambda: b"\x00" in m.received(0x700 + NODE), what="boot-up")
    assert m.sdo_read(0x6081, 0, "<I") != 1234
    assert m.statusword() & 0x4F == 0x40
    assert m.sdo_read(0x6061, 0, "<b") == 0
    count = len(m.received(0x700 + NODE))
    time.sleep(0.1)
    assert len(m.received(0x700 + NODE)) == count         # heartbeat off again (0x1017 = 0)


def test_drive_on_a_canopen_network(can_channel, clock):
    network = canopen.Network()
    network.connect(**can_channel)
    sim = SimDrive(network, NODE, SimDriveParams(position=-0.25), clock=clock)
    master = Master(can_channel)
    try:
        sim.start()
        assert master.sdo_read(0x6064, 0, "<i") == -2500
        enable(master, 1)
    finally:
        sim.stop()
        master.close()
        network.disconnect()
