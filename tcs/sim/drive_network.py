"""Several simulated drives on one bus, started and stopped together.

``start_sim_drives(bus, {node_id: params})`` opens the simulator's own bus attachment (one
receive thread and one timer thread for all the drives), creates and starts one
:class:`SimDrive` per node and returns a :class:`SimDriveNetwork`; ``stop()`` (or leaving the
``with`` block) stops the drives and closes the bus the helper opened.

:func:`params_from_config` turns ``[simulation.drives.<name>]`` into :class:`SimDriveParams`:
the EDS the drive behaves as (``eds``, default the drive's own), its unit factors, its boot
time and its identity (the ``[drives]`` identity; fields left out there come from the EDS).

``bus`` is a dict of ``can.Bus`` keyword arguments (``{"interface": "virtual", "channel":
"tcs"}``, a socketcand or socketcan bus …), or an existing python-can bus or canopen
``Network`` to share (never shut down by the helper).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any

from tcs.sim.can_port import open_port
from tcs.config.can import sdo_entry
from tcs.sim.cia402_drive import DEFAULT_EDS, SimDrive, _load_od
from tcs.sim.drive_params import SimDriveParams


class SimDriveNetwork(Mapping[int, SimDrive]):
    """The running simulated drives of one bus, by node id."""

    def __init__(self, bus: Any, drives: Mapping[int, SimDriveParams | None],
                 clock: Callable[[], float] = time.monotonic, eds: str | Path = DEFAULT_EDS,
                 start: bool = True):
        self.port = open_port(bus)
        self._released = False
        self._drives: dict[int, SimDrive] = {}
        try:
            for node_id, params in sorted(drives.items()):
                self._drives[node_id] = SimDrive(self.port, node_id, params, clock=clock, eds=eds)
            if start:
                self.start()
        except BaseException:
            self.stop()
            raise

    def start(self, wait: bool = True) -> None:
        """Power the drives up; with ``wait``, as a cabinet powered before the software starts:
        each sends its boot-up at once (this returns once they have). Without ``wait`` each
        takes its ``boot_delay``, as NMT resets later do, as real drives do."""
        for drive in self._drives.values():
            drive.start(powered=wait)
        if wait:
            deadline = time.monotonic() + max((d.params.boot_delay for d in self._drives.values()),
                                              default=0.0) + 2.0
            while time.monotonic() < deadline and any(
                    d.nmt_state_name == "INITIALISING" for d in self._drives.values()):
                time.sleep(0.005)

    def stop(self) -> None:
        """Stop every drive and close the simulator's bus attachment. Idempotent."""
        for drive in self._drives.values():
            drive.stop()
        if not self._released:
            self._released = True
            self.port.release()

    def __enter__(self) -> SimDriveNetwork:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def __getitem__(self, node_id: int) -> SimDrive:
        return self._drives[node_id]

    def __iter__(self) -> Iterator[int]:
        return iter(self._drives)

    def __len__(self) -> int:
        return len(self._drives)


def start_sim_drives(bus: Any, drives: Mapping[int, SimDriveParams | None],
                     clock: Callable[[], float] = time.monotonic,
                     eds: str | Path = DEFAULT_EDS) -> SimDriveNetwork:
    """Start simulated drives ``{node_id: params}`` on ``bus``; ``.stop()`` the result."""
    return SimDriveNetwork(bus, drives, clock=clock, eds=eds)


def params_from_config(config) -> dict[int, SimDriveParams]:
    """``{node_id: SimDriveParams}`` of the ``[simulation]`` drives (identity from ``[drives]``)."""
    params = {}
    for name, sim in config.simulation.drives.items():
        drive = config.drives[name]
        ident = drive.identity
        eds = sim.eds or drive.eds
        path = str(config.resolve(eds)) if eds else None
        info = _load_od(path or DEFAULT_EDS, drive.node_id).device_information
        ipu = abs(drive.increments_per_unit)

        def pick(*values: int | None) -> int:
            return next((int(v) for v in values if v is not None), 0)

        params[drive.node_id] = SimDriveParams(
            increments_per_unit=ipu,
            max_velocity=sim.max_velocity, max_acceleration=sim.max_acceleration,
            position=sim.position, negative_limit_switch=sim.negative_limit_switch,
            positive_limit_switch=sim.positive_limit_switch, home_switch=sim.home_switch,
            home_switch_active_below=sim.home_switch_active_below,
            index_pulse_spacing=sim.index_pulse_spacing,
            identity=(pick(ident.vendor, info.vendor_number), pick(ident.product, info.product_number),
                      pick(sim.revision, ident.revision, info.revision_number),
                      ident.serial if ident.serial is not None else sim.serial),
            boot_delay=sim.boot_time, eds=path,
            velocity_scale=sim.velocity_factor / ipu if sim.velocity_factor else 1.0,
            acceleration_scale=sim.acceleration_factor / ipu if sim.acceleration_factor else 1.0,
            objects={sdo_entry(k): v for k, v in sim.objects.items()})
    return params


def start_simulated_drives(config):
    """Start the ``[simulation]`` drives of the hardware file ``config`` on its ``[can]`` bus, in
    this process. Called by whoever builds that bus (the service's model or its control
    process, ``tcs-commission``), never by the model for another process."""
    return SimDriveNetwork(config.can.bus_kwargs(), params_from_config(config))
