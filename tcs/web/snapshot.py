"""One snapshot of the whole telescope, as plain data: what the status page, ``/status.json``
and ``/metrics`` all show.

:func:`take` reads the running :class:`tcs.app.Service` once, on the service's event loop, in
one synchronous pass (no ``await`` inside, so no command of a TPL2 client runs in between) and
returns a JSON-ready dict. It only reads: every value comes from the same model attributes the
OpenTCI tree serves (``AZ.REALPOS`` is ``axis.real_position`` …), with the tree's rule that a
measured value without a fresh readback is unknown (``null``), never the last one.

Time: ``time`` has UTC, UT1 and TAI of the moment the snapshot was taken (LOCAL's clock and
offsets). Each axis carries its ``sample``, stamped in the control loop (in the control process
when it runs there) with the time of the SYNC it belongs to: the position the drive measured
at that SYNC and the setpoint sent in the same cycle with the time the drive reaches it
(:attr:`tcs.axes.axis.Axis.sample`; UTC and TAI from the same UT1 with LOCAL's offsets). The
snapshot's ``sync`` is the newest of them, so a consumer can tell which control cycle it shows.
"""

from __future__ import annotations

import logging
import math
import platform
import time
from typing import Any

import tcs
from tcs.errors import TcsError

log = logging.getLogger(__name__)

#: Modules whose positions are angles in degrees (their following error is shown in arcsec).
ANGULAR = frozenset({"AZ", "ZD", "HA", "DEC", "DEROTATOR", "DOME"})
ARCSEC = 3600.0
#: Motion state bits (OpenTCI generic axis): 1 moving, 2 trajectory, 4 blocked, 8 on target, 16 limited.
MOTION_BITS = ((1, "moving"), (2, "trajectory"), (4, "blocked"), (8, "on target"), (16, "limited"))


def _num(value) -> float | None:
    """A finite float, or None (JSON has no NaN)."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


_reported: set = set()


def _safe(fn, default=None):
    """``fn()``, or ``default`` when it raises: a TcsError is the model saying the value is
    unknown now (a stale drive, a lost PLC); anything else is a bug here, logged once per place."""
    try:
        return fn()
    except TcsError:
        return default
    except Exception:
        where = getattr(fn, "__code__", None)
        key = (where.co_filename, where.co_firstlineno) if where is not None else repr(fn)
        if key not in _reported:
            _reported.add(key)
            log.exception("status snapshot: a value could not be read (reported once)")
        return default


def motion_text(state: int | None) -> str:
    if state is None:
        return "unknown"
    names = [name for bit, name in MOTION_BITS if state & bit]
    return ", ".join(names) if names else "idle"


def _time_base(local) -> dict[str, float]:
    return {"ut1_utc": local.ut1_utc, "tai_utc": local.tai_utc}


def _stamps(ut1: float | None, base: dict[str, float]) -> dict[str, float | None]:
    if ut1 is None:
        return {"ut1": None, "utc": None, "tai": None}
    utc = ut1 - base["ut1_utc"]
    return {"ut1": ut1, "utc": utc, "tai": utc + base["tai_utc"]}


def axis_snapshot(axis, base: dict[str, float]) -> dict[str, Any]:
    section = axis.section
    stale = getattr(axis, "stale", None)
    fresh = stale is None
    module = section.module
    angular = module in ANGULAR
    sample = getattr(axis, "sample", None)
    drive = _safe(axis.drive_status) if hasattr(axis, "drive_status") else None
    following = None
    if fresh and drive is not None and drive.following_error is not None:
        following = _num(drive.following_error)
    elif fresh and sample is not None and sample[3] is not None:
        following = _num(sample[1] - sample[3])
    fault = getattr(axis, "fault", None)
    out = {
        "name": axis.module_name,
        "module": module,
        "unit": "deg" if angular else ("mm" if module == "FOCUS" else "position"),
        "fresh": fresh,
        "stale": None if fresh else stale.message,
        "position": _num(axis.real_position) if fresh else None,
        "target": _num(axis.target_position),
        "distance": _num(_safe(lambda: axis.target_distance)) if fresh else None,
        "velocity": _num(axis.current_speed) if fresh else None,
        "offset": _num(axis.offset),
        "power": _num(axis.power_state) if fresh else None,
        "referenced": _num(axis.referenced),
        "motion_state": int(axis.motion_state) if fresh else None,
        "motion": motion_text(int(axis.motion_state) if fresh else None),
        "limit_state": int(axis.limit_state) if fresh else None,
        "error_state": int(axis.error_state),
        "fault": None if fault is None else fault.message,
        "following_error": following,
        "following_error_arcsec": None if following is None or not angular else following * ARCSEC,
        "min": section.min, "max": section.max,
        "park": _num(getattr(section, "park", None)),
        "drive_state": None if drive is None else drive.state.name,
        "sample": None,
    }
    if sample is not None:
        sync, actual, setpoint_t, demand = sample
        out["sample"] = {"sync": _stamps(sync, base), "actual": _num(actual),
                         "demand_time": _stamps(setpoint_t, base), "demand": _num(demand)}
    return out


#: How the status page names a dome part (the hardware file's part names, App. C.3 positions).
PART_LABELS = {"rotation": "rotation", "slit": "slit", "flap": "flap", "seal": "seal",
               "roof": "roof", "fold": "enclosure", "shell1": "first shell",
               "shell2": "second shell"}


def opening_text(part: str | None, position: float | None, low: float, high: float | None,
                 moving: bool) -> str:
    """What an opening part's position means: closed, open, or how far (App. C.3: the
    lowest position is closed). The rotation has no open or closed: its azimuth."""
    if position is None:
        return "unknown"
    if part == "rotation":
        return f"azimuth {position % 360.0:.1f}°" + (", moving" if moving else "")
    if part == "seal":
        word = "sealed" if position <= low + 1e-3 else "released"
        return word + (", moving" if moving else "")
    if high is None or high <= low:
        return f"{position:.2f}" + (", moving" if moving else "")
    fraction = (position - low) / (high - low)
    if fraction <= 0.005:
        word = "closed"
    elif fraction >= 0.995:
        word = "open"
    else:
        word = f"{fraction * 100:.0f} % open"
    return ("opening" if moving and word != "open" else word) if moving else word


def plc_axis_snapshot(module, part: str | None = None, label: str | None = None) -> dict[str, Any]:
    stale = _safe(lambda: module.stale)
    fresh = stale is None
    section = getattr(module, "section", None)
    low = float(getattr(section, "min", 0.0) or 0.0)
    high = getattr(section, "max", None)
    position = _num(module.real_position) if fresh else None
    motion_state = int(module.motion_state) if fresh else None
    moving = bool(motion_state and motion_state & 1)
    return {
        "name": module.module_name,
        "part": part,
        "label": label or PART_LABELS.get(part or "", part or ""),
        "fresh": fresh,
        "position": position,
        "target": _num(_safe(lambda: module.target_position)),
        "motion_state": motion_state,
        "motion": motion_text(motion_state),
        "state": opening_text(part, position, low, None if high is None else float(high), moving)
        if fresh else "unknown (no readback)",
        "power": _num(module.power_state) if fresh else None,
        "error_state": int(module.error_state),
        "fault": None if getattr(module, "_fault", None) is None else module._fault.message,
        "closing": bool(getattr(module, "closing", False)),
        # closed … fully open (App. C.3: 0 closed); a cyclic part (the dome's rotation) turns
        "min": _num(_safe(lambda: module.section.min)), "max": _num(_safe(lambda: module.section.max)),
        "cyclic": bool(_safe(lambda: module.section.cyclic, 0.0)),
    }


def _dome(tel) -> list[dict[str, Any]]:
    dome = getattr(tel.config, "dome", None)
    parts = _safe(dome.parts, {}) if dome is not None else {}
    out = []
    for index, module in enumerate(tel.dome or []):
        if module is None:
            continue
        part = parts.get(index, (None, None))[0]
        out.append(plc_axis_snapshot(module, part))
    return out


def _covers(tel) -> list[dict[str, Any]]:
    sections = list(getattr(tel.config, "covers", None) or [])
    out = []
    for i, module in enumerate(tel.peripherals.covers):
        name = getattr(sections[i], "name", "") if i < len(sections) else ""
        out.append(plc_axis_snapshot(module, "cover", name or "cover"))
    return out


def _point(module, what: str) -> dict[str, Any]:
    value = _safe(lambda: module.value)
    return {"name": module.module_name, "label": module.name, "unit": module.unit,
            "value": _num(value) if value is not None else None, "error_state": int(module.error_state),
            "kind": what}


def _sessions(server, front_end: str) -> list[dict[str, Any]]:
    if server is None:
        return []
    now = time.time()
    return [{"front_end": front_end, "id": s.id, "address": s.address, "user": s.username,
             "logged_in": bool(s.authenticated), "since": s.starttime, "age": now - s.starttime,
             "commands": len(s.commands)}
            for s in list(server.sessions.values())]


def _front_ends(service) -> dict[str, Any]:
    """Per front end that runs: open connections and its command counts and latencies
    (:class:`tcs.model.command_stats.CommandStats`)."""
    out = {}
    for name, server in (("opentci", service.server), ("opentsi", getattr(service, "opentsi_server", None)),
                         ("alpaca", getattr(service, "alpaca_server", None))):
        stats = getattr(server, "command_stats", None)
        if stats is None:
            continue
        connections = server.connections if name == "alpaca" else len(server.sessions)
        out[name] = {"connections": connections, **stats.figures()}
    return out


def take(service) -> dict[str, Any]:
    """The snapshot of ``service`` (call on its event loop)."""
    tel = service.telescope
    local = tel.local
    base = _time_base(local)
    now_ut1 = local.ut1()
    cab = tel.cabinet
    snap: dict[str, Any] = {
        "version": str(tcs.__version__),
        "time": {**_stamps(now_ut1, base), **base},
        "cabinet": {
            "power": _num(_safe(lambda: cab.power_state)),
            "referenced": _num(_safe(lambda: cab.referenced)),
            "error_state": int(_safe(lambda: cab.error_state, 0)),
            "errors": [{"device": e.device, "error": e.error, "bits": e.bits, "last": e.last,
                        "total": e.total, "count": e.count, "active": e.active}
                       for e in _safe(lambda: cab.status_list.entries(), [])],
        },
        "axes": [axis_snapshot(a, base) for a in tel.axes],
    }
    syncs = [a["sample"]["sync"]["ut1"] for a in snap["axes"] if a["sample"] is not None]
    snap["sync"] = _stamps(max(syncs) if syncs else None, base)
    loop = tel.control_loop
    stats = _safe(loop.stats, {}) if loop is not None else {}
    period = tel.config.can.sync_period if tel.config.can is not None else None
    snap["loop"] = {
        "running": loop is not None and bool(_safe(loop.healthy, False)),
        "period": period,
        "sync_interval": None if period is None else period * (stats.get("sync_divider") or 1),
        "cycles": stats.get("cycles"), "late": stats.get("late"), "missed": stats.get("missed"),
        "tpdo_timeouts": stats.get("tpdo_timeouts"), "errors": stats.get("errors"),
        "max_lateness": _num(stats.get("max_lateness")), "realtime": stats.get("realtime"),
        "loop_time_hist": stats.get("loop_time_hist"), "lateness_hist": stats.get("lateness_hist"),
    }
    bus = stats.get("bus")
    if bus is None and tel.can is not None and hasattr(tel.can, "bus"):  # (the loop in this process)
        from tcs.axes.control_core import bus_figures
        bus = _safe(lambda: bus_figures(tel.can))
    snap["can"] = bus
    snap["tracking"] = _tracking(tel)
    per = tel.peripherals
    snap["dome"] = _dome(tel)
    snap["covers"] = _covers(tel)
    snap["sensors"] = [_point(m, "sensor") for m in per.sensors]
    snap["switches"] = [_point(m, "switch") for m in per.switches]
    interlock = per.interlock
    snap["interlock"] = None if interlock is None else {
        "active": bool(interlock.active), "reason": interlock.reason,
        "causes": _safe(interlock.causes, {})}
    snap["plcs"] = [{"name": name, "connected": bool(d.connected), "message": d.message,
                     "round_trip": _num(d.stats.latencies[-1]) if d.stats.latencies else None,
                     "failures": d.stats.failures, "connects": d.stats.connects,
                     "poll_interval": d.stats.interval}
                    for name, d in per.drivers.items()]
    gps = per.gps
    if gps is None:
        snap["gps"] = None
    else:
        reader = gps.reader
        gps_time = _safe(lambda: gps.time)
        utc = snap["time"]["utc"]
        st = _safe(lambda: reader.status)
        snap["gps"] = {"position_good": bool(_safe(lambda: reader.position_good, False)),
                       "time_good": bool(_safe(lambda: reader.time_good, False)),
                       "time_valid": bool(_safe(lambda: reader.time_valid, False)),
                       "time_offset": None if gps_time is None else gps_time - utc,
                       "latitude": _num(_safe(lambda: gps.latitude)),
                       "longitude": _num(_safe(lambda: gps.longitude)),
                       "height": _num(_safe(lambda: gps.height)),
                       "data": bool(st.data_good) if st else False,
                       "satellites": st.satellites if st else None,
                       "fix_quality": st.fix_quality if st and st.data_good else 0,
                       "quality_name": st.quality_name if st and st.data_good else "no data",
                       "summary": _safe(lambda: st.summary(), ""),
                       "constellations": [
                           {"talker": t, "used": used, "in_view": view, "quality": q, "fix": bool(fix)}
                           for t, used, view, q, fix in (st.constellations if st else ())]}
    snap["clients"] = (_sessions(service.server, "opentci")
                       + _sessions(getattr(service, "opentsi_server", None), "opentsi"))
    snap["front_ends"] = _front_ends(service)
    snap["site"] = {"latitude": local.latitude, "longitude": local.served_longitude, "height": local.height}
    snap["horizon"] = _horizon(tel)
    snap["sun"] = _sun(tel, snap)
    snap["build"] = {"version": str(tcs.__version__), "python": platform.python_version(),
                     "config": str(tel.config.source.name)}
    snap["headline"] = _safe(lambda: headline(snap), {
        "state": "unknown", "level": "warn", "text": "State unknown (see the service log)",
        "remedy": "", "warnings": []})
    return snap


def _tracking(tel) -> dict[str, Any] | None:
    p = tel.pointing
    if p is None:
        return None
    track = int(_safe(lambda: p.track, 0) or 0)
    distance = _num(_safe(lambda: p.targetdistance)) if track else None
    target = _safe(lambda: p.target)
    current = _safe(lambda: p.current)
    out = {"mount": p.mount, "track": track, "tracking": bool(track),
           "distance": distance, "distance_arcsec": None if distance is None else distance * ARCSEC,
           "on_target": None, "target": None, "current": None}
    if track:
        axes = _safe(p._controlled, []) or []
        out["on_target"] = bool(axes) and all(a.motion_state & 8 for a in axes)
    for key, place in (("target", target), ("current", current)):
        if place is None:
            continue
        entry = {"ra": _num(_safe(lambda: place.ra)), "dec": _num(_safe(lambda: place.dec))}
        if key == "target" and not _safe(lambda: place.complete, False):
            entry = {"ra": None, "dec": None}
        entry.update(_horizontal(tel, p.mount, key))
        out[key] = entry
    out["target_distance"] = _separation(out["current"], out["target"])
    return out


def _separation(a, b) -> float | None:
    """Angle on the sky between two RA (hours) / Dec (degrees) places, degrees (or None)."""
    if not a or not b or None in (a.get("ra"), a.get("dec"), b.get("ra"), b.get("dec")):
        return None
    r1, d1 = math.radians(a["ra"] * 15.0), math.radians(a["dec"])
    r2, d2 = math.radians(b["ra"] * 15.0), math.radians(b["dec"])
    h = (math.sin((d2 - d1) / 2) ** 2 + math.cos(d1) * math.cos(d2) * math.sin((r2 - r1) / 2) ** 2)
    return math.degrees(2 * math.asin(min(1.0, math.sqrt(h))))


def _horizontal(tel, mount: str, key: str) -> dict[str, float | None]:
    """Azimuth and altitude (degrees) of where the telescope points (``current``: the observed
    place of an AZ-ZD mount's axes) or of the target (its observed place now, through the
    pointing's own pipeline; any mount)."""
    p = tel.pointing
    if key == "current":
        if mount != "AZ-ZD":
            return {"az": None, "alt": None}
        az, zd = tel.axis("AZ"), tel.axis("ZD")
        if az is None or zd is None or az.stale is not None or zd.stale is not None:
            return {"az": None, "alt": None}
        a, z = az.real_position, zd.real_position
        a += 180.0 if z < 0 else 0.0  # the reverse orientation: (AZ + 180°, −ZD)
        return {"az": _num(a % 360.0), "alt": _num(90.0 - abs(z))}
    target = p.target
    if not _safe(lambda: target.complete, False):
        return {"az": None, "alt": None}

    def observed():
        d = p.pipeline().demand(target.ra, target.dec, p.utc(), p.orientation_in_use())
        return float(d.observed.az[0]) % 360.0, 90.0 - float(d.observed.zd[0])
    place = _safe(observed)
    return {"az": None, "alt": None} if place is None else {"az": _num(place[0]), "alt": _num(place[1])}


def _envelope(tel):
    p = tel.pointing
    return None if p is None else getattr(p, "envelope", None)


def _horizon(tel) -> list[list[float]] | None:
    """The lowest altitude the telescope may point at: the envelope's horizon table, never
    below ``[pointing] min_altitude``, as [azimuth, altitude] pairs for the sky plot (degrees)."""
    if tel.pointing is None:
        return None
    env = _envelope(tel)
    azimuths = list(range(0, 361, 5))
    if env is not None:
        alts = _safe(lambda: [float(a) for a in env.min_altitude(azimuths)])
        if alts is not None:
            return [[float(az), alt] for az, alt in zip(azimuths, alts)]
    alt = float(tel.config.pointing.min_altitude)
    return [[float(az), alt] for az in azimuths]


#: seconds a Sun place is reused (it moves 0.04° in 10 s; the page is a glance, not a guard)
SUN_REUSE = 10.0
_sun_cache: dict = {}


def _sun(tel, snap) -> dict[str, Any] | None:
    """The Sun for the page: where it is (az, alt), the avoidance cone's radius, and how far
    the tube is from it now (degrees; None where the tube's place is unknown)."""
    env = _envelope(tel)
    utc = snap["time"]["utc"]
    if env is None or utc is None:
        return None
    key = (id(env), math.floor(utc / SUN_REUSE))
    place = _sun_cache.get(key)
    if place is None:
        place = _safe(lambda: env.sun_altaz(utc))
        if place is None:
            return None
        _sun_cache.clear()
        _sun_cache[key] = place
    az, alt = place
    current = (snap.get("tracking") or {}).get("current") or {}
    distance = None
    if current.get("az") is not None and current.get("alt") is not None:
        distance = _angle(az, alt, current["az"], current["alt"])
    return {"az": _num(az), "alt": _num(alt), "cone": _num(env.sun_radius),
            "distance": _num(distance)}


def _angle(az1: float, alt1: float, az2: float, alt2: float) -> float:
    """Angle between two horizontal places, degrees."""
    a1, h1, a2, h2 = map(math.radians, (az1, alt1, az2, alt2))
    c = math.sin(h1) * math.sin(h2) + math.cos(h1) * math.cos(h2) * math.cos(a1 - a2)
    return math.degrees(math.acos(max(-1.0, min(1.0, c))))


# ---------------------------------------------------------------------------- the headline
#: OpenTCI ERROR_STATE bits (spec §4)
PANIC, ERROR, WARNING = 1, 2, 4
ACKNOWLEDGE = "fix the cause, then acknowledge: tcs-client set CABINET.ERROR_STATE=0"


def _hours(ra: float) -> str:
    h = ra % 24.0
    hh, rest = divmod(round(h * 3600.0), 3600)
    mm, ss = divmod(rest, 60)
    return f"{hh % 24:02d}h{mm:02d}m{ss:02d}s"


def _degrees(dec: float) -> str:
    sign = "-" if dec < 0 else "+"
    d, rest = divmod(round(abs(dec) * 3600.0), 3600)
    m, s = divmod(rest, 60)
    return f"{sign}{d:02d}°{m:02d}′{s:02d}″"


def _place(p: dict | None) -> str:
    if not p or p.get("ra") is None or p.get("dec") is None:
        return "the target"
    return f"RA {_hours(p['ra'])} Dec {_degrees(p['dec'])}"


def headline(snap: dict[str, Any]) -> dict[str, Any]:
    """One line that says what the telescope is doing and, when something is wrong, what and
    what to do: ``{"state", "level" (ok, info, warn, bad, off), "text", "remedy",
    "warnings"}``. The first match wins: faults and lost links, the weather, power and
    referencing, then what it is doing (slewing, tracking, moving, ready)."""
    cab, loop = snap["cabinet"], snap["loop"]
    axes = snap["axes"]
    main_names = {"AZ", "ZD", "HA", "DEC"}
    warnings = [f"{e['device']}: {e['error']}" for e in cab["errors"]
                if e.get("active") and e.get("bits", 0) & WARNING and not e.get("bits", 0) & (PANIC | ERROR)]

    def out(state, level, text, remedy=""):
        return {"state": state, "level": level, "text": text, "remedy": remedy, "warnings": warnings}

    if snap.get("can") is not None and not loop["running"]:
        return out("fault", "bad", "Control loop stopped: the drives are not commanded",
                   "see the service log (journalctl -u tcs-server); the drives stopped themselves")
    for a in axes:
        if a.get("fault"):
            return out("fault", "bad", f"Fault: {a['name']}: {a['fault']}", ACKNOWLEDGE)
    for plc in snap["plcs"]:
        if not plc["connected"]:
            return out("fault", "bad", f"PLC {plc['name']} lost" + (f": {plc['message']}" if plc.get("message") else ""),
                       "check the PLC's power and network; its dome, covers, sensors and switches "
                       "read unknown meanwhile and recover by themselves when it answers")
    for m in [*snap["dome"], *snap["covers"]]:
        if m["error_state"] & (PANIC | ERROR):
            what = f": {m['fault']}" if m.get("fault") else ""
            return out("fault", "bad", f"Fault: {m['name']} ({m['label']}){what}", ACKNOWLEDGE)
    active = [e for e in cab["errors"] if e.get("active") and e.get("bits", 0) & (PANIC | ERROR)]
    if active:
        e = active[0]
        return out("fault", "bad", f"Error: {e['device']}: {e['error']}", ACKNOWLEDGE)
    if cab["error_state"] & (PANIC | ERROR):
        return out("fault", "bad", f"Error state {cab['error_state']} (see CABINET.STATUS.LIST)",
                   ACKNOWLEDGE)
    stale = [a["name"] for a in axes if not a["fresh"]]
    if stale:
        return out("fault", "bad", "No readback from " + ", ".join(stale),
                   "check the drive's power and the CAN bus (see the service log)")
    il = snap.get("interlock")
    weather = ("; weather interlock: " + il["reason"]) if il and il.get("active") else ""
    main = [a for a in axes if a["module"] in main_names]
    moving = [a for a in axes if a["motion_state"] and a["motion_state"] & 1]
    power = cab["power"]
    if not power:
        parked = bool(main) and all(a["position"] is not None and a.get("park") is not None
                                    and abs(a["position"] - a["park"]) < 0.05 for a in main)
        return out("off", "off", ("Parked, power off" if parked else "Power off") + weather,
                   "tcs-client ready (power on and reference)")
    if il and il.get("active"):
        return out("weather", "warn", "Weather interlock: " + il["reason"],
                   "the dome and covers stay closed until the weather clears")
    t = snap.get("tracking") or {}
    referencing = [a["name"] for a in axes if a["referenced"] is not None and a["referenced"] < 1
                   and a["motion_state"] and a["motion_state"] & 1]
    if referencing:
        return out("referencing", "info", "Referencing " + ", ".join(referencing), "")
    unreferenced = [a for a in axes if a["referenced"] is not None and a["referenced"] < 1
                    and a["power"]]
    if any(a["module"] in main_names for a in unreferenced):
        return out("unreferenced", "warn", "Not referenced: " + ", ".join(a["name"] for a in unreferenced),
                   "tcs-client ready (or CABINET.REINIT=1)")
    if unreferenced:  # the main axes are: what they do comes first, the rest is a warning
        warnings.append("not referenced: " + ", ".join(a["name"] for a in unreferenced))
    if t.get("tracking"):
        if t.get("on_target"):
            return out("tracking", "ok", "Tracking " + _place(t.get("target")), "")
        togo = t.get("target_distance")
        return out("slewing", "info", "Slewing to " + _place(t.get("target"))
                   + (f", {togo:.1f}° to go" if togo is not None else ""), "")
    if moving:
        parts = ", ".join(f"{a['name']} to {a['target']:.2f}" if a.get("target") is not None else a["name"]
                          for a in moving)
        return out("moving", "info", "Moving: " + parts, "")
    if unreferenced:
        return out("unreferenced", "warn", "Ready, but not referenced: "
                   + ", ".join(a["name"] for a in unreferenced), "tcs-client ready (or CABINET.REINIT=1)")
    if warnings:
        return out("warning", "warn", "Ready, with a warning: " + warnings[0],
                   "acknowledge with tcs-client set CABINET.ERROR_STATE=0 once seen")
    return out("ready", "ok", "Ready: powered, referenced, at rest", "")
