"""``tcs-commission``: commissioning of the drives of one hardware file, and pointing reports.

The tool talks to the drives **directly** through the CANopen driver (:mod:`tcs.drivers`), not
through a running ``tcs-server``: stop the service first (``systemctl stop tcs-server``). On a
``socketcan`` / ``socketcand`` bus it listens briefly and refuses (exit 3) when it hears
another master (SYNC frames, or a heartbeat with the TCS's node id); ``--force`` overrides.
On the in-process ``virtual`` bus nobody else can be there, so nothing is checked.

Usage::

    tcs-commission scan              [--nodes 1-127] [--pace 0.005] [--timeout 0.2]
    tcs-commission info   AXIS
    tcs-commission home   AXIS|all   [--keep-going]
    tcs-commission limits AXIS       [--speed V] [--margin M] [--backoff B]
                                     [--overtravel X | --search LO HI]
                                     [--side both|negative|positive] [--no-home] [--write]
    tcs-commission jog    AXIS ±DISTANCE [--speed V] [--home | --unreferenced]
    tcs-commission pointing [--dump FILE | --synthetic N | --guided STARS] [--out DIR]
                            [--terms IA,IE,...] [--fix TERM=ARCSEC]... [--no-plots]
                            [--true TERM=ARCSEC]... [--noise ARCSEC] [--seed N] [--count N]

    common options (after the subcommand): --config FILE (default hwconfig/sim.toml),
    --json, --simulate / --no-simulate, --force, --log-level LEVEL

AXIS is an ``[axes.<name>]`` name or a ``[drives.<name>]`` name, in any case (``AZ`` = ``az``);
``--version`` prints the version. Examples on the simulated
telescope (its drives are started in this process)::

    tcs-commission scan
    tcs-commission home all                     # ZD/DEC first, then AZ/HA, then the rest
    tcs-commission limits az --speed 2 --write  # find the switches, write min/max
    tcs-commission jog zd -- -5 --speed 1 --home  # or: jog zd -5 --home
    tcs-commission pointing --synthetic 60 --out /tmp/pm
    tcs-commission pointing --dump night.dump --fix TX=0 --out /tmp/pm

Subcommands (one module each):

* ``scan`` (:mod:`~tcs.commission.scan`) — paced SDO probe of 0x1000 on node ids 1..127
  (one request per 5 ms, not a burst), then identity 0x1018, NMT state (heartbeats heard),
  402 state, error register and error code of every answering node; each is matched with the
  configured drives (ok / wrong identity / not configured) and missing drives are listed.
* ``info AXIS`` (:mod:`~tcs.commission.info`) — the objects the driver configures at boot,
  read back beside the hardware file's values, and the live values. Read-only.
* ``home AXIS|all`` (:mod:`~tcs.commission.home`) — referencing with the driver's homing
  handshake and the per-axis time-out of the hardware file, progress on stderr (a bar fitted
  to the terminal's width, or a plain line every 10 s when stderr is no terminal), one result
  line per drive; ``all`` in the safe order.
* ``limits AXIS`` (:mod:`~tcs.commission.limits`) — slow CSP moves towards each limit
  switch (the drive faulting with 0x8612 or only showing the input 0x60FD: both handled —
  fault reset, back off), the switch positions, proposed software limits with ``--margin``,
  written to ``[axes.<name>] min/max`` and ``[drives.<name>] min/max_position`` only with
  ``--write``, comments and layout kept (tomlkit; :mod:`~tcs.commission.hwfile`).
* ``jog AXIS ±DISTANCE`` (:mod:`~tcs.commission.jog`) — a move refused beyond the software
  limits (the axis's inside the drive's). An unreferenced drive (its frame is arbitrary) only
  creeps ``creep_distance`` (default 1 % of its range) unless ``--home`` or ``--unreferenced``.
* ``pointing`` (:mod:`~tcs.commission.pointing`) — samples (a dump file, synthetic samples
  for the simulator, or a guided run with a star list), the fit, and a report directory:
  ``report.md``, ``model.json`` (coefficients with errors, correlations), ``pointing.model``,
  ``samples.dump`` and PNG residual plots (against azimuth and elevation, sky map; needs
  matplotlib, the ``commission`` extra, or ``--no-plots``).

Simulation: ``--simulate`` (default when ``[can]`` is ``virtual`` and the file has
``[simulation]``) starts the simulated drives in-process; on a file whose bus is real it moves
``[can]`` to a private virtual channel first. ``--no-simulate`` never starts them.

Output: text on stdout, errors on stderr; ``--json`` prints one JSON object with
``command``, ``ok``, ``exit_code``, ``error`` and the subcommand's details.

Exit codes (every subcommand):

====  =====================================================================================
0     done
1     the operation failed: homing failed or timed out, a limit switch not found, a move or
      the fit failed, a node with a wrong identity, the tool interrupted
2     usage or configuration error: bad options, unknown axis, invalid hardware file,
      a refused request (jog beyond the software limits), an unreadable dump
3     hardware not found / not responding: a configured drive missing or silent at boot,
      the CAN interface cannot be opened, another master on the bus
====  =====================================================================================

When a subcommand ends (or is interrupted) every drive it enabled is disabled, the cycle is
stopped, and each booted drive's heartbeat consumer (0x1016) is switched off so the drive
does not fault when this process goes away; the service configures it again at its boot.
"""

from tcs.commission.cli import main

__all__ = ["main"]
