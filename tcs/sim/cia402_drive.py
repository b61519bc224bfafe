"""A simulated CiA-402 servo drive: a CANopen node a master cannot tell from a real drive.

(Skeleton: the constructor and the fault-injection API are fixed; the behaviour is being
filled in.)
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

DEFAULT_EDS = Path(__file__).resolve().parents[2] / "hwconfig" / "eds" / "tcs-sim-drive.eds"


@dataclass
class SimDriveParams:
    """Everything physical about one simulated axis, in user units (degrees or mm)."""

    increments_per_unit: float = 10000.0
    max_velocity: float = 5.0
    max_acceleration: float = 5.0
    position: float = 0.0
    negative_limit_switch: float | None = None
    positive_limit_switch: float | None = None
    home_switch: float | None = None
    home_switch_active_below: bool = False
    index_pulse_spacing: float = 1.0
    identity: tuple[int, int, int, int] = (0xABC, 0x00402001, 0x00010000, 1)
    boot_delay: float = 0.0


class SimDrive:
    """One simulated CiA-402 drive on a CAN bus."""

    def __init__(self, bus_or_network: Any, node_id: int, params: SimDriveParams | None = None,
                 clock: Callable[[], float] = time.monotonic, eds: str | Path = DEFAULT_EDS):
        raise NotImplementedError

    def start(self) -> None:
        raise NotImplementedError

    def stop(self) -> None:
        raise NotImplementedError

    def inject_fault(self, kind: str) -> None:
        raise NotImplementedError

    def set_responding(self, responding: bool) -> None:
        raise NotImplementedError

    def set_refuse_sdo(self, refuse: bool) -> None:
        raise NotImplementedError
