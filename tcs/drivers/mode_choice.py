"""The mode of operation a drive runs its axis in: ``[drives.x] mode``, or for ``auto`` what
0x6502 offers and the drive's PDOs can carry.

Above :mod:`tcs.drivers.eds` (0x6502, the EDS) and :mod:`tcs.drivers.pdo` (the layouts), below
the start check (:mod:`tcs.drivers.eds_check`), the driver and ``tcs-commission scan``, which
use it: :func:`choose_mode` from an object dictionary (and 0x6502 as the drive answered it, when
the EDS gives no default), :func:`drive_mode` from an EDS file.
"""

from __future__ import annotations

from pathlib import Path

import canopen

from tcs.config.can import DriveSection
from tcs.drivers.eds import (CYCLIC_PREFERENCE, MODE_KEYS, MODE_NAMES, MODE_SHORT, ModeChoice,
                             decode_modes, load_od, modes_text, offers, supported_modes, variable)
from tcs.drivers.pdo import plan_pdos


def mapping_problem(section: DriveSection, od: canopen.ObjectDictionary, key: str) -> str | None:
    """Why the drive's PDOs cannot carry what mode ``key`` needs (None: they can)."""
    problems = plan_pdos(section, od, key, section.node_id).problems
    return problems[0][1] if problems else None


def choose_mode(section: DriveSection, od: canopen.ObjectDictionary,
                eds_name: str = "EDS", modes: int | None | str = "eds",
                source: str | None = None) -> ModeChoice:
    """The mode the drive runs its axis in: ``[drives.x] mode`` or, for ``auto``, the first of
    CSP, IP, CSV that 0x6502 offers AND whose setpoint object the drive's PDOs can carry
    (IP when 0x607A cannot be mapped but 0x60C1:1 can); when 0x6502 is unknown (no EDS
    default, not read yet) the first whose setpoint can be mapped; PP when it offers no
    cyclic mode — enough for axes that never stream.

    ``modes``: 0x6502 as read from the drive (``source`` says where it came from); by default
    the EDS default."""
    wanted = section.wanted_mode
    if modes == "eds":
        modes = supported_modes(od)
        text = modes_text(modes, eds_name)
        if modes is None and variable(od, 0x6502, 0) is not None:
            text += " (read from the drive at boot)"
    else:
        text = (f"0x6502 (supported drive modes) = 0x{modes:08X} = {decode_modes(modes)} "
                f"({source or 'read from the drive'})") if modes is not None else modes_text(None, eds_name)
    if wanted != "auto":
        problem = None
        if not offers(modes, wanted):
            fits = [k for k in (*CYCLIC_PREFERENCE, "pp") if offers(modes, k)
                    and mapping_problem(section, od, k) is None]
            problem = (f"mode = '{wanted}' is configured, but {text} has no "
                       f"{MODE_NAMES[MODE_KEYS[wanted]]}; remedy: " +
                       (f"mode = {' or '.join(repr(k) for k in fits)} (or 'auto')" if fits else
                        "a drive or firmware that offers CSP, IP or CSV"))
        return ModeChoice(wanted, f"configured (mode = '{wanted}')", modes, problem)
    offered = [k for k in CYCLIC_PREFERENCE if offers(modes, k)]
    skipped = []
    for key in offered:
        why = mapping_problem(section, od, key)
        if why is None:
            tail = "; auto prefers CSP, then IP, then CSV"
            if skipped:
                tail += " whose setpoint the drive can map (" + "; ".join(skipped) + ")"
            if modes is None:
                return ModeChoice(key, f"{text}: {MODE_SHORT[MODE_KEYS[key]]} assumed{tail}", modes)
            return ModeChoice(key, f"{text}{tail}", modes)
        skipped.append(f"{key.upper()} not: {why}")
    if offered:  # none can be mapped: the PDO check reports why, naming the objects
        return ModeChoice(offered[0], f"{text}; none of its cyclic modes can be mapped "
                                      f"({'; '.join(skipped)})", modes)
    if offers(modes, "pp"):
        return ModeChoice("pp", f"{text} has no cyclic mode (CSP, IP, CSV): profile position, "
                                f"for axes that never stream only", modes)
    return ModeChoice("csp", text, modes, f"{text} offers none of CSP, IP, CSV or PP; remedy: a "
                                          f"drive or firmware with one of them")


def drive_mode(section: DriveSection, eds, node_id: int) -> ModeChoice:
    """:func:`choose_mode` from the drive's EDS file (CSP or the configured mode when the
    file cannot be read: the boot then reports it)."""
    try:
        od = load_od(eds, node_id)
    except Exception:
        wanted = section.wanted_mode
        return ModeChoice("csp" if wanted == "auto" else wanted, "EDS unreadable", None)
    return choose_mode(section, od, Path(eds).name)
