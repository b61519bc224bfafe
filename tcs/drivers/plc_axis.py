"""A PLC-driven axis (dome rotation, slit, flap, seal, roof, shell, mirror cover) on a PlcDriver.

The register convention (``tcs/config/plc.py``, ``hwconfig/plc-sim-map.toml``): axis ``X`` is
the points ``X_target`` (holding, float), ``X_command`` (holding, integer: 0 idle, 1 move to
target, 2 stop, 3 reset fault; the PLC sets it back to 0 once accepted), ``X_position``,
``X_status`` (bits ``moving``, ``at_target``, ``closed``, ``open``, ``fault``, ``stalled``) and
optionally ``X_speed``. The PLC runs the motion; this class only writes commands and reads
state out of the driver's snapshots. It knows nothing of OpenTCI: the DOME[]/COVER[] modules
wrap it (a move is ``after = await axis.move(t)`` then ``await axis.wait_settled(after)``).
"""

from __future__ import annotations

from dataclasses import dataclass

from tcs.config.plc import AXIS_MOVE, AXIS_RESET, AXIS_STOP
from tcs.drivers.modbus import PlcDriver, PlcSnapshot
from tcs.errors import ConfigError, ErrorNumber, HardwareError


@dataclass(frozen=True)
class AxisState:
    """One axis as seen in one poll snapshot."""

    position: float
    target: float
    speed: float | None
    moving: bool
    at_target: bool
    closed: bool
    open: bool
    fault: bool
    stalled: bool
    cycle: int
    time: float


class PlcAxis:
    """Axis ``name`` of a PLC.

    Raises
    ------
    ConfigError
        The PLC's register map does not follow the axis convention for ``name``.
    """

    def __init__(self, driver: PlcDriver, name: str):
        problems = driver.section.axis_problems(name)
        if problems:
            key, problem = problems[0]
            raise ConfigError("hardware file", f"plcs.{driver.name}.{key}", problem)
        self.driver = driver
        self.name = name
        self.device = f"{driver.name}.{name}"
        self._pt = {s: f"{name}_{s}" for s in ("target", "command", "position", "status", "speed")}
        self._has_speed = self._pt["speed"] in driver.points

    @property
    def unit(self) -> str:
        return self.driver.points[self._pt["position"]].unit

    def state(self, snapshot: PlcSnapshot | None = None) -> AxisState:
        """The axis in ``snapshot`` (default: the latest; ``CommunicationError`` while lost)."""
        if snapshot is None:
            self.driver.value(self._pt["position"])  # raises while the PLC is lost
            snapshot = self.driver.snapshot
        st = self._pt["status"]
        v = snapshot.values
        return AxisState(
            position=float(v[self._pt["position"]]), target=float(v[self._pt["target"]]),
            speed=float(v[self._pt["speed"]]) if self._has_speed else None,
            moving=v[f"{st}.moving"], at_target=v[f"{st}.at_target"],
            closed=v.get(f"{st}.closed", False), open=v.get(f"{st}.open", False),
            fault=v[f"{st}.fault"], stalled=v.get(f"{st}.stalled", False),
            cycle=snapshot.cycle, time=snapshot.time)

    async def move(self, target: float) -> int:
        """Command a move to ``target`` (target and command in one request when adjacent).

        Returns the poll cycle after which snapshots show the PLC's reaction; errors as
        :meth:`PlcDriver.write_many` (a target the PLC refuses gives ``ModbusExceptionResponse``).
        """
        return await self.driver.write_many({self._pt["target"]: target, self._pt["command"]: AXIS_MOVE})

    async def stop(self) -> int:
        """Command a stop (the PLC decelerates); returns the poll cycle as :meth:`move`."""
        return await self.driver.write(self._pt["command"], AXIS_STOP)

    async def reset(self) -> int:
        """Clear a fault (stall); returns the poll cycle as :meth:`move`."""
        return await self.driver.write(self._pt["command"], AXIS_RESET)

    async def wait_settled(self, after: int, timeout: float | None = None) -> AxisState:
        """Wait for the first snapshot newer than ``after`` in which the axis does not move.

        Returns the state (``at_target`` tells whether it arrived, e.g. False after a stop).

        Raises
        ------
        HardwareError
            Number 7 (timeout) when the motor stalled or ``timeout`` passed; number 2 (libfail)
            for another PLC fault.
        CommunicationError
            The PLC was lost while waiting (4 nocon / 3 confail).
        """
        st = self._pt["status"]
        snap = await self.driver.wait_for(
            lambda s: not s[f"{st}.moving"] or s[f"{st}.fault"], after=after, timeout=timeout)
        state = self.state(snap)
        if state.stalled:
            raise HardwareError(self.device, f"motor stalled at {state.position:g}", ErrorNumber.TIMEOUT)
        if state.fault:
            raise HardwareError(self.device, f"PLC reports a fault at {state.position:g}", ErrorNumber.LIBFAIL)
        return state
