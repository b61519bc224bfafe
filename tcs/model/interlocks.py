"""The weather interlock of the dome's opening parts and the mirror covers (``[interlocks]``).

How it works
------------
:class:`WeatherInterlock` reads the rain and wind points named in the hardware file on every
poll of their PLC. The interlock is **active** while it rains, while the wind is above
``wind_limit``, or while the PLC of those sensors cannot be read (the weather is unknown:
fail safe), and for ``release_after`` seconds after the last of these.

While active:

* an *opening* move of a guarded module (a target above its closed position and above where
  it stands) is refused before anything moves: ``DATA ERROR <module>.TARGETPOS FAILED 1020``
  and ``EVENT ERROR <module>:1020 opening refused: <reason>``. Closing is always allowed.
* every guarded module carries the condition ``weather interlock`` (WARNING bit) in its
  ``ERROR_STATE`` and ``CABINET.STATUS.LIST``; ``EVENT WARN <module>:1020`` marks the start,
  ``EVENT INFO <module>:1020`` the release.

When rain starts and ``close_on_rain`` is set (wind above the limit and ``close_on_wind``), the
guarded modules close by themselves — whatever their POWER (the PLC's motors are the PLC's) —
with ``EVENT WARN <module>:1021 closing: <reason>``; their pending SETs fail with 1021. Each
module closed so carries the condition ``weather close`` (WARNING, the reason as its text), so
the close is in ``CABINET.STATUS.LIST``; it ends with the interlock's release.
Unknown weather (sensor PLC lost) refuses opening but closes nothing: the TCS may not even
reach the dome then, and a PLC usually closes on its own rain input.

Guarded: the opening parts of the dome (slit, flap, roof, fold, shells) and the covers, unless
the hardware file says ``interlock = false`` for one (or ``true`` for the rotation or seal).

Project numbers (Appendix B: user numbers from 1000): :data:`WEATHER_INTERLOCK` 1020,
:data:`WEATHER_CLOSE` 1021. Everything runs on the event loop.
"""

from __future__ import annotations

import logging
import time
from typing import Callable

from tcs.config.modules import InterlockSection, split_ref
from tcs.drivers.modbus import PlcDriver
from tcs.errors import TcsError
from tcs.model.events import ERROR, INFO, WARN
from tcs.model.health import WARNING

log = logging.getLogger(__name__)

WEATHER_INTERLOCK = 1020
WEATHER_CLOSE = 1021
CONDITION = "weather interlock"
CLOSE_CONDITION = "weather close"


class WeatherInterlock:
    """Refuses opening and closes on bad weather (see the module docstring).

    Parameters
    ----------
    section:
        The ``[interlocks]`` section.
    drivers:
        PLC drivers by name (those of the rain and wind points must be among them).
    guarded:
        The :class:`~tcs.model.plc_axis_module.PlcAxisModule` objects it protects.
    clock:
        Monotonic seconds (for ``release_after``).
    """

    def __init__(self, section: InterlockSection, drivers: dict[str, PlcDriver], guarded: list,
                 clock: Callable[[], float] = time.monotonic):
        self.section = section
        self.guarded = list(guarded)
        self.clock = clock
        self._rain = self._point(section.rain, drivers)
        self._wind = self._point(section.wind, drivers) if section.wind_limit > 0 else None
        self.active = False
        self.reason = ""
        self._last_bad: float | None = None
        self._closed_for: set[str] = set()
        self._removers: list = []
        for module in self.guarded:
            module.interlock = self

    @staticmethod
    def _point(ref: str, drivers: dict[str, PlcDriver]):
        if not ref:
            return None
        plc, name = split_ref(ref)
        return drivers[plc], name

    def start(self) -> None:
        for driver in {id(p[0]): p[0] for p in (self._rain, self._wind) if p is not None}.values():
            self._removers.append(driver.add_poll_listener(lambda _snap: self.evaluate()))
            self._removers.append(driver.add_connection_listener(lambda _ev: self.evaluate()))
        self.evaluate()

    def stop(self) -> None:
        for remove in self._removers:
            remove()
        self._removers.clear()

    # -- the weather ---------------------------------------------------------------------------
    def causes(self) -> dict[str, str]:
        """What is bad now: ``{"rain"|"wind"|"unknown": text}`` (empty: good weather)."""
        causes: dict[str, str] = {}
        for kind, point in (("rain", self._rain), ("wind", self._wind)):
            if point is None:
                continue
            driver, name = point
            if not driver.connected:
                causes["unknown"] = f"weather unknown: PLC {driver.name} unreachable"
                continue
            value = driver.snapshot.get(name)
            if kind == "rain" and value:
                causes["rain"] = "rain detected"
            elif kind == "wind" and value is not None and float(value) > self.section.wind_limit:
                causes["wind"] = f"wind {float(value):.1f} above {self.section.wind_limit:g}"
        return causes

    def evaluate(self) -> None:
        causes = self.causes()
        now = self.clock()
        if causes:
            self._last_bad = now
            reason = "; ".join(causes.values())
            if not self.active:
                self._activate(reason)
            self.reason = reason
            close = [c for c in causes if (c == "rain" and self.section.close_on_rain)
                     or (c == "wind" and self.section.close_on_wind)]
            fresh = [c for c in close if c not in self._closed_for]
            if fresh:
                self._closed_for.update(fresh)
                self._close("; ".join(causes[c] for c in fresh))
            self._closed_for.intersection_update(causes)
        elif self.active and now - (self._last_bad or now) >= self.section.release_after:
            self._release()

    def _activate(self, reason: str) -> None:
        self.active = True
        log.warning("weather interlock active: %s", reason)
        for module in self.guarded:
            module.raise_condition(CONDITION, WARNING, reason)
            module.emit(WARN, WEATHER_INTERLOCK, f"opening locked: {reason}")

    def _release(self) -> None:
        self.active = False
        self.reason = ""
        self._closed_for.clear()
        text = f"weather good for {self.section.release_after:g} s: opening allowed"
        log.info("weather interlock released")
        for module in self.guarded:
            module.clear_condition(CONDITION)
            module.clear_condition(CLOSE_CONDITION)
            module.emit(INFO, WEATHER_INTERLOCK, text)

    def _close(self, reason: str) -> None:
        error = TcsError(f"closing: {reason}", WEATHER_CLOSE)
        for module in self.guarded:
            try:
                moved = module.safety_close(TcsError(f"{module.module_name}: {error.message}", WEATHER_CLOSE))
            except Exception:
                log.exception("%s: closing for the weather failed", module.module_name)
                continue
            if moved:
                module.raise_condition(CLOSE_CONDITION, WARNING, error.message)
                module.emit(WARN, WEATHER_CLOSE, error.message)

    def reconnected(self, module) -> None:
        """``module``'s PLC is back; its driver wrote stop to every axis at connect. If the
        weather closed the guarded parts and still wants them closed, close ``module`` again."""
        if module not in self.guarded or not self.active:
            return
        close = [c for c in self._closed_for if (c == "rain" and self.section.close_on_rain)
                 or (c == "wind" and self.section.close_on_wind)]
        if not close:
            return
        reason = "; ".join(close) + " (again, after the PLC came back)"
        error = TcsError(f"{module.module_name}: closing: {reason}", WEATHER_CLOSE)
        try:
            moved = module.safety_close(error)
        except Exception:
            log.exception("%s: closing for the weather failed", module.module_name)
            return
        if moved:
            module.raise_condition(CLOSE_CONDITION, WARNING, f"closing: {reason}")
            module.emit(WARN, WEATHER_CLOSE, f"closing: {reason}")

    # -- asked by the modules ------------------------------------------------------------------
    def check_move(self, module, goal: float) -> None:
        """Refuse ``goal`` (PLC frame) for ``module`` when it opens while the interlock is active.

        Raises
        ------
        TcsError
            Number 1020, after ``EVENT ERROR <module>:1020``.
        """
        if not self.active:
            self.evaluate()  # the release may be due
        if not self.active:
            return
        s = module.section
        tol = max(s.tolerance, 1e-9)
        if goal <= s.min + tol or goal <= module.real_position + tol:
            return  # closing, or not opening any further
        error = TcsError(f"{module.module_name}: opening refused: {self.reason}", WEATHER_INTERLOCK)
        module.emit(ERROR, WEATHER_INTERLOCK, f"opening refused: {self.reason}")
        raise error
