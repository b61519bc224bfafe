"""The read-only web port (issue 29): /metrics, /status.json, the live status page.

One service (module scope) runs the simulated telescope (``hwconfig/sim.toml``: the control
loop in its control process) with its web port on a free loopback port. Values are compared
with what TPL2 reads from the same service; the page is opened in a real browser (Debian's
``chromium``, headless, driven over its DevTools protocol) where one is installed — the test
is skipped with the reason where none is (``.ci/run`` installs it).
"""

from __future__ import annotations

import asyncio
import base64
import io
import json
import os
import shutil
import signal
import subprocess
import time
from pathlib import Path

import aiohttp
import pytest
from prometheus_client.parser import text_string_to_metric_families

from support.live import live_service
from support.opentci_client import Client
from tcs.config import DEFAULT_CONFIG, load_config
from test_axes import ready

live = live_service(DEFAULT_CONFIG)
WAIT = 60.0


@pytest.fixture(autouse=True)
def _no_leaked_threads():  # the module's service thread is expected; LiveService.stop checks
    yield


def base(live) -> str:
    return f"http://127.0.0.1:{live.service.web_port}"


async def fetch(live, path: str, method: str = "GET") -> tuple[int, str, str]:
    async with aiohttp.ClientSession() as s:
        async with s.request(method, base(live) + path, timeout=aiohttp.ClientTimeout(total=30)) as r:
            return r.status, r.headers.get("Content-Type", ""), await r.text()


async def metrics(live) -> dict:
    """{(name, ((label, value), …)): value} of one scrape, parsed by prometheus-client."""
    status, kind, text = await fetch(live, "/metrics")
    assert status == 200 and kind.startswith("text/plain"), (status, kind)
    out = {}
    for family in text_string_to_metric_families(text):
        assert family.name.startswith("tcs_"), family.name
        for sample in family.samples:
            out[(sample.name, tuple(sorted(sample.labels.items())))] = sample.value
    return out


async def status(live) -> dict:
    code, kind, text = await fetch(live, "/status.json")
    assert code == 200 and kind.startswith("application/json"), (code, kind)
    return json.loads(text)


async def at_rest(c: Client, *axes: str) -> None:
    for ax in axes:
        await c.wait(f"{ax}.MOTION_STATE", lambda v: not int(v) & 1, WAIT)


def test_shipped_file_serves_the_web_port_on_loopback():
    web = load_config(DEFAULT_CONFIG).web
    assert web.port == 8088 and web.host == "127.0.0.1"
    assert web.interval <= 0.5  # pages are pushed at 2 Hz or more
    assert load_config(Path(__file__).with_name("hw_opentsi.toml")).web.port == -1  # off by default


async def test_metrics_parse_and_match_tpl2(live):
    c = await Client.connect(live.port)
    try:
        await ready(c, "ZD")
        await c.set("ZD.TARGETPOS=31.25", WAIT)
        await at_rest(c, "ZD", "AZ")
        # (the snapshot is at most [web] interval old: wait for one taken after the move)
        await asyncio.sleep(live.service.web_server.interval * 2)
        m = await metrics(live)
        tpl = dict(zip(("ZD.REALPOS", "ZD.TARGETPOS", "ZD.POWER_STATE", "ZD.REFERENCED", "AZ.REALPOS",
                        "CABINET.POWER_STATE", "ZD.MOTION_STATE", "LOCAL.TAI-UTC"),
                       await c.nums("ZD.REALPOS", "ZD.TARGETPOS", "ZD.POWER_STATE", "ZD.REFERENCED",
                                    "AZ.REALPOS", "CABINET.POWER_STATE", "ZD.MOTION_STATE", "LOCAL.TAI-UTC")))
    finally:
        await c.close()
    zd, az = (("axis", "ZD"),), (("axis", "AZ"),)
    assert m[("tcs_axis_position_degrees", zd)] == pytest.approx(tpl["ZD.REALPOS"], abs=1e-9)
    assert m[("tcs_axis_position_degrees", zd)] == pytest.approx(31.25, abs=1e-3)
    assert m[("tcs_axis_target_degrees", zd)] == pytest.approx(tpl["ZD.TARGETPOS"], abs=1e-9)
    assert m[("tcs_axis_power", zd)] == tpl["ZD.POWER_STATE"] == 1.0
    assert m[("tcs_axis_referenced", zd)] == tpl["ZD.REFERENCED"] == 1.0
    assert m[("tcs_axis_motion_state", zd)] == tpl["ZD.MOTION_STATE"]
    assert m[("tcs_axis_position_degrees", az)] == pytest.approx(tpl["AZ.REALPOS"], abs=1e-9)
    assert m[("tcs_cabinet_power", ())] == tpl["CABINET.POWER_STATE"]
    assert m[("tcs_tai_utc_seconds", ())] == tpl["LOCAL.TAI-UTC"]
    # the families the issue lists that the model knows, with their types
    build = [dict(labels) for (name, labels) in m if name == "tcs_build_info"]
    assert len(build) == 1 and build[0]["config"] == "sim.toml" and build[0]["version"]
    assert m[("tcs_control_loop_sync_period_seconds", ())] == 0.01
    assert m[("tcs_control_loop_sync_interval_seconds", ())] in (0.01, 0.1)   # (idle SYNC of sim.toml)
    assert m[("tcs_control_loop_cycles_total", ())] > 0
    assert ("tcs_control_loop_missed_cycles_total", ()) in m
    assert ("tcs_control_loop_tpdo_timeouts_total", ()) in m
    assert m[("tcs_control_loop_time_seconds_count", ())] > 0
    assert m[("tcs_control_loop_lateness_seconds_bucket", (("le", "+Inf"),))] > 0
    assert ("tcs_axis_drive_faults_total", zd) in m and ("tcs_axis_limit_hits_total", zd) in m
    assert ("tcs_axis_following_error_arcsec", zd) in m
    assert m[("tcs_plc_up", (("plc", "dome"),))] == 1.0
    assert m[("tcs_plc_poll_interval_seconds", (("plc", "dome"),))] in (0.1, 0.5)  # (idle poll)
    assert m[("tcs_frontend_connections", (("front_end", "opentci"),))] >= 0
    assert ("tcs_tracking_active", ()) in m and ("tcs_tracking_on_target", ()) in m
    assert ("tcs_gps_position_fix", ()) in m
    assert ("tcs_gps_fix_quality", ()) in m and ("tcs_gps_time_valid", ()) in m and ("tcs_gps_data", ()) in m
    assert m[("tcs_can_bus_state", (("state", "ok"),))] == 1.0  # (from the control process)
    assert m[("tcs_can_error_frames_total", ())] == 0
    assert ("tcs_weather_interlock_active", ()) in m
    gps = (await status(live))["gps"]      # the status page's GPS: the receiver's judgement
    assert {"satellites", "fix_quality", "quality_name", "summary", "constellations", "time_valid"} <= set(gps)


async def test_each_metric_family_has_one_unit_named_in_it(live):
    """Issue 41, item 8: an axis's position, target, target distance and velocity are in one
    family per unit — ``_degrees`` for the angular axes, ``_millimetres`` for FOCUS,
    ``tcs_axis_discrete_*`` (a position number) for FILTER and MIRROR — and the enclosure's are
    the dome's azimuth in degrees and how far each part is open (0 … 1); no family mixes units."""
    c = await Client.connect(live.port)
    try:
        focus, tpl_az = await c.nums("FOCUS.REALPOS", "DOME[0].REALPOS")
    finally:
        await c.close()
    await asyncio.sleep(live.service.web_server.interval * 2)
    m = await metrics(live)
    units = {dict(labels)["axis"]: dict(labels)["unit"] for (name, labels) in m if name == "tcs_axis_info"}
    assert units["AZ"] == units["ZD"] == "deg" and units["FOCUS"] == "mm" and units["FILTER[2]"] == "position"
    suffix = {"deg": "_degrees", "mm": "_millimetres"}
    seen: dict[str, set[str]] = {}
    for name, labels in m:
        axis = dict(labels).get("axis")
        if axis is None or not name.startswith(("tcs_axis_position", "tcs_axis_target", "tcs_axis_velocity",
                                                "tcs_axis_discrete")):
            continue
        seen.setdefault(name, set()).add(units[axis])
        unit = units[axis]
        if unit in suffix:
            assert suffix[unit] in name and not name.startswith("tcs_axis_discrete"), (name, axis)
        else:
            assert name.startswith("tcs_axis_discrete_"), (name, axis)
    assert all(len(u) == 1 for u in seen.values()), seen
    for family in ("tcs_axis_position_degrees", "tcs_axis_target_degrees", "tcs_axis_target_distance_degrees",
                   "tcs_axis_velocity_degrees_per_second", "tcs_axis_position_millimetres",
                   "tcs_axis_discrete_position"):
        assert family in seen, family
    assert m[("tcs_axis_position_millimetres", (("axis", "FOCUS"),))] == pytest.approx(focus, abs=1e-3)
    assert not any(name in ("tcs_axis_position", "tcs_axis_target", "tcs_axis_target_distance",
                            "tcs_axis_velocity", "tcs_enclosure_position") for name, _ in m)
    assert m[("tcs_dome_azimuth_degrees", (("module", "DOME[0]"),))] == pytest.approx(tpl_az, abs=0.5)
    opening = {dict(labels)["module"]: v for (name, labels), v in m.items() if name == "tcs_enclosure_open_ratio"}
    assert {"DOME[1]", "DOME[2]", "DOME[3]", "COVER"} <= set(opening) and "DOME[0]" not in opening
    assert all(0.0 <= v <= 1.0 for v in opening.values()), opening


async def test_metrics_count_commands_by_verb_and_result_and_the_bus_load(live):
    """Front-end command counters and latency histograms move with what a client did, on its
    own front end only; the CAN traffic counters and the bus load come from the control process."""
    key = lambda verb, result: ("tcs_frontend_commands_total",  # noqa: E731
                                (("front_end", "opentci"), ("result", result), ("verb", verb)))
    before = await metrics(live)
    c = await Client.connect(live.port)
    try:
        await c.nums("AZ.REALPOS", "ZD.REALPOS")
        await c.set("ZD.OFFSET=0", WAIT)
        await c.send("7 FROB AZ")  # an unknown verb: refused, counted as OTHER
        assert any("COMMAND FAILED" in line for line in await c.until(7))
        await asyncio.sleep(live.service.web_server.interval * 2)
        after = await metrics(live)
    finally:
        await c.close()
    grew = lambda k: after.get(k, 0) - before.get(k, 0)  # noqa: E731
    assert grew(key("GET", "complete")) >= 1
    assert grew(key("SET", "complete")) >= 1
    assert grew(key("OTHER", "refused")) >= 1
    assert grew(key("AUTH", "complete")) >= 1
    get = (("front_end", "opentci"), ("verb", "GET"))
    assert after[("tcs_frontend_command_latency_seconds_count", get)] >= after[key("GET", "complete")]
    assert after[("tcs_frontend_command_latency_seconds_bucket", (*get[:1], ("le", "+Inf"), get[1]))] == \
        after[("tcs_frontend_command_latency_seconds_count", get)]
    assert not any(name == "tcs_frontend_commands_total" and dict(labels)["front_end"] == "alpaca"
                   and value for (name, labels), value in after.items())  # (nobody used Alpaca)
    # the CAN bus: frames both ways, their bits, a load between 0 and 1 (7 drives at 100 Hz)
    assert after[("tcs_can_frames_total", (("direction", "received"),))] > \
        before.get(("tcs_can_frames_total", (("direction", "received"),)), 0)
    assert after[("tcs_can_frames_total", (("direction", "sent"),))] > 0
    assert after[("tcs_can_frame_bits_total", ())] > 0
    assert after[("tcs_can_bitrate_bits_per_second", ())] == 1_000_000
    assert 0.0 < after[("tcs_can_bus_load_ratio", ())] < 1.0


async def test_status_json_matches_the_tree(live):
    c = await Client.connect(live.port)
    try:
        await at_rest(c, "AZ", "ZD")
        await asyncio.sleep(live.service.web_server.interval * 2)
        snap = await status(live)
        names = [a["name"] for a in snap["axes"]]
        assert names[:2] == ["AZ", "ZD"] and "FOCUS" in names
        for axis in snap["axes"]:
            if axis["module"] in ("FILTER", "MIRROR"):
                continue  # (discrete: REALPOS is the port)
            name = axis["name"]
            real, target, power, ref, err = await c.nums(
                f"{name}.REALPOS", f"{name}.TARGETPOS", f"{name}.POWER_STATE", f"{name}.REFERENCED",
                f"{name}.ERROR_STATE")
            assert axis["fresh"] and axis["position"] == pytest.approx(real, abs=1e-9), name
            assert axis["target"] == pytest.approx(target, abs=1e-9), name
            assert (axis["power"], axis["referenced"], axis["error_state"]) == (power, ref, err), name
        cab = await c.nums("CABINET.POWER_STATE", "CABINET.REFERENCED", "CABINET.ERROR_STATE")
        assert [snap["cabinet"][k] for k in ("power", "referenced", "error_state")] == cab
        listed = (await c.value("CABINET.STATUS.LIST")).strip('"')
        assert len([x for x in listed.split(",") if x]) == len(snap["cabinet"]["errors"])
        dome0 = await c.num("DOME[0].REALPOS")
        assert snap["dome"][0]["name"] == "DOME[0]" and snap["dome"][0]["position"] == pytest.approx(dome0, abs=1e-6)
        lat, lon, tai_utc = await c.nums("LOCAL.LATITUDE", "LOCAL.LONGITUDE", "LOCAL.TAI-UTC")
        assert (snap["site"]["latitude"], snap["site"]["longitude"]) == (lat, lon)
        # one clock: UTC, UT1 and TAI of the snapshot and of every sample from LOCAL's offsets
        t = snap["time"]
        assert t["tai"] - t["utc"] == pytest.approx(tai_utc) and t["ut1"] - t["utc"] == pytest.approx(t["ut1_utc"])
        for axis in snap["axes"]:
            s = axis["sample"]
            assert s["sync"]["tai"] - s["sync"]["utc"] == pytest.approx(tai_utc)
            assert s["sync"]["ut1"] <= s["demand_time"]["ut1"]  # the setpoint is reached after its SYNC
            assert s["actual"] is not None
        assert snap["sync"]["ut1"] == max(a["sample"]["sync"]["ut1"] for a in snap["axes"])
        # this client is listed, logged in
        mine = [x for x in snap["clients"] if x["front_end"] == "opentci" and x["user"] == "admin"]
        assert mine, snap["clients"]
    finally:
        await c.close()


async def test_samples_carry_demand_and_actual_while_moving(live):
    c = await Client.connect(live.port)
    try:
        await ready(c, "ZD")
        start = await c.num("ZD.REALPOS")
        cmd = await c.start(f"ZD.TARGETPOS={35.0 if start < 33 else 28.0}")
        await c.wait("ZD.CURRSPEED", lambda v: abs(v) > 0.5, WAIT)
        snap = await status(live)
        zd = next(a for a in snap["axes"] if a["name"] == "ZD")
        s = zd["sample"]
        assert s["demand"] is not None and s["actual"] is not None
        assert zd["motion_state"] & 1 and zd["velocity"] != 0.0
        await c.until(cmd, WAIT)
    finally:
        await c.close()


async def test_tracking_shows_in_status_and_metrics(live):
    """While POINTING tracks a star, /status.json and /metrics say so with the tracking error
    and the target distance POINTING reads (compared loosely: they are read at other moments)."""
    c = await Client.connect(live.port)
    try:
        await ready(c, "AZ", "ZD")
        ra, dec = await c.nums("POINTING.CURRENT.RA", "POINTING.CURRENT.DEC")
        await c.set(f"POINTING.TARGET.RA={ra!r};POINTING.TARGET.DEC={dec!r}")
        cmd = await c.start("POINTING.TRACK=1")
        await c.wait("POINTING.TARGETDISTANCE", lambda v: 0 < v < 0.01, WAIT)
        deadline = time.monotonic() + WAIT   # (the error is shown once a snapshot found the axes on the path)
        while ("tcs_tracking_error_arcsec", ()) not in (m := await metrics(live)):
            assert time.monotonic() < deadline, "no tracking error while tracking on the path"
            await asyncio.sleep(0.5)
        snap = await status(live)
        track, distance = await c.nums("POINTING.TRACK", "POINTING.TARGETDISTANCE")
        t = snap["tracking"]
        assert t["tracking"] and t["track"] == track == 1
        assert t["distance_arcsec"] is not None and t["distance_arcsec"] < 36.0
        assert m[("tcs_tracking_active", ())] == 1.0
        assert m[("tcs_tracking_error_arcsec", ())] < 36.0 and distance * 3600 < 36.0
        assert m[("tcs_tracking_target_distance_degrees", ())] < 0.01
        assert t["target"]["alt"] is not None and t["current"]["alt"] == pytest.approx(t["target"]["alt"], abs=0.1)
        await c.set("POINTING.TRACK=0")
        await c.until(cmd, WAIT)
        await at_rest(c, "AZ", "ZD")
    finally:
        await c.close()


async def test_tracking_error_only_while_tracking_on_the_path(live):
    """Issue 41, item 8: during the slew to a star there is no tracking error in /metrics (what
    TARGETDISTANCE reads then is the way still to go, e.g. 63,637″), only once the axes follow
    the path; and none once tracking ended."""
    c = await Client.connect(live.port)
    cmd = None
    try:
        await ready(c, "AZ", "ZD")
        ra, dec = await c.nums("POINTING.CURRENT.RA", "POINTING.CURRENT.DEC")
        dec += 15.0 if dec < 50 else -15.0   # a slew of several seconds first
        await c.set(f"POINTING.TARGET.RA={ra!r};POINTING.TARGET.DEC={dec!r}")
        cmd = await c.start("POINTING.TRACK=1")
        await c.wait("POINTING.TRACK", lambda v: v == 1, WAIT)
        await asyncio.sleep(live.service.web_server.interval * 2)   # a snapshot taken since
        during = await metrics(live)
        if await c.num("POINTING.TARGETDISTANCE") > 0.5:   # degrees: the slew was on at the scrape too
            assert during[("tcs_tracking_active", ())] == 1.0
            assert ("tcs_tracking_error_arcsec", ()) not in during, during[("tcs_tracking_error_arcsec", ())]
        else:  # pragma: no cover - a 15° slew is several seconds even unloaded
            pytest.fail("the slew ended before a scrape saw it")
        deadline = time.monotonic() + WAIT
        while ("tcs_tracking_error_arcsec", ()) not in (m := await metrics(live)):
            assert time.monotonic() < deadline, "no tracking error while tracking on the path"
            await asyncio.sleep(0.5)
        assert m[("tcs_tracking_error_arcsec", ())] < 600.0   # on the path, not 15° from it
        await c.set("POINTING.TRACK=0")
        await c.until(cmd, WAIT)
        cmd = None
        await asyncio.sleep(live.service.web_server.interval * 2)
        after = await metrics(live)
        assert after[("tcs_tracking_active", ())] == 0.0 and ("tcs_tracking_error_arcsec", ()) not in after
        await at_rest(c, "AZ", "ZD")
    finally:
        if cmd is not None:
            await c.set("POINTING.TRACK=0")
        await c.close()


async def test_unknown_paths_404_and_nothing_writable(live):
    for path in ("/nope", "/metrics/x", "/static/style.css", "/index.html.bak", "/api/v1/telescope/0/park",
                 "/%2e%2e/etc/passwd", "/status.json/"):
        code, _, _ = await fetch(live, path)
        assert code == 404, path
    for path in ("/", "/metrics", "/status.json", "/events", "/app.js"):
        for method in ("POST", "PUT", "DELETE", "PATCH"):
            code, _, _ = await fetch(live, path, method)
            assert code == 405, (method, path)
    # the query string changes nothing
    before = live.telescope.axis("AZ").target_position
    code, _, _ = await fetch(live, "/status.json?AZ.TARGETPOS=100")
    assert code == 200 and live.telescope.axis("AZ").target_position == before
    # and the service still serves
    assert (await status(live))["axes"]


async def test_event_stream_pushes_new_snapshots(live):
    seqs = []
    async with aiohttp.ClientSession() as s:
        async with s.get(base(live) + "/events", timeout=aiohttp.ClientTimeout(total=WAIT)) as r:
            assert r.status == 200 and r.headers["Content-Type"].startswith("text/event-stream")
            async for line in r.content:
                if line.startswith(b"data: "):
                    seqs.append(json.loads(line[6:])["seq"])
                    if len(seqs) == 4:
                        break
    assert seqs == sorted(seqs) and len(set(seqs)) == 4


# -- a real browser ---------------------------------------------------------------------------

def find_browser() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable"):
        path = shutil.which(name)
        if path:
            return path
    return None


class DevTools:
    """A page of a headless Chromium, over its DevTools protocol (a websocket, aiohttp)."""

    def __init__(self, ws):
        self.ws = ws
        self._id = 0

    async def call(self, method: str, **params):
        self._id += 1
        await self.ws.send_json({"id": self._id, "method": method, "params": params})
        while True:
            msg = await asyncio.wait_for(self.ws.receive_json(), WAIT)
            if msg.get("id") == self._id:
                assert "error" not in msg, msg
                return msg.get("result", {})

    async def eval(self, expression: str):
        result = await self.call("Runtime.evaluate", expression=expression, returnByValue=True)
        return result.get("result", {}).get("value")

    async def until(self, expression: str, what: str, timeout: float = WAIT):
        deadline = time.monotonic() + timeout
        while True:
            value = await self.eval(expression)
            if value:
                return value
            assert time.monotonic() < deadline, f"the page did not show {what}"
            await asyncio.sleep(0.1)


async def start_browser(path: str, profile: Path) -> tuple[subprocess.Popen, int]:
    args = [path, "--headless=new", "--disable-gpu", "--no-first-run", "--no-default-browser-check",
            "--remote-debugging-address=127.0.0.1", "--remote-debugging-port=0",
            f"--user-data-dir={profile}", "--window-size=430,1500", "--hide-scrollbars", "about:blank"]
    if hasattr(os, "geteuid") and os.geteuid() == 0:
        args.insert(1, "--no-sandbox")  # (root: Chromium refuses its sandbox)
    proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    port_file = profile / "DevToolsActivePort"
    deadline = time.monotonic() + WAIT
    while not (port_file.exists() and port_file.read_text().strip()):
        assert proc.poll() is None, f"{path} ended at start (status {proc.returncode})"
        assert time.monotonic() < deadline, "the browser did not open its DevTools port"
        await asyncio.sleep(0.1)
    return proc, int(port_file.read_text().split()[0])


def stop_browser(proc: subprocess.Popen) -> None:
    try:
        os.killpg(proc.pid, signal.SIGTERM)
    except ProcessLookupError:
        return
    try:
        proc.wait(10)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(10)


def png_spread(data: bytes) -> float:
    """Standard deviation of the grey levels of a PNG (0 for a blank picture)."""
    from PIL import Image, ImageStat
    with Image.open(io.BytesIO(data)) as img:
        return ImageStat.Stat(img.convert("L")).stddev[0]


async def test_page_in_a_real_browser_shows_an_axis_move(live, tmp_path):
    browser = find_browser()
    if browser is None:
        pytest.skip("no Chromium/Chrome installed (Debian: apt-get install chromium; .ci/run does)")
    pytest.importorskip("PIL", reason="Pillow (with matplotlib, the 'dev' extra) checks the screenshot")
    proc, port = await start_browser(browser, tmp_path / "profile")
    c = await Client.connect(live.port)
    try:
        await ready(c, "ZD")
        async with aiohttp.ClientSession() as s:
            async with s.put(f"http://127.0.0.1:{port}/json/new?about:blank") as r:
                target = await r.json()
            async with s.ws_connect(target["webSocketDebuggerUrl"], max_msg_size=0) as ws:
                page = DevTools(ws)
                await page.call("Page.enable")
                await page.call("Page.navigate", url=base(live) + "/")
                cell = "document.querySelector('tr[data-axis=\"ZD\"] .pos')"
                first = await page.until(f"{cell} && {cell}.textContent.includes('°') && {cell}.textContent",
                                         "ZD's position")
                seq = int(await page.until("document.body.dataset.seq", "a snapshot"))
                start = await c.num("ZD.REALPOS")
                cmd = await c.start(f"ZD.TARGETPOS={40.0 if start < 35 else 25.0}")
                seen = {first}
                deadline = time.monotonic() + WAIT
                while len(seen) < 3:  # the value changes on the page while the axis moves
                    seen.add(await page.eval(f"{cell}.textContent"))
                    assert time.monotonic() < deadline, f"the page kept showing {seen}"
                    await asyncio.sleep(0.05)
                await c.until(cmd, WAIT)
                assert int(await page.eval("document.body.dataset.seq")) > seq
                assert await page.eval("document.getElementById('link').textContent") == "live"
                shot = await page.call("Page.captureScreenshot", format="png", captureBeyondViewport=True)
        data = base64.b64decode(shot["data"])
        out = tmp_path / "status-page.png"
        out.write_bytes(data)
        if os.environ.get("TCS_SCREENSHOT_DIR"):
            shutil.copy(out, Path(os.environ["TCS_SCREENSHOT_DIR"]) / out.name)
        assert data.startswith(b"\x89PNG") and png_spread(data) > 10.0, f"blank screenshot {out}"
    finally:
        await c.close()
        stop_browser(proc)


def test_grafana_dashboard_uses_only_served_metrics():
    """Every metric a panel of tools/grafana/tcs-dashboard.json queries is one /metrics serves
    (tcs/web/metrics.py names it), and the committed JSON is what its generator writes."""
    import re
    import subprocess
    import sys
    root = Path(__file__).resolve().parent.parent
    board = root / "tools" / "grafana" / "tcs-dashboard.json"
    text = board.read_text()
    served = (root / "tcs" / "web" / "metrics.py").read_text()
    used = set(re.findall(r"\btcs_[a-z0-9_]+", text)) - {"tcs_build_info"}
    assert used
    for name in used:
        base = re.sub(r"_(total|bucket|count|sum)$", "", name)
        assert f'"{base}"' in served, name
    proc = subprocess.run([sys.executable, "-c", "import json, runpy; d = runpy.run_path("
                           "'tools/grafana/make_dashboard.py')['dashboard']; print(json.dumps(d, indent=1))"],
                          cwd=root, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout) == json.loads(text)


async def _shot(page: DevTools, tmp_path: Path, name: str) -> None:
    """A screenshot of what the page shows now (kept under TCS_SCREENSHOT_DIR when set)."""
    shot = await page.call("Page.captureScreenshot", format="png")
    data = base64.b64decode(shot["data"])
    out = tmp_path / f"status-{name}.png"
    out.write_bytes(data)
    if os.environ.get("TCS_SCREENSHOT_DIR"):
        shutil.copy(out, Path(os.environ["TCS_SCREENSHOT_DIR"]) / out.name)
    assert data.startswith(b"\x89PNG") and png_spread(data) > 10.0, f"blank screenshot {out}"


async def _headline(page: DevTools, state: str, words: str) -> str:
    """Wait until the page's headline is in ``state`` and says ``words``; its text."""
    shown = "document.body.dataset.state + ': ' + document.getElementById('headline').textContent"
    await page.until(f"document.body.dataset.state === {state!r} && "
                     f"document.getElementById('headline').textContent.includes({words!r})",
                     f"the headline {state!r} with {words!r} (it shows {await page.eval(shown)!r})")
    return await page.eval("document.getElementById('headline').textContent + ' / ' + "
                           "document.getElementById('remedy').textContent")


async def test_status_page_says_what_the_telescope_does_and_what_is_wrong(live, tmp_path):
    """The headline above the fold (1000 px), in each state an operator meets: off, slewing to a
    target, tracking it, a fault (a stalled slit motor) and a lost PLC — each with its text, the
    remedy where something is wrong, and a screenshot; at phone width nothing runs off the side.
    The sky plot has its legend and the Sun; the dome parts say closed or open."""
    browser = find_browser()
    if browser is None:
        pytest.skip("no Chromium/Chrome installed (Debian: apt-get install chromium; .ci/run does)")
    pytest.importorskip("PIL", reason="Pillow (with matplotlib, the 'dev' extra) checks the screenshot")
    proc, port = await start_browser(browser, tmp_path / "profile")
    c = await Client.connect(live.port)
    plc = live.telescope.peripherals.sims.plcs
    try:
        async with aiohttp.ClientSession() as s:
            async with s.put(f"http://127.0.0.1:{port}/json/new?about:blank") as r:
                target = await r.json()
            async with s.ws_connect(target["webSocketDebuggerUrl"], max_msg_size=0) as ws:
                page = DevTools(ws)
                await page.call("Emulation.setDeviceMetricsOverride", width=1000, height=1000,
                                deviceScaleFactor=1, mobile=False)
                await page.call("Page.enable")
                await page.call("Page.navigate", url=base(live) + "/")
                await page.until("document.body.dataset.state", "a headline")
                # above the fold at 1000 px: the headline, the pointing (RA/Dec) and the errors
                for element in ("headline-card", "target-radec", "current-radec", "errors-card"):
                    top = await page.eval(f"document.getElementById({element!r}).getBoundingClientRect().top")
                    assert top < 1000 - 20, f"{element} starts at {top} px: below the fold"
                legend = await page.eval("document.querySelector('.legend').textContent")
                assert all(w in legend for w in ("telescope", "target", "Sun", "cone")), legend
                slit = await page.until("[...document.querySelectorAll('#enclosure td')]"
                                        ".map(td => td.textContent).join('|')", "the dome parts")
                assert "DOME[1] slit|closed" in slit, slit
                await _shot(page, tmp_path, "idle")

                # slewing, then tracking: the target in the headline
                await ready(c, "AZ", "ZD")
                ra, dec = await c.nums("POINTING.CURRENT.RA", "POINTING.CURRENT.DEC")
                goal = dec - 15.0 if dec > 0 else dec + 15.0
                await c.set(f"POINTING.TARGET.RA={ra!r};POINTING.TARGET.DEC={goal!r}")
                cmd = await c.start("POINTING.TRACK=1")
                text = await _headline(page, "slewing", "Slewing to RA")
                await _shot(page, tmp_path, "slewing")
                assert "to go" in text, text
                track_error = await page.eval("document.getElementById('track-error').textContent")
                assert "slewing" in track_error, track_error   # no tracking error during a slew
                await _headline(page, "tracking", "Tracking RA")
                assert (await page.eval("document.getElementById('track-error').textContent")).endswith("″")
                await _shot(page, tmp_path, "tracking")
                await c.set("POINTING.TRACK=0")
                await c.until(cmd, WAIT)
                await at_rest(c, "AZ", "ZD")

                # a fault: the slit's motor stalls in a move
                await ready(c, "DOME[1]")
                await live.call(plc["dome"].stall, "slit", True)
                try:
                    move = await c.start("DOME[1].TARGETPOS=40")
                    await c.until(move, WAIT)
                    text = await _headline(page, "fault", "DOME[1]")
                    assert "stalled" in text and "CABINET.ERROR_STATE=0" in text, text
                    await _shot(page, tmp_path, "fault")
                finally:
                    await live.call(plc["dome"].stall, "slit", False)
                await c.set("DOME[1].ERROR_STATE=0")

                # a lost PLC
                await live.call(plc["telescope"].set_responding, False)
                try:
                    text = await _headline(page, "fault", "PLC telescope lost")
                    assert "network" in text, text
                    chips = await page.eval("document.getElementById('safety').textContent")
                    assert "PLC lost: telescope" in chips, chips
                    await _shot(page, tmp_path, "plc-lost")
                finally:
                    await live.call(plc["telescope"].set_responding, True)
                await page.until("!document.getElementById('safety').textContent.includes('PLC lost')",
                                 "the PLC back")
                await c.set("CABINET.ERROR_STATE=0")

                # phone width: nothing wider than the screen
                await page.call("Emulation.setDeviceMetricsOverride", width=390, height=844,
                                deviceScaleFactor=1, mobile=True)
                await asyncio.sleep(0.5)
                wide = await page.eval("document.documentElement.scrollWidth")
                assert wide <= 390 + 1, f"the page is {wide} px wide on a 390 px screen"
                await _shot(page, tmp_path, "phone")
    finally:
        await c.close()
        stop_browser(proc)
