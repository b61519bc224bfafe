"""The drives of one hardware file, opened directly for commissioning (no ``tcs-server``).

How it works
------------
:func:`prepare_config` decides whether to simulate: with ``--simulate``, or by default when
``[can]`` is the in-process ``virtual`` bus and the file has ``[simulation.drives]``, the
simulated drives are started in this process (:func:`tcs.sim.drive_network.start_simulated_drives`)
— on a file whose bus is not virtual, ``--simulate`` moves ``[can]`` to a private virtual
channel first, so the real bus is never touched.

:class:`DriveSession` then opens the driver's :class:`~tcs.drivers.can_system.CanDrives`
(bus, TCS heartbeat, SDO worker), boots only the drives a subcommand needs, and runs the SYNC
cycle with its own callback: hooks (motion streaming, watchers) first, then every drive's
``step()``. The main thread waits for states with :meth:`DriveSession.wait` (polling, with a
deadline) — it never touches the drives' cyclic side.

The service must be stopped: two masters on one bus (two SYNC producers, two heartbeats with
one node id, two state machines per drive) is never safe. On a ``socketcan``/``socketcand``
bus :func:`~tcs.drivers.bus_check.other_master` (shared with ``tcs-server``) listens briefly,
before this process sends its heartbeat, for a SYNC or for the TCS node's heartbeat from
somebody else and the session refuses to go on (exit 3) unless ``--force``. On the
in-process ``virtual`` bus nobody else can be there, so it is not checked.

Closing is the safe sequence: disable every booted drive and wait until it is off, stop the
cycle, switch off each drive's heartbeat consumer (0x1016:1 = 0) so it does not fault when
this process's heartbeat stops (the service writes 0x1016 again when it boots the drive),
close the bus, stop the simulated drives.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import threading
import time
from collections.abc import Callable, Iterable

from tcs.drivers.bus_check import AnotherMaster, machine_lock
from tcs.drivers.bus_check import listen_window, other_master  # noqa: F401 (re-exported)
from tcs.drivers.can_system import CanDrives
from tcs.drivers.drive import DriveState, DriveStatus, Mode
from tcs.errors import CommunicationError, TcsError

from tcs.commission.common import CommissionError, ExitCode

log = logging.getLogger(__name__)

SYNC_COB_ID = 0x080
ENABLE_TIMEOUT = 5.0      # s: enable request -> Operation enabled (the driver gives up at 2 s)
DISABLE_TIMEOUT = 2.0
RESET_TIMEOUT = 3.0
MODE_TIMEOUT = 3.0


def replace_config(config, **changes):
    """A copy of a frozen :class:`~tcs.config.HwConfig` with some sections replaced."""
    new = dataclasses.replace(config, **changes)
    object.__setattr__(new, "source", config.source)
    return new


def prepare_config(config, simulate: bool | None):
    """``(config, simulate)``: whether to start the simulated drives, and the config to use.

    Raises
    ------
    CommissionError
        (exit 2) no ``[can]`` section, or ``--simulate`` on a file without ``[simulation]``.
    """
    if config.can is None or not config.drives:
        raise CommissionError(f"{config.source}: no [can] section with [drives]: nothing to "
                              "commission", ExitCode.USAGE)
    has_sim = config.simulation is not None and bool(config.simulation.drives)
    if simulate is None:
        simulate = has_sim and config.can.interface == "virtual"
    if simulate and not has_sim:
        raise CommissionError(f"--simulate: {config.source} has no [simulation.drives] tables",
                              ExitCode.USAGE)
    if simulate and config.can.interface != "virtual":
        can = dataclasses.replace(config.can, interface="virtual", options={},
                                  channel=f"tcs-commission-{os.getpid()}-{id(config):x}")
        config = replace_config(config, can=can)
    return config, bool(simulate)


class DriveSession:
    """Simulators (optional), bus, drives and cycle for one subcommand; a context manager.

    Parameters
    ----------
    config : the (prepared) hardware file.
    simulate : start the ``[simulation]`` drives in this process.
    drives : drive tables to use instead of the file's (the limit search widens limits).
    check_bus : refuse when another master is on a real bus.
    listen : seconds to listen for another master.
    """

    def __init__(self, config, *, simulate: bool, drives=None, check_bus: bool = True,
                 listen: float | None = None):
        self.config = config
        self.simulate = simulate
        self.sections = dict(drives if drives is not None else config.drives)
        self.check_bus = check_bus
        self.listen = listen if listen is not None else listen_window(config.can.heartbeat_period)
        self.sims = None
        self._bus_lock = None  # this machine's lock of a shared bus (bus_check.machine_lock)
        self.system: CanDrives | None = None
        self.booted: set[str] = set()
        self._hooks: list[Callable] = []
        self._hooks_lock = threading.Lock()
        self._cycling = False

    # ------------------------------------------------------------------ life cycle
    def __enter__(self) -> DriveSession:
        try:
            self.open()
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def open(self) -> None:
        from tcs.sim.drive_network import start_simulated_drives

        if self.simulate:
            self.sims = start_simulated_drives(self.config)
        self.system = CanDrives(self.config.can, self.sections, resolve=self.config.resolve,
                                file=str(self.config.source))
        listen = self.config.can.interface != "virtual"
        try:
            self._bus_lock = machine_lock(self.config.can)
        except AnotherMaster as exc:
            if self.check_bus:
                raise CommissionError(f"{exc.message}: stop the service (systemctl stop "
                                      "tcs-server) before commissioning, or pass --force",
                                      ExitCode.HARDWARE) from None
            log.warning("%s; going on (--force)", exc.message)
        try:
            self.system.open(heartbeat=not listen)
        except CommunicationError as exc:
            raise CommissionError(f"{exc.message} (is the CAN interface up?)", ExitCode.HARDWARE) from exc
        if listen:
            # Listening also lets the link settle: with --force the first frame heard proves
            # that this connection receives (a socketcand gateway delivers only after rawmode
            # settled; a probe sent at once would have its answers lost).
            busy = other_master(self.system.bus.network, self.config.can.node_id, self.listen)
            if busy and self.check_bus:
                raise CommissionError(
                    f"{self.system.bus.name}: another master is active ({busy}): stop the "
                    "service (systemctl stop tcs-server) before commissioning, or pass --force",
                    ExitCode.HARDWARE)
            if busy:
                log.warning("%s: another master is active (%s); going on (--force)",
                            self.system.bus.name, busy)
            self.system.bus.start_heartbeat()

    @property
    def network(self):
        return self.system.bus.network

    def drive(self, name: str):
        return self.system.drives[name]

    def status(self, name: str) -> DriveStatus:
        return self.system.drives[name].status()

    def boot(self, names: Iterable[str]) -> None:
        """Boot the named drives (in parallel); refuse with every failure named.

        Raises
        ------
        CommissionError
            exit 3 when a drive did not answer, exit 1 for other boot failures (identity).
        """
        names = list(names)
        failures = self.system.boot(names)
        self.booted |= {n for n in names if n not in failures}
        if failures:
            code = ExitCode.HARDWARE if any(isinstance(e, CommunicationError)
                                            for e in failures.values()) else ExitCode.FAILED
            raise CommissionError("; ".join(e.message for e in failures.values()), code,
                                  {"boot_failures": {n: e.message for n, e in failures.items()}})

    def start(self) -> None:
        """Start SYNC and the cycle (hooks, then every drive's step)."""
        if not self._cycling:
            self._step_all = self.system.step_all
            self.system.cycle.add_callback(self._on_cycle)
            self.system.start()
            self._cycling = True

    def close(self) -> None:
        """Disable, stop the cycle, park the drives, close the bus, stop the simulators."""
        system = self.system
        if system is not None:
            try:
                if self._cycling:
                    self._disable_all(system)
                system.stop()
                self._cycling = False
                self._park(system)
            finally:
                self.system = None
                system.close()
        sims, self.sims = self.sims, None
        if sims is not None:
            sims.stop()
        lock, self._bus_lock = self._bus_lock, None
        if lock is not None:
            lock.close()

    def _disable_all(self, system: CanDrives) -> None:
        names = [n for n in self.booted if system.drives[n].status().state not in
                 (DriveState.OFFLINE, DriveState.SWITCH_ON_DISABLED)]
        for name in names:
            system.drives[name].disable()
        deadline = time.monotonic() + DISABLE_TIMEOUT
        while time.monotonic() < deadline and any(
                system.drives[n].status().state in (DriveState.OPERATION_ENABLED,
                                                    DriveState.QUICK_STOP_ACTIVE) for n in names):
            time.sleep(0.02)

    def _park(self, system: CanDrives) -> None:
        network = system.bus.network
        for name in sorted(self.booted):
            node = network.nodes.get(system.drives[name].node_id) if network is not None else None
            if node is None:
                continue
            try:
                node.sdo.download(0x1016, 1, bytes(4))
            except Exception as exc:  # best effort: the drive may be gone
                log.warning("%s: could not switch its heartbeat consumer off: %s",
                            system.drives[name].device, exc)

    # ------------------------------------------------------------------ cycle side
    def add_hook(self, hook: Callable) -> None:
        """Run ``hook(cycle)`` in every cycle before the drives step (cycle thread)."""
        with self._hooks_lock:
            self._hooks = [*self._hooks, hook]

    def remove_hook(self, hook: Callable) -> None:
        with self._hooks_lock:
            self._hooks = [h for h in self._hooks if h is not hook]

    def _on_cycle(self, cycle) -> None:
        for hook in self._hooks:
            hook(cycle)
        self._step_all(cycle)

    # ------------------------------------------------------------------ waiting (main thread)
    def wait(self, predicate: Callable[[], bool], timeout: float,
             tick: Callable[[], None] | None = None) -> bool:
        """Poll ``predicate`` every 20 ms (calling ``tick`` too) until true or ``timeout``."""
        deadline = time.monotonic() + timeout
        while True:
            if tick is not None:
                tick()
            if predicate():
                return True
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.02)

    def clear_faults(self, names: Iterable[str]) -> list[str]:
        """Reset drives found in fault (an explicit operator action); the faults' texts.

        Raises
        ------
        CommissionError
            (exit 1) a fault that a reset does not clear.
        """
        cleared = []
        for name in names:
            fault = self.status(name).fault
            if fault is None:
                continue
            self.drive(name).fault_reset()
            if not self.wait(lambda: self.status(name).fault is None, RESET_TIMEOUT):
                raise CommissionError(f"{fault.message}: a fault reset did not clear it")
            cleared.append(fault.message)
        return cleared

    def set_mode(self, name: str, mode: Mode) -> None:
        """Switch a drive's mode and wait for the read-back (0x6061)."""
        self.drive(name).set_mode(mode)
        if not self.wait(lambda: self.status(name).mode == mode, MODE_TIMEOUT):
            st = self.status(name)
            raise CommissionError(f"{self.drive(name).device}: mode {mode.name} requested, the "
                                  f"drive shows {st.mode}" + (f" ({st.request_error.message})"
                                                              if st.request_error else ""))

    def enable(self, names: Iterable[str]) -> None:
        """Enable the drives and wait for Operation enabled.

        Raises
        ------
        CommissionError
            (exit 1) a drive refused, faulted or timed out; the message names it.
        """
        names = list(names)
        for name in names:
            try:
                self.drive(name).enable()
            except TcsError as exc:
                raise CommissionError(f"{self.drive(name).device}: {exc.message}") from exc

        def problem() -> str | None:
            for name in names:
                st = self.status(name)
                if st.fault is not None:
                    return st.fault.message
                if st.request_error is not None and not st.enabled:
                    return st.request_error.message
            return None

        ok = self.wait(lambda: problem() is not None or all(self.status(n).enabled for n in names),
                       ENABLE_TIMEOUT)
        why = problem()
        if why or not ok:
            late = [n for n in names if not self.status(n).enabled]
            raise CommissionError(why or f"{', '.join(late)}: not enabled within {ENABLE_TIMEOUT:g} s")

    def disable(self, names: Iterable[str]) -> None:
        """Disable the drives and wait until their power stage is off."""
        names = list(names)
        for name in names:
            self.drive(name).disable()
        self.wait(lambda: not any(self.status(n).state in (DriveState.OPERATION_ENABLED,
                                                           DriveState.QUICK_STOP_ACTIVE)
                                  for n in names), DISABLE_TIMEOUT)
