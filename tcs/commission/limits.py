"""``tcs-commission limits AXIS``: find the hardware limit switches, propose software limits.

How it works
------------
1. The drive is booted with its software limits (0x607D and the driver's clamp) widened to
   the *search range*: the file's ``min_position``/``max_position`` extended by
   ``--overtravel`` (default 10 % of their span) on each side, or ``--search LO HI``. The
   switches protect the mechanics meanwhile — that is what they are for — so go slowly.
2. Unless ``--no-home``, the drive is referenced first (the limits must be in the frame the
   service uses; the service references at start too).
3. For each side (negative first): a slow jerk-limited CSP move (``--speed``, default a tenth
   of ``max_velocity``; :class:`~tcs.commission.motion.CspMover`) towards the end of the
   search range, with a watcher in the cycle thread that catches the switch the first cycle
   it shows: the digital input 0x60FD (limit bit of that side) **or** a drive fault with the
   OpenTCI number ``limit`` (0x8612 position limit, vendor limit codes). The position of that
   cycle is the switch position (accurate to about speed × SYNC period). **Only the input
   makes it a switch**: a limit fault is taken as the switch only when the drive, once
   stopped, shows that side's input active (drives fault on their switch, and the input
   often arrives a cycle after the EMCY); a limit fault with the input inactive is the drive's
   own position limit (0x607D, a vendor travel limit), reported as such and never proposed as
   a switch. A drive that stops on the input without faulting gets a quick stop of the
   profile; a drive that faulted gets a fault reset and is enabled again. Then it backs off
   the switch by ``--backoff`` (default ``--margin``) and must see the switch inactive again.
4. The proposal keeps ``--margin`` (user units, default 1) inside the switches for the axis
   limits (``[axes.<name>] min/max``) and half of it for the drive's own limits
   (``[drives.<name>] min_position/max_position``), which thus sit between the axis limits
   and the switches. With ``--write`` they are written to the hardware file with tomlkit
   (comments and layout kept), after validating the edited file. ``--write`` only ever
   *narrows* the file's limits: a proposed limit outside the file's present one (the file's
   limits already lie inside the switches) is kept as it is and said so, unless ``--force``
   is given — widening a software limit is a decision for the engineer, not a side effect.

A drive with a negative ``increments_per_unit`` has its switches the other way round: the
"negative" side here is always towards smaller user positions.

Exit codes: 0 every searched switch found (and written with ``--write``), 1 a switch not
found in the search range or the search failed (fault, time-out), 2 bad options, 3 the drive
does not answer.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from pathlib import Path

from tcs.axes.motion import SoftLimits
from tcs.drivers.drive import Mode
from tcs.errors import ErrorNumber

from tcs.commission import hwfile
from tcs.commission.common import CommissionError, ExitCode, Outcome, Target, fmt, resolve_target
from tcs.commission.home import home_group
from tcs.commission.jog import jog_speed
from tcs.commission.motion import CspMover, jog_dynamics
from tcs.commission.progress import ProgressBar
from tcs.commission.session import DriveSession, prepare_config

SIDES = ("negative", "positive")
#: s to wait, after a limit fault, for the input that makes it a switch
CONFIRM_TIMEOUT = 2.0


def add_parser(subparsers, parents) -> None:
    p = subparsers.add_parser("limits", parents=parents,
                              help="find the limit switches and propose/write software limits",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("axis", help="axis or drive name")
    p.add_argument("--speed", type=float, help="search speed, units/s (default: a tenth of max_velocity)")
    p.add_argument("--margin", type=float, default=1.0,
                   help="axis limits this far inside the switches, units (default 1; the drive's "
                        "limits at half of it)")
    p.add_argument("--backoff", type=float, help="distance to move off a switch (default: --margin)")
    p.add_argument("--overtravel", type=float,
                   help="search this far beyond the file's min/max_position (default: 10%% of the span)")
    p.add_argument("--search", type=float, nargs=2, metavar=("LO", "HI"),
                   help="search range (overrides --overtravel)")
    p.add_argument("--side", choices=("both", *SIDES), default="both", help="which switch(es) to find")
    p.add_argument("--no-home", action="store_true", help="do not reference the drive first")
    p.add_argument("--write", action="store_true",
                   help="write the proposed limits to the hardware file (comments kept); it only "
                        "narrows the file's limits, --force also widens them")


def search_range(target: Target, overtravel: float | None, search) -> tuple[float, float]:
    """The range the search may move in; CommissionError (exit 2) for a bad one."""
    lo, hi = sorted((target.section.min_position, target.section.max_position))
    if search is not None:
        a, b = search
        if not (math.isfinite(a) and math.isfinite(b) and a < b):
            raise CommissionError(f"--search {a:g} {b:g}: LO must be below HI", ExitCode.USAGE)
        return a, b
    extra = 0.1 * (hi - lo) if overtravel is None else overtravel
    if not (math.isfinite(extra) and extra >= 0):
        raise CommissionError(f"--overtravel {extra:g} must be >= 0", ExitCode.USAGE)
    return lo - extra, hi + extra


def switch_input(target: Target, side: str) -> str:
    """The DriveStatus attribute of the switch on ``side`` (user frame)."""
    flipped = target.section.increments_per_unit < 0
    negative = (side == "negative") != flipped
    return "limit_negative" if negative else "limit_positive"


def propose(negative: float | None, positive: float | None, margin: float) -> dict:
    """Axis limits ``margin`` inside the switches, drive limits at half the margin."""
    out: dict = {"axis": {}, "drive": {}}
    if negative is not None:
        out["axis"]["min"] = round(negative + margin, 4)
        out["drive"]["min_position"] = round(negative + margin / 2, 4)
    if positive is not None:
        out["axis"]["max"] = round(positive - margin, 4)
        out["drive"]["max_position"] = round(positive - margin / 2, 4)
    if "min" in out["axis"] and "max" in out["axis"] and out["axis"]["min"] >= out["axis"]["max"]:
        raise CommissionError(f"the switches at {negative:g} and {positive:g} leave no range "
                              f"inside a margin of {margin:g}")
    return out


def widening(values: dict, current: dict) -> list:
    """Keys whose proposed value lies outside the file's present one (a wider range)."""
    out = []
    for key, value in values.items():
        have = current.get(key)
        if have is None:
            continue
        lower = key[-1] in ("min", "min_position")
        if (value < have) if lower else (value > have):
            out.append(key)
    return out


class SwitchWatch:
    """Cycle-thread watcher: catches the first status showing the switch of one side.

    ``position`` is where the search stopped being free: the first cycle with the input of
    that side (``confirmed`` at once) or with a limit fault (``confirmed`` only once
    :meth:`confirm` sees the input: a limit fault alone may be the drive's own position
    limit, not a switch).
    """

    def __init__(self, attribute: str):
        self.attribute = attribute
        self.position: float | None = None
        self.detected_by: str | None = None
        self.confirmed = False
        self.fault_message: str | None = None

    def __call__(self, st) -> bool:
        if self.position is not None:
            return False
        if getattr(st, self.attribute):
            self.detected_by = "limit switch input (0x60FD)"
            self.confirmed = True
        elif st.fault is not None and st.fault.number == ErrorNumber.LIMIT:
            self.fault_message = st.fault.message
            self.detected_by = f"drive fault: {st.fault.message}"
        else:
            return False
        self.position = st.position
        return True

    def confirm(self, st) -> bool:
        """After the stop: a limit fault counts as the switch when the input shows now."""
        if not self.confirmed and self.position is not None and getattr(st, self.attribute):
            self.confirmed = True
            self.detected_by = (f"limit switch input (0x60FD), with the drive fault "
                                f"{self.fault_message}")
        return self.confirmed


def _move(session: DriveSession, mover: CspMover, name: str, destination: float, speed: float,
          bar: ProgressBar, label: str, stop_when=None) -> bool:
    """Move and wait (until done, or ``stop_when()``); False on time-out."""
    start = session.status(name).position
    seq = mover.move_to(destination)
    span = abs(destination - start) or 1.0
    timeout = 10.0 + 2.0 * abs(destination - start) / speed

    def tick():
        pos = session.status(name).position
        bar.update(label, 1 - abs(destination - pos) / span, fmt(pos, 3))

    return session.wait(lambda: (stop_when is not None and stop_when()) or mover.done(seq),
                        timeout, tick)


def search_side(session: DriveSession, target: Target, mover: CspMover, side: str,
                bound: float, backoff: float, speed: float, bar: ProgressBar) -> dict:
    """Find the switch of one side (see the module docstring, step 3)."""
    name = target.drive
    device = session.drive(name).device
    sign = -1.0 if side == "negative" else 1.0
    attribute = switch_input(target, side)
    result = {"side": side, "found": False, "position": None, "detected_by": None,
              "search_end": bound}
    if getattr(session.status(name), attribute):  # standing on it: off first, then search
        _move(session, mover, name, session.status(name).position - sign * backoff, speed, bar,
              f"{side} off")
        if getattr(session.status(name), attribute):
            raise CommissionError(f"{device}: still on the {side} limit switch after moving "
                                  f"{backoff:g} away: use a larger --backoff")
    watch = SwitchWatch(attribute)

    def search_over() -> bool:
        # A limit fault can reach the status (EMCY) before the next cycle's hook shows it to
        # the watch: leave that one to the watch, so it records where the switch was.
        fault = session.status(name).fault
        return watch.position is not None or (fault is not None
                                               and fault.number != ErrorNumber.LIMIT)

    mover.watch = watch
    try:
        ok = _move(session, mover, name, bound, speed, bar, side, stop_when=search_over)
    finally:
        mover.watch = None
    bar.close()
    st = session.status(name)
    if watch.position is None:
        if st.fault is not None:
            raise CommissionError(f"{side} limit search: {st.fault.message}")
        if not ok:
            raise CommissionError(f"{device}: {side} limit search did not end in time "
                                  f"(at {fmt(st.position)})")
        result["reached"] = st.position
        return result
    # Recover: let it come to rest (fault reaction or the watcher's quick stop), reset a fault.
    session.wait(lambda: session.status(name).fault is not None or (
        not mover.moving and abs(session.status(name).velocity) < 1e-9), 5.0)
    if session.status(name).fault is not None:
        session.wait(lambda: abs(session.status(name).velocity) < 1e-9, 5.0)
        # the input (TPDO, event driven) may come a cycle or two after the fault's EMCY
        session.wait(lambda: watch.confirm(session.status(name)), CONFIRM_TIMEOUT)
        if not watch.confirmed:
            result.update(stopped_by=watch.fault_message, stopped_at=watch.position)
            raise CommissionError(
                f"{device}: the {side} search stopped at {fmt(watch.position)} with "
                f"{watch.fault_message}, but the drive's {side} limit-switch input (0x60FD) is "
                "not active: that is a position limit of the drive (0x607D or its own travel "
                "limit), not a switch, so it is not proposed as one. Check the switch wiring "
                "and that 0x60FD is in the drive's TPDOs, or narrow the search (--search)")
        result["fault_reset"] = session.clear_faults([name])
    result.update(found=True, position=watch.position, detected_by=watch.detected_by)
    session.enable([name])
    _move(session, mover, name, watch.position - sign * backoff, speed, bar, f"{side} off")
    bar.close()
    if getattr(session.status(name), attribute):
        raise CommissionError(f"{device}: still on the {side} limit switch after backing off "
                              f"{backoff:g}: use a larger --backoff")
    return result


def shipped(path) -> bool:
    """Whether ``path`` is one of the hardware files shipped inside the package."""
    from tcs.resources import HWCONFIG_DIR

    try:
        return Path(path).resolve().is_relative_to(Path(HWCONFIG_DIR).resolve())
    except (OSError, ValueError):
        return False


def run(args, config) -> Outcome:
    out = Outcome("limits")
    target = resolve_target(config, args.axis)
    speed = jog_speed(target, args.speed)
    margin = args.margin
    backoff = args.backoff if args.backoff is not None else margin
    if not (math.isfinite(margin) and margin > 0 and math.isfinite(backoff) and backoff > 0):
        raise CommissionError("--margin and --backoff must be positive", ExitCode.USAGE)
    lo, hi = search_range(target, args.overtravel, args.search)
    sides = SIDES if args.side == "both" else (args.side,)
    source = config.source
    if args.write and shipped(source):
        raise CommissionError(
            f"{source} is a hardware file shipped with tcs (package data, replaced by every "
            f"upgrade): copy it (cp {source} tcs.toml) and give the copy with --config tcs.toml "
            "to write limits into it", ExitCode.USAGE)
    # the worst case, said before the search starts: the whole range once per side, and back
    worst = (hi - lo) * len(sides) / speed + 60.0
    out.data["worst_case_s"] = round(worst)
    print(f"tcs-commission limits: searching {' and '.join(sides)} between {fmt(lo)} and {fmt(hi)} at "
          f"{speed:g}/s: up to about {worst / 60:.0f} min (faster with --speed, narrower with --search)",
          file=sys.stderr, flush=True)
    config, simulate = prepare_config(config, args.simulate)
    name = target.drive
    widened = dataclasses.replace(target.section, min_position=lo, max_position=hi)
    bar = ProgressBar()  # stderr: a bar on a terminal, periodic plain lines elsewhere
    results: list[dict] = []
    out.data.update(drive=name, axis=target.axis, search_range=[lo, hi], speed=speed,
                    margin=margin, backoff=backoff, sides=results, referenced=not args.no_home)
    with DriveSession(config, simulate=simulate, drives={name: widened},
                      check_bus=not args.force) as session:
        session.boot([name])
        session.start()
        cleared = session.clear_faults([name])
        if cleared:
            out.lines.append(f"{target.label}: fault reset ({'; '.join(cleared)})")
        if not args.no_home:
            homed = home_group(session, [target], bar)[0]
            if homed["result"] != "done":
                raise CommissionError(f"homing before the limit search failed: {homed['error']}")
            out.lines.append(f"{target.label}: referenced, position {fmt(homed['position'])}")
        cyclic = getattr(session.drive(name), "cyclic_mode", None) or Mode.CSP
        if session.status(name).mode != cyclic:
            session.set_mode(name, cyclic)
        session.enable([name])
        mover = CspMover(session.drive(name), jog_dynamics(target, speed), SoftLimits(lo, hi),
                         config.can.sync_period)
        session.add_hook(mover)
        try:
            for side in sides:
                bound = lo if side == "negative" else hi
                try:
                    results.append(search_side(session, target, mover, side, bound, backoff,
                                               speed, bar))
                except CommissionError as exc:
                    results.append({"side": side, "found": False, "error": exc.message})
                    out.fail(exc.message)
                    break
            session.disable([name])
        finally:
            session.remove_hook(mover)
    found = {r["side"]: r["position"] for r in results if r.get("found")}
    for r in results:
        if r.get("found"):
            out.lines.append(f"{target.label}: {r['side']} limit switch at {fmt(r['position'])} "
                             f"({r['detected_by']})")
        elif "error" not in r:
            out.lines.append(f"{target.label}: NO {r['side']} limit switch up to {fmt(r['search_end'])}")
            out.fail(f"no {r['side']} limit switch between the start and {r['search_end']:g} "
                     "(widen the search with --overtravel or --search)")
    proposal = propose(found.get("negative"), found.get("positive"), margin)
    out.data["proposal"] = proposal
    out.data["current"] = {"axis": {"min": target.axis_section.min, "max": target.axis_section.max}
                           if target.axis_section else {},
                           "drive": {"min_position": target.section.min_position,
                                     "max_position": target.section.max_position}}
    if proposal["drive"]:
        keys = [f"drives.{name}.{k} = {v:g}" for k, v in proposal["drive"].items()]
        if target.axis:
            keys = [f"axes.{target.axis}.{k} = {v:g}" for k, v in proposal["axis"].items()] + keys
        out.lines.append(f"proposed (margin {margin:g}): " + ", ".join(keys))
    out.data["written"] = None
    values = {("drives", name, k): v for k, v in proposal["drive"].items()}
    if target.axis:
        values.update({("axes", target.axis, k): v for k, v in proposal["axis"].items()})
    current = {("drives", name, k): v for k, v in out.data["current"]["drive"].items()}
    current.update({("axes", target.axis, k): v for k, v in out.data["current"]["axis"].items()})
    wider = widening(values, current)
    out.data["widening"] = [{"key": ".".join(key), "file": current[key], "proposed": values[key]}
                            for key in wider]
    for key in wider:
        out.lines.append(f"{'.'.join(key)}: the proposal {values[key]:g} lies outside the file's "
                         f"{current[key]:g} (the file's limit is already inside the switch): "
                         + ("widened (--force)" if args.force else "kept; --force widens it"))
    if not args.force:
        values = {key: v for key, v in values.items() if key not in wider}
    if args.write:
        if out.exit_code != ExitCode.OK or not proposal["drive"]:
            out.lines.append("not written: the search did not find every switch it looked for")
        elif not values:
            out.lines.append("nothing written: every limit of the file already lies inside the "
                             "proposal (--force widens them to it)")
        else:
            hwfile.update_values(source, values)
            out.data["written"] = str(source)
            out.data["written_keys"] = [".".join(key) for key in values]
            out.lines.append(f"written to {source}: " + ", ".join(
                f"{'.'.join(key)} = {v:g}" for key, v in values.items()))
    elif proposal["drive"]:
        out.lines.append("(use --write to write them to the hardware file)")
    return out
