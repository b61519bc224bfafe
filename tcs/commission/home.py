"""``tcs-commission home AXIS|all``: reference drives with the driver's homing handshake.

How it works
------------
The drives are booted, faults found at start are reset (running the tool is the operator's
explicit request), and each group is enabled, told ``start_homing()`` and watched: the
driver's handshake (docs/cia402.md "Homing") ends in done or failed, with the per-axis
``[drives.<name>] homing.timeout`` of the hardware file; this module adds only a wall-clock
guard a little longer than that. A progress bar (stderr, terminals only) shows each drive's
homing fraction and position. The group's drives are disabled when it ends.

``all`` references in a safe order: the drives of ZD / DEC axes first (the tube comes to a
known place before anything turns it), then AZ / HA, then every other drive together.
A group that fails (or whose drive did not boot) ends the run; later groups are skipped.

Exit codes: 0 every drive referenced, 1 a homing failed (time-out, homing error, fault),
3 a drive did not answer at boot.
"""

from __future__ import annotations

import time

from tcs.drivers.drive import Progress

from tcs.commission.common import (CommissionError, ExitCode, Outcome, Target, all_targets, fmt,
                                   resolve_target)
from tcs.commission.progress import ProgressBar
from tcs.commission.session import DriveSession, prepare_config

#: Extra wall-clock time beyond the drive's homing time-out (enable, mode switch, handshakes).
GUARD = 10.0
SAFE_ORDER = (("ZD", "DEC"), ("AZ", "HA"))


def add_parser(subparsers, parents) -> None:
    p = subparsers.add_parser("home", parents=parents, help="reference drives (homing)",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("axis", help="axis or drive name, or 'all'")
    p.add_argument("--keep-going", action="store_true",
                   help="with 'all': go on with later groups after a failure")


def homing_groups(targets: list[Target]) -> list[list[Target]]:
    """The targets in the safe order: ZD/DEC, then AZ/HA, then the rest (empty groups dropped)."""
    groups: list[list[Target]] = [[] for _ in range(len(SAFE_ORDER) + 1)]
    for t in targets:
        for i, modules in enumerate(SAFE_ORDER):
            if t.module in modules:
                groups[i].append(t)
                break
        else:
            groups[-1].append(t)
    return [g for g in groups if g]


def home_group(session: DriveSession, group: list[Target], bar: ProgressBar) -> list[dict]:
    """Home the drives of one group together; one result dict per drive (never raises for a
    homing failure: that is a result)."""
    names = [t.drive for t in group]
    results = {t.drive: {"drive": t.drive, "axis": t.axis, "method": t.section.homing.method,
                         "timeout": t.section.homing.timeout, "result": "failed",
                         "seconds": 0.0, "position": None, "error": None} for t in group}
    start = time.monotonic()
    try:
        session.clear_faults(names)
        session.enable(names)
    except CommissionError as exc:
        for r in results.values():
            r["error"] = exc.message
        return list(results.values())
    for name in names:
        session.drive(name).start_homing()
    sections = {t.drive: t.section for t in group}
    ended: dict[str, float] = {}

    def tick() -> None:
        now = time.monotonic()
        for name in names:
            if name in ended:
                continue
            st = session.status(name)
            # Booted in this process, so no earlier run: DONE / FAILED are this run's end.
            finished = st.homing in (Progress.DONE, Progress.FAILED)
            guard = now - start > sections[name].homing.timeout + GUARD
            if finished or guard:
                ended[name] = now
                r = results[name]
                r["seconds"] = round(now - start, 3)
                r["position"] = st.position
                if st.homing is Progress.DONE and st.homed:
                    r["result"] = "done"
                else:
                    err = st.request_error or st.fault
                    r["error"] = err.message if err is not None else (
                        f"homing did not end within {sections[name].homing.timeout + GUARD:g} s")
            bar.update(name, 1.0 if name in ended else st.homing_progress, fmt(st.position, 3))

    session.wait(lambda: len(ended) == len(names), max(s.homing.timeout for s in sections.values())
                 + GUARD + 1.0, tick)
    tick()
    bar.close()
    session.disable(names)
    return list(results.values())


def run(args, config) -> Outcome:
    out = Outcome("home")
    config, simulate = prepare_config(config, args.simulate)
    targets = all_targets(config) if args.axis.lower() == "all" else [resolve_target(config, args.axis)]
    groups = homing_groups(targets)
    out.data["order"] = [[t.drive for t in g] for g in groups]
    results: list[dict] = []
    out.data["drives"] = results
    bar = ProgressBar()  # stderr: a bar on a terminal, periodic plain lines elsewhere
    with DriveSession(config, simulate=simulate, check_bus=not args.force) as session:
        boot_error: CommissionError | None = None
        try:
            session.boot([t.drive for t in targets])
        except CommissionError as exc:
            boot_error = exc  # the drives that booted may still be referenced, in order
        session.start()
        stop = False
        for group in groups:
            if stop:
                results.extend({"drive": t.drive, "axis": t.axis, "result": "skipped",
                                "error": "an earlier group failed"} for t in group)
                continue
            runnable = [t for t in group if t.drive in session.booted]
            for t in group:
                if t.drive not in session.booted:
                    results.append({"drive": t.drive, "axis": t.axis, "result": "failed",
                                    "error": boot_error.data.get("boot_failures", {}).get(
                                        t.drive, "not booted") if boot_error else "not booted"})
            if runnable:
                results.extend(home_group(session, runnable, bar))
            if any(r["result"] != "done" for r in results) and not args.keep_going:
                stop = True
    for r in results:
        label = r["drive"] if not r.get("axis") or r["axis"] == r["drive"] else f"{r['axis']} ({r['drive']})"
        if r["result"] == "done":
            out.lines.append(f"{label}: referenced (method {r['method']}) in {r['seconds']:.1f} s, "
                             f"position {fmt(r['position'])}")
        elif r["result"] == "skipped":
            out.lines.append(f"{label}: skipped ({r['error']})")
        else:
            out.lines.append(f"{label}: homing FAILED: {r['error']}")
    failed = [r for r in results if r["result"] != "done"]
    if boot_error is not None:
        out.fail(boot_error.message, boot_error.exit_code)
    if failed:
        first = next((r for r in failed if r["result"] == "failed"), failed[0])
        out.fail(f"{first['drive']}: {first['error']}", ExitCode.FAILED)
    return out
