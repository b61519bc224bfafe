"""The ASCOM Alpaca front end: the telescope as Alpaca devices over HTTP (``docs/architecture.md``
rule 0: a declaration over the same telescope model as the OpenTCI and OpenTSI trees).

- ``protocol``: the wire rules without I/O; ``device``: the common members and dispatch;
- ``telescope``: ITelescopeV4; ``equipment``: Focuser, FilterWheel, Rotator, Dome,
  CoverCalibrator; ``site``: Switch, ObservingConditions, SafetyMonitor;
- ``commands``: CommandBlind/Bool/String as a TPL2 GET or SET of either tree;
- ``server``: the aiohttp server, management API, /setup pages, UDP discovery;
- ``start``: what ``tcs-server`` (:class:`tcs.app.Service`) calls to start it.

:func:`build_devices` numbers the devices of each type from 0, as the hardware file has them.
"""

from __future__ import annotations

from tcs.alpaca.server import AlpacaServer


def build_devices(telescope, commands=None) -> list:
    """Every Alpaca device the hardware file gives ``telescope``."""
    from tcs.alpaca.equipment import equipment_devices
    from tcs.alpaca.telescope import TelescopeDevice

    seed = telescope.config.cabinet.hw_id
    devices = []
    if telescope.pointing is not None:
        devices.append(TelescopeDevice(0, "Telescope", "the telescope mount (pointing and tracking)",
                                       telescope, commands=commands, unique_seed=seed))
    devices.extend(equipment_devices(telescope, commands, seed))
    return devices


def build_alpaca_server(config, telescope, commands=None) -> AlpacaServer:
    """The Alpaca listener for ``telescope`` (not started)."""
    section = config.alpaca
    devices = build_devices(telescope, commands)
    for device in devices:  # a state read's value answers the same read again while nothing changed
        device.reuse_value = config.server.reuse_reply
        device.read_only = section.read_only
    return AlpacaServer(devices, manufacturer=config.cabinet.manufacturer,
                        server_name=section.server_name, location=section.location)


__all__ = ["AlpacaServer", "build_alpaca_server", "build_devices"]
