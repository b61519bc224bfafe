"""Switch, ObservingConditions and SafetyMonitor devices over SWITCH[], SENSOR[] and the
weather interlock.

What maps to what
-----------------
* **Switch** (ISwitchV3): one device; switch ``Id`` n = ``SWITCH[n]``. ``GetSwitchValue`` is the
  feedback (what *is* on), ``SetSwitchValue``/``SetSwitch`` write the point and return once the
  PLC took the write; min/max from the hardware file (a coil 0…1, a register its range), step 1.
  Names and descriptions are the hardware file's (``SetSwitchName`` is not implemented). No
  asynchronous switches (``CanAsync`` False).
* **ObservingConditions**: the weather sensors among ``SENSOR[]``, recognised by their point's
  name: ``temp_outside``/``temperature`` → Temperature, ``pressure`` → Pressure, ``humidity``
  → Humidity, ``wind_speed`` → WindSpeed, ``wind_direction`` → WindDirection, ``dew_point`` →
  DewPoint, ``sky_quality``, ``sky_brightness``, ``sky_temperature``, ``cloud_cover``,
  ``rain_rate``, ``star_fwhm``, ``wind_gust``. Anything not configured is not implemented.
  ``AveragePeriod`` is 0 (instantaneous values; another period is InvalidValue).
* **SafetyMonitor**: ``IsSafe`` is True while the weather interlock lets the dome and covers
  open (no rain, wind below the limit, weather known, released) — the TCS's own decision.
"""

from __future__ import annotations

import asyncio

from tcs.alpaca.device import Device, need
from tcs.alpaca.protocol import AscomError, Code, not_implemented
from tcs.errors import TcsError

# ObservingConditions member → point names (the sensor's point, without the PLC) it is read from
CONDITIONS = {
    "temperature": ("temp_outside", "temperature", "air_temperature"),
    "pressure": ("pressure", "air_pressure"),
    "humidity": ("humidity", "relative_humidity"),
    "windspeed": ("wind_speed", "windspeed"),
    "winddirection": ("wind_direction", "winddirection"),
    "windgust": ("wind_gust",),
    "dewpoint": ("dew_point", "dewpoint"),
    "cloudcover": ("cloud_cover",),
    "rainrate": ("rain_rate",),
    "skybrightness": ("sky_brightness",),
    "skyquality": ("sky_quality",),
    "skytemperature": ("sky_temperature",),
    "starfwhm": ("star_fwhm",),
}
NAMES = {"temperature": "Temperature", "pressure": "Pressure", "humidity": "Humidity",
         "windspeed": "WindSpeed", "winddirection": "WindDirection", "windgust": "WindGust",
         "dewpoint": "DewPoint", "cloudcover": "CloudCover", "rainrate": "RainRate",
         "skybrightness": "SkyBrightness", "skyquality": "SkyQuality",
         "skytemperature": "SkyTemperature", "starfwhm": "StarFWHM"}


# ------------------------------------------------------------------------------------- Switch

class SwitchDevice(Device):
    TYPE = "switch"
    NAME = "Switch"
    INTERFACE_VERSION = 3
    MEMBERS = ("maxswitch", "canwrite", "getswitch", "getswitchdescription", "getswitchname",
               "getswitchvalue", "minswitchvalue", "maxswitchvalue", "setswitch", "setswitchname",
               "setswitchvalue", "switchstep", "canasync", "setasync", "setasyncvalue",
               "statechangecomplete", "cancelasync")
    RULES = {
        "setswitch": "synchronous: returns once the feedback reads it (GetSwitch reads the new state right after)",
        "setswitchvalue": "synchronous: as SetSwitch (GetSwitchValue reads the new value right after)",
        "setswitchname": "NotImplemented", "setasync": "NotImplemented", "setasyncvalue": "NotImplemented",
        "cancelasync": "NotImplemented",
    }
    PARAMETERS = {
        "get_canwrite": (("Id", "int"),),
        "get_canasync": (("Id", "int"),),
        "get_getswitch": (("Id", "int"),),
        "get_getswitchdescription": (("Id", "int"),),
        "get_getswitchname": (("Id", "int"),),
        "get_getswitchvalue": (("Id", "int"),),
        "get_minswitchvalue": (("Id", "int"),),
        "get_maxswitchvalue": (("Id", "int"),),
        "get_switchstep": (("Id", "int"),),
        "get_statechangecomplete": (("Id", "int"),),
        "put_setswitch": (("Id", "int"), ("State", "bool")),
        "put_setswitchvalue": (("Id", "int"), ("Value", "float")),
        "put_setswitchname": (("Id", "int"), ("Name", "text")),
        "put_setasync": (("Id", "int"), ("State", "bool")),
        "put_setasyncvalue": (("Id", "int"), ("Value", "float")),
        "put_cancelasync": (("Id", "int"),),
    }

    def __init__(self, number, name, description, telescope, switches, **kw):
        super().__init__(number, name, description, telescope, **kw)
        self.switches = switches

    def _switch(self, r):
        n = r.int("Id")
        need(0 <= n < len(self.switches), Code.INVALID_VALUE, f"Id {n} is outside 0…{len(self.switches) - 1}")
        return self.switches[n]

    def get_maxswitch(self, r) -> int:
        return len(self.switches)

    def get_canwrite(self, r) -> bool:
        self._switch(r)
        return True

    def get_canasync(self, r) -> bool:
        self._switch(r)
        return False

    def get_getswitchname(self, r) -> str:
        return str(self._switch(r).name)

    def get_getswitchdescription(self, r) -> str:
        return str(self._switch(r).description or self._switch(r).name)

    def get_minswitchvalue(self, r) -> float:
        return float(self._switch(r).min)

    def get_maxswitchvalue(self, r) -> float:
        return float(self._switch(r).max)

    def get_switchstep(self, r) -> float:
        self._switch(r)
        return 1.0

    def get_getswitchvalue(self, r) -> float:
        return float(self._switch(r).value)

    def get_getswitch(self, r) -> bool:
        s = self._switch(r)
        return s.value > s.min

    async def put_setswitch(self, r) -> None:
        s = self._switch(r)
        state = r.bool("State")
        await self._set(s, s.max if state else s.min)

    async def put_setswitchvalue(self, r) -> None:
        s = self._switch(r)
        value = r.float("Value")
        need(s.min <= value <= s.max, Code.INVALID_VALUE, f"Value {value} is outside {s.min}…{s.max}")
        need(value == int(value), Code.INVALID_VALUE, f"Value {value} is not a whole step")
        await self._set(s, int(value))

    @staticmethod
    async def _set(s, value: int, timeout: float = 10.0) -> None:
        """Synchronous (ISwitchV3): write, then reply once the feedback reads the new value, so
        that GetSwitch/GetSwitchValue right after the reply read it."""
        await s.set_value(value)
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        while s.value != value:
            if loop.time() > deadline:
                raise AscomError(Code.DRIVER_ERROR, f"{s.module_name}: the feedback reads {s.value}, "
                                                    f"not {value}, {timeout:g} s after the write")
            await asyncio.sleep(0.02)

    def put_setswitchname(self, r) -> None:
        self._switch(r)
        r.text("Name")
        raise not_implemented("SetSwitchName (names are the hardware file's)")

    def get_statechangecomplete(self, r) -> bool:
        self._switch(r)
        raise AscomError(Code.OPERATION_CANCELLED, "no asynchronous switch operation (CanAsync is False)")

    def put_setasync(self, r) -> None:
        self._switch(r)
        r.bool("State")
        raise not_implemented("SetAsync (CanAsync is False)")

    def put_setasyncvalue(self, r) -> None:
        self._switch(r)
        r.float("Value")
        raise not_implemented("SetAsyncValue (CanAsync is False)")

    def put_cancelasync(self, r) -> None:
        self._switch(r)
        raise not_implemented("CancelAsync (CanAsync is False)")

    async def get_devicestate(self, r):
        out = []
        for i, s in enumerate(self.switches):
            try:
                out.append({"Name": f"GetSwitch{i}", "Value": s.value > s.min})
                out.append({"Name": f"GetSwitchValue{i}", "Value": float(s.value)})
            except TcsError:
                continue
        return out + await super().get_devicestate(r)

    def setup_rows(self):
        rows = []
        for i, s in enumerate(self.switches):
            try:
                value = str(s.value)
            except TcsError as exc:
                value = f"({exc.message})"
            rows.append((f"{i}: {s.name}", value))
        return rows


# ------------------------------------------------------------------------ ObservingConditions

class ObservingConditionsDevice(Device):
    TYPE = "observingconditions"
    NAME = "ObservingConditions"
    INTERFACE_VERSION = 2
    MEMBERS = ("averageperiod", "refresh", "sensordescription", "timesincelastupdate", *CONDITIONS)
    RULES = {
        "averageperiod": "synchronous (only 0)",
        "refresh": "synchronous: nothing to do (the PLCs are polled continuously)",
    }
    PARAMETERS = {
        "put_averageperiod": (("AveragePeriod", "float"),),
        "get_sensordescription": (("SensorName", "text"),),
        "get_timesincelastupdate": (("SensorName", "text"),),
    }

    def __init__(self, number, name, description, telescope, sensors: dict, **kw):
        super().__init__(number, name, description, telescope, **kw)
        self.sensors = sensors   # member -> Sensor
        self.STATE = tuple(m for m in CONDITIONS if m in sensors)
        self.STATE_NAMES = NAMES
        for member in CONDITIONS:
            if member in sensors:
                setattr(self, f"get_{member}", self._reader(member))

    def _reader(self, member: str):
        def get(r) -> float:
            return float(self.sensors[member].value)
        return get

    def get_averageperiod(self, r) -> float:
        return 0.0

    def put_averageperiod(self, r) -> None:
        period = r.float("AveragePeriod")
        need(period == 0.0, Code.INVALID_VALUE, f"AveragePeriod {period}: only 0 (instantaneous) is supported")

    def put_refresh(self, r) -> None:
        pass   # the PLCs are polled continuously

    def _named(self, r):
        name = r.text("SensorName").strip().lower()
        if name not in CONDITIONS:
            raise AscomError(Code.INVALID_VALUE, f"{r.text('SensorName')!r} is not a sensor name")
        sensor = self.sensors.get(name)
        if sensor is None:
            raise not_implemented(f"sensor {NAMES[name]}")
        return sensor

    def get_sensordescription(self, r) -> str:
        sensor = self._named(r)
        return str(sensor.description or sensor.name)

    def get_timesincelastupdate(self, r) -> float:
        if not r.text("SensorName").strip():
            sensors = list(self.sensors.values())
        else:
            sensors = [self._named(r)]
        now = asyncio.get_running_loop().time()
        return max((now - s.driver.snapshot.time for s in sensors), default=0.0)


# ------------------------------------------------------------------------------ SafetyMonitor

class SafetyMonitorDevice(Device):
    TYPE = "safetymonitor"
    NAME = "SafetyMonitor"
    INTERFACE_VERSION = 3
    MEMBERS = ("issafe",)
    STATE = ("issafe",)
    STATE_NAMES = {"issafe": "IsSafe"}
    ALWAYS = frozenset({"issafe"})   # ISafetyMonitor: IsSafe reads False while not connected

    def __init__(self, number, name, description, telescope, interlock, **kw):
        super().__init__(number, name, description, telescope, **kw)
        self.interlock = interlock

    def get_issafe(self, r) -> bool:
        if not self.connected:
            return False   # ISafetyMonitor: False while not connected
        self.interlock.evaluate()
        return not self.interlock.active


def site_devices(telescope, commands, seed: str) -> list[Device]:
    kw = dict(commands=commands, unique_seed=seed)
    out: list[Device] = []
    per = telescope.peripherals
    if per.switches:
        out.append(SwitchDevice(0, "SWITCH", "the switches SWITCH[] of the PLCs", telescope,
                                list(per.switches), **kw))
    sensors = {}
    for sensor in per.sensors:
        point = sensor.point.split(".", 1)[0].lower()
        for member, names in CONDITIONS.items():
            if point in names and member not in sensors:
                sensors[member] = sensor
    if sensors:
        out.append(ObservingConditionsDevice(0, "WEATHER", "the weather sensors among SENSOR[]", telescope,
                                             sensors, **kw))
    if per.interlock is not None:
        out.append(SafetyMonitorDevice(0, "WEATHER INTERLOCK", "the weather interlock of dome and covers",
                                       telescope, per.interlock, **kw))
    return out
