"""What every subcommand of ``tcs-commission`` shares: exit codes, outcomes, targets.

* :class:`ExitCode` — the process status scripts can rely on (0 ok, 1 operation failed,
  2 usage or configuration error, 3 hardware not found / not responding).
* :class:`CommissionError` — raised by a subcommand to end with a message and an exit code;
  :func:`exit_code_of` maps any other :class:`~tcs.errors.TcsError` (a lost node is 3, a
  refused request 2, anything else 1).
* :class:`Outcome` — what a subcommand returns: text lines for people, a JSON-able dict for
  scripts (``--json``), and the exit code. The CLI prints it; subcommands never print.
* :func:`resolve_target` — turns the AXIS argument (an ``[axes.<name>]`` or a
  ``[drives.<name>]``) into the drive, its table, and the axis bound to it, if any;
  :func:`software_limits` is the range a jog may use there.

Pure: no I/O, no bus.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import Any

from tcs.config.axes import AxisSection
from tcs.config.can import DriveSection
from tcs.errors import CommunicationError, ConfigErrors, RequestRefused, TcsError


class ExitCode(enum.IntEnum):
    """Process exit status of ``tcs-commission`` (documented in the package docstring)."""

    OK = 0
    FAILED = 1        # the operation ran and failed (homing timeout, no limit switch found …)
    USAGE = 2         # bad arguments or hardware file, a refused request (jog beyond a limit)
    HARDWARE = 3      # hardware not found / not responding (no node, no answer, bus busy)


class CommissionError(TcsError):
    """End a subcommand with ``message`` and ``exit_code``; ``data`` goes into the JSON."""

    def __init__(self, message: str, exit_code: int = ExitCode.FAILED, data: dict | None = None):
        super().__init__(message)
        self.exit_code = int(exit_code)
        self.data = dict(data or {})


def exit_code_of(error: BaseException) -> int:
    """The exit code for an error that ended a subcommand."""
    if isinstance(error, CommissionError):
        return error.exit_code
    if isinstance(error, ConfigErrors):
        return ExitCode.USAGE
    if isinstance(error, CommunicationError):
        return ExitCode.HARDWARE
    if isinstance(error, RequestRefused):
        return ExitCode.USAGE
    return ExitCode.FAILED


@dataclass
class Outcome:
    """Result of one subcommand.

    Attributes
    ----------
    command : the subcommand's name.
    exit_code : see :class:`ExitCode`.
    data : JSON-able details (the ``--json`` output adds ``command``, ``ok``, ``exit_code``,
        ``error``).
    lines : the human-readable report.
    error : one-line reason when ``exit_code`` is not 0.
    """

    command: str
    exit_code: int = ExitCode.OK
    data: dict[str, Any] = field(default_factory=dict)
    lines: list[str] = field(default_factory=list)
    error: str | None = None

    def fail(self, message: str, exit_code: int = ExitCode.FAILED) -> Outcome:
        """Record a failure: the message of the highest exit code (the first among equals)
        is kept as ``error``."""
        if self.error is None or exit_code > self.exit_code:
            self.error = message
            self.exit_code = int(exit_code)
        return self

    def as_json(self) -> dict[str, Any]:
        return {"command": self.command, "ok": self.exit_code == ExitCode.OK,
                "exit_code": int(self.exit_code), "error": self.error, **self.data}


@dataclass(frozen=True)
class Target:
    """One drive the AXIS argument named, with the axis that uses it (if any)."""

    drive: str
    section: DriveSection
    axis: str | None = None
    axis_section: AxisSection | None = None

    @property
    def label(self) -> str:
        if self.axis is None or self.axis == self.drive:
            return self.drive
        return f"{self.axis} (drive {self.drive})"

    @property
    def module(self) -> str | None:
        return self.axis_section.module if self.axis_section is not None else None


def resolve_target(config, name: str) -> Target:
    """The drive an AXIS argument names: an axis name first, then a drive name.

    Raises
    ------
    CommissionError
        (exit 2) neither an axis nor a drive of the hardware file; the message lists both.
    """
    axes = dict(config.axes)
    drives = dict(config.drives)
    if name not in axes and name not in drives:  # AZ, Az: names are case-insensitive
        folded = {n.casefold(): n for n in (*drives, *axes)}  # an axis wins over a drive
        name = folded.get(name.casefold(), name)
    if name in axes:
        axis = axes[name]
        return Target(axis.drive, drives[axis.drive], name, axis)
    if name in drives:
        for axis_name, axis in axes.items():
            if axis.drive == name:
                return Target(name, drives[name], axis_name, axis)
        return Target(name, drives[name])
    raise CommissionError(
        f"{name!r} is neither an axis nor a drive of {config.source} (axes: "
        f"{', '.join(axes) or 'none'}; drives: {', '.join(drives) or 'none'})", ExitCode.USAGE)


def all_targets(config) -> list[Target]:
    """Every configured drive as a target, in file order."""
    return [resolve_target(config, name) for name in config.drives]


def software_limits(target: Target) -> tuple[float, float]:
    """The range motion of this drive must stay in: the axis limits inside the drive's own."""
    lo = min(target.section.min_position, target.section.max_position)
    hi = max(target.section.min_position, target.section.max_position)
    if target.axis_section is not None:
        lo = max(lo, target.axis_section.min)
        hi = min(hi, target.axis_section.max)
    return lo, hi


def fmt(value: float | None, digits: int = 4) -> str:
    """A position for people: fixed decimals, ``-`` for None."""
    return "-" if value is None else f"{value:.{digits}f}"
