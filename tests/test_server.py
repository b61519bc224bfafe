"""The TPL2 server over a real socket against the service: login, GET/SET, properties,
command-id rules, limits, persistence, and the SERVER/LOCAL/CONFIG modules."""

from __future__ import annotations

import asyncio
import re
import time

import pytest

from support.service import start_service
from support.tpl2 import RawClient


async def test_greeting_and_login(service):
    _, port = service
    c = await RawClient.connect(port, login=None)
    m = re.fullmatch(r"TPL2 2\.1 CONN (\d+) AUTH PLAIN ENC MESSAGE (.*)", c.greeting)
    assert m, c.greeting
    assert c.greeting.split(" ")[3] == m.group(1)  # SONG reads the 4th word
    await c.send('AUTH PLAIN "admin" "admin"')
    assert await c.readline() == "AUTH OK 0 0"
    assert await c.get("SERVER.CONNECTION.USERNAME") == '"admin"'
    assert await c.get("SERVER.CONNECTION.ID") == m.group(1)
    await c.close()


async def test_login_failures_are_delayed_then_dropped(service):
    svc, port = service
    c = await RawClient.connect(port, login=None)
    t0 = time.monotonic()
    await c.send('AUTH PLAIN "admin" "wrong"')
    assert await c.readline() == "AUTH FAILED"
    assert time.monotonic() - t0 >= svc.config.server.auth_fail_delay * 0.9
    await c.send("1 GET LOCAL.UTC")
    assert await c.until(1) == ["1 COMMAND ERROR UNAUTHENTICATED", "1 COMMAND FAILED"]
    await c.send("AUTH PLAIN nobody admin")
    assert await c.readline() == "AUTH FAILED"
    await c.send('AUTH PLAIN "admin" "again-wrong"')
    assert await c.readline() == "AUTH FAILED"
    assert await c.reader.read() == b""  # dropped after three failures
    await c.close()


async def test_auth_variants(service):
    _, port = service
    c = await RawClient.connect(port, login=None)
    await c.send("AUTH KERBEROS x y")
    assert await c.readline() == "AUTH UNSUPPORTED"
    await c.send("AUTH PLAIN")
    assert await c.readline() == "AUTH ERROR"
    await c.send('AUTH PLAIN "admin" "admin" 2 3')  # asks for less privilege
    assert await c.readline() == "AUTH OK 2 3"
    assert await c.get("SERVER.CONNECTION.WLEVEL") == "3"
    # level 3 may not write a configuration variable (WLEVEL 1)
    assert await c.command(5, "SET LOCAL.UT1-UTC=0.1") == [
        "5 COMMAND OK", "5 DATA ERROR LOCAL.UT1-UTC DENIED", "5 COMMAND COMPLETE"]
    await c.close()


async def test_get_values_and_types(service):
    _, port = service
    c = await RawClient.connect(port)
    lines = await c.command(1, "GET LOCAL.UTC;LOCAL.LATITUDE;CONFIG.MOUNT;LOCAL.VERSION;NO.SUCH;LOCAL")
    assert lines[0] == "1 COMMAND OK" and lines[-1] == "1 COMMAND COMPLETE"
    values = dict(line.split(" ", 3)[3].split("=", 1) for line in lines[1:-1])
    assert abs(float(values["LOCAL.UTC"]) - time.time()) < 5
    assert "." in values["LOCAL.UTC"] and "e" not in values["LOCAL.UTC"]
    assert values["LOCAL.LATITUDE"] == "28.7606"
    assert values["CONFIG.MOUNT"] == '"AZ-ZD"'
    assert values["LOCAL.VERSION"] == str((24 << 16) | 1)
    assert values["NO.SUCH"] == "UNKNOWN"
    assert values["LOCAL"] == "INVALID"  # a module has no value
    await c.close()


async def test_names_are_case_insensitive_and_echoed_as_sent(service):
    _, port = service
    c = await RawClient.connect(port)
    lines = await c.command(2, "get local.latitude")
    assert lines[1] == "2 DATA INLINE local.latitude=28.7606"
    await c.close()


async def test_properties(service):
    _, port = service
    c = await RawClient.connect(port)
    assert await c.get("LOCAL.UT1-UTC!TYPE") == "2"
    assert await c.get("LOCAL.UT1-UTC!MIN") == "-1.0"
    assert await c.get("LOCAL.UT1-UTC!MAX") == "1.0"
    assert await c.get("LOCAL.UTC!WLEVEL") == "-1"
    assert await c.get("LOCAL.UTC!CLASS") == "1006"
    assert await c.get("LOCAL!CLASS") == "1002"
    assert await c.get("!CLASS") == "1001"
    assert await c.get("SERVER.CONNECTION.ID!CLASS") == "2006"
    assert await c.get("CONFIG.MOUNT!MIN") == "UNKNOWN"  # strings have no range
    assert await c.get("LOCAL.UTC!COUNT") == "UNKNOWN"
    members = await c.members()
    assert members[:3] == ["SERVER", "LOCAL", "CONFIG"]
    assert await c.get("LOCAL!NAME") == '"LOCAL"'
    assert (await c.get("LOCAL.UTC!INFO")).startswith('"UTC')
    # numeric access: <n> is the member's !INDEX
    index = await c.get("LOCAL!INDEX")
    latitude_index = await c.get("LOCAL.LATITUDE!INDEX")
    assert await c.get(f"<{index}>.<{latitude_index}>!NAME") == '"LATITUDE"'
    assert await c.get(f"<{index}>.<{latitude_index}>") == "28.7606"
    await c.close()


async def test_chimera_type_then_value(service):
    _, port = service
    c = await RawClient.connect(port)
    lines = await c.command(3, "GET LOCAL.HEIGHT!TYPE;LOCAL.HEIGHT")
    assert lines == ["3 COMMAND OK", "3 DATA INLINE LOCAL.HEIGHT!TYPE=2",
                     "3 DATA INLINE LOCAL.HEIGHT=2326.0", "3 COMMAND COMPLETE"]
    await c.close()


async def test_set_weak_typing_range_type_denied(service):
    _, port = service
    c = await RawClient.connect(port)
    assert await c.command(1, 'SET LOCAL.UT1-UTC="0.25"') == [
        "1 COMMAND OK", "1 DATA OK LOCAL.UT1-UTC", "1 COMMAND COMPLETE"]
    assert await c.get("LOCAL.UT1-UTC") == "0.25"
    lines = await c.command(2, "GET LOCAL.UT1;LOCAL.UTC")
    ut1, utc = (float(line.split("=")[1]) for line in lines[1:3])
    assert ut1 - utc == pytest.approx(0.25, abs=0.05)
    assert (await c.command(3, "SET LOCAL.UT1-UTC=5"))[1] == "3 DATA ERROR LOCAL.UT1-UTC RANGE"
    assert (await c.command(4, 'SET LOCAL.UT1-UTC="soon"'))[1] == "4 DATA ERROR LOCAL.UT1-UTC TYPE"
    assert (await c.command(5, "SET LOCAL.UTC=1.0"))[1] == "5 DATA ERROR LOCAL.UTC DENIED"
    assert (await c.command(6, "SET LOCAL=1"))[1] == "6 DATA ERROR LOCAL INVALID"
    assert (await c.command(7, "SET LOCAL.UTC!MIN=1"))[1] == "7 DATA ERROR LOCAL.UTC!MIN INVALID"
    assert (await c.command(8, "SET NO.SUCH=1"))[1] == "8 DATA ERROR NO.SUCH UNKNOWN"
    assert (await c.command(9, "SET LOCAL.HEIGHT=1,2"))[1] == "9 DATA ERROR LOCAL.HEIGHT DIMENSION"
    # several assignments: applied in order, each answered
    assert await c.command(10, "SET LOCAL.HEIGHT=100;LOCAL.LATITUDE=99") == [
        "10 COMMAND OK", "10 DATA OK LOCAL.HEIGHT", "10 DATA ERROR LOCAL.LATITUDE RANGE",
        "10 COMMAND COMPLETE"]
    await c.close()


async def test_syncpos_rule_and_mount(service):
    _, port = service
    c = await RawClient.connect(port)
    await c.command(1, "SET LOCAL.SYNCPOS=1")
    assert await c.get("LOCAL.SYNCPOS") == "1"
    await c.command(2, "SET LOCAL.LONGITUDE=10.5")
    assert await c.get("LOCAL.SYNCPOS") == "0"
    assert await c.get("LOCAL.LONGITUDE") == "10.5"
    assert (await c.command(3, 'SET CONFIG.MOUNT="AZ-ZD"'))[1] == "3 DATA OK CONFIG.MOUNT"
    assert (await c.command(4, 'SET CONFIG.MOUNT="RA-DEC"'))[1] == "4 DATA ERROR CONFIG.MOUNT RANGE"
    assert await c.get("CONFIG.MOUNTOPTIONS") == '"AZ-ZD"'
    await c.close()


async def test_values_written_by_clients_survive_a_restart(tmp_path):
    svc, port = await start_service(tmp_path / "state")
    try:
        c = await RawClient.connect(port)
        await c.command(1, "SET LOCAL.UT1-UTC=-0.125;LOCAL.HEIGHT=2400;CONFIG.ORIENTATION=12.5")
        await c.close()
    finally:
        await svc.stop()
    svc, port = await start_service(tmp_path / "state")
    try:
        c = await RawClient.connect(port)
        assert await c.get("LOCAL.UT1-UTC") == "-0.125"
        assert await c.get("LOCAL.HEIGHT") == "2400.0"
        assert await c.get("CONFIG.ORIENTATION") == "12.5"
        await c.close()
    finally:
        await svc.stop()


async def test_command_ids(service):
    _, port = service
    c = await RawClient.connect(port)
    assert (await c.command(7, "GET LOCAL.HEIGHT"))[0] == "7 COMMAND OK"
    await c.send("007 GET LOCAL.HEIGHT")  # leading zeros accepted, reply uses the number
    assert await c.until(7) == ["7 COMMAND OK", "7 DATA INLINE LOCAL.HEIGHT=2326.0", "7 COMMAND COMPLETE"]
    await c.send("4294967296 GET LOCAL.HEIGHT")
    # a refused command ends with a final line, id 0 where the line's id cannot be used
    # (service events, which carry id 0 too, are left out)
    async def refused() -> list[str]:
        return [x for x in await c.until(0) if not x.startswith("0 EVENT ")]

    assert await refused() == ["0 COMMAND ERROR IDRANGE 4294967296", "0 COMMAND FAILED"]
    await c.send("0 GET LOCAL.HEIGHT")
    assert await refused() == ["0 COMMAND ERROR IDRANGE 0", "0 COMMAND FAILED"]
    await c.send("GET LOCAL.HEIGHT")  # no id at all
    assert await refused() == ["0 COMMAND ERROR SYNTAX", "0 COMMAND FAILED"]
    await c.send("5 FROB X")
    assert await c.until(5) == ["5 COMMAND ERROR UNKNOWN [unknown command FROB]", "5 COMMAND FAILED"]
    await c.send("6 GET A[")
    assert await c.until(6) == ["6 COMMAND ERROR SYNTAX", "6 COMMAND FAILED"]
    await c.send("6 ABORT 12")
    assert await c.until(6) == ["6 COMMAND ERROR NOTRUNNING", "6 COMMAND FAILED"]
    await c.close()


async def test_server_module_and_connection_settings(service):
    _, port = service
    c = await RawClient.connect(port)
    assert float(await c.get("SERVER.UPTIME")) >= 0.0
    assert (await c.get("SERVER.VERSION")).startswith('"tcs ')
    assert await c.get("SERVER.CONNECTION.EVENTMASK") == "15"
    assert (await c.command(1, "SET SERVER.CONNECTION.EVENTMASK=0"))[1] == "1 DATA OK SERVER.CONNECTION.EVENTMASK"
    assert await c.get("SERVER.CONNECTION.EVENTMASK") == "0"
    other = await RawClient.connect(port)
    assert await other.get("SERVER.CONNECTION.EVENTMASK") == "15"  # per connection
    assert await other.get("SERVER.CONNECTION.ADDRESS") == '"127.0.0.1"'  # the address only (TPL2 §9)
    await other.close()
    await c.close()


async def test_too_many_connections(tmp_path):
    svc, port = await start_service(tmp_path / "state", max_connections=2, admin_reserve=0)
    try:
        a = await RawClient.connect(port)
        b = await RawClient.connect(port)
        c = await RawClient.connect(port, login=None)
        assert "too many connections" in c.greeting
        assert await c.reader.read() == b""
        assert await a.get("LOCAL.HEIGHT") == "2326.0"  # the others are not disturbed
        for x in (a, b, c):
            await x.close()
    finally:
        await svc.stop()


async def test_long_lines_are_refused_and_the_connection_goes_on(tmp_path):
    svc, port = await start_service(tmp_path / "state", max_line_length=1024)
    try:
        c = await RawClient.connect(port)
        await c.send("3 GET " + ";".join(["LOCAL.UTC"] * 500))
        assert await c.until(3) == ["3 COMMAND ERROR SYNTAX", "3 COMMAND FAILED"]
        assert await c.get("LOCAL.HEIGHT") == "2326.0"
        await c.close()
    finally:
        await svc.stop()


async def test_every_variable_of_the_tree_reads(service):
    """Walk the declared tree: every variable answers a value (never FAILED) and its !TYPE
    (array elements without hardware, e.g. DEROTATOR[0], answer FAILED 4 by design)."""
    svc, port = service
    from tcs.opentci_server.tree import VarNode

    c = await RawClient.connect(port)
    paths = [p for p, node in svc.server.tree.walk() if isinstance(node, VarNode) and not node.absent]
    assert len(paths) > 20
    for i, path in enumerate(paths, start=1):
        lines = await c.command(i, f"GET {path}!TYPE;{path}")
        assert lines[0] == f"{i} COMMAND OK"
        assert "FAILED" not in lines[2] and "UNKNOWN" not in lines[2], lines
    await c.close()


async def test_disconnect(service):
    _, port = service
    c = await RawClient.connect(port)
    await c.send("DISCONNECT")
    assert await c.readline() == "DISCONNECT OK"
    assert await c.reader.read() == b""
    await c.close()


async def test_line_endings_crlf_in_lf_out(service):
    _, port = service
    c = await RawClient.connect(port)
    await c.send_bytes(b"1 GET LOCAL.HEIGHT\r\n\r\n\n2 GET LOCAL.HEIGHT\n")
    for _ in range(6):
        raw = await c.readraw()
        assert raw.endswith(b"\n") and not raw.endswith(b"\r\n")
    await c.close()


async def test_pending_commands_fail_when_the_server_stops(tmp_path):
    """A GET answers at once; the server stops cleanly with clients connected."""
    svc, port = await start_service(tmp_path / "state")
    c = await RawClient.connect(port)
    await svc.stop()
    assert await asyncio.wait_for(c.reader.read(), 5) == b""
    await c.close()
