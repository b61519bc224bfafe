"""What a drive's EDS allows, checked before anything talks to the bus.

Real object dictionaries differ: objects the boot writes may be absent (0x1016, 0x607D,
0x6066, homing objects …), restricted (read-only, ``HighLimit``), not PDO-mappable (0x603F),
and modes missing from 0x6502. Every SDO access of the boot goes through one rule,
:func:`verdict`, fed by the drive's own EDS (``canopen.import_od``):

* the object exists: write it if it is writable and the value lies within the EDS limits
  (and the data type's range);
* it is absent (or read-only and already holding the value): an **optional** object
  (:data:`tcs.drivers.eds.OPTIONAL`) is skipped — logged once at INFO, naming the drive,
  the object and what is lost; a mandatory one is an error naming the drive and what the
  axis cannot do without it;
* a value outside the limits is a configuration error naming the hardware file, the key,
  the object and the allowed range — at start, never as an SDO abort halfway through a boot.

:func:`check_drive` runs that rule over the boot's whole configuration
(:func:`tcs.drivers.boot.configuration`), the PDO mapping (:func:`tcs.drivers.pdo.eds_mapping`),
the ``[drives.<name>.sdo]`` raw writes and the modes of 0x6502; :func:`check_config` does it
for every drive of a hardware file (``load_config`` and :class:`~tcs.drivers.can_system.CanDrives`
call it). The boot (:func:`tcs.drivers.boot.boot_node`) uses :func:`usable_writes` — the same
rule — so what was validated is what is written. The rule itself and the EDS loading live in
:mod:`tcs.drivers.eds`, below the boot, the PDO mapping and this check.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace

import canopen
from canopen import objectdictionary as odmod

from tcs.config.can import CanSection, DriveSection
from tcs.errors import ConfigError, HardwareError

# what the boot and others import from here too (defined in tcs.drivers.eds, below the boot)
from tcs.drivers.eds import (  # noqa: F401
    CYCLIC_PREFERENCE, HOMING_OBJECTS, LOST, MODE_BITS, MODE_KEYS, MODE_NAMES, MODE_SHORT,
    NAMES, OPTIONAL, SIM_EDS, ModeChoice, Verdict, decode_modes, default_value,
    eds_path, is_optional, limits, load_od, modes_text, object_name, offers,
    range_value, raw_writes, supported_modes, usable_writes, value_format, variable, verdict)
from tcs.drivers.mode_choice import choose_mode, drive_mode, mapping_problem  # noqa: F401

log = logging.getLogger(__name__)

# ----------------------------------------------------------------------------------------------
# start-up check of the configuration

#: The hardware-file key behind each boot write, and the unit its drive value is in.
KEYS: dict[tuple[int, int], tuple[str, str]] = {
    (0x1017, 0): ("heartbeat_period", "ms"),
    (0x1016, 1): ("heartbeat_consumer_timeout", "ms"),
    (0x1006, 0): ("can.sync_period", "µs"),
    (0x60C2, 1): ("can.sync_period", ""),
    (0x60C2, 2): ("can.sync_period", ""),
    (0x607D, 1): ("min_position", "position"),
    (0x607D, 2): ("max_position", "position"),
    (0x6065, 0): ("following_error_window", "position"),
    (0x6066, 0): ("following_error_timeout", "ms"),
    (0x607F, 0): ("max_velocity", "velocity"),
    (0x6081, 0): ("max_velocity", "velocity"),
    (0x6083, 0): ("max_acceleration", "acceleration"),
    (0x6084, 0): ("max_acceleration", "acceleration"),
    (0x6085, 0): ("quick_stop_deceleration", "acceleration"),
    (0x6098, 0): ("homing.method", ""),
    (0x6099, 1): ("homing.speed_switch", "velocity"),
    (0x6099, 2): ("homing.speed_zero", "velocity"),
    (0x609A, 0): ("homing.acceleration", "acceleration"),
    (0x607C, 0): ("homing.offset", "position"),
    (0x60C0, 0): ("mode", ""),
    (0x6007, 0): ("abort_connection_option", ""),
    (0x605A, 0): ("quick_stop_option", ""),
    (0x605C, 0): ("disable_operation_option", ""),
    (0x605E, 0): ("fault_reaction_option", ""),
}

#: What the axis loses without a mandatory object (for the error text).
NEEDED_FOR = {
    0x1017: "the TCS cannot watch the drive (heartbeat producer)",
    0x6040: "the axis cannot be commanded (controlword)",
    0x6041: "the axis state cannot be read (statusword)",
    0x6060: "the axis cannot switch modes (CSP, homing, profile moves)",
    0x6061: "the mode of operation cannot be confirmed",
    0x6064: "the axis position cannot be read",
    0x607A: "the axis cannot be given setpoints (target position)",
    0x60C1: "the axis cannot be given IP setpoints (interpolation data record)",
    0x60FF: "the axis cannot be given CSV velocity commands (target velocity)",
    0x6081: "profile moves (discrete axes) have no speed",
    0x6083: "profile moves (discrete axes) have no acceleration",
    0x6098: "the axis cannot be referenced by a homing run (set absolute = true for an "
            "absolute encoder)",
}


def _user_range(lo, hi, kind: str, section: DriveSection) -> str:
    scale = {"position": abs(section.increments_per_unit), "velocity": abs(section.velocity_scale),
             "acceleration": section.acceleration_scale}.get(kind)
    if scale:
        unit = {"position": "units", "velocity": "units/s", "acceleration": "units/s²"}[kind]
        a = "" if lo is None else f"{lo / scale:g}"
        b = "" if hi is None else f"{hi / scale:g}"
        return f" (= {a}..{b} {unit})"
    if kind == "ms":
        a = "" if lo is None else f"{lo / 1000:g}"
        b = "" if hi is None else f"{hi / 1000:g}"
        return f" (= {a}..{b} s)"
    return ""


@dataclass
class DriveReport:
    """The outcome of :func:`check_drive` for one drive."""

    problems: list[ConfigError] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)      # optional objects skipped (INFO)
    warnings: list[str] = field(default_factory=list)   # loud: e.g. no heartbeat consumer
    conditions: list[tuple[str, str]] = field(default_factory=list)  # axis WARNING conditions
    mapping: dict[str, tuple[int, ...]] = field(default_factory=dict)
    layouts: dict = field(default_factory=dict)  # name -> tcs.drivers.pdo.PdoLayout
    hand_written: bool = False  # the layout is [drives.x] pdo
    has_error_code: bool = True
    mode: ModeChoice | None = None


def object_label(index: int, sub: int = 0) -> str:
    name = object_name(index)
    return f"0x{index:04X}:{sub}" + (f" ({name})" if name else "")


def check_drive(name: str, section: DriveSection, can: CanSection, od: canopen.ObjectDictionary,
                file: str, eds_name: str = "EDS") -> DriveReport:
    """Check one drive's configuration against its EDS (nothing is sent)."""
    from tcs.drivers.boot import configuration
    from tcs.drivers.pdo import plan_pdos

    report = DriveReport()
    device = f"drive {name} (node {section.node_id})"
    prefix = f"drives.{name}"

    def problem(key: str, text: str) -> None:
        report.problems.append(ConfigError(file, key, f"{device}: {text}"))

    # -- the mode of operation (0x6502; optional on many drives: then CSP is assumed) -----------
    choice = report.mode = choose_mode(section, od, eds_name)
    if choice.problem is not None:
        problem(f"{prefix}.mode", choice.problem)
    if section.default_mode == "pp" and not offers(choice.offered, "pp"):
        problem(f"{prefix}.default_mode",
                f"{modes_text(choice.offered, eds_name)} has no profile position (PP), the "
                f"default_mode configured; remedy: default_mode = 'csp' (boot in the drive's "
                f"streaming mode)")
    # -- identity: each field the hardware file pins is read from 0x1018 at boot (a field the
    # EDS lacks cannot be: said loudly, the others are checked) -------------------------------
    for field_name, sub in (("vendor", 1), ("product", 2), ("revision", 3), ("serial", 4)):
        if getattr(section.identity, field_name) is not None and variable(od, 0x1018, sub) is None:
            report.warnings.append(
                f"{device}: identity {field_name} is not checked at boot: the EDS ({eds_name}) "
                f"has no 0x1018:{sub}; leave {field_name} out of identity to silence this")
    # -- mandatory objects the axis cannot work without ---------------------------------------
    from tcs.config.can import SETPOINT_OBJECT
    mandatory = [0x6040, 0x6041, 0x6060, 0x6061, 0x6064, SETPOINT_OBJECT[choice.mode], 0x1017]
    if choice.mode == "pp" or section.profile_moves:
        mandatory += [0x6081, 0x6083]
    if not section.absolute:
        mandatory.append(0x6098)
    for index in mandatory:
        if od.get(index) is None:
            remedy = (" — set absolute = true if the axis is referenced by configuration"
                      if index == 0x6098 else " — this drive cannot run the axis")
            problem(f"{prefix}.eds", f"the EDS ({eds_name}) has no {object_label(index)}: "
                                     f"{NEEDED_FOR.get(index, 'the axis needs it')}{remedy}")
    # -- the configuration writes ---------------------------------------------------------------
    try:
        writes = configuration(section, can, device, choice.number)
    except HardwareError as exc:
        problem(prefix, exc.message)
        writes = []
    for index, sub, _fmt, value in writes:
        if section.absolute and index in HOMING_OBJECTS:
            continue
        optional = is_optional(index, sub, section)
        v = verdict(od, index, sub, value, optional)
        key, kind = KEYS.get((index, sub), ("", ""))
        full_key = key if key.startswith("can.") else (f"{prefix}.{key}" if key else prefix)
        if v.action == "skip" and variable(od, index, sub) is not None:
            lost = LOST.get(index, "left as the drive has it")
            text = f"{device}: {object_label(index, sub)} skipped: {v.why}; {lost}"
            (report.warnings if index == 0x1016 else report.notes).append(text)
        elif v.action == "error":
            var = variable(od, index, sub)
            if var is None:
                if index not in mandatory:  # (mandatory absences are reported above)
                    problem(full_key, f"{v.why} ({eds_name}): {NEEDED_FOR.get(index, 'the boot needs it')}")
            elif not var.writable:
                problem(full_key, f"{object_label(index, sub)}: {v.why} ({eds_name}); configure "
                                  f"{key or 'it'} to match")
            else:
                lo, hi = limits(var)
                checked = range_value(var, value)
                if checked != value:  # 0x1016: the time part, node id in bits 16-23
                    value = f"{checked} (time part; node id {value >> 16 & 0xFF} in bits 16-23)"
                problem(full_key, f"{object_label(index, sub)} = {value} is outside the range "
                                  f"the drive allows, {'' if lo is None else lo}.."
                                  f"{'' if hi is None else hi}{_user_range(lo, hi, kind, section)} "
                                  f"({eds_name})")
    # The skip verdicts of absent objects: one line each (verdict text says "has no").
    absent_seen = set()
    for index, sub, _fmt, value in writes:
        if section.absolute and index in HOMING_OBJECTS:
            continue
        if variable(od, index, sub) is None and is_optional(index, sub, section) and index not in absent_seen:
            absent_seen.add(index)
            lost = LOST.get(index, "left as the drive has it")
            text = f"{device}: the drive has no {object_label(index, sub)}: skipped; {lost}"
            (report.warnings if index == 0x1016 else report.notes).append(text)
    if variable(od, 0x1016, 1) is None:
        report.conditions.append(("no_heartbeat_consumer",
                                  f"drive {name} has no 0x1016 heartbeat consumer: it will not "
                                  f"notice a dead TCS"))
    # -- PDO mapping -----------------------------------------------------------------------------
    plan = plan_pdos(section, od, choice.mode, section.node_id)
    report.mapping = plan.mapping
    report.layouts = plan.layouts(section.node_id)
    report.hand_written = bool(section.pdo)
    if plan.problems:
        others = [k for k in (*CYCLIC_PREFERENCE, "pp") if k != choice.mode
                  and offers(choice.offered, k) and (k != "pp" or not choice.cyclic)
                  and mapping_problem(replace(section, pdo={}), od, k) is None]
        if section.pdo:
            remedy = ("remedy: leave pdo out (the TCS then lays the PDOs out from the EDS" +
                      (")" if mapping_problem(replace(section, pdo={}), od, choice.mode) is None
                       else f"), or mode = {' or '.join(repr(k) for k in others)}" if others
                       else "), or a drive or firmware whose PDOs take these objects"))
        elif others:
            remedy = f"remedy: mode = {' or '.join(repr(k) for k in others)} (its setpoint can be mapped)"
        else:
            remedy = ("remedy: none in the hardware file — a drive or firmware whose PDOs can carry "
                      "these objects (more mapping entries, PDOMapping=1)")
        for key, text in plan.problems:
            problem(f"{prefix}.{key}", f"mode {choice.mode.upper()}: {text} ({eds_name}); {remedy}")
    report.notes.extend(f"{device}: {n}" for n in plan.notes)
    code = variable(od, 0x603F, 0)
    report.has_error_code = code is not None and code.readable
    if not report.has_error_code:
        report.notes.append(f"{device}: the drive has no readable {object_label(0x603F)}: "
                            f"{LOST[0x603F]}")
    # -- modes (0x6502; optional on many drives: then nothing is checked) -------------------------
    modes = choice.offered
    if modes is not None:
        if not section.absolute and not modes >> MODE_BITS[6] & 1:
            problem(f"{prefix}.homing", f"0x6502 (supported drive modes 0x{modes:08X}, "
                                        f"{eds_name}) has no homing mode; remedy: absolute = "
                                        f"true when the encoder is absolute (referenced by "
                                        f"configuration)")
    if not section.absolute:
        supported = od.get(0x60E3)
        if supported is not None and not isinstance(supported, odmod.ODVariable):
            # Sub-entries without a DefaultValue are unknown, not absent: the list is checked
            # only when the EDS states every entry.
            values = [default_value(v) for s, v in supported.subindices.items() if s]
            methods = {m - 256 if m > 127 else m for m in values if isinstance(m, int)}
            known = all(isinstance(m, int) for m in values)
            if not known:
                report.notes.append(f"{device}: {object_label(0x60E3)} does not state every "
                                    f"supported homing method (entries without a default): "
                                    f"homing method {section.homing.method} not checked")
            elif methods and section.homing.method not in methods:
                problem(f"{prefix}.homing.method",
                        f"homing method {section.homing.method} is not among the drive's "
                        f"0x60E3 supported homing methods {sorted(m for m in methods if m is not None)} "
                        f"({eds_name})")
    # -- raw writes ------------------------------------------------------------------------------
    for key, index, sub, value in section.raw_writes:
        var = variable(od, index, sub)
        full_key = f"{prefix}.sdo.{key}"
        if var is None:
            problem(full_key, f"the drive has no object 0x{index:04X}:{sub} ({eds_name})")
        elif value_format(var) is None:
            problem(full_key, f"0x{index:04X}:{sub} is not a number object ({eds_name})")
        else:
            v = verdict(od, index, sub, value, optional=False)
            if not var.writable:
                problem(full_key, f"0x{index:04X}:{sub} is read-only ({eds_name})")
            elif v.action == "error":
                lo, hi = limits(var)
                problem(full_key, f"{value} is outside the range of 0x{index:04X}:{sub}, "
                                  f"{'' if lo is None else lo}..{'' if hi is None else hi} ({eds_name})")
    return report


def check_config(can: CanSection | None, drives: dict[str, DriveSection], axes: dict | None,
                 resolve, file: str) -> tuple[list[ConfigError], dict[str, DriveReport]]:
    """Every drive of a hardware file against its EDS; (problems, reports by drive)."""
    problems: list[ConfigError] = []
    reports: dict[str, DriveReport] = {}
    if can is None:
        return problems, reports
    for name, section in drives.items():
        path = eds_path(section, resolve)
        if not path.is_file():
            problems.append(ConfigError(file, f"drives.{name}.eds", f"EDS file {path} not found"))
            continue
        try:
            od = load_od(path, section.node_id)
        except Exception as exc:  # canopen raises many kinds on a broken file
            problems.append(ConfigError(file, f"drives.{name}.eds", f"cannot read EDS {path}: {exc}"))
            continue
        report = check_drive(name, section, can, od, file, path.name)
        reports[name] = report
        problems.extend(report.problems)
    from tcs.config.axes import DISCRETE_MODULES
    for axis_name, axis in (axes or {}).items():
        section = drives.get(axis.drive)
        if section is None or axis.drive not in reports:
            continue
        choice = reports[axis.drive].mode
        if axis.module in DISCRETE_MODULES:
            if choice is not None and choice.mode in ("ip", "csv") and not section.pdo:
                problems.append(ConfigError(
                    file, f"drives.{axis.drive}.mode",
                    f"drive {axis.drive} (node {section.node_id}): axis {axis.module} moves in "
                    f"profile position (PP), but the drive would stream in "
                    f"{choice.mode.upper()} ({choice.reason}) and map no 0x607A; remedy: "
                    f"mode = 'pp'"))
            continue
        if choice is None or choice.cyclic or choice.problem is not None:
            continue
        path = eds_path(section, resolve)
        text = modes_text(choice.offered, path.name)
        if section.wanted_mode == "auto":
            why, remedy = "the drive offers none of them", "a drive or firmware with one of them"
        else:
            why, remedy = f"mode = '{section.wanted_mode}' is configured", "mode = 'auto'"
        problems.append(ConfigError(
            file, f"axes.{axis_name}.drive",
            f"drive {axis.drive} (node {section.node_id}): {text}; axis {axis.module} follows "
            f"trajectories and needs cyclic synchronous position (CSP), interpolated position "
            f"(IP) or cyclic synchronous velocity (CSV), but {why} (the TCS does not run a "
            f"tracking axis in PP/PV); remedy: {remedy}, or use the drive for an axis that "
            f"never streams (filter wheel, M3)"))
    return problems, reports


def log_report(reports: dict[str, DriveReport]) -> None:
    """Log each note (INFO) and warning (WARNING): once per start (``CanDrives`` calls it;
    boots and re-boots do not log again)."""
    for name, report in reports.items():
        if report.mode is not None:
            log.info("drive %s: mode %s — %s", name, report.mode.mode.upper(), report.mode.reason)
        if report.layouts:
            from tcs.drivers.pdo import describe
            log.info("drive %s: PDO layout (%s) — %s", name,
                     "hardware file" if report.hand_written else "from the EDS",
                     "; ".join(describe(report.layouts)))
        for level, lines in ((logging.WARNING, report.warnings), (logging.INFO, report.notes)):
            for line in lines:
                log.log(level, "%s", line)
