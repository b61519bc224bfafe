"""The Alpaca wire rules without a telescope: the pure request/reply core and the UDP
discovery responder of an (empty) Alpaca server on loopback."""

from __future__ import annotations

import asyncio
import json
import socket

import pytest

from tcs.alpaca.protocol import (AlpacaRequest, AscomError, BadRequest, Code, TransactionCounter,
                                 from_tcs_error, reply)
from tcs.alpaca.server import AlpacaServer
from tcs.errors import ErrorNumber, RangeRefused, TcsError


@pytest.mark.parametrize("method, params, name, expected", [
    ("GET", {"clienttransactionid": "5"}, "ClientTransactionID", "5"),
    ("GET", {"AXIS": "1"}, "Axis", "1"),
    ("PUT", {"Axis": "1"}, "Axis", "1"),
    ("PUT", {"axis": "1"}, "Axis", None),          # PUT form fields: exact spelling only
])
def test_parameter_names(method, params, name, expected):
    assert AlpacaRequest(method, params).raw(name) == expected


@pytest.mark.parametrize("text, value", [("5", 5), ("4294967295", 4294967295), ("4294967296", 0),
                                         ("-1", 0), ("x", 0), (" 7 ", 7), (None, 0)])
def test_transaction_ids_are_uint32_or_zero(text, value):
    params = {} if text is None else {"ClientTransactionID": text}
    assert AlpacaRequest("GET", params).client_transaction_id == value


@pytest.mark.parametrize("kind, text, value", [
    ("bool", "True", True), ("bool", "false", False), ("bool", "yes", BadRequest),
    ("float", "1.5", 1.5), ("float", "1e3", 1000.0), ("float", "nan", BadRequest),
    ("float", "1e400", BadRequest), ("float", "", BadRequest), ("int", "12", 12),
    ("int", "1.5", BadRequest), ("int", "x", BadRequest),
])
def test_typed_parameters(kind, text, value):
    r = AlpacaRequest("GET", {"P": text})
    if value is BadRequest:
        with pytest.raises(BadRequest):
            getattr(r, kind)("P")
    else:
        assert getattr(r, kind)("P") == value
    with pytest.raises(BadRequest):
        getattr(AlpacaRequest("GET", {}), kind)("P")


def test_replies_and_error_mapping():
    r = AlpacaRequest("GET", {"ClientTransactionID": "9"})
    ids = TransactionCounter()
    first, second = ids(), ids()
    assert second == first + 1
    assert reply(r, first, 1.5) == {"Value": 1.5, "ClientTransactionID": 9, "ServerTransactionID": first,
                                    "ErrorNumber": 0, "ErrorMessage": ""}
    body = reply(r, second, error=AscomError(Code.INVALID_VALUE, "no"))
    assert "Value" not in body and body["ErrorNumber"] == 0x401 and body["ErrorMessage"] == "no"
    assert from_tcs_error(RangeRefused("x")).code == Code.INVALID_VALUE
    assert from_tcs_error(TcsError("below the horizon", ErrorNumber.SOFTLIMIT)).code == Code.INVALID_VALUE
    assert from_tcs_error(TcsError("not powered", ErrorNumber.INVMODE)).code == Code.INVALID_OPERATION
    assert from_tcs_error(TcsError("opening refused: rain", 1020)).code == Code.INVALID_OPERATION
    assert from_tcs_error(TcsError("PLC lost", ErrorNumber.NOCON)).code == Code.DRIVER_ERROR


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("0.0.0.0", 0))
        return s.getsockname()[1]


async def _ask(port: int, data: bytes, timeout: float = 1.0) -> bytes | None:
    loop = asyncio.get_running_loop()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.setblocking(False)
        s.bind(("127.0.0.1", 0))
        s.sendto(data, ("127.0.0.1", port))
        try:
            return await asyncio.wait_for(loop.sock_recv(s, 1024), timeout)
        except asyncio.TimeoutError:
            return None


async def test_discovery_answers_the_http_port_and_can_be_off():
    server = AlpacaServer([])
    port = await server.start("127.0.0.1", 0, _free_udp_port())
    try:
        answer = await _ask(server.discovery_port, b"alpacadiscovery1")
        assert json.loads(answer) == {"AlpacaPort": port}
        assert await _ask(server.discovery_port, b"something else", timeout=0.3) is None
    finally:
        await server.stop()
    off = AlpacaServer([])
    await off.start("127.0.0.1", 0, -1)
    try:
        assert off.discovery_port == -1 and off._discovery is None
    finally:
        await off.stop()


def _reads(cls, name: str, depth: int = 0) -> set[str]:
    """Parameter names the handler ``name`` of ``cls`` reads (its own ``r.<kind>("Name")`` and
    those of the helpers it hands ``r`` to; a helper's literal name arguments count too)."""
    import inspect
    import re

    source = inspect.getsource(getattr(cls, name))
    names = set(re.findall(r'\br\.(?:float|int|bool|text|raw)\(\s*"(\w+)"', source))
    for helper, args in re.findall(r"self\.(\w+)\(r\b([^)]*)\)", source):
        if depth < 2 and helper != name:
            names |= _reads(cls, helper, depth + 1)
            names |= set(re.findall(r'"(\w+)"', args))
    return names


def test_parameter_tables_match_what_the_handlers_read():
    """Each device's PARAMETERS (checked before the connection, see
    test_alpaca.test_parameters_are_checked_before_the_connection) names exactly the
    parameters its handlers read: the table cannot drift from the code."""
    from tcs.alpaca import equipment, site, telescope
    from tcs.alpaca.device import COMMON_PARAMETERS, Device

    classes = [c for module in (equipment, site, telescope) for c in vars(module).values()
               if isinstance(c, type) and issubclass(c, Device) and c is not Device]
    assert len(classes) >= 8
    for cls in classes:
        for name in dir(cls):
            if not name.startswith(("get_", "put_")) or name == "get_devicestate":
                continue
            table = cls.PARAMETERS.get(name) or COMMON_PARAMETERS.get(name, ())
            assert {n for n, _kind in table} == _reads(cls, name), (cls.__name__, name)


async def test_state_reads_answer_at_once_and_a_waiting_call_still_times_out():
    """A state read is answered without a task (issue 27: its cost); a member that waits is
    still bounded by ``request_timeout``, and a TcsError of either kind becomes its ASCOM
    error — over real HTTP."""
    import aiohttp

    from tcs.alpaca.device import Device

    class Probe(Device):
        TYPE, NAME, MEMBERS = "focuser", "Focuser", ("position", "temperature", "ismoving")

        def get_position(self, r):
            return 1234

        def get_temperature(self, r):
            raise RangeRefused("no sensor")

        async def get_ismoving(self, r):
            await asyncio.sleep(30)
            return False

    device = Probe(0, "probe", "a probe", None)
    device.connected = True
    server = AlpacaServer([device], request_timeout=0.3)
    port = await server.start("127.0.0.1", 0, -1)
    try:
        async with aiohttp.ClientSession() as http:
            async def get(member: str) -> dict:
                async with http.get(f"http://127.0.0.1:{port}/api/v1/focuser/0/{member}",
                                    params={"ClientTransactionID": "3"}) as resp:
                    assert resp.status == 200
                    return await resp.json()

            assert (await get("position"))["Value"] == 1234
            failed = await get("temperature")
            assert failed["ErrorNumber"] == from_tcs_error(RangeRefused("no sensor")).code
            slow = await get("ismoving")
            assert slow["ErrorNumber"] != 0 and "did not finish within 0.3 s" in slow["ErrorMessage"]
            assert (await get("position"))["ClientTransactionID"] == 3
            async with http.get(f"http://127.0.0.1:{port}/api/v1/focuser/9/position") as resp:
                assert resp.status == 400  # no such device
            assert server.connections >= 1  # (this session's keep-alive connection)
        # what /metrics shows of this front end: requests by method and result, and their times
        figures = server.command_stats.figures()
        assert sorted(figures["counts"]) == [["GET", "bad_request", 1], ["GET", "error", 2], ["GET", "ok", 2]]
        counts, total = figures["latency"]["GET"]
        assert sum(counts) == 5 and total >= 0.3  # (the one that timed out took 0.3 s)
    finally:
        await server.stop()


def test_a_state_read_is_reused_only_while_nothing_changed():
    """``[server] reuse_reply`` for Alpaca: a GET of a member without parameters answers with
    the value just read — not after anything changed (``tcs.state_epoch``), never a member that
    takes parameters, never past its age, and not at all with 0. The reply text is the one
    ``json.dumps`` gives."""
    from tcs import state_epoch
    from tcs.alpaca.device import Device
    from tcs.alpaca.server import encode_reply

    class Counting(Device):
        TYPE, NAME, MEMBERS, ALWAYS = "counting", "Counting", ("count", "twice"), frozenset({"count", "twice"})
        PARAMETERS = {"get_twice": (("Value", "float"),)}
        reads = 0

        def get_count(self, r):
            self.reads += 1
            return float(self.reads)

        def get_twice(self, r):
            self.reads += 1
            return 2 * r.float("Value")

    d = Counting(0, "c", "counting", telescope=None)
    get = AlpacaRequest("GET", {"ClientTransactionID": "1"})
    assert d.begin("GET", "count", get) == (True, 1.0) and d.begin("GET", "count", get) == (True, 2.0)
    d.reuse_value = 3600.0  # (only the rules decide here, never the clock)
    first = d.begin("GET", "count", get)
    assert d.begin("GET", "count", get) == first and d.reads == 3
    state_epoch.bump()  # a readback, a PLC poll, a PUT
    assert d.begin("GET", "count", get) == (True, 4.0)
    twice = AlpacaRequest("GET", {"Value": "2"})
    d.begin("GET", "twice", twice), d.begin("GET", "twice", twice)
    assert d.reads == 6  # a member with parameters is read each time
    d.reuse_value = 1e-9
    before = d.reads
    d.begin("GET", "count", get)
    import time
    time.sleep(0.001)
    d.begin("GET", "count", get)
    assert d.reads == before + 2  # past its age
    for body in ({"Value": 1.5, "ClientTransactionID": 3, "ServerTransactionID": 4, "ErrorNumber": 0,
                  "ErrorMessage": ""}, {"Value": float("nan"), "ClientTransactionID": 3, "ServerTransactionID": 4,
                                        "ErrorNumber": 0, "ErrorMessage": ""},
                 {"ClientTransactionID": 3, "ServerTransactionID": 4, "ErrorNumber": 1025, "ErrorMessage": "é\""},
                 {"Value": [1, {"a": "x\"y"}], "ClientTransactionID": 0, "ServerTransactionID": 1,
                  "ErrorNumber": 0, "ErrorMessage": ""}, {"Value": True, "ClientTransactionID": 0,
                                                          "ServerTransactionID": 1, "ErrorNumber": 0, "ErrorMessage": ""}):
        assert encode_reply(body) == json.dumps(body)
