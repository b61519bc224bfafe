"""INDI front end: the telescope as INDI devices, for KStars/Ekos, PHD2 and every INDI client.

:mod:`tcs.indi.protocol` is the pure XML protocol core (no I/O), :mod:`tcs.indi.server` the
TCP server with pushed, coalesced updates, :mod:`tcs.indi.telescope` the Telescope device
and :mod:`tcs.indi.equipment` the focuser, filter wheel, rotator, dome and weather devices
over the model's public methods. :func:`start_indi` builds and starts them for a running
:class:`tcs.app.Service` (``[indi] port``; ``tcs-server --indi-port``).
"""

from __future__ import annotations


async def start_indi(service):
    from tcs.indi.server import IndiServer
    from tcs.indi.equipment import equipment_devices
    from tcs.indi.telescope import TelescopeDevice

    config = service.config.indi
    devices = []
    if service.telescope.pointing is not None:
        devices.append(TelescopeDevice(service.telescope))
    devices.extend(equipment_devices(service.telescope))
    server = IndiServer(devices, interval=config.interval, read_only=config.read_only)
    host = config.host if service.host is None else service.host
    await server.start(host, service.indi_port)
    return server
