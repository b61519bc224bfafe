"""``/metrics``: the snapshot (:mod:`tcs.web.snapshot`) in the Prometheus text format.

:class:`SnapshotCollector` is a ``prometheus_client`` collector on a registry of its own (not
the library's global one): each scrape turns the newest snapshot into metric families, and
``prometheus_client.generate_latest`` writes them — no hand-written formatter. The few
counters the model does not keep itself (drive faults, limit hits: a new fault or limit seen
by a snapshot) are counted by :class:`Counters`, which the web server feeds every snapshot.

Conventions: every name starts with ``tcs_``; seconds for times; every family has one unit,
named at its end (``_degrees``, ``_millimetres``, ``_arcsec``, ``_ratio``, ``_seconds``): an
axis's position, target, target distance and velocity are ``tcs_axis_*_degrees`` for the
angular axes (AZ, ZD, HA, DEC, DEROTATOR), ``tcs_axis_*_millimetres`` for FOCUS and
``tcs_axis_discrete_*`` (the number of the position: filter slot, M3 port) for FILTER and
MIRROR — :data:`AXIS_FAMILIES`; the dome's azimuth is ``tcs_dome_azimuth_degrees``, how far each
other dome part and cover is open ``tcs_enclosure_open_ratio`` (0 closed … 1 fully open).
Labels are the fixed names of the hardware file (``axis="AZ"``, ``plc="dome"``) — nothing per
client or per request. A measured value without a fresh readback is left out (absent =
unknown), never reported with its last value; so is ``tcs_tracking_error_arcsec`` while no
tracking runs on its path (not tracking, or still slewing to the target:
:attr:`Counters.on_path`).
"""

from __future__ import annotations

from typing import Any, Iterable

from prometheus_client import CollectorRegistry, generate_latest
from prometheus_client.core import (CounterMetricFamily, GaugeMetricFamily, HistogramMetricFamily,
                                    InfoMetricFamily)

from tcs.axes.control_loop import HISTOGRAM_BOUNDS
from tcs.model.command_stats import LATENCY_BOUNDS

CONTENT_TYPE = "text/plain; version=0.0.4; charset=utf-8"
#: The CAN controller states of :class:`tcs.drivers.canbus.BusHealth`.
BUS_STATES = ("ok", "warning", "passive", "bus-off", "failed")


#: (snapshot key, the axis's unit) → the family of that quantity in that unit, and its help.
AXIS_FAMILIES: dict[tuple[str, str], tuple[str, str]] = {
    ("position", "deg"): ("tcs_axis_position_degrees", "REALPOS of an angular axis, degrees"),
    ("position", "mm"): ("tcs_axis_position_millimetres", "REALPOS of a linear axis (FOCUS), mm"),
    ("position", "position"): ("tcs_axis_discrete_position",
                               "REALPOS of a discrete axis: the number of its position (filter slot, M3 port)"),
    ("target", "deg"): ("tcs_axis_target_degrees", "TARGETPOS of an angular axis, degrees"),
    ("target", "mm"): ("tcs_axis_target_millimetres", "TARGETPOS of a linear axis (FOCUS), mm"),
    ("target", "position"): ("tcs_axis_discrete_target", "TARGETPOS of a discrete axis: a position number"),
    ("distance", "deg"): ("tcs_axis_target_distance_degrees",
                          "TARGETDISTANCE (TARGETPOS - CURRPOS) of an angular axis, degrees"),
    ("distance", "mm"): ("tcs_axis_target_distance_millimetres",
                         "TARGETDISTANCE (TARGETPOS - CURRPOS) of a linear axis (FOCUS), mm"),
    ("distance", "position"): ("tcs_axis_discrete_target_distance",
                               "TARGETDISTANCE of a discrete axis, in position numbers"),
    ("velocity", "deg"): ("tcs_axis_velocity_degrees_per_second", "CURRSPEED of an angular axis, degrees/s"),
    ("velocity", "mm"): ("tcs_axis_velocity_millimetres_per_second", "CURRSPEED of a linear axis (FOCUS), mm/s"),
    ("velocity", "position"): ("tcs_axis_discrete_velocity",
                               "CURRSPEED of a discrete axis, position numbers per second"),
}


class Counters:
    """Counts fault and limit transitions between snapshots (per axis name), and follows
    whether tracking runs on its path (:attr:`on_path`)."""

    def __init__(self) -> None:
        self.faults: dict[str, int] = {}
        self.limit_hits: dict[str, int] = {}
        self._fault: dict[str, Any] = {}
        self._limit: dict[str, int] = {}
        #: True from the first snapshot that finds every tracked axis on target until tracking
        #: ends or the target changes: the slew to the target is over, what POINTING.TARGETDISTANCE
        #: reads is the tracking error (during the slew it is the distance still to go)
        self.on_path = False
        self._tracked: Any = None

    def update(self, snap: dict[str, Any]) -> None:
        self._follow_tracking(snap.get("tracking"))
        for axis in snap.get("axes", ()):
            name = axis["name"]
            self.faults.setdefault(name, 0)
            self.limit_hits.setdefault(name, 0)
            fault = axis["fault"]
            if fault is not None and self._fault.get(name) is None:
                self.faults[name] += 1
            self._fault[name] = fault
            limit = axis["limit_state"]
            if limit is not None:
                if limit and not self._limit.get(name):
                    self.limit_hits[name] += 1
                self._limit[name] = limit

    def _follow_tracking(self, t: dict[str, Any] | None) -> None:
        if not t or not t["tracking"]:
            self.on_path, self._tracked = False, None
            return
        target = t.get("target") or {}
        tracked = (t.get("track"), target.get("ra"), target.get("dec"))
        if tracked != self._tracked:  # a new goal: a new slew first
            self.on_path, self._tracked = False, tracked
        if t["on_target"]:
            self.on_path = True


def _gauge(name: str, doc: str, labels: list[str] | None = None) -> GaugeMetricFamily:
    return GaugeMetricFamily(name, doc, labels=labels or [])


def _one(name: str, doc: str, value: float, counter: bool = False):
    """A family of one unlabelled sample (a gauge, or a counter)."""
    family = CounterMetricFamily(name, doc) if counter else GaugeMetricFamily(name, doc)
    family.add_metric([], value)
    return family


def _buckets(bounds, counts) -> list[tuple[str, int]]:
    """Cumulative Prometheus buckets of per-bucket ``counts`` (the last one past every bound)."""
    buckets, running = [], 0
    for bound, count in zip((*bounds, float("inf")), counts):
        running += count
        buckets.append(("+Inf" if bound == float("inf") else repr(bound), running))
    return buckets


def _histogram(name: str, doc: str, data) -> HistogramMetricFamily | None:
    if not data:
        return None
    counts, total = data
    family = HistogramMetricFamily(name, doc)
    family.add_metric([], _buckets(HISTOGRAM_BOUNDS, counts), total)
    return family


class SnapshotCollector:
    """A collector over ``source()`` (the newest snapshot) and ``counters``."""

    def __init__(self, source, counters: Counters):
        self.source = source
        self.counters = counters

    def collect(self) -> Iterable:
        snap = self.source()
        if snap is None:
            return
        yield from self._build(snap)
        yield from self._cabinet(snap)
        yield from self._axes(snap)
        yield from self._loop(snap)
        yield from self._can(snap)
        yield from self._tracking(snap)
        yield from self._enclosure(snap)
        yield from self._links(snap)
        yield from self._front_ends(snap)

    # -- families ------------------------------------------------------------------------------
    @staticmethod
    def _build(snap):
        info = InfoMetricFamily("tcs_build", "the running tcs: version, Python, hardware file")
        b = snap["build"]
        info.add_metric([], {"version": b["version"], "python": b["python"], "config": b["config"]})
        yield info
        t = snap["time"]
        yield _one("tcs_snapshot_timestamp_seconds", "UTC (Unix seconds) when the snapshot shown was taken", t["utc"])
        sync = snap.get("sync") or {}
        if sync.get("utc") is not None:
            yield _one("tcs_sync_timestamp_seconds",
                       "UTC of the newest control cycle's SYNC in the snapshot (Unix seconds)", sync["utc"])
        yield _one("tcs_tai_utc_seconds", "TAI - UTC in use (LOCAL.TAI-UTC)", t["tai_utc"])
        yield _one("tcs_ut1_utc_seconds", "UT1 - UTC in use (LOCAL.UT1-UTC)", t["ut1_utc"])

    @staticmethod
    def _cabinet(snap):
        c = snap["cabinet"]
        for key, name, doc in (("power", "tcs_cabinet_power", "CABINET.POWER state (0 off … 1 on)"),
                               ("referenced", "tcs_cabinet_referenced", "CABINET.REFERENCED (0 … 1)"),
                               ("error_state", "tcs_cabinet_error_state", "CABINET.ERROR_STATE bits")):
            if c[key] is not None:
                yield _one(name, doc, c[key])
        g = _gauge("tcs_cabinet_status_entries", "entries of CABINET.STATUS.LIST", ["active"])
        errors = c["errors"]
        g.add_metric(["1"], sum(1 for e in errors if e["active"]))
        g.add_metric(["0"], sum(1 for e in errors if not e["active"]))
        yield g

    def _axes(self, snap):
        axes = snap["axes"]
        fam = {
            "info": InfoMetricFamily("tcs_axis", "the axes of the hardware file and their position unit",
                                     labels=["axis"]),
            "fresh": _gauge("tcs_axis_fresh", "1 while the drive gives fresh readbacks (else the "
                                              "measured values are unknown and left out)", ["axis"]),
            "following": _gauge("tcs_axis_following_error_arcsec",
                                "following error of the drive (measured - demand), arcsec", ["axis"]),
            "motion": _gauge("tcs_axis_motion_state", "MOTION_STATE bits (1 moving, 2 trajectory, "
                                                      "4 blocked, 8 on target, 16 limited)", ["axis"]),
            "moving": _gauge("tcs_axis_moving", "1 while the axis moves (MOTION_STATE bit 0)", ["axis"]),
            "power": _gauge("tcs_axis_power", "POWER state (0 off, 1 on)", ["axis"]),
            "referenced": _gauge("tcs_axis_referenced", "REFERENCED (0 no, 1 yes)", ["axis"]),
            "error_state": _gauge("tcs_axis_error_state", "ERROR_STATE bits", ["axis"]),
            "fault": _gauge("tcs_axis_fault", "1 while the axis has a drive fault", ["axis"]),
            "limit": _gauge("tcs_axis_limit_state", "LIMIT_STATE bits (0: no limit)", ["axis"]),
            "sync": _gauge("tcs_axis_sample_timestamp_seconds",
                           "UTC of the SYNC at which the position shown was measured", ["axis"]),
        }
        faults = CounterMetricFamily("tcs_axis_drive_faults", "drive faults seen (a new fault)", labels=["axis"])
        limits = CounterMetricFamily("tcs_axis_limit_hits", "times a limit was reached (LIMIT_STATE became non-zero)",
                                     labels=["axis"])
        units = {(key, unit): _gauge(name, doc, ["axis"]) for (key, unit), (name, doc) in AXIS_FAMILIES.items()
                 if any(a["unit"] == unit for a in axes)}
        for a in axes:
            name = [a["name"]]
            fam["info"].add_metric(name, {"unit": a["unit"], "module": a["module"]})
            fam["fresh"].add_metric(name, 1.0 if a["fresh"] else 0.0)
            for key in ("position", "target", "distance", "velocity"):
                if a[key] is not None and (key, a["unit"]) in units:
                    units[key, a["unit"]].add_metric(name, a[key])
            for key, value in (("following", a["following_error_arcsec"]), ("motion", a["motion_state"]),
                               ("power", a["power"]), ("referenced", a["referenced"]),
                               ("error_state", a["error_state"]), ("limit", a["limit_state"])):
                if value is not None:
                    fam[key].add_metric(name, value)
            if a["motion_state"] is not None:
                fam["moving"].add_metric(name, float(a["motion_state"] & 1))
            fam["fault"].add_metric(name, 0.0 if a["fault"] is None else 1.0)
            sample = a["sample"]
            if a["fresh"] and sample is not None and sample["sync"]["utc"] is not None:
                fam["sync"].add_metric(name, sample["sync"]["utc"])
            faults.add_metric(name, self.counters.faults.get(a["name"], 0))
            limits.add_metric(name, self.counters.limit_hits.get(a["name"], 0))
        yield from fam.values()
        yield from units.values()
        yield faults
        yield limits

    @staticmethod
    def _loop(snap):
        loop = snap["loop"]
        yield _one("tcs_control_loop_running", "1 while the control loop runs (healthy)",
                   1.0 if loop["running"] else 0.0)
        if loop["period"] is not None:
            yield _one("tcs_control_loop_sync_period_seconds", "the SYNC period ([can] sync_period)", loop["period"])
        if loop.get("sync_interval") is not None:
            yield _one("tcs_control_loop_sync_interval_seconds", "the time between SYNCs now: the "
                       "period, or [can] idle_sync_period while every drive rests", loop["sync_interval"])
        for key, name, doc in (("cycles", "tcs_control_loop_cycles", "control cycles run"),
                               ("late", "tcs_control_loop_late_cycles", "cycles whose work ended after the next SYNC was due"),
                               ("missed", "tcs_control_loop_missed_cycles", "SYNC slots skipped (the loop was still busy)"),
                               ("tpdo_timeouts", "tcs_control_loop_tpdo_timeouts", "cycles run without every synchronous TPDO"),
                               ("errors", "tcs_control_loop_errors", "axis steps that raised")):
            if loop[key] is not None:
                yield _one(name, doc, loop[key], counter=True)
        if loop["max_lateness"] is not None:
            yield _one("tcs_control_loop_max_lateness_seconds", "worst SYNC lateness since start",
                       loop["max_lateness"])
        if loop["realtime"] is not None:
            yield _one("tcs_control_loop_realtime", "1 when the loop runs with real-time priority", loop["realtime"])
        for fam in (_histogram("tcs_control_loop_lateness_seconds", "SYNC lateness of each cycle",
                               loop["lateness_hist"]),
                    _histogram("tcs_control_loop_time_seconds", "time of each control loop step",
                               loop["loop_time_hist"])):
            if fam is not None:
                yield fam

    @staticmethod
    def _can(snap):
        bus = snap.get("can")
        if not bus:
            return
        g = _gauge("tcs_can_bus_state", "1 for the CAN controller's present state", ["state"])
        for state in BUS_STATES:
            g.add_metric([state], 1.0 if bus["state"] == state else 0.0)
        yield g
        for key, name, doc in (("error_frames", "tcs_can_error_frames", "CAN error frames received"),
                               ("bus_off", "tcs_can_bus_off", "times the controller went bus-off"),
                               ("send_failures", "tcs_can_send_failures", "frames that could not be sent"),
                               ("receive_failures", "tcs_can_receive_failures", "receive errors of the bus")):
            yield _one(name, doc, bus[key], counter=True)
        if "bits" not in bus:
            return
        c = CounterMetricFamily("tcs_can_frames", "CAN data frames seen by the TCS (received: the drives' "
                                "and the kernel's; sent: its own)", labels=["direction"])
        c.add_metric(["received"], bus["rx_frames"])
        c.add_metric(["sent"], bus["tx_frames"])
        yield c
        yield _one("tcs_can_frame_bits", "bits of those frames on the wire, without stuff bits "
                   "(rate / tcs_can_bitrate_bits_per_second = bus load)", bus["bits"], counter=True)
        yield _one("tcs_can_bitrate_bits_per_second", "the bus's bit rate ([can] bitrate)", bus["bitrate"])
        if bus["load"] is not None:
            yield _one("tcs_can_bus_load_ratio", "share of the bit rate used over the last second (0..1, "
                       "without stuff bits: up to ~20 % more on the wire)", bus["load"])

    def _tracking(self, snap):
        t = snap["tracking"]
        if t is None:
            return
        yield _one("tcs_tracking_active", "1 while POINTING tracks (POINTING.TRACK != 0)",
                   1.0 if t["tracking"] else 0.0)
        yield _one("tcs_tracking_on_target", "1 while tracking with every controlled axis on target",
                   1.0 if t["on_target"] else 0.0)
        if t["distance_arcsec"] is not None and t["tracking"] and self.counters.on_path:
            yield _one("tcs_tracking_error_arcsec", "POINTING.TARGETDISTANCE while tracking on the path (absent "
                       "while not tracking and during the slew to the target): largest distance of the "
                       "controlled axes from their demand on the sky", t["distance_arcsec"])
        if t["target_distance"] is not None:
            yield _one("tcs_tracking_target_distance_degrees",
                       "angle on the sky between POINTING.CURRENT and POINTING.TARGET", t["target_distance"])

    @staticmethod
    def _enclosure(snap):
        parts = [("dome", m) for m in snap["dome"]] + [("cover", m) for m in snap["covers"]]
        if parts:
            azimuth = _gauge("tcs_dome_azimuth_degrees", "azimuth of the dome's slit (DOME[0].REALPOS), degrees",
                             ["module"])
            opening = _gauge("tcs_enclosure_open_ratio", "how far a dome part or cover is open: 0 closed "
                             "… 1 fully open (REALPOS from !MIN to !MAX)", ["module", "kind"])
            mov = _gauge("tcs_enclosure_moving", "1 while the dome part or cover moves", ["module", "kind"])
            err = _gauge("tcs_enclosure_error_state", "ERROR_STATE bits", ["module", "kind"])
            for kind, m in parts:
                labels = [m["name"], kind]
                position, lo, hi = m["position"], m.get("min"), m.get("max")
                if position is not None and m.get("cyclic"):
                    azimuth.add_metric([m["name"]], position)
                elif position is not None and lo is not None and hi is not None and hi > lo:
                    opening.add_metric(labels, min(1.0, max(0.0, (position - lo) / (hi - lo))))
                if m["motion_state"] is not None:
                    mov.add_metric(labels, float(m["motion_state"] & 1))
                err.add_metric(labels, m["error_state"])
            yield from (azimuth, opening, mov, err)
        if snap["interlock"] is not None:
            yield _one("tcs_weather_interlock_active", "1 while the weather interlock holds dome and covers closed",
                       1.0 if snap["interlock"]["active"] else 0.0)
        if snap["sensors"]:
            g = _gauge("tcs_sensor_value", "SENSOR[].VALUE (the unit is the sensor's)", ["module", "name"])
            for s in snap["sensors"]:
                if s["value"] is not None:
                    g.add_metric([s["name"], s["label"]], s["value"])
            yield g
        if snap["switches"]:
            g = _gauge("tcs_switch_value", "SWITCH[].VALUE", ["module", "name"])
            for s in snap["switches"]:
                if s["value"] is not None:
                    g.add_metric([s["name"], s["label"]], s["value"])
            yield g

    @staticmethod
    def _links(snap):
        if snap["plcs"]:
            up = _gauge("tcs_plc_up", "1 while the PLC's Modbus link is up", ["plc"])
            rtt = _gauge("tcs_plc_round_trip_seconds", "the last Modbus request's round trip", ["plc"])
            fails = CounterMetricFamily("tcs_plc_failures", "failed Modbus poll cycles", labels=["plc"])
            connects = CounterMetricFamily("tcs_plc_connects", "Modbus (re)connections", labels=["plc"])
            interval = _gauge("tcs_plc_poll_interval_seconds", "the poll interval in effect (the idle "
                              "one while the PLC rests)", ["plc"])
            for p in snap["plcs"]:
                up.add_metric([p["name"]], 1.0 if p["connected"] else 0.0)
                if p["round_trip"] is not None:
                    rtt.add_metric([p["name"]], p["round_trip"])
                fails.add_metric([p["name"]], p["failures"])
                connects.add_metric([p["name"]], p["connects"])
                interval.add_metric([p["name"]], p["poll_interval"])
            yield from (up, rtt, fails, connects, interval)
        gps = snap["gps"]
        if gps is not None:
            yield _one("tcs_gps_position_fix", "1 while the GPS has a good position fix",
                       1.0 if gps["position_good"] else 0.0)
            yield _one("tcs_gps_time_good", "1 while the GPS time is good", 1.0 if gps["time_good"] else 0.0)
            yield _one("tcs_gps_time_valid", "1 while the receiver's time is valid (it may disagree with "
                       "the system clock)", 1.0 if gps.get("time_valid") else 0.0)
            yield _one("tcs_gps_data", "1 while valid NMEA sentences come", 1.0 if gps.get("data") else 0.0)
            if gps["time_offset"] is not None:
                yield _one("tcs_gps_time_offset_seconds", "GPS time minus the system's UTC", gps["time_offset"])
            yield _one("tcs_gps_fix_quality", "GGA fix quality of the last position sentence (1-5 and 9 fixes; "
                       "6 dead reckoning, 7 manual, 8 simulator are not)", float(gps.get("fix_quality") or 0))
            if gps.get("satellites") is not None:
                yield _one("tcs_gps_satellites", "satellites used in the fix", float(gps["satellites"]))
            used = _gauge("tcs_gps_constellation_satellites", "satellites used per constellation (talker)",
                          ["talker"])
            for c in gps.get("constellations") or ():
                if c["used"] is not None:
                    used.add_metric([c["talker"]], float(c["used"]))
            yield used

    @staticmethod
    def _front_ends(snap):
        ends = snap.get("front_ends") or {}
        g = _gauge("tcs_frontend_connections", "open connections per front end (TPL2 sessions, Alpaca "
                                               "HTTP connections)", ["front_end"])
        for name, end in ends.items():
            g.add_metric([name], end["connections"])
        yield g
        c = CounterMetricFamily("tcs_frontend_commands", "commands answered, by verb (TPL2 command, "
                                "Alpaca HTTP method) and result", labels=["front_end", "verb", "result"])
        h = HistogramMetricFamily("tcs_frontend_command_latency_seconds", "time from handling a command "
                                  "to its final answer (a SET that moves: until the move ended)",
                                  labels=["front_end", "verb"])
        for name, end in ends.items():
            for verb, result, n in end["counts"]:
                c.add_metric([name, verb, result], n)
            for verb, (counts, total) in end["latency"].items():
                h.add_metric([name, verb], _buckets(LATENCY_BOUNDS, counts), total)
        yield c
        yield h


def make_registry(source, counters: Counters) -> CollectorRegistry:
    registry = CollectorRegistry(auto_describe=False)
    registry.register(SnapshotCollector(source, counters))
    return registry


def render(registry: CollectorRegistry) -> bytes:
    return generate_latest(registry)
