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
        "drive_state": None if drive is None else drive.state.name,
        "sample": None,
    }
    if sample is not None:
        sync, actual, setpoint_t, demand = sample
        out["sample"] = {"sync": _stamps(sync, base), "actual": _num(actual),
                         "demand_time": _stamps(setpoint_t, base), "demand": _num(demand)}
    return out


def plc_axis_snapshot(module) -> dict[str, Any]:
    stale = _safe(lambda: module.stale)
    fresh = stale is None
    return {
        "name": module.module_name,
        "fresh": fresh,
        "position": _num(module.real_position) if fresh else None,
        "target": _num(_safe(lambda: module.target_position)),
        "motion_state": int(module.motion_state) if fresh else None,
        "motion": motion_text(int(module.motion_state) if fresh else None),
        "power": _num(module.power_state) if fresh else None,
        "error_state": int(module.error_state),
        "closing": bool(getattr(module, "closing", False)),
    }


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
    snap["dome"] = [plc_axis_snapshot(m) for m in (tel.dome or []) if m is not None]
    snap["covers"] = [plc_axis_snapshot(m) for m in per.covers]
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
    snap["build"] = {"version": str(tcs.__version__), "python": platform.python_version(),
                     "config": str(tel.config.source.name)}
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


def _horizon(tel) -> list[list[float]] | None:
    """The lowest altitude the pointing tracks to (``[pointing] min_altitude``), as a table
    of [azimuth, altitude] pairs for the sky plot (degrees)."""
    if tel.pointing is None:
        return None
    alt = float(tel.config.pointing.min_altitude)
    return [[float(az), alt] for az in range(0, 361, 10)]
