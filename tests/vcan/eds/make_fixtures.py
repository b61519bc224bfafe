"""Write the vendor-like EDS fixtures of this directory (run it after changing the sim EDS).

Each fixture is OUR simulated drive's EDS (hwconfig/eds/tcs-sim-drive.eds) changed in one
way that real drives differ (facts from public vendor EDS files; nothing is copied from
them):

========================  ====================================================================
vendor-no-hbconsumer      no 0x1016 consumer heartbeat time (node guarding only)
vendor-no-softlimits      no 0x607D software position limit
vendor-fe-limited         0x6066 following-error time-out with HighLimit 0
vendor-no-homing          no homing objects 0x6098-0x609A, 0x607C; 0x6502 without homing
                          mode; a vendor home offset 0x2100 instead
vendor-rpm                velocities in rpm (0x60A9 says so), 0x607F HighLimit 6000
vendor-no-csp             0x6502 without cyclic synchronous position
vendor-pdo-restricted     0x603F not PDO-mappable; no event timer (sub-index 5) in 0x1800-0x1803
vendor-revision           another RevisionNumber (a firmware update)
vendor-ip-only            0x6502 = PP, HM, IP: interpolated position, no CSP/CSV
vendor-csv-only           0x6502 = PP, HM, CSV: cyclic synchronous velocity, no CSP/IP
vendor-ip-no-607a-map     IP only, and 0x607A cannot be mapped (0x60C1:1 is the setpoint)
vendor-homing-list        0x60E3 supported homing methods whose entries have no DefaultValue
vendor-hb16               0x1016 consumer heartbeat entries with HighLimit 0xFFFF (the time
                          part only; the node id sits in bits 16-23)
vendor-no-devtype-default 0x1000 device type without a DefaultValue
vendor-pdo1-single        RPDO1/TPDO1 take ONE mapped object each (0x1600/0x1A00 have one
                          mapping entry), RPDO2-4/TPDO2-4 two
vendor-tpdo2-empty        TPDO2 has no mapping entries at all (0x1A01 has only sub-index 0),
                          TPDO1 takes three
vendor-ip-nomodes         0x607A not PDO-mappable (0x60C1:1 is), and 0x6502 without a
                          DefaultValue (the drive answers it over SDO)
vendor-absolute-ro6098    0x6098 read-only, 0x6502 without homing mode (PP, PV, CSP, CSV):
                          run with absolute = true
vendor-no-modes-default   0x6502 without a DefaultValue, everything mappable (the modes are
                          known only from the drive's answer at boot)
========================  ====================================================================

Usage: ``python tests/vcan/eds/make_fixtures.py [NAME ...]`` (all fixtures, or those named).
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
SOURCE = HERE.parents[2] / "hwconfig" / "eds" / "tcs-sim-drive.eds"


def sections(text: str) -> list[tuple[str, list[str]]]:
    out: list[tuple[str, list[str]]] = [("", [])]
    for line in text.splitlines():
        m = re.match(r"^\[(.+)\]\s*$", line)
        if m:
            out.append((m.group(1), []))
        else:
            out[-1][1].append(line)
    return out


def render(parts: list[tuple[str, list[str]]]) -> str:
    lines = []
    for name, body in parts:
        if name:
            lines.append(f"[{name}]")
        lines.extend(body)
    return "\n".join(lines).rstrip("\n") + "\n"


def relist(parts):
    """Rebuild [OptionalObjects] / [ManufacturerObjects] from the objects present."""
    present = sorted({int(n, 16) for n, _ in parts if re.fullmatch(r"[0-9A-Fa-f]{4}", n)})
    mandatory = {0x1000, 0x1001, 0x1018}
    optional = [i for i in present if i not in mandatory and not 0x2000 <= i < 0x6000]
    vendor = [i for i in present if 0x2000 <= i < 0x6000]
    out = []
    for name, body in parts:
        if name == "OptionalObjects":
            body = [f"SupportedObjects={len(optional)}"] + [f"{k}=0x{i:04X}" for k, i in enumerate(optional, 1)] + [""]
        elif name == "ManufacturerObjects":
            body = [f"SupportedObjects={len(vendor)}"] + [f"{k}=0x{i:04X}" for k, i in enumerate(vendor, 1)] + [""]
        out.append((name, body))
    return out


def without(parts, *indices: str, subs: tuple[str, ...] = ()):
    drop = re.compile(r"^(" + "|".join(indices) + r")(sub[0-9A-Fa-f]+)?$") if indices else None
    return [(n, b) for n, b in parts
            if not (drop and drop.match(n)) and n not in subs]


def setkey(parts, section: str, key: str, value: str):
    out = []
    for name, body in parts:
        if name == section:
            body = [line for line in body if not line.startswith(f"{key}=")]
            while body and body[-1] == "":
                body.pop()
            body = body + [f"{key}={value}", ""]
        out.append((name, body))
    return out


def header(parts, description: str):
    return setkey(setkey(parts, "FileInfo", "Description", description), "DeviceInfo",
                  "ProductName", description)


def add(parts, name: str, body: list[str]):
    return parts + [(name, body + [""])]


def pdo_no_timer(parts):
    for n in range(4):
        parts = setkey(parts, f"180{n}sub0", "DefaultValue", "3")
    return parts


def unset(parts, section: str, key: str):
    """``section`` without ``key`` (an EDS entry that states no value)."""
    return [(n, [line for line in b if not line.startswith(f"{key}=")] if n == section else b)
            for n, b in parts]


def homing_list(parts):
    """0x60E3 with three entries, none stating a method (DefaultValue left out)."""
    parts = add(parts, "60E3", ["ParameterName=Supported homing methods", "ObjectType=0x8",
                                "SubNumber=0x4"])
    parts = add(parts, "60E3sub0", ["ParameterName=Number of entries", "ObjectType=0x7",
                                    "DataType=0x0005", "AccessType=ro", "DefaultValue=3",
                                    "PDOMapping=0"])
    for sub in (1, 2, 3):
        parts = add(parts, f"60E3sub{sub}", [f"ParameterName=Homing method {sub}",
                                             "ObjectType=0x7", "DataType=0x0002",
                                             "AccessType=ro", "PDOMapping=0"])
    return parts


def hb16(parts):
    for sub in (1, 2, 3, 4):
        parts = setkey(parts, f"1016sub{sub}", "HighLimit", "0x0000FFFF")
    return parts


def entries(parts, index: str, n: int):
    """Mapping object ``index`` (e.g. "1600") with only ``n`` mapping entries (sub-index 1..n;
    none for 0), its sub-index 0 defaulting to at most ``n`` (no HighLimit: the entries the
    EDS lists are all it says)."""
    parts = [(name, body) for name, body in parts
             if not (m := re.fullmatch(index + r"sub([0-9A-Fa-f]+)", name)) or int(m.group(1), 16) <= n]
    parts = setkey(parts, index, "SubNumber", f"0x{n + 1:X}")
    for name, body in parts:
        if name == f"{index}sub0":
            default = next((line.split("=", 1)[1] for line in body if line.startswith("DefaultValue=")), "0")
            parts = setkey(parts, name, "DefaultValue", str(min(int(default, 0), n)))
            break
    return parts


def pdo1_single(parts):
    """RPDO1/TPDO1 with one mapping entry (controlword / statusword), the others two."""
    for index in ("1600", "1A00"):
        parts = entries(parts, index, 1)
    for index in ("1601", "1602", "1603", "1A01", "1A02", "1A03"):
        parts = entries(parts, index, 2)
    return parts


def tpdo2_empty(parts):
    """0x1A01 with only sub-index 0 (no mapping entries); TPDO1 takes three."""
    return entries(entries(parts, "1A01", 0), "1A00", 3)


def main() -> None:
    base = sections(SOURCE.read_text(encoding="utf-8"))
    base[0] = ("", ["; Vendor-like fixture written for the TCS tests (tests/vcan/eds/make_fixtures.py),",
                    "; derived from the simulated drive's EDS. Not a copy of any vendor's file.", ""])
    fixtures = {
        "vendor-no-hbconsumer": without(base, "1016"),
        "vendor-no-softlimits": without(base, "607D"),
        "vendor-fe-limited": setkey(setkey(setkey(base, "6066", "HighLimit", "0"), "6066", "LowLimit", "0"),
                                    "6066", "DefaultValue", "0"),
        "vendor-no-homing": add(setkey(without(base, "6098", "6099", "609A", "607C"), "6502",
                                       "DefaultValue", "0x00000085"),
                                "2100", ["ParameterName=Vendor home offset", "ObjectType=0x7",
                                         "DataType=0x0004", "AccessType=rw", "DefaultValue=0",
                                         "PDOMapping=0"]),
        "vendor-rpm": add(setkey(base, "607F", "HighLimit", "6000"),
                          "60A9", ["ParameterName=SI unit velocity", "ObjectType=0x7",
                                   "DataType=0x0007", "AccessType=ro",
                                   "DefaultValue=0x00B44700", "PDOMapping=0"]),
        "vendor-no-csp": setkey(base, "6502", "DefaultValue", "0x00000025"),
        "vendor-pdo-restricted": setkey(pdo_no_timer(without(base, subs=("1800sub5", "1801sub5", "1802sub5",
                                                                         "1803sub5"))),
                                        "603F", "PDOMapping", "0"),
        "vendor-revision": setkey(base, "DeviceInfo", "RevisionNumber", "0x00020003"),
        "vendor-ip-only": setkey(base, "6502", "DefaultValue", "0x00000061"),
        "vendor-csv-only": setkey(base, "6502", "DefaultValue", "0x00000121"),
        "vendor-ip-no-607a-map": setkey(setkey(base, "6502", "DefaultValue", "0x00000061"),
                                        "607A", "PDOMapping", "0"),
        "vendor-homing-list": homing_list(base),
        "vendor-hb16": hb16(base),
        "vendor-no-devtype-default": unset(base, "1000", "DefaultValue"),
        "vendor-pdo1-single": pdo1_single(base),
        "vendor-tpdo2-empty": tpdo2_empty(base),
        "vendor-ip-nomodes": unset(setkey(base, "607A", "PDOMapping", "0"), "6502", "DefaultValue"),
        "vendor-absolute-ro6098": setkey(setkey(base, "6098", "AccessType", "ro"), "6502",
                                         "DefaultValue", "0x00000185"),
        "vendor-no-modes-default": unset(base, "6502", "DefaultValue"),
    }
    only = set(sys.argv[1:])  # names to write (default: all)
    for name, parts in fixtures.items():
        if only and name not in only:
            continue
        parts = setkey(header(relist(parts), f"TCS test fixture {name}"), "FileInfo", "FileName", f"{name}.eds")
        (HERE / f"{name}.eds").write_text(render(parts), encoding="utf-8")


if __name__ == "__main__":
    main()
