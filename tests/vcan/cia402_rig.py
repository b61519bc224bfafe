"""A test rig: simulated CiA-402 drives and the TCS's CAN driver on one bus.

The simulated drives (``tcs.sim``) share one python-can bus of their own; the TCS opens its
own bus on the same channel (``can_channel`` fixture: ``virtual`` by default, kernel ``vcan0``
with ``TCS_CAN_INTERFACE=socketcan``) — two parties on one cable, real CANopen frames between
them. ``Rig.wait`` polls a condition with a generous deadline: tests wait for states, never
for durations.

``TCS_TEST_SLOWDOWN`` (a whole number, default 1) stretches every protocol time of the rig —
SYNC period, heartbeats and their consumer times, SDO and boot time-outs, following-error,
homing, enable, fault-reset and mode-switch time-outs — and every wait, for a host several
times slower than real hardware: the QEMU guest of ``tools/ci/vm`` under software emulation
runs with 5. The exchanges and states the tests check stay the same; only the clock runs
slower.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import can

from tcs.config.can import CanSection, DriveSection, HomingSection, IdentitySection
from tcs.drivers.can_system import CanDrives
from tcs.drivers.drive import DriveState, DriveStatus
from tcs.sim.cia402_drive import SimDrive, SimDriveParams

SIM_IDENTITY = (0xABC, 0x00402001, 0x00010000, 1)
SCALE = 10000.0   # increments per unit, sims and drives alike
SLOWDOWN = int(os.environ.get("TCS_TEST_SLOWDOWN", "1"))  # see the module docstring
#: s per SDO answer: the service's default ([can] sdo_timeout), one retry — 0.3 s (twice) ran out
#: once in CI while a drive was remapped in a loaded suite run ("No SDO response received")
SDO_TIMEOUT = 0.5


def drive_section(node_id: int, **overrides) -> DriveSection:
    """A drive table matching the simulated drive's defaults; ``overrides`` replace fields."""
    base = DriveSection(
        node_id=node_id,
        identity=IdentitySection(vendor=SIM_IDENTITY[0], product=SIM_IDENTITY[1],
                                 revision=SIM_IDENTITY[2]),
        increments_per_unit=SCALE, min_position=-100.0, max_position=100.0,
        following_error_window=0.5, following_error_timeout=0.05 * SLOWDOWN,
        max_velocity=4.0, max_acceleration=4.0, heartbeat_period=0.2 * SLOWDOWN,
        heartbeat_consumer_timeout=1.0 * SLOWDOWN,
        master_loss_timeout=0.5 * SLOWDOWN,  # (generous: shared machine)
        # the driver's state-machine time-outs too (an enable takes several cycles: under
        # emulation 2 s ran out before Operation enabled, issue 23)
        enable_timeout=2.0 * SLOWDOWN, fault_reset_timeout=1.0 * SLOWDOWN,
        mode_switch_timeout=1.0 * SLOWDOWN,
        homing=HomingSection(method=37, speed_switch=2.0, speed_zero=0.5, acceleration=20.0,
                             timeout=20.0 * SLOWDOWN))
    return replace(base, **overrides)


@dataclass
class AxisSpec:
    node_id: int
    params: SimDriveParams = field(default_factory=SimDriveParams)
    section: dict = field(default_factory=dict)
    sim: bool = True  # False: nothing answers at this node id
    sim_eds: object = None  # another EDS for the simulated drive


class Rig:
    """Sims + TCS ``CanDrives`` on one bus; use as a context manager (stops everything)."""

    def __init__(self, can_channel: dict, axes: dict[str, AxisSpec], *, sync_period: float = 0.01,
                 heartbeat_period: float = 0.05, boot_timeout: float = 3.0,
                 kernel_sync: bool | None = None, options: dict | None = None,
                 realtime_priority: int = 0, idle_sync_period: float = 0.0):
        self.channel = dict(can_channel)
        self.axes = axes
        self.can = CanSection(interface=self.channel["interface"], channel=self.channel["channel"],
                              sync_period=sync_period * SLOWDOWN,
                              heartbeat_period=heartbeat_period * SLOWDOWN,
                              boot_timeout=boot_timeout * SLOWDOWN, sdo_timeout=SDO_TIMEOUT * SLOWDOWN,
                              options=options or {},
                              realtime_priority=realtime_priority,
                              idle_sync_period=idle_sync_period * SLOWDOWN)
        self.kernel_sync = kernel_sync
        self.sections = {name: drive_section(spec.node_id, **spec.section)
                         for name, spec in axes.items()}
        self.sim_bus: can.BusABC | None = None
        self.sims: dict[str, SimDrive] = {}
        self.system: CanDrives | None = None
        self.cycle_hooks: list[Callable] = []

    # ---------------------------------------------------------------- life cycle
    def __enter__(self) -> Rig:
        try:
            self.sim_bus = can.Bus(**self.channel)
            for name, spec in self.axes.items():
                if spec.sim:
                    extra = {"eds": spec.sim_eds} if spec.sim_eds else {}
                    sim = SimDrive(self.sim_bus, spec.node_id, spec.params, **extra)
                    self.sims[name] = sim
                    sim.start()
            self.system = CanDrives(self.can, self.sections)
            if self.kernel_sync is not None:
                self.system.cycle.kernel_sync = self.kernel_sync
            self.system.open()
            self.system.cycle.add_callback(self._on_cycle)
        except BaseException:
            self.__exit__()
            raise
        return self

    def __exit__(self, *exc) -> None:
        if self.system is not None:
            self.system.close()
        for sim in self.sims.values():
            sim.stop()
        if self.sim_bus is not None:
            self.sim_bus.shutdown()

    def _on_cycle(self, cycle) -> None:
        for hook in list(self.cycle_hooks):
            hook(cycle)
        self.system.step_all(cycle)

    def boot_and_start(self, names=None) -> dict:
        failures = self.system.boot(names)
        self.system.start()
        return failures

    # ---------------------------------------------------------------- helpers
    def drive(self, name: str):
        return self.system.drives[name]

    def status(self, name: str) -> DriveStatus:
        return self.system.drives[name].status()

    def wait(self, predicate: Callable[[], bool], timeout: float = 10.0, what: str = "") -> None:
        """Poll ``predicate`` until true; fail with ``what`` and the drives' states otherwise."""
        deadline = time.monotonic() + timeout * SLOWDOWN
        while time.monotonic() < deadline:
            if predicate():
                return
            time.sleep(0.01)
        if predicate():
            return
        states = {n: (d.status().state.value, d.status().fault, d.status().request_error)
                  for n, d in self.system.drives.items()}
        raise AssertionError(f"timed out waiting for {what or predicate}: {states}")

    def wait_state(self, name: str, state: DriveState, timeout: float = 10.0) -> DriveStatus:
        self.wait(lambda: self.status(name).state is state, timeout, f"{name} {state.value}")
        return self.status(name)

    def enable(self, *names: str) -> None:
        for name in names:
            self.drive(name).enable()
        for name in names:
            self.wait_state(name, DriveState.OPERATION_ENABLED)


def sine(amplitude: float, period: float, t0: float) -> Callable[[float], float]:
    """Position of a sine profile starting at 0 with zero offset."""
    return lambda t: amplitude * math.sin(2 * math.pi * (t - t0) / period)
