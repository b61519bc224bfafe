"""Start the real service (telescope model + TPL2 server) in-process for a test."""

from __future__ import annotations

import dataclasses
import socket
import uuid
from pathlib import Path

from tcs.app import Service
from tcs.config import DEFAULT_CONFIG, HwConfig, load_config
from tcs.config.sections import StateSection


def make_config(state_dir: Path, path: Path = DEFAULT_CONFIG, *, envelope: dict | None = None,
                **server) -> HwConfig:
    """The hardware file at ``path`` with state in ``state_dir`` and server settings overridden
    (port 0 = a free port, for the OpenTSI tree too where the file serves it; a short
    login-failure delay).

    The Sun cone of the safety envelope is switched off (``sun_avoidance = 0``): the real Sun
    stands wherever the hour CI runs at puts it, and a test that slews to an arbitrary place
    must not fail because the Sun is there. ``envelope``: ``[envelope]`` keys to use instead
    (the envelope tests: ``envelope={"sun_avoidance": 30.0, ...}``)."""
    config = load_config(path)
    settings = dict(port=0, auth_fail_delay=0.05)
    if config.server.opentsi_port >= 0:
        settings["opentsi_port"] = 0   # the OpenTSI tree too: a free port
    settings.update(server)
    changes = dict(server=dataclasses.replace(config.server, **settings),
                   state=StateSection(path=str(state_dir)),
                   envelope=dataclasses.replace(config.envelope, **(envelope or {"sun_avoidance": 0.0})))
    if config.alpaca.port >= 0:   # the Alpaca devices too: a free port, discovery on a free UDP port
        changes["alpaca"] = dataclasses.replace(config.alpaca, port=0, discovery_port=free_udp_port())
    if config.web.port >= 0:      # the status page and /metrics too: a free port
        changes["web"] = dataclasses.replace(config.web, port=0)
    if config.indi.port >= 0:     # the INDI devices too: a free port
        changes["indi"] = dataclasses.replace(config.indi, port=0)
    if config.can is not None and config.can.interface == "virtual":
        # a bus of its own: services of different tests must not hear each other
        changes["can"] = dataclasses.replace(config.can, channel=f"tcs-test-{uuid.uuid4().hex[:12]}")
    new = dataclasses.replace(config, **changes)
    object.__setattr__(new, "source", config.source)
    return new


def tolerant_heartbeats(config: HwConfig) -> HwConfig:
    """``config`` with drive heartbeats every 1 s and the drives' wait for the TCS heartbeat
    5 s (instead of the shipped files' 0.1–0.2 s and 0.5–1 s): on a loaded 2-core machine the
    simulator's timer thread was seen 0.66 s late, and a test starting a shipped file as it is
    is not about lost heartbeats (see tests/hw_axes_fast.toml). Everything else stays."""
    drives = {name: dataclasses.replace(d, heartbeat_period=1.0, heartbeat_consumer_timeout=5.0)
              for name, d in config.drives.items()}
    new = dataclasses.replace(config, drives=drives)
    object.__setattr__(new, "source", config.source)
    return new


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("0.0.0.0", 0))
        return s.getsockname()[1]


async def start_service(state_dir: Path, path: Path = DEFAULT_CONFIG, *, envelope: dict | None = None,
                        **server) -> tuple[Service, int]:
    service = Service(make_config(state_dir, path, envelope=envelope, **server))
    port = await service.start()
    return service, port
