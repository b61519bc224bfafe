"""What every OpenTCI module on a PLC does when its PLC goes away and comes back.

:class:`PlcModule` is the :class:`~tcs.model.health.ModuleHealth` base of the DOME[], COVER,
SENSOR[] and SWITCH[] domain objects. :meth:`PlcModule.watch` subscribes to the connection
listener of the module's :class:`~tcs.drivers.modbus.PlcDriver` (one, or several for a module
reading points of more than one PLC) and keeps one condition per PLC:

* lost — condition ``"PLC <name> unreachable"`` (ERROR bit) raised with the driver's message,
  and an event ``EVENT ERROR <module>:4`` (nocon: cannot connect, connection closed) or
  ``:3`` (confail: no answer in time, garbled answer);
* back — the condition is cleared (it stays latched in ``ERROR_STATE`` until a client writes
  ``ERROR_STATE=0``, like every ModuleHealth condition) and ``EVENT INFO <module>:15`` says so.

A PLC that is not connected when the module starts watching (it never answered at start)
counts as lost at once. Subclasses add their own reaction in :meth:`on_link` (an axis fails
its pending SETs there). Everything runs on the event loop.
"""

from __future__ import annotations

from tcs.drivers.modbus import PlcConnectionEvent, PlcDriver
from tcs.errors import CommunicationError, ErrorNumber
from tcs.model.events import ERROR, INFO
from tcs.model.health import ERROR as ERROR_BIT
from tcs.model.health import ModuleHealth


class PlcModule(ModuleHealth):
    """A module whose hardware is behind one or more PLCs."""

    def __init__(self, module_name: str, events=None, hw_type: int = 1, status_sink=None):
        super().__init__(module_name, events, hw_type=hw_type, status_sink=status_sink)
        self._drivers: list[PlcDriver] = []
        self._unwatch: list = []

    # -- life cycle --------------------------------------------------------------------------
    def watch(self, *drivers: PlcDriver) -> None:
        """Follow the connection state of ``drivers`` (and take their present state)."""
        for driver in drivers:
            if driver in self._drivers:
                continue
            self._drivers.append(driver)
            self._unwatch.append(driver.add_connection_listener(self._on_connection))
            if not driver.connected:
                self._on_connection(PlcConnectionEvent(driver.name, False, driver.error, driver.message))

    def unwatch(self) -> None:
        for remove in self._unwatch:
            remove()
        self._unwatch.clear()

    # -- state ---------------------------------------------------------------------------------
    @property
    def plc_connected(self) -> bool:
        return all(d.connected for d in self._drivers)

    def link_error(self) -> CommunicationError | None:
        """The error of the first PLC that is not connected (None when all are)."""
        for d in self._drivers:
            if not d.connected:
                return CommunicationError(d.name, f"not connected ({d.message})", d.error)
        return None

    def emit(self, level: str, number: int, text: str = "", cause=None) -> None:
        if self._events is not None:
            self._events.emit(level, self.module_name, number, text, cause)

    # -- reactions -----------------------------------------------------------------------------
    def _on_connection(self, event: PlcConnectionEvent) -> None:
        condition = f"PLC {event.plc} unreachable"
        if event.connected:
            if self.conditions().get(condition, (0, False))[1]:
                self.clear_condition(condition)
                self.emit(INFO, ErrorNumber.ERRORCHANGE, f"PLC {event.plc} reachable again")
        else:
            number = event.number or ErrorNumber.NOCON
            text = f"PLC {event.plc}: {event.message}"
            self.raise_condition(condition, ERROR_BIT, text)
            if self._events is not None:  # the driver logged the loss once for all modules
                self._events.emit(ERROR, self.module_name, number, text, quiet=True)
        self.on_link(event)

    def on_link(self, event: PlcConnectionEvent) -> None:
        """Hook: a PLC of this module was lost or came back."""
