"""``tcs-commission info AXIS``: a drive's configuration as the drive holds it, and live values.

Read-only, over SDO, without booting the drive: every object the driver would write at boot
(:func:`tcs.drivers.boot.configuration` — heartbeat, SYNC and interpolation period, software
limits, following-error window, profile dynamics, homing) is read back and shown beside the
value the hardware file asks for, so a drive configured by an earlier service run can be
checked; then identity, state and the live values (statusword, mode, position, velocity,
following error, digital inputs, error register and code) in user units.

The service writes every one of these objects at each boot, and most drives forget them at
power-off: a drive the service has not booted since it powered up holds its own defaults, so
its differences say nothing. Whether the service configured it is read from the producer
heartbeat time 0x1017, which the service writes first and nothing changes afterwards: when
it differs, the rows are marked ``·`` ("written at the next boot") and a summary says so;
only a configured drive's differences are marked ``≠``. 0x1006 may also hold the idle SYNC's
period (``[can] idle_sync_period``), which the service sets while every drive rests.

Exit codes: 0 read, 3 the node does not answer.
"""

from __future__ import annotations

from tcs.drivers.boot import NAMES, configuration, object_name
from tcs.drivers.cia402 import decode_state
from tcs.drivers.emcy import describe
from tcs.errors import CommunicationError, HardwareError

from tcs.commission.common import CommissionError, ExitCode, Outcome, fmt, resolve_target
from tcs.commission.scan import bare_sdo, compare_identity, optional
from tcs.commission.session import DriveSession, prepare_config

#: Live objects: (index, format, key, scaled to user units).
LIVE = ((0x6041, "<H", "statusword", None), (0x6061, "<b", "mode", None),
        (0x6064, "<i", "position", "position"), (0x606C, "<i", "velocity", "velocity"),
        (0x60F4, "<i", "following_error", "position"), (0x60FD, "<I", "digital_inputs", None),
        (0x1001, "<B", "error_register", None), (0x603F, "<H", "error_code", None))


def add_parser(subparsers, parents) -> None:
    p = subparsers.add_parser("info", parents=parents,
                              help="a drive's configuration (read back) and live values",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("axis", help="axis or drive name")


def run(args, config) -> Outcome:
    out = Outcome("info")
    target = resolve_target(config, args.axis)
    config, simulate = prepare_config(config, args.simulate)
    section = target.section
    k = section.increments_per_unit
    device = f"drive {target.drive} (node {section.node_id})"
    rows = []
    live: dict = {}
    with DriveSession(config, simulate=simulate, check_bus=not args.force) as session:
        with bare_sdo(session.network, section.node_id, config.can.sdo_timeout, device) as sdo:
            try:
                device_type = sdo.read(0x1000, 0, "<I")
            except CommunicationError as exc:
                raise CommissionError(f"{exc.message}: is the drive powered and its node id "
                                      f"{section.node_id}?", ExitCode.HARDWARE) from exc
            identity = {name: optional(sdo, 0x1018, sub, "<I") for sub, name in
                        ((1, "vendor"), (2, "product"), (3, "revision"), (4, "serial"))}
            for index, sub, f, want in configuration(section, config.can, device):
                try:
                    got = sdo.read(index, sub, f)
                    note = None
                except HardwareError as exc:
                    got, note = None, exc.message.split(": ", 1)[-1]
                rows.append({"object": f"0x{index:04X}:{sub}",
                             "name": object_name(index) or NAMES.get(index, ""),
                             "file": want, "drive": got, "match": got == want, "note": note})
            for index, f, key, scale in LIVE:
                value = optional(sdo, index, 0, f)
                live[key] = value
                if value is not None and scale is not None:
                    live[key] = value / k
    sw = live.get("statusword")
    state = decode_state(sw) if sw is not None else None
    code = live.get("error_code")
    inputs = live.get("digital_inputs")
    live["state"] = state.value if state is not None else None
    live["error"] = describe(code)[0] if code else None
    if inputs is not None:
        live["negative_limit"] = bool(inputs & 1)
        live["positive_limit"] = bool(inputs & 2)
        live["home_switch"] = bool(inputs & 4)
    idle = getattr(config.can, "idle_sync_period", None)
    for r in rows:
        if not r["match"] and r["object"] == "0x1006:0" and idle and r["drive"] == round(idle * 1e6):
            r["match"], r["note"] = True, "idle SYNC period"
    heartbeat = next((r for r in rows if r["object"] == "0x1017:0"), None)
    configured = heartbeat is not None and heartbeat["match"]
    differing = [r for r in rows if not r["match"]]
    wrong = compare_identity(section, identity)
    axis = target.axis_section
    out.data.update(
        drive=target.drive, axis=target.axis, node_id=section.node_id, simulated=simulate,
        device_type=f"0x{device_type:08X}", identity=identity, identity_ok=not wrong,
        file={"increments_per_unit": k, "min_position": section.min_position,
              "max_position": section.max_position, "default_mode": section.default_mode,
              "homing_method": section.homing.method, "homing_timeout": section.homing.timeout,
              "axis_min": axis.min if axis else None, "axis_max": axis.max if axis else None,
              "module": axis.module if axis else None},
        configuration=rows, configured_by_service=configured,
        differing=[r["object"] for r in differing], live=live)
    out.lines.append(f"{target.label}: node {section.node_id}, device type 0x{device_type:08X}, "
                     + " ".join(f"{n} 0x{v:08X}" for n, v in identity.items() if v is not None))
    if wrong:
        out.lines.append("  IDENTITY DIFFERS from the hardware file: " + ", ".join(wrong))
    if axis:
        out.lines.append(f"  axis {target.axis}: module {axis.module}, limits [{axis.min:g}, "
                         f"{axis.max:g}]")
    out.lines.append(f"  drive limits [{section.min_position:g}, {section.max_position:g}], "
                     f"{k:g} increments/unit, mode {section.default_mode}, homing method "
                     f"{section.homing.method} (time-out {section.homing.timeout:g} s)")
    out.lines.append("  configuration the service writes at every boot (drive now / hardware file):")
    for r in rows:
        mark = "  " if r["match"] else ("≠ " if configured else "· ")
        shown = r["note"] if r["drive"] is None else r["drive"]
        out.lines.append(f"   {mark}{r['object']:<9} {r['name']:<28} {shown!s:>12} / {r['file']}")
    if not differing:
        out.lines.append("  every value is as the hardware file asks")
    elif configured:
        out.lines.append(f"  ≠ {len(differing)} value(s) differ on a drive the service has "
                         "configured: changed since (by another tool?) or refused by the drive; "
                         "the service writes them again at its next boot")
    else:
        out.lines.append(f"  · the drive holds its power-on values ({len(differing)} differ from "
                         "the file): the service has not booted it since it powered up, and "
                         "writes each of them at boot — nothing to do")
    out.lines.append(f"  live: state {live['state']}, statusword "
                     f"{'-' if sw is None else f'0x{sw:04X}'}, mode {live.get('mode')}, "
                     f"position {fmt(live.get('position'))}, velocity {fmt(live.get('velocity'))}, "
                     f"following error {fmt(live.get('following_error'))}")
    if inputs is not None:
        out.lines.append(f"        inputs 0x{inputs:08X} (negative limit {live['negative_limit']}, "
                         f"positive limit {live['positive_limit']}, home {live['home_switch']})")
    reg = live.get("error_register")
    out.lines.append(f"        error register {'-' if reg is None else f'0x{reg:02X}'}, "
                     + (f"error code 0x{code:04X} {live['error']}" if code else "no error"))
    if wrong:
        out.fail(f"{device}: wrong identity: " + ", ".join(wrong))
    return out
