"""The served OpenTCI tree against the spec's own tables, for every shipped hardware file.

The spec's variable tables (``Name  Type  Access  Description`` in ``shared/spec/OpenTCI-2.5.txt``)
are read from the spec text itself, not copied: each table is placed on the paths it describes
(``PLACES``: the generic axis tables on every axis of the telescope, TRAJECTORY on the axes that
have one, CABINET, LOCAL, GPS, POINTING …). A client walks the tree over TPL2 (a real socket)
and reads ``!CLASS``, ``!TYPE``, ``!RLEVEL`` and ``!WLEVEL`` of every object a table names. Each
difference — missing, another type, another access — must be one docs/opentci.md's "Deviations
from the spec" explains (``EXPLAINED``: the difference and the reason); any other fails the
test with the whole list. Extra objects (the TCS's own additions) are not differences.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from support.opentci_client import Client
from support.service import start_service

ROOT = Path(__file__).resolve().parent.parent
SPEC = ROOT.parent / "shared" / "spec" / "OpenTCI-2.5.txt"
# every shipped telescope that runs on its own (sim-remote.toml is sim.toml's tree with the drives
# in tcs-sim; cabinet.toml needs the real bus)
FILES = ["sim.toml", "sim-equatorial.toml", "sim-rollroof.toml", "sim-zdzd.toml"]

pytestmark = pytest.mark.skipif(not SPEC.exists(), reason=f"the spec text is not at {SPEC}")

TYPES = {"INT": 1, "FLOAT": 2, "STRING": 3}
MODULE_CLASSES = {1002, 1003}   # MODULE, MODULEARR (a STRUCT row is served as a module)
VARIABLE_CLASSES = {1006, 1007, 2006, 2007}
NOBODY = -1

# Where each table of the spec (in the order they appear) applies. "{axis}" is every generic
# axis of the telescope, "{tracked}" every axis with a TRAJECTORY, "{module}" every module.
PLACES: list[list[str]] = [
    ["{module}"],                        # 3.2 VERSION, TYPE
    [],                                  # 3.2 ERROR_STATE (RW) — 5.1 repeats it RO; both served per module below
    ["{axis}"],                          # 5.1 POWER, POWER_STATE, ERROR_STATE
    ["{axis}"],                          # 5.1 LIMIT_STATE … REINIT
    ["{axis}"],                          # 5.1 REALPOS … CURRJRK
    ["{axis}"],                          # 5.1 TARGETPOS, OFFSET, TARGETDISTANCE
    ["{axis}"],                          # 5.1 STOP, TRAJECTORY (optional: checked on {tracked})
    ["{tracked}.TRAJECTORY"],            # 5.1.1 BUFFER[], ADDPPOINTS, FREEPOINTS, RUN, STARTTIME
    ["{tracked}.TRAJECTORY"],            # 5.1.1 RUNTIME
    ["{tracked}.TRAJECTORY.BUFFER[0]"],  # 5.1.1 TIME, TARGETPOS
    ["CABINET"],                         # 6.1 POWER, POWER_STATE, REFERENCED
    ["CABINET"],                         # 6.1 REINIT … STOP
    ["CABINET.MANUAL_CONTROL"],          # 6.1 ACTIVE, BRIGHTNESS, MODE
    ["CABINET.MANUAL_CONTROL"],          # 6.2 SELECTION
    ["CABINET.SETUP"],                   # 6.2 MANUFACTURER …
    ["CABINET.STATUS"],                  # 6.2 GLOBAL, LOG[], LIST, CLEAR
    ["CONFIG"],                          # 7
    ["LOCAL"],                           # 8 UT1
    ["LOCAL"],                           # 8 UTC …
    ["GPS"],                             # 11 TIME, POS
    ["GPS.POS"],                         # 11 LAT, LON, HEIGHT
    ["SENSOR[0]", "SWITCH[0]"],          # 13
    ["POINTING"],                        # 14
    ["POINTING"],                        # 14 (more)
    ["POINTING.TARGET", "POINTING.CURRENT"],   # 14.1
    ["POINTING.POINTINGPARAMS"],         # 14.2
    ["POINTING.POINTINGPARAMS"],         # 14.2 (more)
    ["POINTING.REFRACTION"],             # 14.3
]

# Names the spec's tables misspell (its own text and every client use the other)
SPEC_TYPOS = {"ADDPPOINTS": "ADDPOINTS",   # 5.1.1 table; "ADDPOINTS" in TPL2 clients and the spec's prose
              "DUMPFIL": "DUMPFILE"}       # 14.2 table; "If a DUMPFILE is given" two rows below

# Differences docs/opentci.md's "Deviations from the spec" explains: (regex on the difference) → why.
EXPLAINED: dict[str, str] = {
    r"\.ERROR_STATE: RO served RW$":
        "§3.2 makes every module's ERROR_STATE RW (writing 0 acknowledges), §5.1's table RO",
    r"^(DOME\[\d\]|COVER(\[\d\])?)\.CURRSPEED: RW served RO$":
        "CURRSPEED of PLC parts: the PLC sets the speed",
    r"^(FILTER\[\d\]|MIRROR|DOME\[[1-3]\]|COVER(\[\d\])?)\.OFFSET: RW served RO$":
        "OFFSET of discrete axes and PLC parts that only open and close",
    r"^SENSOR\[\d\]\.VALUE: type INT served as 2$": "SENSOR[].VALUE is FLOAT (12.3 °C)",
}


def spec_tables() -> list[list[tuple[str, str, str]]]:
    """Every ``Name Type Access Description`` table of the spec: (name, type, access) rows."""
    tables: list[list[tuple[str, str, str]]] = []
    rows: list[tuple[str, str, str]] | None = None
    for line in SPEC.read_text(encoding="utf-8").splitlines():
        cells = [re.sub(r"</?code>", "", c).strip() for c in line.split("\t")]
        if cells[:3] == ["Name", "Type", "Access"]:
            rows = []
            tables.append(rows)
        elif rows is not None and len(cells) >= 3 and cells[0]:
            rows.append((cells[0], cells[1], cells[2]))
        else:
            rows = None
    return tables


async def _props(c: Client, path: str) -> dict[str, str]:
    props = ("CLASS", "TYPE", "RLEVEL", "WLEVEL")
    lines = await c.command(7, "GET " + ";".join(f"{path}!{p}" for p in props))
    out = {}
    for line in lines:
        m = re.match(r"7 DATA INLINE (\S+)!(\w+)=(.*)$", line)
        if m:
            out[m.group(2)] = m.group(3)
    return out


async def _instances(c: Client, name: str) -> list[str]:
    """``name`` or its elements, as served (nothing when the module is absent)."""
    props = await _props(c, name)
    if props.get("CLASS") == "1003":
        count = int(await c.get(f"{name}!COUNT"))
        return [f"{name}[{i}]" for i in range(count)]
    return [name] if props.get("CLASS") == "1002" else []


async def telescope_modules(c: Client) -> tuple[list[str], list[str], list[str]]:
    """(every module, every generic axis, every axis with TRAJECTORY) of the served tree."""
    count = int(await c.get("!MEMBERS"))
    names = [await c.get(f"<{i}>!NAME") for i in range(count)]
    modules: list[str] = []
    for name in (n.strip('"') for n in names):
        if name != "SERVER":
            modules += await _instances(c, name)
    axes, tracked = [], []
    for module in modules:
        base = module.split("[")[0]
        if base in ("AZ", "ZD", "HA", "DEC", "DEROTATOR", "FOCUS", "FILTER", "COVER", "DOME", "MIRROR"):
            axes.append(module)
            if (await _props(c, f"{module}.TRAJECTORY")).get("CLASS") in ("1002", "1003"):
                tracked.append(module)
    return modules, axes, tracked


def _served_access(props: dict[str, str]) -> str:
    rlevel, wlevel = int(props["RLEVEL"]), int(props["WLEVEL"])
    if wlevel == NOBODY:
        return "RO"
    return "WO" if rlevel == NOBODY else "RW"


async def differences(c: Client) -> list[str]:
    modules, axes, tracked = await telescope_modules(c)
    mount = (await c.get("CONFIG.MOUNT")).strip('"')
    tables = spec_tables()
    assert len(tables) == len(PLACES), f"the spec has {len(tables)} tables, PLACES places {len(PLACES)}"
    found: list[str] = []
    for rows, places in zip(tables, PLACES):
        for place in places:
            if "{module}" in place:
                prefixes = modules
            elif "{axis}" in place:
                prefixes = axes
            elif "{tracked}" in place:
                prefixes = [place.replace("{tracked}", t) for t in tracked]
            else:
                root = place.split(".")[0]
                present = root in modules or any(m.startswith(root + "[") for m in modules)
                prefixes = [place] if present else []
            for prefix in prefixes:
                for name, typ, access in rows:
                    if name == "TRAJECTORY" and prefix not in tracked:
                        continue   # optional per axis
                    optional = name.endswith("*")          # "*) Optional, needs not to be supported"
                    if "¹" in name and mount == "RA-DEC" or "²" in name and mount != "RA-DEC":
                        continue   # ¹ AZ-ZD and ZD-ZD mounts only, ² RA-DEC only
                    bare = re.sub(r"[*¹²\s]|\[\]", "", name)
                    bare = SPEC_TYPOS.get(bare, bare)
                    if prefix == "POINTING.CURRENT" and access == "RW":
                        access = "RO"   # 14.1: "variables of the CURRENT module are read only"
                    path = f"{prefix}.{bare}"
                    props = await _props(c, path)
                    klass = int(props["CLASS"]) if props.get("CLASS", "").lstrip("-").isdigit() else None
                    if klass is None:
                        if not optional:
                            found.append(f"{path}: missing")
                        continue
                    if typ in ("MODULE", "STRUCT"):
                        if klass not in MODULE_CLASSES:
                            found.append(f"{path}: {typ} served as class {klass}")
                        continue
                    if klass not in VARIABLE_CLASSES:
                        found.append(f"{path}: {typ} served as class {klass}")
                        continue
                    want = TYPES.get(typ)
                    if want is not None and props.get("TYPE") != str(want):
                        found.append(f"{path}: type {typ} served as {props.get('TYPE')}")
                    served = _served_access(props)
                    if access in ("RO", "RW", "WO") and served != access:
                        found.append(f"{path}: {access} served {served}")
    return found


def unexplained(found: list[str]) -> list[str]:
    return [d for d in found if not any(re.search(rx, d) for rx in EXPLAINED)]


@pytest.mark.parametrize("hwfile", FILES)
async def test_served_tree_matches_the_spec_tables(tmp_path, hwfile):
    service, port = await start_service(tmp_path / "state", ROOT / "hwconfig" / hwfile)
    c = await Client.connect(port)
    try:
        found = await differences(c)
    finally:
        await c.close()
        await service.stop()
    assert not unexplained(found), "\n".join(unexplained(found))
