"""``tcs-commission jog AXIS ±DISTANCE``: move one drive by a distance, inside its limits.

The target (actual position + DISTANCE, user units) must lie inside the software limits —
the ``[axes.<name>]`` min/max of the axis that uses the drive, inside the drive's own
``min_position``/``max_position`` — or the jog is refused before anything moves (exit 2).
Drives whose ``default_mode`` is ``csp`` are moved by a jerk-limited profile streamed in CSP
(:class:`~tcs.commission.motion.CspMover`); ``pp`` drives by a profile-position move of the
driver (``move_to``). Speed: ``--speed`` (default a tenth of the drive's ``max_velocity``).

A drive that is not referenced (not homed in this run, no ``absolute`` encoder) counts its
position in an arbitrary frame (where it was switched on), so the software limits cannot be
checked: it only *creeps*, at most ``creep_distance`` of the drive (default
:data:`DEFAULT_CREEP_FRACTION` of its range ``max_position - min_position``, e.g. 5.44 deg of a
544 deg azimuth), and the limits are not applied. ``--home`` references it first with the
configured method (then any distance inside the limits); ``--unreferenced`` jogs it further
anyway, with the limits counted in the current frame — only when you know where the axis
stands (the limit switches are then the protection).

Exit codes: 0 moved, 1 the move failed, 2 refused (outside the limits, unreferenced beyond the
creep distance, bad speed),
3 the drive does not answer.
"""

from __future__ import annotations

import math

from tcs.axes.motion import SoftLimits
from tcs.drivers.drive import Mode, Progress

from tcs.commission.common import (CommissionError, ExitCode, Outcome, fmt, resolve_target,
                                   software_limits)
from tcs.commission.home import home_group
from tcs.commission.motion import CspMover, jog_dynamics
from tcs.commission.progress import ProgressBar
from tcs.commission.session import DriveSession, prepare_config

DEFAULT_SPEED_FRACTION = 0.1
DEFAULT_CREEP_FRACTION = 0.01  # of the drive's range: how far an unreferenced drive may creep


def add_parser(subparsers, parents) -> None:
    p = subparsers.add_parser("jog", parents=parents, help="move a drive by ±DISTANCE within its limits",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("axis", help="axis or drive name")
    p.add_argument("distance", type=float, help="signed distance in user units (degrees, mm)")
    p.add_argument("--speed", type=float, help="units/s (default: a tenth of the drive's max_velocity)")
    p.add_argument("--home", action="store_true", help="reference the drive first")
    p.add_argument("--unreferenced", action="store_true",
                   help="jog an unreferenced drive further than its creep distance (limits are then "
                        "counted in its arbitrary current frame)")


def jog_speed(target, speed: float | None) -> float:
    """The speed to use; CommissionError (exit 2) when outside (0, max_velocity]."""
    vmax = target.section.max_velocity
    if speed is None:
        return DEFAULT_SPEED_FRACTION * vmax
    if not (math.isfinite(speed) and 0 < speed <= vmax):
        raise CommissionError(f"--speed {speed:g} is not in (0, {vmax:g}] (max_velocity of drive "
                              f"{target.drive})", ExitCode.USAGE)
    return speed


def creep_distance(target) -> float:
    """How far an unreferenced drive may jog: ``creep_distance`` or 1 % of its range."""
    section = target.section
    if section.creep_distance is not None:
        return section.creep_distance
    return DEFAULT_CREEP_FRACTION * abs(section.max_position - section.min_position)


def move_csp(session: DriveSession, target, destination: float, speed: float,
             limits: tuple[float, float], bar: ProgressBar) -> float:
    """Move one enabled drive to ``destination`` in CSP; returns the position reached."""
    name = target.drive
    cyclic = getattr(session.drive(name), "cyclic_mode", None) or Mode.CSP
    if session.status(name).mode != cyclic:
        session.set_mode(name, cyclic)
    session.enable([name])
    start = session.status(name).position
    lo, hi = min(limits[0], start), max(limits[1], start)
    mover = CspMover(session.drive(name), jog_dynamics(target, speed), SoftLimits(lo, hi),
                     session.config.can.sync_period)
    session.add_hook(mover)
    try:
        seq = mover.move_to(destination)
        span = abs(destination - start) or 1.0
        timeout = 10.0 + 2.0 * abs(destination - start) / speed
        ok = session.wait(lambda: mover.done(seq), timeout, lambda: bar.update(
            name, 1 - abs(destination - session.status(name).position) / span,
            fmt(session.status(name).position, 3)))
        bar.close()
        st = session.status(name)
        if mover.error is not None:
            raise CommissionError(mover.error.message)
        if st.fault is not None:
            raise CommissionError(st.fault.message)
        if not ok or not st.enabled:
            raise CommissionError(f"{session.drive(name).device}: move did not end within "
                                  f"{timeout:.0f} s (state {st.state.value})")
        session.wait(lambda: abs(session.status(name).velocity) < 1e-9, 2.0)
        return session.status(name).position
    finally:
        session.remove_hook(mover)


def move_pp(session: DriveSession, target, destination: float, speed: float,
            bar: ProgressBar) -> float:
    """Move one drive with the driver's profile-position move; returns the position reached."""
    name = target.drive
    session.enable([name])
    drive = session.drive(name)
    start = session.status(name).position
    drive.move_to(destination, speed)
    timeout = 10.0 + 2.0 * abs(destination - start) / speed
    span = abs(destination - start) or 1.0
    session.wait(lambda: session.status(name).move in (Progress.RUNNING, Progress.DONE,
                                                        Progress.FAILED), 2.0)
    ok = session.wait(lambda: session.status(name).move is not Progress.RUNNING, timeout,
                      lambda: bar.update(name, 1 - abs(destination - session.status(name).position)
                                         / span, fmt(session.status(name).position, 3)))
    bar.close()
    st = session.status(name)
    if st.move is not Progress.DONE:
        err = st.request_error or st.fault
        raise CommissionError(err.message if err else f"{drive.device}: move did not end within "
                                                      f"{timeout:.0f} s")
    return st.position


def run(args, config) -> Outcome:
    out = Outcome("jog")
    target = resolve_target(config, args.axis)
    speed = jog_speed(target, args.speed)
    if not math.isfinite(args.distance):
        raise CommissionError("DISTANCE must be a finite number", ExitCode.USAGE)
    config, simulate = prepare_config(config, args.simulate)
    lo, hi = software_limits(target)
    name = target.drive
    bar = ProgressBar()  # stderr: a bar on a terminal, periodic plain lines elsewhere
    out.data.update(drive=name, axis=target.axis, distance=args.distance, speed=speed,
                    limits=[lo, hi])
    with DriveSession(config, simulate=simulate, check_bus=not args.force) as session:
        session.boot([name])
        session.start()
        cleared = session.clear_faults([name])
        if cleared:
            out.lines.append(f"{target.label}: fault reset ({'; '.join(cleared)})")
        referenced = session.status(name).homed  # an absolute encoder is referenced by configuration
        if args.home:
            result = home_group(session, [target], bar)[0]
            if result["result"] != "done":
                raise CommissionError(f"homing failed: {result['error']}")
            referenced = True
        start = session.status(name).position
        destination = start + args.distance
        creep = creep_distance(target)
        out.data.update(start=start, target=destination, referenced=referenced, creep_distance=creep)
        limits = (lo, hi)
        if not referenced and not args.unreferenced:
            if abs(args.distance) > creep:
                raise CommissionError(
                    f"refused: {target.label} is not referenced (not homed in this run, no absolute "
                    f"encoder): its position {start:.4f} is counted from where it was switched on, so "
                    f"the software limits [{lo:g}, {hi:g}] cannot be checked and it may only creep "
                    f"{creep:g} (creep_distance): reference it with --home, or give --unreferenced "
                    f"to jog {args.distance:+g} with the limits counted in that frame",
                    ExitCode.USAGE, out.data)
            limits = (start - creep, start + creep)  # the limits mean nothing in this frame
        elif not lo <= destination <= hi:
            raise CommissionError(
                f"refused: {target.label} target {destination:.4f} (from {start:.4f} by "
                f"{args.distance:+g}) is outside the software limits [{lo:g}, {hi:g}]",
                ExitCode.USAGE, out.data)
        if target.section.default_mode == "pp":
            reached = move_pp(session, target, destination, speed, bar)
        else:
            reached = move_csp(session, target, destination, speed, limits, bar)
        session.disable([name])
    out.data["position"] = reached
    out.lines.append(f"{target.label}: moved {args.distance:+g} from {fmt(start)} to {fmt(reached)} "
                     f"(target {fmt(destination)}, speed {speed:g}/s)")
    if not referenced:
        out.lines.append("  note: not referenced: positions are in the drive's current frame "
                         + ("(limits counted in it: --unreferenced)" if args.unreferenced else
                            f"(a creep of at most {creep:g}; use --home to reference first)"))
    return out
