"""``tcs-server``: run the TCS.

No arguments: the simulated telescope of ``hwconfig/sim.toml`` on 127.0.0.1:65432.
``--config FILE`` runs whatever the file describes; ``--host``/``--port`` override the file,
``--opentsi-port`` the port of the OpenTSI tree (65433 in sim.toml; -1 serves none),
``--alpaca-port`` the ASCOM Alpaca devices' (11111 in sim.toml; -1 serves none),
``--alpaca-discovery-port`` their UDP discovery (32227 in sim.toml; -1: no discovery),
``--web-port`` the read-only status page and ``/metrics`` (8088 in sim.toml; -1 serves none).
Logs go to stderr: under systemd (stderr is the journal, ``$JOURNAL_STREAM``) as ``LEVEL
name: message`` — journald adds the time; started by hand with the time (UTC, as in
``CABINET.STATUS.LOG[]``) in front: ``2026-11-25T21:03:04.123Z INFO name: message``. A bad
hardware file is
reported key by key and the exit status is 2 — also a valid file that cannot run a service: no
``[[users]]``, or a real telescope without ``[site]``. ``--check-config FILE`` does only that
validation (and that the EDS files exist), touching no hardware: status 0 or 2. SIGINT and
SIGTERM stop cleanly (status 0).
Exit status 1, with one line saying why and before any hardware is touched: a listening port
(TPL2, OpenTSI, Alpaca, discovery, web) is taken — the line names its role, address and the
flag or key that moves it — or, before any frame is sent on the CAN bus, another master (SYNC,
or a heartbeat with our node id) is heard on a shared CAN bus (socketcan, socketcand) — e.g.
the service is already running.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import os
import signal
import sys
import time

from tcs import __version__
from tcs.config import DEFAULT_CONFIG, HwConfig, load_config
from tcs.drivers.bus_check import AnotherMaster
from tcs.errors import ConfigError, ConfigErrors, TcsError


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="tcs-server", description=__doc__.splitlines()[0])
    p.add_argument("--config", default=str(DEFAULT_CONFIG), help="hardware file (default: %(default)s)")
    p.add_argument("--host", help="bind address (overrides [server] host)")
    p.add_argument("--port", type=int, help="TCP port (overrides [server] port)")
    p.add_argument("--opentsi-port", type=int,
                   help="TCP port of the OpenTSI tree (overrides [server] opentsi_port; -1: off)")
    p.add_argument("--alpaca-port", type=int,
                   help="HTTP port of the ASCOM Alpaca devices (overrides [alpaca] port; -1: off)")
    p.add_argument("--alpaca-discovery-port", type=int,
                   help="UDP port answering Alpaca discovery (overrides [alpaca] discovery_port; -1: none)")
    p.add_argument("--web-port", type=int,
                   help="HTTP port of the status page and /metrics (overrides [web] port; -1: off)")
    p.add_argument("--indi-port", type=int,
                   help="TCP port of the INDI devices (overrides [indi] port; -1: off)")
    p.add_argument("--log-level", default="INFO", choices=["DEBUG", "INFO", "WARNING", "ERROR"])
    p.add_argument("--check-config", metavar="FILE",
                   help="validate FILE as a service's hardware file and exit (0 valid, 2 not); "
                        "no hardware is touched")
    p.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    return p.parse_args(argv)


def service_config(path: str) -> HwConfig:
    """The hardware file at ``path`` checked for running the service: valid, with users, with
    ``[site]`` on a real telescope, and with its EDS files present. Raises ConfigErrors."""
    config = load_config(path)
    problems = config.service_problems()
    for name, drive in config.drives.items():
        if drive.eds and not config.resolve(drive.eds).is_file():
            problems.append(ConfigError(str(config.source), f"drives.{name}.eds",
                                        f"EDS file {config.resolve(drive.eds)} not found"))
    if problems:
        raise ConfigErrors(problems)
    return config


def stderr_is_journal() -> bool:
    """True when stderr is connected to journald: systemd sets ``$JOURNAL_STREAM`` to the
    ``device:inode`` of that stream (a child whose stderr was redirected elsewhere inherits the
    variable, so it is compared with stderr's own device and inode)."""
    value = os.environ.get("JOURNAL_STREAM", "")
    dev, _, ino = value.partition(":")
    if not (dev.isdigit() and ino.isdigit()):
        return False
    try:
        st = os.fstat(sys.stderr.fileno())
    except (OSError, ValueError, AttributeError):
        return False
    return (st.st_dev, st.st_ino) == (int(dev), int(ino))


#: Log line formats: journald stamps each line itself; a log started by hand needs the time.
JOURNAL_FORMAT = "%(levelname)s %(name)s: %(message)s"
#: (UTC, as the lines of ``CABINET.STATUS.LOG[]``: ``2026-11-25T21:03:04.123Z``).
HAND_FORMAT = "%(asctime)s.%(msecs)03dZ %(levelname)s %(name)s: %(message)s"


def setup_logging(level: str) -> None:
    journal = stderr_is_journal()
    handler = logging.StreamHandler(sys.stderr)
    formatter = logging.Formatter(JOURNAL_FORMAT if journal else HAND_FORMAT, datefmt="%Y-%m-%dT%H:%M:%S")
    formatter.converter = time.gmtime
    handler.setFormatter(formatter)
    logging.basicConfig(level=getattr(logging, level), handlers=[handler])
    logging.getLogger("can.interfaces.socketcand").setLevel(logging.ERROR)
    from tcs.log_repeat import install
    install()  # a repeated line: once, then a count every 10 s (a dead bus floods otherwise)


def main(argv=None) -> int:
    args = parse_args(argv)
    setup_logging(args.log_level)
    try:
        config = service_config(args.check_config or args.config)
    except ConfigErrors as exc:
        print(f"tcs-server: the hardware file is not valid:\n{exc}", file=sys.stderr)
        return 2
    if args.check_config:
        print(f"{config.source}: valid", file=sys.stderr)
        return 0
    from tcs.listeners import PortInUse, check_free, planned
    try:  # every listening port, before the service (and the hardware) is even loaded
        check_free(planned(config, args.host, args.port, args.opentsi_port, args.alpaca_port,
                           args.web_port, args.alpaca_discovery_port, args.indi_port))
    except PortInUse as exc:
        print(f"tcs-server: cannot start: {exc.message}", file=sys.stderr)
        return 1
    from tcs.app import Service, serve_until_signalled

    return run_until_signalled("tcs-server", lambda stop: serve_until_signalled(
        Service(config, args.host, args.port, args.opentsi_port,
                args.alpaca_port, args.web_port, alpaca_discovery_port=args.alpaca_discovery_port,
                indi_port=args.indi_port), stop))


def run_until_signalled(prog: str, main_coro) -> int:
    """Run ``main_coro(stop_event)`` with SIGINT/SIGTERM setting the event; exit status 0, or 1
    with a one-line message when the operating system refuses (port in use …), another
    master already runs the CAN bus (:class:`~tcs.drivers.bus_check.AnotherMaster`), or the
    hardware cannot be reached at start (the CAN bus: no traceback)."""

    async def run() -> None:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
        await main_coro(stop)

    try:
        asyncio.run(run())
    except OSError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return 1
    except AnotherMaster as exc:
        print(f"{prog}: refusing to start: {exc.message}", file=sys.stderr)
        return 1
    except TcsError as exc:
        print(f"{prog}: cannot start: {exc.message}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
