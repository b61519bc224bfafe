"""Writes ``tools/grafana/tcs-dashboard.json``, the Grafana dashboard of the service's
``/metrics`` (issue 29): ``python3 tools/grafana/make_dashboard.py``. The JSON is committed;
this script is how it is kept consistent (one panel list, one datasource variable, every
query filtered by the ``instance`` variable). Import it in Grafana (Dashboards → Import) and
pick the Prometheus datasource that scrapes the telescope."""

from __future__ import annotations

import json
from pathlib import Path

DS = {"type": "prometheus", "uid": "${datasource}"}
SEL = 'instance=~"$instance"'
panels: list[dict] = []
_y = [0]


def _grid(w: int, h: int, x: int) -> dict:
    return {"h": h, "w": w, "x": x, "y": _y[0]}


def stat(title: str, expr: str, x: int, w: int = 4, unit: str = "none", mappings=None, desc: str = "",
         thresholds=None) -> None:
    panels.append({
        "type": "stat", "title": title, "description": desc, "datasource": DS, "gridPos": _grid(w, 4, x),
        "targets": [{"refId": "A", "expr": expr, "datasource": DS}],
        "options": {"reduceOptions": {"calcs": ["lastNotNull"]}, "colorMode": "background", "textMode": "value"},
        "fieldConfig": {"defaults": {"unit": unit, "mappings": mappings or [],
                                     "thresholds": thresholds or {"mode": "absolute", "steps": [
                                         {"color": "red", "value": None}, {"color": "green", "value": 1}]}},
                        "overrides": []}})


def series(title: str, targets: list[tuple[str, str]], x: int, w: int = 12, h: int = 8, unit: str = "none",
           desc: str = "") -> None:
    panels.append({
        "type": "timeseries", "title": title, "description": desc, "datasource": DS, "gridPos": _grid(w, h, x),
        "targets": [{"refId": chr(65 + i), "expr": e, "legendFormat": leg, "datasource": DS}
                    for i, (e, leg) in enumerate(targets)],
        "fieldConfig": {"defaults": {"unit": unit, "custom": {"lineWidth": 1, "showPoints": "never"}},
                        "overrides": []},
        "options": {"legend": {"displayMode": "list", "placement": "bottom"}, "tooltip": {"mode": "multi"}}})


def row(title: str) -> None:
    panels.append({"type": "row", "title": title, "collapsed": False, "gridPos": _grid(24, 1, 0), "panels": []})
    _y[0] += 1


ONOFF = [{"type": "value", "options": {"0": {"text": "off"}, "1": {"text": "on"}}}]
YESNO = [{"type": "value", "options": {"0": {"text": "no"}, "1": {"text": "yes"}}}]
ZERO_OK = {"mode": "absolute", "steps": [{"color": "green", "value": None}, {"color": "red", "value": 1}]}

row("Telescope")
stat("Main power", f"tcs_cabinet_power{{{SEL}}}", 0, mappings=ONOFF,
     desc="CABINET.POWER_STATE: 1 on, 0 off, between: switching")
stat("Referenced", f"tcs_cabinet_referenced{{{SEL}}}", 4, unit="percentunit",
     desc="CABINET.REFERENCED: share of the axes referenced")
stat("Error state", f"tcs_cabinet_error_state{{{SEL}}}", 8, thresholds=ZERO_OK,
     desc="CABINET.ERROR_STATE bits (0: no error); the entries are in CABINET.STATUS.LIST")
stat("Control loop", f"tcs_control_loop_running{{{SEL}}}", 12, mappings=[{"type": "value", "options": {
    "0": {"text": "STOPPED"}, "1": {"text": "running"}}}], desc="1 while the control loop runs (healthy)")
stat("Tracking", f"tcs_tracking_active{{{SEL}}}", 16, mappings=YESNO, desc="POINTING.TRACK != 0")
stat("On target", f"tcs_tracking_on_target{{{SEL}}}", 20, mappings=YESNO,
     desc="tracking with every controlled axis on target")
_y[0] += 4

row("Axes")
series("Position", [(f"tcs_axis_position_degrees{{{SEL}}}", "{{axis}}")], 0, unit="degree",
       desc="REALPOS of the angular axes (AZ, ZD or HA, DEC, derotators), degrees")
series("Following error", [(f"tcs_axis_following_error_arcsec{{{SEL}}}", "{{axis}}")], 12, unit="none",
       desc="the drive's following error (measured - demand), arcsec, angular axes")
_y[0] += 8
series("Velocity", [(f"tcs_axis_velocity_degrees_per_second{{{SEL}}}", "{{axis}}")], 0, unit="none",
       desc="CURRSPEED of the angular axes, degrees per second")
series("Drive faults and limit hits (per hour)",
       [(f"increase(tcs_axis_drive_faults_total{{{SEL}}}[1h])", "fault {{axis}}"),
        (f"increase(tcs_axis_limit_hits_total{{{SEL}}}[1h])", "limit {{axis}}")], 12,
       desc="a new drive fault / a limit reached, counted by the service")
_y[0] += 8
series("Focus", [(f"tcs_axis_position_millimetres{{{SEL}}}", "{{axis}} position"),
                 (f"tcs_axis_target_millimetres{{{SEL}}}", "{{axis}} target")], 0, unit="lengthmm",
       desc="REALPOS and TARGETPOS of the linear axes (FOCUS), mm")
series("Filter wheel and M3", [(f"tcs_axis_discrete_position{{{SEL}}}", "{{axis}}")], 12, unit="none",
       desc="REALPOS of the discrete axes: the number of the position (filter slot, M3 port)")
_y[0] += 8

row("Tracking")
series("Tracking error", [(f"tcs_tracking_error_arcsec{{{SEL}}}", "on the sky")], 0, unit="none",
       desc="POINTING.TARGETDISTANCE while tracking on the path: largest distance of the controlled axes "
            "from their demand, arcsec (no value while not tracking or slewing to the target)")
series("Target distance", [(f"tcs_tracking_target_distance_degrees{{{SEL}}}", "current - target")], 12, unit="none",
       desc="angle on the sky between where the telescope points and the target, degrees")
_y[0] += 8

row("Control loop")
series("Missed, late cycles and TPDO time-outs (per minute)",
       [(f"increase(tcs_control_loop_missed_cycles_total{{{SEL}}}[1m])", "missed"),
        (f"increase(tcs_control_loop_late_cycles_total{{{SEL}}}[1m])", "late"),
        (f"increase(tcs_control_loop_tpdo_timeouts_total{{{SEL}}}[1m])", "TPDO time-outs"),
        (f"increase(tcs_control_loop_errors_total{{{SEL}}}[1m])", "step errors")], 0,
       desc="missed: SYNC slots skipped; late: work ended after the next SYNC was due; should stay 0")
series("Loop time and SYNC lateness (p50, p99 over 5 min)",
       [(f"histogram_quantile(0.99, rate(tcs_control_loop_time_seconds_bucket{{{SEL}}}[5m]))", "loop time p99"),
        (f"histogram_quantile(0.5, rate(tcs_control_loop_time_seconds_bucket{{{SEL}}}[5m]))", "loop time p50"),
        (f"histogram_quantile(0.99, rate(tcs_control_loop_lateness_seconds_bucket{{{SEL}}}[5m]))", "lateness p99"),
        (f"tcs_control_loop_sync_period_seconds{{{SEL}}}", "SYNC period")], 12, unit="s",
       desc="the time of one loop step and how late each SYNC went out; both well under the SYNC period")
_y[0] += 8
series("CAN bus errors (per minute)",
       [(f"increase(tcs_can_error_frames_total{{{SEL}}}[1m])", "error frames"),
        (f"increase(tcs_can_bus_off_total{{{SEL}}}[1m])", "bus-off"),
        (f"increase(tcs_can_send_failures_total{{{SEL}}}[1m])", "send failures")], 0,
       desc="error frames, bus-off events and failed sends of the drives' CAN bus; should stay 0")
series("CAN controller state", [(f"tcs_can_bus_state{{{SEL}}} == 1", "{{state}}")], 12,
       desc="the controller's state: ok, warning, passive, bus-off or failed")
_y[0] += 8
series("CAN bus load", [(f"tcs_can_bus_load_ratio{{{SEL}}}", "load (last second)"),
                        (f"rate(tcs_can_frame_bits_total{{{SEL}}}[1m]) / tcs_can_bitrate_bits_per_second{{{SEL}}}",
                         "load (1 min)")], 0, unit="percentunit",
       desc="share of the bit rate the frames use (without stuff bits: up to ~20 % more on the wire)")
series("CAN frames (per second)", [(f"rate(tcs_can_frames_total{{{SEL}}}[1m])", "{{direction}}")], 12,
       desc="data frames received (drives, kernel SYNC) and sent by the TCS")
_y[0] += 8

row("Dome, weather, links")
series("Dome and covers", [(f"tcs_enclosure_open_ratio{{{SEL}}}", "{{module}} open"),
                           (f"tcs_dome_azimuth_degrees{{{SEL}}} / 360", "{{module}} azimuth / 360°")], 0, w=8,
       unit="percentunit", desc="how far each dome part and cover is open (0 closed, 100 % fully open); "
                               "the dome's azimuth as a share of the full turn")
series("Weather", [(f"tcs_sensor_value{{{SEL}}}", "{{name}}")], 8, w=8, desc="SENSOR[].VALUE (each in its own unit)")
series("Weather interlock", [(f"tcs_weather_interlock_active{{{SEL}}}", "active")], 16, w=8,
       desc="1 while the weather interlock holds dome and covers closed")
_y[0] += 8
series("PLC links", [(f"tcs_plc_up{{{SEL}}}", "{{plc}} up"),
                     (f"tcs_plc_round_trip_seconds{{{SEL}}}", "{{plc}} round trip")], 0, w=8,
       desc="Modbus link up (1) and the last request's round trip, s")
series("GPS", [(f"tcs_gps_position_fix{{{SEL}}}", "fix"), (f"tcs_gps_time_good{{{SEL}}}", "time good"),
               (f"tcs_gps_time_offset_seconds{{{SEL}}}", "time offset (s)")], 8, w=8,
       desc="position fix, time good, GPS time minus the system's UTC")
series("Clients", [(f"tcs_frontend_connections{{{SEL}}}", "{{front_end}}")], 16, w=8,
       desc="open connections per front end (TPL2 sessions, Alpaca HTTP connections)")
_y[0] += 8

row("Front ends")
series("Commands (per second)", [(f"sum by (front_end, verb, result) (rate(tcs_frontend_commands_total{{{SEL}}}[1m]))",
                                  "{{front_end}} {{verb}} {{result}}")], 0, w=12,
       desc="commands answered by front end, verb (TPL2 command, Alpaca HTTP method) and result")
series("Command latency p99 (5 min)",
       [(f"histogram_quantile(0.99, sum by (front_end, verb, le) "
         f"(rate(tcs_frontend_command_latency_seconds_bucket{{{SEL}}}[5m])))", "{{front_end}} {{verb}}")],
       12, w=12, unit="s", desc="from handling a command to its final answer (a SET that moves: until the move ended)")
_y[0] += 8

dashboard = {
    "__inputs": [], "title": "tcs telescope", "uid": "tcs-telescope", "editable": True, "schemaVersion": 39,
    "tags": ["tcs", "telescope"], "time": {"from": "now-3h", "to": "now"}, "refresh": "10s",
    "description": "The tcs service's /metrics (docs/metrics.md: 'Metrics and status page')",
    "templating": {"list": [
        {"type": "datasource", "name": "datasource", "label": "Prometheus", "query": "prometheus"},
        {"type": "query", "name": "instance", "label": "telescope", "datasource": DS, "refresh": 2,
         "query": {"query": "label_values(tcs_build_info, instance)", "refId": "instance"},
         "definition": "label_values(tcs_build_info, instance)", "includeAll": True, "multi": False},
    ]},
    "panels": [dict(p, id=i + 1) for i, p in enumerate(panels)],
}

if __name__ == "__main__":
    out = Path(__file__).with_name("tcs-dashboard.json")
    out.write_text(json.dumps(dashboard, indent=1) + "\n")
    print(f"wrote {out} ({len(panels)} panels)")
