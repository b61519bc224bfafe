"""``tcs-commission scan``: which nodes are on the bus, who they are, which configured drive.

How it works
------------
1. :func:`probe` sends one SDO upload request of 0x1000:0 (device type) to each node id,
   **paced** — one request every ``--pace`` seconds (default 5 ms), never canopen's burst of
   127 — and collects the answers (and any heartbeat heard) in the notifier thread; after the
   last request it waits ``--timeout`` for late answers.
2. Each node that answered is read with ordinary SDO transfers, one after the other:
   identity 0x1018:1..4, error register 0x1001, and, for CiA-402 devices, the statusword
   0x6041 (the power state), the error code 0x603F, the mode display 0x6061 and the
   supported drive modes 0x6502 (optional: when the drive has it), shown as mode names.
3. Nodes are matched with the ``[drives]`` of the hardware file by node id: identity equal
   (``ok``), different (``wrong identity``) or not configured; configured drives whose node
   id was probed and did not answer are listed as missing. For a configured drive the scan
   also shows the mode the TCS would run its axis in (``[drives.x] mode``, or for ``auto``
   what 0x6502 offers — the EDS's, or the drive's own answer when the EDS gives no default —
   and what its PDOs can carry: :func:`tcs.drivers.eds.choose_mode`) and why, and the PDO
   layout the boot would write (:func:`tcs.drivers.pdo.plan_pdos`: from the EDS, or the
   hardware file's ``pdo``), or what does not fit and the PDOs tried.

Nothing is written and no drive is booted. The NMT state comes from heartbeats heard during
the scan (a node whose heartbeat producer is off shows "no heartbeat"; answering SDO, it is
pre-operational or operational). The TCS's own node id (``[can] node_id``) is not probed.

Exit codes: 0 every configured drive answered with its identity, 1 a configured node id
answered with another identity, 3 a configured drive is missing (or nothing answered).
"""

from __future__ import annotations

import contextlib
import struct
import time

import canopen

from tcs.config.axes import DISCRETE_MODULES
from tcs.drivers.boot import DEVICE_PROFILE_402, NMT_STATE_NAMES, Sdo
from tcs.drivers.cia402 import decode_state
from tcs.drivers.eds_check import (choose_mode, decode_modes, drive_mode, eds_path, load_od,
                                   supported_modes)
from tcs.drivers.pdo import describe as describe_pdos
from tcs.drivers.pdo import plan_pdos
from tcs.drivers.emcy import describe
from tcs.errors import HardwareError

from tcs.commission.common import CommissionError, ExitCode, Outcome
from tcs.commission.session import DriveSession, prepare_config

SDO_REQUEST, SDO_RESPONSE, HEARTBEAT = 0x600, 0x580, 0x700
UPLOAD_1000 = bytes([0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0])


def add_parser(subparsers, parents) -> None:
    p = subparsers.add_parser("scan", parents=parents, help="find and identify the nodes on the bus",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("--nodes", default="1-127", help="node ids to probe, e.g. 1-10,20 (default 1-127)")
    p.add_argument("--pace", type=float, default=0.005,
                   help="seconds between two probe requests (default 0.005)")
    p.add_argument("--timeout", type=float, default=0.2,
                   help="seconds to wait for late answers after the last request (default 0.2)")


def parse_nodes(text: str) -> list[int]:
    """``"1-5,9"`` → [1, 2, 3, 4, 5, 9]; CommissionError (exit 2) for anything else."""
    ids: set[int] = set()
    try:
        for part in text.split(","):
            lo, sep, hi = part.strip().partition("-")
            first, last = int(lo), int(hi) if sep else int(lo)
            if not 1 <= first <= last <= 127:
                raise ValueError
            ids.update(range(first, last + 1))
    except ValueError:
        raise CommissionError(f"--nodes {text!r}: use node ids 1..127 like 1-10,20",
                              ExitCode.USAGE) from None
    return sorted(ids)


def probe(network: canopen.Network, node_ids: list[int], pace: float = 0.005,
          timeout: float = 0.2) -> tuple[dict[int, object], dict[int, int]]:
    """Paced SDO probe of 0x1000:0.

    Returns
    -------
    (answers, heartbeats)
        ``answers[node] = device type`` (int), or the abort code as ``("abort", code)``;
        ``heartbeats[node] = NMT state`` of every heartbeat heard meanwhile.
    """
    answers: dict[int, object] = {}
    heartbeats: dict[int, int] = {}

    def on_response(cob_id: int, data: bytearray, timestamp: float) -> None:
        node = cob_id - SDO_RESPONSE
        if len(data) < 8 or data[1:4] != b"\x00\x10\x00":
            return
        cmd = data[0]
        if cmd == 0x80:
            answers[node] = ("abort", struct.unpack_from("<I", data, 4)[0])
        elif cmd & 0xE0 == 0x40:  # upload response (expedited or segmented: size in data)
            answers[node] = struct.unpack_from("<I", data, 4)[0]

    def on_heartbeat(cob_id: int, data: bytearray, timestamp: float) -> None:
        if data:
            heartbeats[cob_id - HEARTBEAT] = data[0] & 0x7F

    subs = [(SDO_RESPONSE + n, on_response) for n in node_ids]
    subs += [(HEARTBEAT + n, on_heartbeat) for n in range(1, 128)]
    for cob_id, cb in subs:
        network.subscribe(cob_id, cb)
    try:
        next_send = time.monotonic()
        for node in node_ids:
            delay = next_send - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            network.send_message(SDO_REQUEST + node, UPLOAD_1000)
            next_send += pace
        time.sleep(timeout)
    finally:
        for cob_id, cb in subs:
            network.unsubscribe(cob_id, cb)
    return answers, heartbeats


@contextlib.contextmanager
def bare_sdo(network: canopen.Network, node_id: int, timeout: float, device: str):
    """A blocking :class:`~tcs.drivers.boot.Sdo` to a node without an object dictionary."""
    node = canopen.RemoteNode(node_id, canopen.ObjectDictionary())
    node.sdo.RESPONSE_TIMEOUT = timeout
    network.add_node(node)
    try:
        yield Sdo(node, device)
    finally:
        if network.nodes.get(node_id) is node:
            del network[node_id]


def optional(sdo: Sdo, index: int, sub: int, fmt: str):
    """An SDO read that gives None for an object the node does not have."""
    try:
        return sdo.read(index, sub, fmt)
    except HardwareError:
        return None


def identify(network, node_id: int, device_type, timeout: float) -> dict:
    """What one answering node tells over SDO (identity, error register, 402 state)."""
    entry: dict = {"node_id": node_id}
    if isinstance(device_type, tuple):
        entry["device_type"] = None
        entry["note"] = f"0x1000 aborted: 0x{device_type[1]:08X}"
        return entry
    entry["device_type"] = f"0x{device_type:08X}"
    entry["cia402"] = device_type & 0xFFFF == DEVICE_PROFILE_402
    with bare_sdo(network, node_id, timeout, f"node {node_id}") as sdo:
        entry["identity"] = {name: optional(sdo, 0x1018, sub, "<I") for sub, name in
                             ((1, "vendor"), (2, "product"), (3, "revision"), (4, "serial"))}
        entry["error_register"] = optional(sdo, 0x1001, 0, "<B")
        if entry["cia402"]:
            sw = optional(sdo, 0x6041, 0, "<H")
            entry["statusword"] = sw
            state = decode_state(sw) if sw is not None else None
            entry["state"] = state.value if state is not None else None
            code = optional(sdo, 0x603F, 0, "<H")
            entry["error_code"] = code
            entry["error"] = describe(code)[0] if code else None
            entry["mode"] = optional(sdo, 0x6061, 0, "<b")
            modes = optional(sdo, 0x6502, 0, "<I")
            entry["supported_modes"] = modes
            entry["offered"] = decode_modes(modes) if modes is not None else None
    return entry


def planned(section, eds, node_id: int, read_modes: int | None) -> dict:
    """The mode and PDO layout the TCS would give a configured drive (as its boot does: the
    EDS's 0x6502, or the drive's own answer when the EDS gives no default)."""
    choice = drive_mode(section, eds, node_id)
    out = {"tcs_mode": choice.mode.upper(), "tcs_mode_reason": choice.reason}
    try:
        od = load_od(eds, node_id)
    except Exception as exc:  # (the start reports an unreadable EDS too)
        out["pdo_problems"] = [f"cannot read EDS {eds}: {exc}"]
        return out
    if supported_modes(od) is None and read_modes is not None:
        choice = choose_mode(section, od, eds.name, modes=read_modes,
                             source=f"read from the drive over SDO; {eds.name} gives no default")
        out.update(tcs_mode=choice.mode.upper(), tcs_mode_reason=choice.reason)
    plan = plan_pdos(section, od, choice.mode, node_id)
    out.update(pdo_layout=describe_pdos(plan.layouts(node_id)), pdo_hand_written=bool(section.pdo),
               pdo_problems=[text for _key, text in plan.problems], pdo_notes=list(plan.notes))
    return out


def compare_identity(section, identity: dict) -> list[str]:
    """Differences between a node's 0x1018 and the hardware file's ``identity`` table."""
    ident = section.identity
    wrong = []
    for name in ("vendor", "product", "revision", "serial"):
        want = getattr(ident, name)
        got = identity.get(name)
        if want is not None and got != want:
            shown = "none" if got is None else f"0x{got:08X}"
            wrong.append(f"{name} {shown} (file 0x{want:08X})")
    return wrong


def profile_only(config, name: str) -> str | None:
    """Why drive ``name`` runs in profile position only (a discrete axis — filter wheel, M3 —
    moves between its positions and never streams; a drive no axis uses boots in
    ``default_mode`` pp), or None when the axis streams in the drive's cyclic mode."""
    section = config.drives[name]
    modules = [axis.module for axis in config.axes.values() if axis.drive == name]
    discrete = [m for m in modules if m in DISCRETE_MODULES]
    if discrete:
        return f"{discrete[0]} moves between discrete positions: profile moves; it never streams"
    if not modules and section.default_mode == "pp":
        return "no axis uses the drive; default_mode pp at boot"
    return None


def run(args, config) -> Outcome:
    out = Outcome("scan")
    node_ids = parse_nodes(args.nodes)
    if not 0.0 <= args.pace <= 1.0 or not 0.0 < args.timeout <= 10.0:
        raise CommissionError("--pace must be 0..1 s and --timeout 0..10 s", ExitCode.USAGE)
    config, simulate = prepare_config(config, args.simulate)
    node_ids = [n for n in node_ids if n != config.can.node_id]
    by_id = {section.node_id: name for name, section in config.drives.items()}
    with DriveSession(config, simulate=simulate, check_bus=not args.force) as session:
        network = session.network
        answers, heartbeats = probe(network, node_ids, args.pace, args.timeout)
        nodes = [identify(network, n, answers[n], config.can.sdo_timeout) for n in sorted(answers)]
    for entry in nodes:
        n = entry["node_id"]
        hb = heartbeats.get(n)
        entry["nmt"] = NMT_STATE_NAMES.get(hb, f"0x{hb:02X}") if hb is not None else None
        name = by_id.get(n)
        entry["drive"] = name
        if name is None:
            entry["match"] = "not configured"
        else:
            wrong = compare_identity(config.drives[name], entry.get("identity") or {})
            if not entry.get("cia402"):
                wrong.insert(0, f"device type {entry['device_type']} is not a CiA-402 drive")
            entry["match"] = "ok" if not wrong else "wrong identity: " + ", ".join(wrong)
            section = config.drives[name]
            entry.update(planned(section, eds_path(section, config.resolve), n,
                                 entry.get("supported_modes")))
            profile = profile_only(config, name)
            if profile is not None:   # filter wheel, M3: profile moves, whatever the drive offers
                entry["tcs_mode"], entry["tcs_mode_reason"] = "PP", profile
    probed = set(node_ids)
    missing = [{"drive": name, "node_id": s.node_id} for name, s in config.drives.items()
               if s.node_id in probed and s.node_id not in answers]
    skipped = [name for name, s in config.drives.items() if s.node_id not in probed]
    out.data.update(bus=f"{config.can.interface}:{config.can.channel}", simulated=simulate,
                    probed=len(node_ids), nodes=nodes, missing=missing, not_probed=skipped)
    out.lines.append(f"bus {config.can.interface}:{config.can.channel}: {len(nodes)} node(s) "
                     f"answered of {len(node_ids)} probed" + (" (simulated drives)" if simulate else ""))
    for e in nodes:
        ident = e.get("identity") or {}
        ident_text = " ".join(f"{k} 0x{v:08X}" for k, v in ident.items() if v is not None)
        state = e.get("state") or "-"
        nmt = e["nmt"] or "no heartbeat"
        err = (f"error 0x{e['error_code']:04X} {e['error']}" if e.get("error_code")
               else "no error")
        reg = e.get("error_register")
        out.lines.append(f"  node {e['node_id']:3d}: {e['device_type'] or e.get('note')} {ident_text}")
        out.lines.append(f"            NMT {nmt}, 402 {state}, error register "
                         f"{'-' if reg is None else f'0x{reg:02X}'}, {err}")
        if e.get("cia402"):
            offered = e.get("offered") or "not stated (no 0x6502)"
            used = f"; the TCS uses {e['tcs_mode']} ({e['tcs_mode_reason']})" if e.get("tcs_mode") else ""
            out.lines.append(f"            modes offered: {offered}{used}")
            if e.get("pdo_layout") is not None:
                source = "hardware file" if e.get("pdo_hand_written") else "from the EDS"
                out.lines.append(f"            PDO layout ({source}):" +
                                 ("" if e["pdo_layout"] else " none"))
                out.lines.extend(f"              {line}" for line in e["pdo_layout"])
                out.lines.extend(f"              does not fit: {text}" for text in e["pdo_problems"])
                out.lines.extend(f"              note: {text}" for text in e["pdo_notes"])
        out.lines.append(f"            -> {'drive ' + e['drive'] + ': ' if e['drive'] else ''}{e['match']}")
    for m in missing:
        out.lines.append(f"  MISSING: drive {m['drive']} (node {m['node_id']}) did not answer")
    if skipped:
        out.lines.append(f"  not probed (outside --nodes): {', '.join(skipped)}")
    wrong = [e for e in nodes if e["drive"] and e["match"] != "ok"]
    if wrong:
        out.fail("; ".join(f"drive {e['drive']} (node {e['node_id']}): {e['match']}" for e in wrong))
    if missing:
        out.fail("configured drive(s) not found: " + ", ".join(
            f"{m['drive']} (node {m['node_id']})" for m in missing), ExitCode.HARDWARE)
    return out
