"""``tcs-sim``: the simulated cabinet as its own process.

    tcs-sim [--config hwconfig/sim-remote.toml] [--can-port N]

Serves, from the hardware file, the ``[simulation]`` drives as a CAN bus over socketcand on
the ``[can]`` host/port (or, with ``interface = "socketcan"``, on that kernel interface), each simulated PLC as Modbus TCP on its host/port, and the GPS as NMEA
over TCP — so that ``tcs-server --config hwconfig/sim-remote.toml`` in another process drives
it exactly like real hardware. Runs until SIGINT/SIGTERM. A bad file exits with status 2.
"""

from __future__ import annotations

import argparse
import sys

from tcs.app import freeze_heap, thaw_heap
from tcs.cli.server import run_until_signalled, setup_logging
from tcs.config import load_config
from tcs import __version__
from tcs.resources import hwconfig_file
from tcs.errors import ConfigErrors

DEFAULT = hwconfig_file("sim-remote.toml")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="tcs-sim", description=__doc__.splitlines()[0])
    p.add_argument("--config", default=str(DEFAULT), help="hardware file (default: %(default)s)")
    p.add_argument("--can-port", type=int, help="socketcand port (overrides [can] port; 0 = any)")
    p.add_argument("--log-level", default="INFO", choices=["DEBUG", "INFO", "WARNING", "ERROR"])
    p.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    args = p.parse_args(argv)
    setup_logging(args.log_level)
    try:
        config = load_config(args.config)
        from tcs.sim.cabinet import SimCabinet

        cabinet = SimCabinet(config, port=args.can_port)
    except ConfigErrors as exc:
        print(f"tcs-sim: the hardware file is not valid:\n{exc}", file=sys.stderr)
        return 2

    async def run(stop) -> None:
        await cabinet.start()
        freeze_heap()
        where = f"socketcand port {cabinet.can_port}" if cabinet.socketcand is not None else \
            f"{config.can.interface} {config.can.channel}" if config.can is not None else "no drives"
        print(f"tcs-sim: ready ({where})", file=sys.stderr, flush=True)
        try:
            await stop.wait()
        finally:
            await cabinet.stop()
            thaw_heap()

    return run_until_signalled("tcs-sim", run)

if __name__ == "__main__":
    sys.exit(main())
