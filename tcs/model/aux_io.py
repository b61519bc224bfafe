"""SENSOR[] and SWITCH[] (spec §13): PLC points as OpenTCI modules.

A :class:`Sensor` serves one readable point of the register map: ``VALUE`` is its engineering
value (scaled by the map) as a FLOAT — the spec's table says INT, the project reads it as
FLOAT so that 12.3 °C is not truncated (``docs/opentci-notes.md``); a bit reads 1.0 / 0.0.
A :class:`Switch` serves a writable coil or integer register: ``SET VALUE`` writes it and
completes as soon as the PLC acknowledged the write (a few ms: "returns immediately");
``GET VALUE`` reads the feedback point when the hardware file names one (the contactor's
auxiliary contact: what *is* on), else the point itself. Values are read from the driver's
latest poll snapshot, so a GET never waits for the PLC.

While the PLC is unreachable a GET of ``VALUE`` answers ``FAILED 4`` (or 3) and the module's
``ERROR_STATE`` has the ERROR bit (:mod:`tcs.model.plc_link`). ``NAME``, ``DESCRIPTION`` and
``UNIT`` come from the hardware file, defaulting to the point's own name, description, unit.
"""

from __future__ import annotations

from tcs.config.modules import SensorSection, SwitchSection, split_ref
from tcs.drivers.modbus import PlcDriver
from tcs.errors import RangeRefused
from tcs.model.plc_link import PlcModule

_INT_RANGE = {"int16": (-2**15, 2**15 - 1), "uint16": (0, 2**16 - 1),
              "int32": (-2**31, 2**31 - 1), "uint32": (0, 2**32 - 1)}


class _PointModule(PlcModule):
    def __init__(self, module_name: str, driver: PlcDriver, point: str, section, events=None):
        super().__init__(module_name, events, hw_type=section.hw_type)
        self.driver = driver
        self.point = point
        spec = driver.points[point.split(".", 1)[0]]
        self.name = section.name or point
        self.description = section.description or spec.description
        self.unit = section.unit or spec.unit

    def start(self) -> None:
        self.watch(self.driver)

    def close(self) -> None:
        self.unwatch()


class Sensor(_PointModule):
    """``SENSOR[n]``: one readable PLC point."""

    def __init__(self, index: int, section: SensorSection, drivers: dict[str, PlcDriver], events=None):
        plc, point = split_ref(section.point)
        super().__init__(f"SENSOR[{index}]", drivers[plc], point, section, events)

    @property
    def value(self) -> float:
        """The latest value; ``CommunicationError`` (4/3) while the PLC is lost."""
        return float(self.driver.value(self.point))


class Switch(_PointModule):
    """``SWITCH[n]``: a writable coil or integer register, read back from its feedback."""

    def __init__(self, index: int, section: SwitchSection, drivers: dict[str, PlcDriver], events=None):
        plc, point = split_ref(section.point)
        super().__init__(f"SWITCH[{index}]", drivers[plc], point, section, events)
        self.feedback_driver, self.feedback = self.driver, point
        if section.feedback:
            fplc, fpoint = split_ref(section.feedback)
            self.feedback_driver, self.feedback = drivers[fplc], fpoint
        spec = self.driver.points[point]
        lo, hi = (0, 1) if spec.type == "bool" else _INT_RANGE[spec.type]
        self.min = section.min if section.min is not None else max(lo, 0)
        self.max = section.max if section.max is not None else hi
        self._bit = spec.type == "bool"

    def start(self) -> None:
        self.watch(self.driver, self.feedback_driver)

    @property
    def value(self) -> int:
        """The switch state (feedback); ``CommunicationError`` (4/3) while the PLC is lost."""
        return int(self.feedback_driver.value(self.feedback))

    def set_value(self, value: int):
        """``SET VALUE``: validated at once; the returned awaitable ends when the PLC took it."""
        value = int(value)
        if not self.min <= value <= self.max:
            raise RangeRefused(f"{self.module_name}: {value} is outside {self.min}..{self.max}")
        link = self.link_error()
        if link is not None:
            raise link
        return self.driver.write(self.point, bool(value) if self._bit else value)
