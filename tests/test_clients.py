"""What each TPL2 client in the field does and requires (protocol doc §1–9), replayed over a
real socket against the service."""

from __future__ import annotations

import asyncio
import re

from support.service import start_service
from support.tpl2 import RawClient


async def test_pyobs_pilar(service):
    """AUTH PLAIN substring in the greeting; quoted values; every line after login starts with
    an integer id; bare lowercase ``disconnect`` with no newline, then close."""
    _, port = service
    c = await RawClient.connect(port, login=None)
    assert "AUTH PLAIN" in c.greeting
    await c.send('AUTH PLAIN "admin" "admin"')
    assert "AUTH OK" in await c.readline()
    await c.send('1 SET LOCAL.UT1-UTC="0.1"')
    await c.send("2 GET LOCAL.UT1-UTC;LOCAL.HEIGHT;CONFIG.MOUNT")
    lines = await c.until(1) + await c.until(2)
    for line in lines:
        int(line.split()[0])  # pyobs: int(line.split()[0]) of every line
        line.encode("utf-8")
    values = {}
    for line in lines:
        if "DATA INLINE" in line:
            pos = line.find("=")
            value = line[pos + 1:]
            values[line[line.find("DATA INLINE") + 12:pos]] = value[1:-1] if value[0] == '"' else value
    assert values == {"LOCAL.UT1-UTC": "0.1", "LOCAL.HEIGHT": "2326.0", "CONFIG.MOUNT": "AZ-ZD"}
    await c.send_bytes(b"disconnect")
    c.writer.write_eof()
    line = await c.readline()
    while line.startswith("0 EVENT "):  # a service event (GPS fix, late on a loaded machine)
        line = await c.readline()
    assert line == "DISCONNECT OK"
    assert await c.reader.read() == b""
    await c.close()


async def test_chimera(service):
    """Greeting matched by chimera's regex; single-digit levels; ``GET X!TYPE;X``; bare LF."""
    _, port = service
    c = await RawClient.connect(port, login=None)
    assert re.match(r"TPL2\s(?P<version>\d+\.\d+)\sCONN\s(?P<conn>\d+)\sAUTH\s(?P<auth>[\w,]+)\sENC\s"
                    r"(?P<enc>)\s?MESSAGE\s(?P<msg>.*)", c.greeting), c.greeting
    await c.send('AUTH PLAIN "admin" "admin"')
    assert re.fullmatch(r"AUTH OK (\d) (\d)", await c.readline())
    await c.send("1 GET LOCAL.LATITUDE!TYPE;LOCAL.LATITUDE")
    raw = [await c.readraw() for _ in range(4)]
    assert all(r.endswith(b"\n") and not r.endswith(b"\r\n") for r in raw)
    assert raw[1] == b"1 DATA INLINE LOCAL.LATITUDE!TYPE=2\n"
    assert float(raw[2].split(b"=")[1]) == 28.7606
    assert int(raw[1].split(b"=")[1]) == 2
    await c.close()


async def test_rts2_crlf_and_implicit_auth(tmp_path):
    """RTS2 never sends AUTH and compares ``COMMAND OK\\r`` / ``COMPLETE\\r`` exactly."""
    svc, port = await start_service(tmp_path / "state", line_ending="CRLF", implicit_auth=True,
                                    implicit_user="admin")
    try:
        c = await RawClient.connect(port, login=None)
        assert c.greeting.startswith("TPL2 2.1 CONN ") and " AUTH ENC MESSAGE " in c.greeting
        assert await c.readraw() == b"AUTH OK 0 0\r\n"
        await c.send("1 GET LOCAL.HEIGHT", end="\r\n")
        assert await c.readraw() == b"1 COMMAND OK\r\n"
        assert await c.readraw() == b"1 DATA INLINE LOCAL.HEIGHT=2326.0\r\n"
        assert await c.readraw() == b"1 COMMAND COMPLETE\r\n"
        await c.send("1 GET LOCAL.HEIGHT", end="\r\n")  # ids reused at once
        assert await c.readraw() == b"1 COMMAND OK\r\n"
        await c.close()
    finally:
        await svc.stop()


async def test_unam_auth_and_first_get_back_to_back(service):
    _, port = service
    c = await RawClient.connect(port, login=None)
    await c.send_bytes(b'AUTH PLAIN "admin" "admin"\n1 GET LOCAL.HEIGHT\n')
    assert await c.readline() == "AUTH OK 0 0"
    assert await c.until(1) == ["1 COMMAND OK", "1 DATA INLINE LOCAL.HEIGHT=2326.0", "1 COMMAND COMPLETE"]
    await c.close()


async def test_song_connection_number_and_fixed_ids(service):
    _, port = service
    a = await RawClient.connect(port)
    b = await RawClient.connect(port)
    na, nb = int(a.greeting.split(" ")[3]), int(b.greeting.split(" ")[3])
    assert na != nb
    for _ in range(3):  # SONG uses one fixed id per function
        assert (await b.command(100, "GET LOCAL.HEIGHT"))[1] == "100 DATA INLINE LOCAL.HEIGHT=2326.0"
    await a.close()
    await b.close()


async def test_indi_blank_line_first(service):
    _, port = service
    c = await RawClient.connect(port, login=None)
    await c.send_bytes(b'\n\r\nAUTH PLAIN "admin" "admin"\n')
    assert await c.readline() == "AUTH OK 0 0"
    await c.close()


async def test_a_broken_client_does_not_disturb_another(service):
    _, port = service
    good = await RawClient.connect(port)
    bad = await RawClient.connect(port)
    await bad.send_bytes(b"\xff\xfe\x00garbage\n1 GET \"\n\x80\x81 SET =\n")
    while True:  # the bad client gets syntax errors, in 7-bit ASCII
        line = await asyncio.wait_for(bad.reader.readline(), 5)
        line.decode("ascii")
        if line.startswith(b"1 COMMAND FAILED"):
            break
    assert await good.get("LOCAL.HEIGHT") == "2326.0"
    await bad.close()
    await good.close()
