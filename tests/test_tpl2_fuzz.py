"""Property tests for the pure TPL2 core: arbitrary input never raises and never depends on
chunking; formatting then parsing gives back what was formatted; every line is 7-bit ASCII."""

from __future__ import annotations

import math
import string

from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from tcs.opentci_server.messages import (
    CommandAbortedBy,
    CommandComplete,
    CommandError,
    CommandOk,
    DataError,
    DataInline,
    DataOk,
    Disconnect,
    Event,
    Greeting,
    Set,
)
from tcs.opentci_server.paths import parse_object
from tcs.opentci_server.protocol import (
    Tpl2ClientConnection,
    Tpl2Connection,
    format_message,
    parse_line,
    parse_reply,
)
from tcs.opentci_server.values import (
    ErrorValue,
    Value,
    ValueType,
    format_float,
    format_value,
    quote_string,
    unescape,
)

FUZZ = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])

# Fragments that steer random bytes into the interesting corners of the grammar.
FRAGMENTS = [
    b"\n", b"\r\n", b"\r", b" ", b"\t", b"1 ", b"007 ", b"0 ", b"4294967296 ", b"GET ", b"set ",
    b"ABORT ", b"AUTH PLAIN ", b"DISCONNECT", b"disconnect", b"ENC ", b"X", b"A.B", b"!TYPE",
    b"[0-3]", b"[1,2-4]", b"<5>", b";", b",", b"=", b'"', b"\\", b"\\x", b"\\377", b"NULL",
    b"1.5", b"-2", b"1e9", b"\xff", b"\xc3\xa9", b"\xe2\x82", b"\x00", b"0",
]  # fmt: skip

wire_bytes = st.one_of(
    st.binary(max_size=400),
    st.lists(st.sampled_from(FRAGMENTS) | st.binary(max_size=4), max_size=80).map(b"".join),
)


def chunked(data: bytes, cuts: list[int]) -> list[bytes]:
    points = sorted({c % (len(data) + 1) for c in cuts})
    pieces, last = [], 0
    for p in points:
        pieces.append(data[last:p])
        last = p
    pieces.append(data[last:])
    return pieces


def run(chunks: list[bytes], max_line_length: int) -> list:
    conn = Tpl2Connection(max_line_length=max_line_length)
    out = []
    for c in chunks:
        out += conn.receive(c)
        assert conn.buffered <= max_line_length
    return out + conn.eof()


@FUZZ
@given(data=wire_bytes, cuts=st.lists(st.integers(min_value=0), max_size=30), limit=st.sampled_from([8, 40, 65536]))
def test_any_bytes_any_chunking_same_messages(data, cuts, limit):
    whole = run([data], limit)
    assert run(chunked(data, cuts), limit) == whole
    assert run([data[i : i + 1] for i in range(len(data))], limit) == whole
    assert whole and type(whole[-1]) is Disconnect


@FUZZ
@given(st.text(max_size=200) | st.lists(st.sampled_from([f.decode("latin-1") for f in FRAGMENTS])).map("".join))
def test_parse_line_never_raises(line):
    parse_line(line)


@FUZZ
@given(st.text())
def test_strings_round_trip(s):
    wire = quote_string(s)
    assert wire.isascii() and wire.isprintable()
    assert wire[0] == wire[-1] == '"'
    assert unescape(wire[1:-1]) == s
    # through a whole SET line and the framing, as a client would send it
    (msg,) = Tpl2Connection().receive(f"1 SET X={wire};Y={wire}\r\n".encode("ascii"))
    assert type(msg) is Set
    assert [a.values for a in msg.assignments] == [(Value(ValueType.STRING, s, True),)] * 2
    # back through a DATA INLINE line to a client
    line = format_message(DataInline(1, "X", (wire, wire)))
    assert parse_reply(line).values == (wire, wire)


@FUZZ
@given(st.floats(allow_nan=False, allow_infinity=False))
def test_floats_round_trip_exactly_without_exponent(x):
    text = format_float(x)
    assert "e" not in text and "E" not in text and "." in text
    assert text.isascii()
    assert float(text) == x
    (a,) = parse_line(f"1 SET X={text}").assignments
    assert a.values[0].kind is ValueType.FLOAT and a.values[0].value == x


@FUZZ
@given(st.floats(allow_nan=True, allow_infinity=True) | st.integers() | st.booleans() | st.none() | st.text())
def test_format_value_always_ascii(v):
    text = format_value(v)
    assert text.isascii() and text.isprintable()
    if isinstance(v, float) and not math.isfinite(v):
        assert text == "NULL"


name = st.text(string.ascii_letters + string.digits + "_-", min_size=1, max_size=12)
index = st.lists(st.integers(0, 999), min_size=1, max_size=3).map(lambda xs: "[" + ",".join(map(str, xs)) + "]")
part = st.tuples(name | st.integers(0, 99).map(lambda n: f"<{n}>"), st.none() | index).map(
    lambda t: t[0] + (t[1] or "")
)
obj_text = st.tuples(st.lists(part, min_size=1, max_size=4), st.none() | name).map(
    lambda t: ".".join(t[0]) + (f"!{t[1]}" if t[1] else "")
)
cmd_id = st.integers(0, 2**64 - 1)
free_text = st.text(max_size=40)
wire_value = (
    st.floats() | st.integers() | st.text(max_size=20) | st.none() | st.sampled_from([ErrorValue("UNKNOWN"), ErrorValue.failed(15)])
).map(format_value)

server_messages = st.one_of(
    st.builds(Greeting, st.just("2.1"), st.integers(0, 2**31), st.lists(name, max_size=3).map(tuple),
              st.lists(name, max_size=2).map(tuple), free_text),
    st.builds(CommandOk, cmd_id),
    st.builds(CommandComplete, cmd_id),
    st.builds(CommandAbortedBy, cmd_id, cmd_id),
    st.builds(CommandError, cmd_id, st.sampled_from(["SYNTAX", "UNKNOWN", "DENIED", "TOOMANY"]), st.none() | free_text),
    st.builds(DataInline, cmd_id, obj_text, st.lists(wire_value, max_size=5).map(tuple)),
    st.builds(DataOk, cmd_id, obj_text),
    st.builds(DataError, cmd_id, obj_text,
              st.lists(st.sampled_from(["RANGE", "TYPE", "FAILED 8", "DENIED"]), min_size=1, max_size=4).map(tuple)),
    st.builds(Event, cmd_id, st.sampled_from(["ERROR", "WARN", "INFO", "DEBUG"]), obj_text, st.integers(0, 10**6), free_text),
)  # fmt: skip


@FUZZ
@given(server_messages, st.sampled_from([b"\n", b"\r\n"]))
def test_server_lines_are_ascii_one_line_and_round_trip(msg, ending):
    line = format_message(msg)
    assert line.isascii() and line.isprintable()
    assert parse_reply(line) == msg
    data = Tpl2Connection(line_ending=ending).send(msg)
    assert data.count(b"\n") == 1 and data.endswith(ending)
    assert Tpl2ClientConnection().receive(data) == [msg]


@FUZZ
@given(obj_text)
def test_generated_objects_parse_and_echo(text):
    ref = parse_object(text)
    assert ref.text == text
    assert all(p.name is None or p.name == p.name.upper() for p in ref.parts)


@FUZZ
@given(st.lists(st.tuples(obj_text, st.lists(wire_value.filter(lambda v: not v.startswith("FAILED")), min_size=1, max_size=3)),
                min_size=1, max_size=4), st.integers(1, 2**32 - 1))  # fmt: skip
def test_set_lines_parse_back_to_what_was_sent(assignments, cid):
    line = f"{cid} SET " + ";".join(o + "=" + ",".join(vs) for o, vs in assignments)
    msg = parse_line(line)
    assume(type(msg) is Set)  # an UNKNOWN bare word is fine, but the line must parse
    assert format_message(msg) == line
