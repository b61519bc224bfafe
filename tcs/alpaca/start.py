"""Start the Alpaca front end of a running :class:`tcs.app.Service` (what ``tcs-server`` calls)."""

from __future__ import annotations

from tcs.alpaca import build_alpaca_server
from tcs.alpaca.commands import CommandBridge


async def start_alpaca(service):
    """Build the devices over ``service.telescope``, with CommandBlind/Bool/String on the
    service's TPL2 trees, and listen on ``[alpaca]`` host/port (discovery on its port)."""
    config = service.config
    section = config.alpaca
    tsi = service.opentsi_server.tree if service.opentsi_server is not None else None
    tci = service.server.tree if service.server is not None else None
    server = build_alpaca_server(config, service.telescope, CommandBridge(tci, tsi))
    host = section.host or service.host or config.server.host
    await server.start(host, service.alpaca_port, service.alpaca_discovery_port)
    return server
