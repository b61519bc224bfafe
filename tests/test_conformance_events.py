"""Issue 12 item 4 (and 12-13): which id an event carries, over a real socket.

TPL2 §5: only an event raised for a command that is still executing carries its id (its
extended id on other connections); anything after the command's final line carries 0, also
when the client already reuses the id for a new command (RTS2, SONG do at once).
Runs the fast simulated telescope (``tests/hw_axes_fast.toml``) in-process.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from support.opentci_client import Client
from support.service import start_service

FAST = Path(__file__).with_name("hw_axes_fast.toml")
WAIT = 30.0  # generous: behaviour, not timing


@pytest.fixture
async def fast(tmp_path):
    svc, port = await start_service(tmp_path / "state", FAST)
    try:
        yield port
    finally:
        await svc.stop()


async def powered(c: Client, axis: str) -> None:
    lines = await c.set("CABINET.POWER=1", 60)
    assert lines[-1].endswith("COMMAND COMPLETE"), lines
    lines = await c.set(f"{axis}.POWER=1", WAIT)
    assert lines[-2].endswith(f"DATA OK {axis}.POWER"), lines


async def test_event_after_the_final_line_carries_id_zero(fast):
    c = await Client.connect(fast)
    other = await Client.connect(fast)
    await powered(c, "AZ")
    # REINIT answers at once; referencing ends later: its events are nobody's command
    assert await c.command(6, "SET AZ.REINIT=1") == ["6 COMMAND OK", "6 DATA OK AZ.REINIT", "6 COMMAND COMPLETE"]
    line = await c.event(r"^\d+ EVENT INFO AZ:19\b", WAIT)
    assert line.startswith("0 EVENT INFO AZ:19"), line
    line = await other.event(r"^\d+ EVENT INFO AZ:19\b", WAIT)
    assert line.startswith("0 EVENT INFO AZ:19"), line
    await other.close()
    await c.close()


async def test_aborted_command_reused_id_gets_no_late_event(fast):
    c = await Client.connect(fast)
    await powered(c, "AZ")
    await c.command(2, "SET AZ.REINIT=1")
    await c.wait("AZ.REFERENCED", lambda v: float(v) == 1.0, WAIT)
    start = float(await c.value("AZ.REALPOS"))
    # (at 10 of this file's 160 deg/s the 60 deg move lasts 6 s: on a loaded host the ABORT
    # still reaches a moving axis, whose stop is what emits the late event)
    assert (await c.set("AZ.CURRSPEED=10"))[-1].endswith("COMMAND COMPLETE")
    await c.send(f"1 SET AZ.TARGETPOS={start + 60.0}")
    await c.event(r"^1 COMMAND OK$")
    assert (await c.command(3, "ABORT 1"))[-1] == "3 COMMAND COMPLETE"
    assert "1 COMMAND ABORTEDBY 3" in c.lines
    c.lines.clear()
    # the client reuses id 1 at once: the aborted command's later events (the ABORT stops its
    # motion) carry id 0, never the new 1's
    lines = await c.command(1, f"SET AZ.TARGETPOS={start + 1.0}", WAIT)
    assert lines[-2:] == ["1 DATA OK AZ.TARGETPOS", "1 COMMAND COMPLETE"], lines
    assert not any(re.match(r"1 EVENT ERROR AZ:10\b", x) for x in lines), lines
    assert not any("aborted" in x for x in lines), lines
    assert any(re.match(r"0 EVENT INFO AZ:23 aborted", x) for x in c.lines), c.lines
    await c.close()


# ------------------------------------------------------------------ item 13: event texts


async def test_every_event_has_a_text_and_limits_are_decoded(fast):
    c = await Client.connect(fast)
    await powered(c, "FOCUS")
    await c.set("FOCUS.REINIT=1")
    await c.wait("FOCUS.REFERENCED", lambda v: float(v) == 1.0, WAIT)
    # tests/hw_axes_fast.toml: FOCUS's positive limit switch sits at ~15 mm, inside its range
    lines = await c.command(3, "SET FOCUS.TARGETPOS=30", WAIT)
    assert "3 DATA ERROR FOCUS.TARGETPOS FAILED 8" in lines, lines
    line = await c.event(r"^\d+ EVENT ERROR FOCUS:22 ", WAIT)
    assert " FOCUS:22 hardware max limit" in line, line  # not "limit state 2"
    # a trajectory's TRAJ events (29..32) carry their meaning where the follower gives no reason
    await powered(c, "AZ")
    await c.set("AZ.REINIT=1")
    await c.wait("AZ.REFERENCED", lambda v: float(v) == 1.0, WAIT)
    p0 = float(await c.value("AZ.REALPOS"))
    t0 = float(await c.value("LOCAL.UT1")) + 0.5
    parts = []
    for i in range(6):
        parts += [f"AZ.TRAJECTORY.BUFFER[{i}].TIME={t0 + 0.25 * i!r}",
                  f"AZ.TRAJECTORY.BUFFER[{i}].TARGETPOS={p0 + 0.01 * i!r}"]
    await c.set(";".join(parts))
    await c.set("AZ.TRAJECTORY.ADDPOINTS=6")
    lines = await c.command(5, "SET AZ.TRAJECTORY.RUN=1", WAIT)
    await c.event(r"^\d+ EVENT INFO AZ:23 ", WAIT)
    seen = [x for x in lines + c.lines if " EVENT " in x]
    assert any(":29 " in x for x in seen), seen
    for x in seen:
        assert re.match(r"^\d+ EVENT [A-Z]+ [A-Z0-9\[\]_]+:\d+ \S", x), x
    await c.close()


def test_reference_tool_lists_every_event_number():
    import subprocess
    import sys

    tool = Path(__file__).resolve().parent.parent / "tools" / "opentci_reference.py"
    out = subprocess.run([sys.executable, str(tool)], capture_output=True, text=True, timeout=120).stdout
    assert "## Event and error numbers" in out
    for number in (5, 10, 22, 23, 29, 32, 1000, 1013, 1014, 1015, 1020):
        assert re.search(rf"^\| {number} \| \S", out, re.M), number
    assert "SERVER.CONNECTION.ADDRESS" in out
