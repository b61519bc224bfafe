"""``tcs-client`` drives a whole observing session against the real service (in this process,
its own event-loop thread, ``tests/hw_pointing.toml``: fast axes): power, referencing, a slew,
a refused target, tracking, stop, park and power off — each step a separate ``tcs-client``
process, as an operator's script would run it. Plus login options, ``tree`` and ``watch``."""

from __future__ import annotations

import asyncio
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from support.live import LiveService

CONFIG = Path(__file__).with_name("hw_pointing.toml")
WAIT = 120.0


@pytest.fixture(scope="module")
def live(tmp_path_factory):
    svc = LiveService(CONFIG, tmp_path_factory.mktemp("client-state")).start()
    try:
        # one login first: the service's password-check thread then exists before the tests
        warm = client({**os.environ, "TCS_PORT": str(svc.port), "TCS_USER": "admin"},
                      "get", "CONFIG.MOUNT", "--password-file", "-", stdin="admin\n")
        assert warm.returncode == 0, warm.stderr
        yield svc
    finally:
        svc.stop()


@pytest.fixture
def env(live, tmp_path) -> dict:
    password = tmp_path / "password"
    password.write_text("admin\n")
    env = dict(os.environ, TCS_HOST="127.0.0.1", TCS_PORT=str(live.port), TCS_USER="admin",
               TCS_PASSWORD_FILE=str(password))
    return env


def client(env, *args, timeout=WAIT, stdin=None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "tcs.cli.client", *map(str, args)], env=env,
                          capture_output=True, text=True, timeout=timeout, input=stdin)


def get(env, *names) -> dict:
    proc = client(env, "get", "--json", *names)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)


def until(env, name, check, timeout=WAIT):
    deadline = time.monotonic() + timeout
    while True:
        value = get(env, name)[name]
        if check(value):
            return value
        assert time.monotonic() < deadline, f"{name} stayed {value!r}"
        time.sleep(0.3)


def test_a_complete_session(env):
    assert get(env, "CONFIG.MOUNT") == {"CONFIG.MOUNT": "AZ-ZD"}
    power = client(env, "set", "CABINET.POWER=1")
    assert power.returncode == 0, power.stderr
    assert "CABINET.POWER=1: done" in power.stderr
    assert client(env, "set", "CABINET.REINIT=1").returncode == 0
    until(env, "CABINET.REFERENCED", lambda v: v == 1.0)

    # a slew: waits for the arrival, progress lines while not a terminal, exit 0
    slew = client(env, "set", "AZ.TARGETPOS=40", "ZD.TARGETPOS=35", "--progress-interval", "0.5")
    assert slew.returncode == 0, slew.stderr
    assert "AZ.TARGETPOS=40;ZD.TARGETPOS=35: done" in slew.stderr
    pos = get(env, "AZ.REALPOS", "ZD.REALPOS")
    assert pos["AZ.REALPOS"] == pytest.approx(40, abs=0.01)
    assert pos["ZD.REALPOS"] == pytest.approx(35, abs=0.01)

    # a refused target: exit 1 and why
    refused = client(env, "set", "ZD.TARGETPOS=100")
    assert refused.returncode == 1
    assert "ZD.TARGETPOS: RANGE" in refused.stderr

    # tracking the place the telescope points at (above the altitude limit by construction)
    here = get(env, "POINTING.CURRENT.RA", "POINTING.CURRENT.DEC")
    target = client(env, "set", f"POINTING.TARGET.RA={here['POINTING.CURRENT.RA']}",
                    f"POINTING.TARGET.DEC={here['POINTING.CURRENT.DEC']}")
    assert target.returncode == 0, target.stderr
    track = client(env, "set", "POINTING.TRACK=1", "--no-wait")
    assert track.returncode == 0, track.stderr
    assert "started" in track.stderr
    assert get(env, "POINTING.TRACK") == {"POINTING.TRACK": 1}
    watch = client(env, "watch", "--count", "1", "POINTING.TARGETDISTANCE")
    assert watch.returncode == 0, watch.stderr
    status = watch.stdout.strip().splitlines()[-1]
    assert "power 1.00 ref 1.00" in status and "track 1" in status and "errors none" in status
    assert "AZ " in status and "ZD " in status and "POINTING.TARGETDISTANCE=" in status
    stop_tracking = client(env, "set", "POINTING.TRACK=0")
    assert stop_tracking.returncode == 0, stop_tracking.stderr
    until(env, "POINTING.TRACK", lambda v: v == 0)

    # stop, park, power off
    stop = client(env, "set", "AZ.STOP=1", "ZD.STOP=1")
    assert stop.returncode == 0, stop.stderr
    park = client(env, "set", "AZ.TARGETPOS=0", "ZD.TARGETPOS=0")
    assert park.returncode == 0, park.stderr
    off = client(env, "set", "CABINET.POWER=0")
    assert off.returncode == 0, off.stderr
    assert get(env, "CABINET.POWER_STATE") == {"CABINET.POWER_STATE": 0.0}


def test_login_options_and_failures(env, live, tmp_path):
    # options win over the environment; the password from standard input
    bare = {k: v for k, v in env.items() if not k.startswith("TCS_")}
    ok = client(bare, "get", "CONFIG.MOUNT", "--port", live.port, "--user", "admin",
                "--password-file", "-", stdin="admin\n")
    assert ok.returncode == 0 and ok.stdout == "CONFIG.MOUNT=AZ-ZD\n", ok.stderr
    wrong = tmp_path / "wrong"
    wrong.write_text("nope\n")
    refused = client(env, "get", "CONFIG.MOUNT", "--password-file", wrong)
    assert refused.returncode == 3 and "login as 'admin' refused" in refused.stderr
    closed = client(env, "get", "CONFIG.MOUNT", "--port", "1")
    assert closed.returncode == 3 and "cannot connect" in closed.stderr
    unknown = client(env, "get", "CONFIG.MOUNT", "NOPE.X", "--value-only")
    assert unknown.returncode == 1 and unknown.stdout == "AZ-ZD\n" and "NOPE.X: UNKNOWN" in unknown.stderr
    usage = client(env, "set", "AZ.TARGETPOS")
    assert usage.returncode == 2 and "not an assignment" in usage.stderr
    for proc in (ok, refused, closed, unknown, usage):
        assert "Traceback" not in proc.stderr


def test_tree_lists_objects_with_properties(env):
    proc = client(env, "tree", "POINTING.TARGET", "--json")
    assert proc.returncode == 0, proc.stderr
    objects = {o["name"]: o for o in json.loads(proc.stdout)}
    ra = objects["POINTING.TARGET.RA"]
    assert ra["type"] == 2 and ra["wlevel"] == 3 and "info" in ra
    text = client(env, "tree", "AZ")
    assert text.returncode == 0
    assert any(line.startswith("AZ.TRAJECTORY.BUFFER ") and "module array[" in line
               for line in text.stdout.splitlines()), text.stdout
    assert "AZ.TRAJECTORY.BUFFER[0].TIME" in text.stdout


def test_implicit_login_and_crlf_lines(tmp_path):
    # RTS2's setting: no AUTH (the greeting lists no method), CRLF line ends; no password needed
    text = CONFIG.read_text().replace('port = 0\n', 'port = 0\nimplicit_auth = true\n'
                                      'implicit_user = "admin"\nline_ending = "CRLF"\n', 1)
    hwfile = tmp_path / "implicit.toml"
    hwfile.write_text(text)
    svc = LiveService(hwfile, tmp_path / "state").start()
    try:
        bare = {k: v for k, v in os.environ.items() if not k.startswith("TCS_")}
        proc = client(bare, "get", "CONFIG.MOUNT", "SERVER.CONNECTION.USERNAME", "--port", svc.port,
                      stdin="")
        assert proc.returncode == 0, proc.stderr
        assert proc.stdout == "CONFIG.MOUNT=AZ-ZD\nSERVER.CONNECTION.USERNAME=admin\n"
    finally:
        svc.stop()


# ------------------------------------------------------------------ issue 25: smaller client items
def on_service(live, fn):
    """``fn()`` on the service's loop (its objects are not thread-safe), from a plain test."""
    async def call():
        return fn()

    return asyncio.run_coroutine_threadsafe(call(), live.loop).result(WAIT)


def test_set_polls_at_the_progress_interval(env, live):
    """Issue 25: while a SET runs, tcs-client reads the progress variables once per progress
    interval (old code: a GET after every answer, ~410 GETs/s). Counted on the server: the
    commands of the client's connection over the time it was connected."""
    assert client(env, "set", "CABINET.POWER=1").returncode == 0
    try:
        assert client(env, "set", "CABINET.REINIT=1").returncode == 0
        until(env, "CABINET.REFERENCED", lambda v: v == 1.0)
        # from AZ 0 (AZ is cyclic: from 40, say, where an earlier test may have left it, the
        # nearer 210 would be the way to -150); a TARGETPOS also ends any tracking left running
        assert client(env, "set", "AZ.TARGETPOS=0").returncode == 0
        server = live.service.server
        before = set(on_service(live, lambda: list(server.sessions)))
        started = time.monotonic()
        proc = subprocess.Popen([sys.executable, "-m", "tcs.cli.client", "set", "AZ.TARGETPOS=-150",
                                 "--progress-interval", "1"], env=env, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
        commands: dict[int, int] = {}
        while proc.poll() is None:
            for sid, n in on_service(live, lambda: [(s.id, len(s.command_times))
                                                    for s in server.sessions.values()]):
                if sid not in before:
                    commands[sid] = max(n, commands.get(sid, 0))
            time.sleep(0.05)
        elapsed = time.monotonic() - started
        out, err = proc.communicate(timeout=WAIT)
        assert proc.returncode == 0, err
        assert get(env, "AZ.REALPOS")["AZ.REALPOS"] == pytest.approx(-150, abs=0.01)
        assert len(commands) == 1, commands
        (count,) = commands.values()
        # the SET, one GET per second connected (the first after 0.5 s), DISCONNECT: old code ~100s
        assert 1 <= count <= elapsed / 1.0 + 3, (count, elapsed, err)
        assert "AZ.TARGETPOS=-150: done" in err
    finally:
        client(env, "set", "AZ.TARGETPOS=0")
        assert client(env, "set", "CABINET.POWER=0").returncode == 0


def test_get_of_a_module_prints_its_members(env):
    """Issue 25: ``get CABINET.CORE.CYCLE`` (a module) printed INVALID; now its variables."""
    proc = client(env, "get", "CABINET.CORE.CYCLE")
    assert proc.returncode == 0, proc.stderr
    lines = dict(line.split("=", 1) for line in proc.stdout.splitlines())
    assert {"CABINET.CORE.CYCLE.CYCLES", "CABINET.CORE.CYCLE.LATE",
            "CABINET.CORE.CYCLE.MAX_LATENESS"} <= set(lines), proc.stdout
    assert int(lines["CABINET.CORE.CYCLE.CYCLES"]) > 0
    both = client(env, "get", "--json", "CONFIG.MOUNT", "CABINET.CORE")  # a sub-module and a variable
    assert both.returncode == 0, both.stderr
    values = json.loads(both.stdout)
    assert values["CONFIG.MOUNT"] == "AZ-ZD" and "CABINET.CORE.CYCLE.LATE" in values
    assert "CABINET.CORE.DRIVE[]: module array" in both.stderr


def test_errors_say_what_they_mean(env):
    """Issue 25: bare keywords get their meaning: RANGE with the object's MIN/MAX, DENIED with
    read-only / write-only / the levels, FAILED n with the OpenTCI meaning of n."""
    refused = client(env, "set", "ZD.TARGETPOS=100")
    assert refused.returncode == 1
    assert "ZD.TARGETPOS: RANGE (allowed -85 .. 85)" in refused.stderr, refused.stderr
    read_only = client(env, "set", "AZ.REALPOS=1")
    assert read_only.returncode == 1 and "AZ.REALPOS: DENIED (read-only)" in read_only.stderr, read_only.stderr
    write_only = client(env, "get", "CABINET.REINIT")
    assert write_only.returncode == 1
    assert "CABINET.REINIT: DENIED (write-only)" in write_only.stderr, write_only.stderr
    off = client(env, "set", "ZD.TARGETPOS=10")  # main power is off
    assert off.returncode == 1
    assert "ZD.TARGETPOS: FAILED 5 (invalid operation mode" in off.stderr, off.stderr
    unknown = client(env, "get", "NOPE.X")
    assert "NOPE.X: UNKNOWN (no such object)" in unknown.stderr


def test_watch_on_the_opentsi_port_shows_faults(tmp_path):
    """Issue 25: on the OpenTSI port ``watch`` printed "errors none" while
    TELESCOPE.STATUS.LIST listed faults (it looked for OpenTCI's ERROR_STATE variables)."""
    text = CONFIG.read_text().replace('port = 0\n', 'port = 0\nopentsi_port = 0\n', 1)
    hwfile = tmp_path / "tsi.toml"
    hwfile.write_text(text)
    svc = LiveService(hwfile, tmp_path / "state").start()
    try:
        env = {**os.environ, "TCS_HOST": "127.0.0.1", "TCS_PORT": str(svc.service.opentsi_port),
               "TCS_USER": "admin"}
        quiet = client(env, "watch", "--count", "1", "--password-file", "-", stdin="admin\n")
        assert quiet.returncode == 0, quiet.stderr
        assert "errors none" in quiet.stdout and "ready " in quiet.stdout, quiet.stdout
        on_service(svc, lambda: svc.telescope.sims[1].inject_fault("overcurrent"))
        deadline = time.monotonic() + WAIT
        while True:
            watch = client(env, "watch", "--count", "1", "--password-file", "-", stdin="admin\n")
            assert watch.returncode == 0, watch.stderr
            status = watch.stdout.strip().splitlines()[-1]
            if "errors none" not in status:
                break
            assert time.monotonic() < deadline, status
            time.sleep(0.3)
        assert "AZ=" in status, status
    finally:
        svc.stop()


def test_the_client_does_not_load_the_server_or_the_model():
    """``tcs-client`` is started once per call by scripts and checks that poll: it loads the
    protocol core only, not the server, the model or numpy/erfa (half a second of CPU a start,
    seconds on a slow cabinet computer or an emulated one)."""
    code = ("import sys, tcs.cli.client, tcs.opentci_server; "
            "heavy = sorted(m for m in ('numpy', 'erfa', 'tcs.model', 'tcs.axes', 'tcs.opentci_server.server') "
            "if m in sys.modules); print(heavy)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]", out.stdout
    from tcs.opentci_server import Tpl2Server, build_tree   # (still there, loaded on use)
    assert callable(build_tree) and Tpl2Server.__name__ == "Tpl2Server"
