"""Wire tables for the pure TPL2 core (tcs.opentci_server.protocol, messages, values, paths).

Every row is (message, exact line), checked both ways: parsing the line gives the message and
formatting the message gives the line. Client rows are also fed to a Tpl2Connection whole,
byte by byte, with CRLF, and with the next line's first bytes in the same chunk; server rows
go through Tpl2Connection.send and back through Tpl2ClientConnection. Then the real lines of
the protocol doc's §9 exchange and of the clients in the field.
"""

from __future__ import annotations

import math
import re

import pytest

from tcs.errors import TypeRefused
from tcs.opentci_server.messages import (
    Abort,
    Assignment,
    Auth,
    AuthDisabled,
    AuthError,
    AuthFailed,
    AuthOk,
    AuthSyntaxError,
    AuthUnsupported,
    BadId,
    BadSyntax,
    CommandAbortedBy,
    CommandComplete,
    CommandError,
    CommandFailed,
    CommandOk,
    CommandTimeout,
    DataError,
    DataInline,
    DataOk,
    Disconnect,
    DisconnectOk,
    Enc,
    EncUnsupported,
    Event,
    Get,
    Greeting,
    LineTooLong,
    Set,
    UnknownCommand,
)
from tcs.opentci_server.paths import ObjectRef, PathPart, PathSyntaxError, parse_object
from tcs.opentci_server.protocol import (
    ReplySyntaxError,
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
    ValueTypeError,
    convert,
    format_float,
    format_value,
    quote_string,
    unescape,
)

# ------------------------------------------------------------------ building blocks


def P(name: str, index=None) -> PathPart:
    return PathPart(name, None, index)


def N(number: int, index=None) -> PathPart:
    return PathPart(None, number, index)


def ref(text: str, *parts: PathPart, prop: str | None = None) -> ObjectRef:
    return ObjectRef(text, tuple(parts), prop)


def dotted(text: str) -> ObjectRef:
    """An ObjectRef for a plain dotted name, built without the parser."""
    path, _, prop = text.partition("!")
    parts = tuple(P(n.upper()) for n in path.split(".")) if path else ()
    return ObjectRef(text, parts, prop.upper() or None)


def INT(v: int) -> Value:
    return Value(ValueType.INT, v, False)


def FLT(v: float) -> Value:
    return Value(ValueType.FLOAT, v, False)


def STR(v: str) -> Value:
    return Value(ValueType.STRING, v, True)


NULL = Value(ValueType.NULL, None, False)


def assign(obj: str | ObjectRef, *values: Value) -> Assignment:
    return Assignment(dotted(obj) if isinstance(obj, str) else obj, values)


# ------------------------------------------------------------------ client table

CLIENT_ROWS = [
    # connection set-up (§2)
    (Auth("PLAIN", "admin", "secret"), 'AUTH PLAIN "admin" "secret"'),
    (Auth("PLAIN", "obs", "pw", 1, 2), 'AUTH PLAIN "obs" "pw" 1 2'),
    (Auth("PLAIN", 'a"b', "c\\d"), r'AUTH PLAIN "a\"b" "c\\d"'),
    (Auth("PLAIN", "", ""), 'AUTH PLAIN "" ""'),
    (Auth("CRAM-MD5"), "AUTH CRAM-MD5"),
    (Enc("TLS"), "ENC TLS"),
    (Disconnect(), "DISCONNECT"),
    # GET (§3): plain, several, properties, root property, numeric access, indices
    (Get(1, (dotted("AZ.REALPOS"),)), "1 GET AZ.REALPOS"),
    (Get(2, (dotted("AZ.REALPOS!MIN"), dotted("AZ.REALPOS"))), "2 GET AZ.REALPOS!MIN;AZ.REALPOS"),
    (Get(3, (ref("!MEMBERS", prop="MEMBERS"),)), "3 GET !MEMBERS"),
    (Get(4, (ref("<5>.<3>!NAME", N(5), N(3), prop="NAME"),)), "4 GET <5>.<3>!NAME"),
    (Get(5, (ref("DOME[1].TARGETPOS", P("DOME", ((1, 1),)), P("TARGETPOS")),)), "5 GET DOME[1].TARGETPOS"),
    (
        Get(6, (ref("AZ.TRAJECTORY.BUFFER[0-59].TIME", P("AZ"), P("TRAJECTORY"), P("BUFFER", ((0, 59),)), P("TIME")),)),
        "6 GET AZ.TRAJECTORY.BUFFER[0-59].TIME",
    ),
    (Get(7, (ref("X[0,2-4,7]", P("X", ((0, 0), (2, 4), (7, 7)))),)), "7 GET X[0,2-4,7]"),
    (Get(8, (ref("local.tai-utc", P("LOCAL"), P("TAI-UTC")),)), "8 GET local.tai-utc"),
    (Get(9, (ref("<2>[3]!TYPE", N(2, ((3, 3),)), prop="TYPE"),)), "9 GET <2>[3]!TYPE"),
    (Get(4294967295, (dotted("SERVER.UPTIME"),)), "4294967295 GET SERVER.UPTIME"),
    # SET (§3, §6): numbers, quoted numbers, NULL, strings with every escape, lists
    (Set(10, (assign("CABINET.POWER", STR("1")),)), '10 SET CABINET.POWER="1"'),
    (Set(11, (assign("AZ.TARGETPOS", INT(400)),)), "11 SET AZ.TARGETPOS=400"),
    (Set(12, (assign("AZ.OFFSET", FLT(-2.5)),)), "12 SET AZ.OFFSET=-2.5"),
    (Set(13, (assign("X", NULL),)), "13 SET X=NULL"),
    (Set(14, (assign("X", STR("")),)), '14 SET X=""'),
    (Set(15, (assign("X", STR("a,b;c=d \"e\"")),)), r'15 SET X="a,b;c=d \"e\""'),
    (Set(16, (assign("X", STR("\a\b\f\n\r\t\v\\\"")),)), r'16 SET X="\a\b\f\n\r\t\v\\\""'),
    (Set(17, (assign("X", STR("\x00\x01\x7f")),)), r'17 SET X="\000\001\177"'),
    (Set(18, (assign("X", STR("é€")),)), r'18 SET X="\303\251\342\202\254"'),
    (
        Set(19, (assign(ref("X[0,2-3]", P("X", ((0, 0), (2, 3)))), INT(1), FLT(2.0), STR("3")),)),
        '19 SET X[0,2-3]=1,2.0,"3"',
    ),
    (
        Set(20, (assign("A.B", INT(1)), assign("C!D", STR("x")), assign("E", NULL))),
        '20 SET A.B=1;C!D="x";E=NULL',
    ),
    (Set(21, (assign("X", FLT(0.0000001)),)), "21 SET X=0.0000001"),
    (Set(22, (assign("X", INT(-7)),)), "22 SET X=-7"),
    # ABORT (§3)
    (Abort(23, 5), "23 ABORT 5"),
    (Abort(24, 0), "24 ABORT 0"),
]

# Lines that parse into a message but are not its canonical wire form (or have none).
PARSE_ONLY_ROWS = [
    # leading zeros, case, spacing, lenient tokens
    ("007 GET X", Get(7, (dotted("X"),))),
    ("01 get a.b", Get(1, (ref("a.b", P("A"), P("B")),))),
    ("1 Get X;", Get(1, (dotted("X"),))),
    ("1   GET   X ; Y  ", Get(1, (dotted("X"), dotted("Y")))),
    ("  2 set X = 1 , 2 ; Y = \"a b\"  ", Set(2, (assign("X", INT(1), INT(2)), assign("Y", STR("a b"))))),
    ("3 SET X=1;", Set(3, (assign("X", INT(1)),))),
    ("4 SET X=null", Set(4, (assign("X", NULL),))),
    ("5 SET X=abc", Set(5, (assign("X", Value(ValueType.STRING, "abc", False)),))),
    ("6 SET X=1e-05,+3,.5,7.", Set(6, (assign("X", FLT(1e-05), INT(3), FLT(0.5), FLT(7.0)),))),
    ("6 SET X=12.500000", Set(6, (assign("X", FLT(12.5)),))),
    ("7 abort 0005", Abort(7, 5)),
    ("8 ABORT 000", Abort(8, 0)),
    ("8 ABORT 30064771077", Abort(8, (7 << 32) | 5)),  # another connection's extended id
    ("auth plain admin secret", Auth("PLAIN", "admin", "secret")),
    ('AUTH PLAIN "admin" "admin" ', Auth("PLAIN", "admin", "admin")),
    ('Auth Plain "u" p 0 9', Auth("PLAIN", "u", "p", 0, 9)),
    ("AUTH foo a b", Auth("FOO", "a", "b")),
    ("disconnect", Disconnect()),
    ("Disconnect now", Disconnect()),
    ("enc tls", Enc("TLS")),
    ("ENC", Enc("")),
    # other escapes the parser understands: \0, short octal, hex, \', unknown \q
    (r'9 SET X="\0\7\12\x41\x4a\xA\'\q\?"', Set(9, (assign("X", STR("\x00\x07\nAJ\n'q?")),))),
    (r'9 SET X="\xc3\xa9"', Set(9, (assign("X", STR("é")),))),
    (r'9 SET X="\351t\351"', Set(9, (assign("X", STR("été")),))),  # Latin-1 bytes
    ('9 SET X="é"', Set(9, (assign("X", STR("é")),))),
    # parse failures
    ("0 GET X", BadId("0")),
    ("4294967296 GET X", BadId("4294967296")),
    ("99999999999999999999999 GET X", BadId("99999999999999999999999")),
    ("-1 GET X", BadId("-1")),
    ("7 FROB X", UnknownCommand(7, "FROB")),
    ("7 subscribe X", UnknownCommand(7, "subscribe")),
    ("AUTH", AuthSyntaxError()),
    ("AUTH PLAIN", AuthSyntaxError()),
    ('AUTH PLAIN "admin"', AuthSyntaxError()),
    ('AUTH PLAIN "a" "b" 1', AuthSyntaxError()),
    ('AUTH PLAIN "a" "b" x y', AuthSyntaxError()),
    ('AUTH PLAIN "a" "b" 1 2 3', AuthSyntaxError()),
    ('AUTH PLAIN "a "b"', AuthSyntaxError()),
]

BAD_SYNTAX_LINES = [
    ("GET X", 0),
    ("hello world", 0),
    ("12abc GET X", 0),
    ("5", 5),
    ("5 GET", 5),
    ("5 GET ;", 5),
    ("5 GET X;;Y", 5),
    ("5 GET X Y", 5),
    ("5 GET X.", 5),
    ("5 GET X[5-2]", 5),
    ("5 GET X[]", 5),
    ("5 GET X[a]", 5),
    ("5 GET X!", 5),
    ("5 GET X!A!B", 5),
    ("5 GET A..B", 5),
    ("5 GET <x>", 5),
    ("5 GET X[1", 5),
    ("5 SET", 5),
    ("5 SET X", 5),
    ("5 SET X=", 5),
    ("5 SET =1", 5),
    ("5 SET X=1,", 5),
    ("5 SET X=1 2", 5),
    ('5 SET X="abc', 5),
    ('5 SET X="a"b', 5),
    ('5 SET X="a\\"', 5),
    ("5 SET X=1;;Y=2", 5),
    ("5 SET X[2-1]=1", 5),
    ("5 ABORT", 5),
    ("5 ABORT x", 5),
    ("5 ABORT 1 2", 5),
    ("5 ABORT 99999999999999999999", 5),  # beyond an extended id (64 bits)
    ("5 ABORT 21474836480", 5),  # extended id of connection 5 with command id 0
]

# ------------------------------------------------------------------ server table

SERVER_ROWS = [
    (Greeting("2.1", 7, ("PLAIN",), (), "Welcome"), "TPL2 2.1 CONN 7 AUTH PLAIN ENC MESSAGE Welcome"),
    (Greeting("2.1", 1, (), (), "OpenTCI telescope"), "TPL2 2.1 CONN 1 AUTH ENC MESSAGE OpenTCI telescope"),
    (Greeting("2.1", 2, ("PLAIN", "NONE"), ("TLS",), ""), "TPL2 2.1 CONN 2 AUTH PLAIN,NONE ENC TLS MESSAGE "),
    (Greeting("2.1", 3, ("PLAIN",), (), "tab\there é"), r"TPL2 2.1 CONN 3 AUTH PLAIN ENC MESSAGE tab\there \303\251"),
    (AuthOk(0, 0), "AUTH OK 0 0"),
    (AuthOk(1, 2), "AUTH OK 1 2"),
    (AuthFailed(), "AUTH FAILED"),
    (AuthError(), "AUTH ERROR"),
    (AuthUnsupported(), "AUTH UNSUPPORTED"),
    (AuthDisabled(), "AUTH DISABLED"),
    (DisconnectOk(), "DISCONNECT OK"),
    (EncUnsupported(), "ENC UNSUPPORTED"),
    (CommandOk(1), "1 COMMAND OK"),
    (CommandError(3, "UNAUTHENTICATED"), "3 COMMAND ERROR UNAUTHENTICATED"),
    (CommandError(0, "SYNTAX"), "0 COMMAND ERROR SYNTAX"),
    (CommandError(7, "SYNTAX", "bad index [x] in X[x]"), "7 COMMAND ERROR SYNTAX [bad index [x] in X[x]]"),
    (CommandError(7, "UNKNOWN", "unknown command FROB"), "7 COMMAND ERROR UNKNOWN [unknown command FROB]"),
    (CommandError.idbusy(5), "0 COMMAND ERROR IDBUSY 5"),
    (CommandError(0, "IDBUSY", arg="5"), "0 COMMAND ERROR IDBUSY 5"),
    (CommandError.idrange("0000"), "0 COMMAND ERROR IDRANGE 0000"),
    (CommandError(9, "TOOMANY"), "9 COMMAND ERROR TOOMANY"),
    (CommandError(9, "NOTRUNNING"), "9 COMMAND ERROR NOTRUNNING"),
    (CommandError(9, "DENIED", "no\nline\tbreaks"), r"9 COMMAND ERROR DENIED [no\nline\tbreaks]"),
    (CommandComplete(1), "1 COMMAND COMPLETE"),
    (CommandFailed(7), "7 COMMAND FAILED"),
    (CommandAbortedBy(5, 6), "5 COMMAND ABORTEDBY 6"),
    (CommandTimeout(6), "6 COMMAND TIMEOUT"),
    (DataInline(1, "CABINET.POWER_STATE", ("0.0",)), "1 DATA INLINE CABINET.POWER_STATE=0.0"),
    (DataInline(1, "AZ.REALPOS!MIN", ("-270.0",)), "1 DATA INLINE AZ.REALPOS!MIN=-270.0"),
    (DataInline(1, "X!TYPE", ("2",)), "1 DATA INLINE X!TYPE=2"),
    (DataInline(1, "CABINET.STATUS.LIST", ('""',)), '1 DATA INLINE CABINET.STATUS.LIST=""'),
    (DataInline(1, "S", ('"a,b\\"c\\\\"',)), r'1 DATA INLINE S="a,b\"c\\"'),
    (DataInline(2, "X[0,2-4]", ("1", "NULL", "3", "UNKNOWN")), "2 DATA INLINE X[0,2-4]=1,NULL,3,UNKNOWN"),
    (DataInline(7, "NO.SUCH", ("UNKNOWN",)), "7 DATA INLINE NO.SUCH=UNKNOWN"),
    (DataInline(5, "SENSOR[3].VALUE", ("FAILED 15",)), "5 DATA INLINE SENSOR[3].VALUE=FAILED 15"),
    (DataInline(5, "x", ()), "5 DATA INLINE x="),
    (DataOk(2, "CABINET.POWER"), "2 DATA OK CABINET.POWER"),
    (DataError(4, "AZ.TARGETPOS", ("RANGE",)), "4 DATA ERROR AZ.TARGETPOS RANGE"),
    (DataError(4, "X[0-2]", ("RANGE", "FAILED 8", "TYPE")), "4 DATA ERROR X[0-2] RANGE,FAILED 8,TYPE"),
    (Event(2, "INFO", "CABINET", 21, "power on"), "2 EVENT INFO CABINET:21 power on"),
    (Event(0, "ERROR", "AZ", 8), "0 EVENT ERROR AZ:8"),
    (Event((7 << 32) | 3, "WARN", "DOME[1]", 1000, "x"), f"{(7 << 32) | 3} EVENT WARN DOME[1]:1000 x"),
    (Event(0, "DEBUG", "AZ", 23, 'moved "far"\r\nnow'), r'0 EVENT DEBUG AZ:23 moved "far"\r\nnow'),
    (Event(0, "INFO", "AZ", 23, "Grad °"), r"0 EVENT INFO AZ:23 Grad \302\260"),
]


# ================================================================== client rows


@pytest.mark.parametrize(("msg", "line"), CLIENT_ROWS, ids=[r[1] for r in CLIENT_ROWS])
def test_client_row_both_ways(msg, line):
    assert parse_line(line) == msg
    assert format_message(msg) == line


def _feed(chunks: list[bytes], **kw) -> list:
    conn = Tpl2Connection(**kw)
    out = []
    for c in chunks:
        out += conn.receive(c)
    return out


@pytest.mark.parametrize(("msg", "line"), CLIENT_ROWS, ids=[r[1] for r in CLIENT_ROWS])
@pytest.mark.parametrize("ending", [b"\n", b"\r\n"], ids=["LF", "CRLF"])
def test_client_row_framing(msg, line, ending):
    data = line.encode("utf-8") + ending
    assert _feed([data]) == [msg]
    assert _feed([data[i : i + 1] for i in range(len(data))]) == [msg]
    # trailing data: the next line's first bytes arrive in the same chunk
    conn = Tpl2Connection()
    assert conn.receive(data + b"99 GE") == [msg]
    assert conn.receive(b"T X" + ending) == [Get(99, (dotted("X"),))]
    # two lines in one chunk, and the unterminated last line at EOF
    conn = Tpl2Connection()
    assert conn.receive(data + data) == [msg, msg]
    assert conn.receive(data[:-len(ending)]) == []
    tail = conn.eof()
    assert tail[0] == msg
    assert tail[1:] == ([] if msg == Disconnect() else [Disconnect()])


@pytest.mark.parametrize(("line", "msg"), PARSE_ONLY_ROWS, ids=[r[0] for r in PARSE_ONLY_ROWS])
def test_parse_only_rows(line, msg):
    assert parse_line(line) == msg
    assert _feed([line.encode("utf-8") + b"\r\n"]) == [msg]


@pytest.mark.parametrize(("line", "cmd_id"), BAD_SYNTAX_LINES, ids=[r[0] for r in BAD_SYNTAX_LINES])
def test_bad_syntax(line, cmd_id):
    msg = parse_line(line)
    assert type(msg) is BadSyntax, msg
    assert msg.cmd_id == cmd_id
    assert msg.detail


@pytest.mark.parametrize(
    "msg", [BadSyntax(0, "x"), BadId("0"), UnknownCommand(1, "X"), AuthSyntaxError(), LineTooLong(0), object()]
)
def test_parse_failures_have_no_wire_form(msg):
    with pytest.raises(TypeError):
        format_message(msg)


# ================================================================== server rows


@pytest.mark.parametrize(("msg", "line"), SERVER_ROWS, ids=[r[1] for r in SERVER_ROWS])
def test_server_row_both_ways(msg, line):
    assert format_message(msg) == line
    assert parse_reply(line) == msg
    assert line.isascii() and line.isprintable()


@pytest.mark.parametrize(("msg", "line"), SERVER_ROWS, ids=[r[1] for r in SERVER_ROWS])
@pytest.mark.parametrize("ending", [b"\n", b"\r\n"], ids=["LF", "CRLF"])
def test_server_row_framing(msg, line, ending):
    data = Tpl2Connection(line_ending=ending).send(msg)
    assert data == line.encode("ascii") + ending
    client = Tpl2ClientConnection()
    assert [m for i in range(len(data)) for m in client.receive(data[i : i + 1])] == [msg]
    assert Tpl2ClientConnection().receive(data + data + b"1 COMM") == [msg, msg]


def test_send_all_is_the_lines_joined():
    conn = Tpl2Connection(line_ending=b"\r\n")
    msgs = [CommandOk(1), DataInline(1, "X", ("1.0",)), CommandComplete(1)]
    assert conn.send_all(msgs) == b"1 COMMAND OK\r\n1 DATA INLINE X=1.0\r\n1 COMMAND COMPLETE\r\n"
    assert conn.send_all(msgs) == b"".join(conn.send(m) for m in msgs)


def test_line_ending_option_is_checked():
    with pytest.raises(ValueError):
        Tpl2Connection(line_ending=b"\r")


@pytest.mark.parametrize(
    "line",
    ["", "hello", "1 COMMAND", "1 COMMAND WHAT", "x COMMAND OK", "1 DATA INLINE X", "1 DATA OK", "1 DATA OK a b",
     "1 DATA ERROR X", "1 EVENT INFO X", "1 EVENT INFO X:y", "AUTH OK 1", 'TPL2 2.1 CONN x AUTH ENC MESSAGE',
     '1 DATA INLINE X="a"b'],
)  # fmt: skip
def test_bad_replies_raise(line):
    with pytest.raises(ReplySyntaxError):
        parse_reply(line)


def test_echoed_object_and_words_are_made_ascii():
    line = format_message(DataInline(1, "ä\n", ("1",)))
    assert line.isascii() and line.isprintable()
    assert line == r"1 DATA INLINE \303\244\n=1"
    line = format_message(CommandError(1, "UNKNOWN", "unknown command ÄÖ\x00"))
    assert line == r"1 COMMAND ERROR UNKNOWN [unknown command \303\204\303\226\000]"
    assert parse_reply(line).detail == "unknown command ÄÖ\x00"


# ================================================================== framing


def test_blank_lines_are_ignored():
    assert _feed([b"\n\r\n   \n\t\r\n1 GET X\n\n"]) == [Get(1, (dotted("X"),))]


def test_eof_without_input_is_a_disconnect():
    conn = Tpl2Connection()
    assert conn.eof() == [Disconnect()]
    assert conn.eof() == []
    with pytest.raises(RuntimeError):
        conn.receive(b"1 GET X\n")


def test_eof_after_a_complete_disconnect_adds_nothing():
    conn = Tpl2Connection()
    assert conn.receive(b"DISCONNECT\n") == [Disconnect()]
    assert conn.eof() == []


def test_eof_parses_the_unterminated_line_first():
    conn = Tpl2Connection()
    assert conn.receive(b"1 GET X\n2 GET Y") == [Get(1, (dotted("X"),))]
    assert conn.eof() == [Get(2, (dotted("Y"),)), Disconnect()]


def test_invalid_utf8_never_raises_and_reads_as_latin1():
    out = _feed([b'1 SET X="\xe9t\xe9"\n', b"\xff\xfe\n", b"2 GET \xc3\n"])
    assert out[0] == Set(1, (assign("X", STR("été")),))
    assert type(out[1]) is BadSyntax and out[1].cmd_id == 0
    assert type(out[2]) is BadSyntax and out[2].cmd_id == 2


def test_unicode_digits_and_spaces_are_not_ascii_ones():
    assert type(parse_line("١ GET X")) is BadSyntax  # Arabic-Indic digit one
    assert parse_line("1 GET X[١]").cmd_id == 1 and type(parse_line("1 GET X[١]")) is BadSyntax
    assert type(parse_line("1\u00a0GET X")) is BadSyntax  # no-break space is no separator


@pytest.mark.parametrize("chunk", [1, 7, 4096, 1 << 20])
def test_overlong_line_gives_one_message_and_bounded_memory(chunk):
    limit = 64
    long_line = b"42 GET " + b"A" * 100_000 + b"\n"
    data = long_line + b"43 GET X\n" + b"B" * 1000 + b"\n" + b"44 GET Y\n"
    conn = Tpl2Connection(max_line_length=limit)
    out = []
    for i in range(0, len(data), chunk):
        out += conn.receive(data[i : i + chunk])
        assert conn.buffered <= limit
    assert out == [LineTooLong(42), Get(43, (dotted("X"),)), LineTooLong(0), Get(44, (dotted("Y"),))]
    assert conn.eof() == [Disconnect()]


def test_line_length_limit_is_exact():
    conn = Tpl2Connection(max_line_length=9)
    assert conn.receive(b"1 GET XYZ\n") == [Get(1, (dotted("XYZ"),))]  # 9 bytes: accepted
    assert conn.receive(b"1 GET XYZW\n") == [LineTooLong(1)]  # 10 bytes
    assert conn.receive(b"1 GET XYZW") == [LineTooLong(1)]  # detected before the line end
    assert conn.receive(b"Q;R;S\n2 GET A\n") == [Get(2, (dotted("A"),))]  # rest dropped
    assert conn.receive(b"99999999999") == [LineTooLong(0)]  # no complete id in the window
    assert conn.eof() == [Disconnect()]


# ================================================================== paths


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("AZ", ref("AZ", P("AZ"))),
        ("pointing.track", ref("pointing.track", P("POINTING"), P("TRACK"))),
        ("LOCAL.UT1-UTC", ref("LOCAL.UT1-UTC", P("LOCAL"), P("UT1-UTC"))),
        ("X!type", ref("X!type", P("X"), prop="TYPE")),
        ("!MEMBERS", ref("!MEMBERS", prop="MEMBERS")),
        ("<0>", ref("<0>", N(0))),
        ("<5>.<3>!NAME", ref("<5>.<3>!NAME", N(5), N(3), prop="NAME")),
        ("ZD[0].REALPOS", ref("ZD[0].REALPOS", P("ZD", ((0, 0),)), P("REALPOS"))),
        ("B[007-010]", ref("B[007-010]", P("B", ((7, 10),)))),
        ("X[ 0 , 2 - 4 ]", ref("X[ 0 , 2 - 4 ]", P("X", ((0, 0), (2, 4))))),
        ("X[7,1]", ref("X[7,1]", P("X", ((7, 7), (1, 1))))),
        ("A[0-1].B[2,3].C", ref("A[0-1].B[2,3].C", P("A", ((0, 1),)), P("B", ((2, 2), (3, 3))), P("C"))),
        ("A[3-3]!COUNT", ref("A[3-3]!COUNT", P("A", ((3, 3),)), prop="COUNT")),
    ],
)
def test_parse_object(text, expected):
    assert parse_object(text) == expected


@pytest.mark.parametrize(
    "text",
    ["", "!", ".", "A.", ".A", "A..B", "A!", "A!B!C", "A!B.C", "A B", "A[", "A[]", "A[1,]", "A[-1]", "A[5-2]",
     "A[1]x", "<>", "<a>", "<1", "A.<1>x", "A[1][2]", "Ä", "A;B", "A=B", "A[1234567890]", "<1234567890>",
     "A!Ä", "A[١]"],
)  # fmt: skip
def test_parse_object_rejects(text):
    with pytest.raises(PathSyntaxError):
        parse_object(text)


def test_path_helpers():
    r = parse_object("A[0-1].B[2,4-5].C[3]")
    assert [p.count for p in r.parts] == [2, 3, 1]
    assert [p.multi for p in r.parts] == [True, True, False]
    assert r.multi_count == 2
    assert list(r.parts[1].elements()) == [2, 4, 5]
    assert str(r) == "A[0-1].B[2,4-5].C[3]"
    assert parse_object("X").parts[0].count == 1 and not parse_object("X").parts[0].multi


# ================================================================== values


@pytest.mark.parametrize(
    ("value", "vtype", "text"),
    [
        (None, None, "NULL"),
        (None, ValueType.FLOAT, "NULL"),
        (0, None, "0"),
        (-42, ValueType.INT, "-42"),
        (True, None, "1"),
        (False, ValueType.INT, "0"),
        (2.6, ValueType.INT, "3"),
        (1.0, None, "1.0"),
        (0.0, None, "0.0"),
        (-0.0, None, "0.0"),
        (-3.0, None, "-3.0"),
        (123192.751, None, "123192.751"),
        (1e-7, None, "0.0000001"),
        (1e20, None, "100000000000000000000.0"),
        (-1.5e-10, None, "-0.00000000015"),
        (float("nan"), None, "NULL"),
        (float("inf"), ValueType.FLOAT, "NULL"),
        (float("-inf"), None, "NULL"),
        (1, ValueType.FLOAT, "1.0"),
        (2**60 + 1, ValueType.FLOAT, "1152921504606846977.0"),
        ("", None, '""'),
        ("plain text", None, '"plain text"'),
        ('"\\', ValueType.STRING, r'"\"\\"'),
        ("\a\b\f\n\r\t\v\x00\x1b\x7f", None, r'"\a\b\f\n\r\t\v\000\033\177"'),
        ("é", None, r'"\303\251"'),
        ("\U0001f52d", None, r'"\360\237\224\255"'),
        (5, ValueType.STRING, '"5"'),
        (ErrorValue("UNKNOWN"), None, "UNKNOWN"),
        (ErrorValue.failed(15), ValueType.FLOAT, "FAILED 15"),
        ("x", ValueType.NULL, "NULL"),
    ],
)
def test_format_value(value, vtype, text):
    assert format_value(value, vtype) == text


def test_format_value_numpy_scalars():
    np = pytest.importorskip("numpy")
    assert format_value(np.int64(5)) == "5"
    assert format_value(np.float64(2.0)) == "2.0"
    assert format_value(np.float32(0.5)) == "0.5"
    assert format_value(np.int16(3), ValueType.FLOAT) == "3.0"


def test_format_value_refuses_unknown_types():
    with pytest.raises(TypeError):
        format_value(object())


@pytest.mark.parametrize(
    ("value", "target", "result"),
    [
        (INT(1), ValueType.INT, 1),
        (FLT(1.0), ValueType.INT, 1),
        (FLT(-4.0), ValueType.INT, -4),
        (STR("1"), ValueType.INT, 1),
        (STR(" 007 "), ValueType.INT, 7),
        (STR("-3"), ValueType.INT, -3),
        (STR("2.0"), ValueType.INT, 2),
        (STR("1e3"), ValueType.INT, 1000),
        (INT(2), ValueType.FLOAT, 2.0),
        (FLT(2.5), ValueType.FLOAT, 2.5),
        (STR("2.5"), ValueType.FLOAT, 2.5),
        (STR(" -1e-5 "), ValueType.FLOAT, -1e-5),
        (STR("12"), ValueType.FLOAT, 12.0),
        (STR("abc"), ValueType.STRING, "abc"),
        (STR("1"), ValueType.STRING, "1"),
        (Value(ValueType.STRING, "abc", False), ValueType.STRING, "abc"),
        (INT(5), ValueType.STRING, "5"),
        (FLT(1.0), ValueType.STRING, "1.0"),
        (NULL, ValueType.INT, None),
        (NULL, ValueType.STRING, None),
        (NULL, ValueType.NULL, None),
    ],
)
def test_convert(value, target, result):
    got = convert(value, target)
    assert got == result and type(got) is type(result)


@pytest.mark.parametrize(
    ("value", "target"),
    [
        (FLT(1.5), ValueType.INT),
        (STR("1.5"), ValueType.INT),
        (STR("abc"), ValueType.INT),
        (STR(""), ValueType.INT),
        (STR("nan"), ValueType.FLOAT),
        (STR("inf"), ValueType.FLOAT),
        (STR("1_000"), ValueType.INT),
        (STR("0x10"), ValueType.INT),
        (STR("1e999"), ValueType.FLOAT),
        (STR("1e999"), ValueType.INT),
        (STR("9" * 5000), ValueType.INT),
        (FLT(math.inf), ValueType.FLOAT),
        (INT(10**400), ValueType.FLOAT),
        (Value(ValueType.STRING, "abc", False), ValueType.FLOAT),
        (INT(1), ValueType.NULL),
    ],
)
def test_convert_refuses_with_type(value, target):
    with pytest.raises(ValueTypeError) as info:
        convert(value, target)
    assert isinstance(info.value, TypeRefused)
    assert info.value.reply == "TYPE"


def test_unescape_oddities_never_raise():
    assert unescape("a\\") == "a\\"  # lone trailing backslash stands for itself
    assert unescape(r"\400") == " 0"  # \40 then '0'
    assert unescape(r"\xZ") == "xZ"
    assert unescape(r"\e") == "\x1b"


def test_huge_integer_literal_is_kept_as_text():
    msg = parse_line("1 SET X=" + "9" * 5000)
    (v,) = msg.assignments[0].values
    assert v == Value(ValueType.STRING, "9" * 5000, False)


# ================================================================== real exchanges


def test_section_9_exchange():
    """The complete exchange of the protocol doc §9, both directions."""
    server = Tpl2Connection()
    wire = server.send(Greeting("2.1", 7, ("PLAIN",), (), "OpenTCI telescope"))
    assert wire == b"TPL2 2.1 CONN 7 AUTH PLAIN ENC MESSAGE OpenTCI telescope\n"

    client_lines = (
        b'AUTH PLAIN "admin" "secret"\n'
        b"1 GET CABINET.POWER_STATE;AZ.REALPOS;AZ.REALPOS!MIN;CABINET.STATUS.LIST\n"
        b'2 SET CABINET.POWER="1"\n'
        b"3 GET CABINET.POWER_STATE\n"
        b"4 SET AZ.TARGETPOS=400\n"
        b"5 SET AZ.TARGETPOS=90\n"
        b"6 ABORT 5\n"
        b"7 FROB X\n"
        b"DISCONNECT\n"
    )
    assert server.receive(client_lines) == [
        Auth("PLAIN", "admin", "secret"),
        Get(1, tuple(map(dotted, ["CABINET.POWER_STATE", "AZ.REALPOS", "AZ.REALPOS!MIN", "CABINET.STATUS.LIST"]))),
        Set(2, (assign("CABINET.POWER", STR("1")),)),
        Get(3, (dotted("CABINET.POWER_STATE"),)),
        Set(4, (assign("AZ.TARGETPOS", INT(400)),)),
        Set(5, (assign("AZ.TARGETPOS", INT(90)),)),
        Abort(6, 5),
        UnknownCommand(7, "FROB"),
        Disconnect(),
    ]
    replies = [
        AuthOk(0, 0),
        CommandOk(1),
        DataInline(1, "CABINET.POWER_STATE", (format_value(0.0),)),
        DataInline(1, "AZ.REALPOS", (format_value(180.0),)),
        DataInline(1, "AZ.REALPOS!MIN", (format_value(-270.0),)),
        DataInline(1, "CABINET.STATUS.LIST", (format_value(""),)),
        CommandComplete(1),
        CommandOk(2),
        CommandOk(3),
        DataInline(3, "CABINET.POWER_STATE", (format_value(0, ValueType.FLOAT),)),
        CommandComplete(3),
        Event(2, "INFO", "CABINET", 21, "power on"),
        DataOk(2, "CABINET.POWER"),
        CommandComplete(2),
        CommandOk(4),
        DataError(4, "AZ.TARGETPOS", ("RANGE",)),
        CommandComplete(4),
        CommandOk(5),
        CommandOk(6),
        CommandAbortedBy(5, 6),
        CommandComplete(6),
        CommandError(7, "UNKNOWN", "unknown command FROB"),
        CommandFailed(7),
        DisconnectOk(),
    ]
    assert server.send_all(replies).decode("ascii").splitlines() == [
        "AUTH OK 0 0",
        "1 COMMAND OK",
        "1 DATA INLINE CABINET.POWER_STATE=0.0",
        "1 DATA INLINE AZ.REALPOS=180.0",
        "1 DATA INLINE AZ.REALPOS!MIN=-270.0",
        '1 DATA INLINE CABINET.STATUS.LIST=""',
        "1 COMMAND COMPLETE",
        "2 COMMAND OK",
        "3 COMMAND OK",
        "3 DATA INLINE CABINET.POWER_STATE=0.0",
        "3 COMMAND COMPLETE",
        "2 EVENT INFO CABINET:21 power on",
        "2 DATA OK CABINET.POWER",
        "2 COMMAND COMPLETE",
        "4 COMMAND OK",
        "4 DATA ERROR AZ.TARGETPOS RANGE",
        "4 COMMAND COMPLETE",
        "5 COMMAND OK",
        "6 COMMAND OK",
        "5 COMMAND ABORTEDBY 6",
        "6 COMMAND COMPLETE",
        "7 COMMAND ERROR UNKNOWN [unknown command FROB]",
        "7 COMMAND FAILED",
        "DISCONNECT OK",
    ]
    assert server.eof() == []


def test_pyobs_lines():
    """pyobs-pilar: quotes every SET value (str(value)), joins GETs with ';', bare
    lowercase 'disconnect' without a line end, then closes."""
    conn = Tpl2Connection()
    assert conn.receive(b'AUTH PLAIN "admin" "admin"\n') == [Auth("PLAIN", "admin", "admin")]
    variables = [
        "POSITION.HORIZONTAL.ALT", "POSITION.HORIZONTAL.AZ", "POSITION.INSTRUMENTAL.FOCUS.REALPOS",
        "POSITION.INSTRUMENTAL.DEROTATOR[2].REALPOS", "POINTING.SETUP.DEROTATOR.OFFSET",
        "TELESCOPE.READY_STATE", "TELESCOPE.MOTION_STATE", "AUXILIARY.SENSOR[1].VALUE",
    ]  # fmt: skip
    (get,) = conn.receive(("1 GET " + ";".join(variables) + "\n").encode())
    assert [o.text for o in get.objects] == variables
    assert get.objects[3].parts[2] == P("DEROTATOR", ((2, 2),))
    out = conn.receive(
        b'2 SET TELESCOPE.READY="1"\n3 SET POINTING.TRACK="0"\n'
        b'4 SET OBJECT.EQUATORIAL.RA="12.5"\n5 SET POSITION.INSTRUMENTAL.FOCUS.OFFSET="1e-05"\n'
        b'6 SET TELESCOPE.STATUS.CLEAR="3"\n'
    )
    values = [m.assignments[0].values[0] for m in out]
    assert values == [STR("1"), STR("0"), STR("12.5"), STR("1e-05"), STR("3")]
    assert convert(values[0], ValueType.INT) == 1
    assert convert(values[2], ValueType.FLOAT) == 12.5
    assert convert(values[3], ValueType.FLOAT) == 1e-05
    assert conn.receive(b"disconnect") == []
    assert conn.eof() == [Disconnect()]
    # what pyobs does with our lines: int(line.split()[0]) of every line after login, and
    # value[0] == '"' on the text after '='
    for msg in (CommandOk(2), DataInline(1, "X", ('""',)), Event(0, "INFO", "AZ", 23, "x")):
        line = format_message(msg)
        int(line.split()[0])
    line = format_message(DataInline(1, "TELESCOPE.STATUS.LIST", ('""',)))
    assert line[line.find("=") + 1 :][0] == '"'


def test_chimera_lines():
    """chimera-astelco: CRLF lines, 'GET X!TYPE;X' for every read, unquoted SET values,
    and regexes on the greeting, AUTH OK and DATA lines."""
    conn = Tpl2Connection()
    out = conn.receive(
        b'AUTH PLAIN "admin" "admin"\r\n'
        b"1 GET POSITION.HORIZONTAL.ALT!TYPE;POSITION.HORIZONTAL.ALT\r\n"
        b"2 SET POINTING.TRACK=1\r\n"
        b"3 SET OBJECT.EQUATORIAL.RA=12.3456\r\n"
    )
    assert out == [
        Auth("PLAIN", "admin", "admin"),
        Get(1, (dotted("POSITION.HORIZONTAL.ALT!TYPE"), dotted("POSITION.HORIZONTAL.ALT"))),
        Set(2, (assign("POINTING.TRACK", INT(1)),)),
        Set(3, (assign("OBJECT.EQUATORIAL.RA", FLT(12.3456)),)),
    ]
    # chimera's expectations, restated as regexes: one-digit levels, empty ENC list and a
    # space after MESSAGE, 'DATA INLINE obj=value' with no space in a number.
    greeting = Tpl2Connection().send(Greeting("2.1", 7, ("PLAIN",), (), "")).decode()
    assert re.match(r"TPL2\s+\S+\s+CONN\s+\d+\s+AUTH\s+\S+(,\S+)*\s+ENC MESSAGE (.*?)\s*\n", greeting)
    assert re.match(r"AUTH\s+(\S+)\s+(\d)\s+(\d)\n", conn.send(AuthOk(1, 2)).decode())
    data = conn.send(DataInline(1, "POSITION.HORIZONTAL.ALT!TYPE", (format_value(2),))).decode()
    m = re.match(r"(\d+) DATA INLINE (\S+)=(\S+)\n", data)
    assert m and m.group(3) == "2"
    data = conn.send(DataInline(1, "POSITION.HORIZONTAL.ALT", (format_value(45.0),))).decode()
    assert float(re.match(r"(\d+) DATA INLINE (\S+)=(\S+)\n", data).group(3)) == 45.0


def test_unam_auth_and_get_in_one_chunk():
    """UNAM's Tcl client sends AUTH and its status GET without waiting for AUTH OK."""
    chunk = (
        b'AUTH PLAIN "admin" "admin"\n'
        b"1 GET TELESCOPE.READY_STATE;POSITION.INSTRUMENTAL.FOCUS.LIMIT_STATE;"
        b"POSITION.INSTRUMENTAL.FOCUS.OFFSET;TELESCOPE.READY_STATE\n"
    )
    out = Tpl2Connection().receive(chunk)
    assert out[0] == Auth("PLAIN", "admin", "admin")
    assert [o.text for o in out[1].objects] == [
        "TELESCOPE.READY_STATE",
        "POSITION.INSTRUMENTAL.FOCUS.LIMIT_STATE",
        "POSITION.INSTRUMENTAL.FOCUS.OFFSET",
        "TELESCOPE.READY_STATE",
    ]
    # UNAM scans '%*d DATA INLINE TELESCOPE.READY_STATE=%f' and matches '^[0-9]+ EVENT INFO '
    line = format_message(DataInline(1, "TELESCOPE.READY_STATE", (format_value(1.0),)))
    assert re.fullmatch(r"[0-9]+ DATA INLINE TELESCOPE\.READY_STATE=(-?[0-9.]+)", line)
    assert re.match(r"^[0-9]+ EVENT INFO ", format_message(Event(0, "INFO", "AZ", 23)))


def test_indi_blank_line_first_and_printf_floats():
    """The INDI Astelco driver: a blank line first, AUTH with a trailing space, and SETs
    written with printf's %f."""
    out = _feed([b"\n", b'AUTH PLAIN "admin" "admin" \n', b"5 SET POSITION.INSTRUMENTAL.FOCUS.TARGETPOS=12.500000\n"])
    assert out == [
        Auth("PLAIN", "admin", "admin"),
        Set(5, (assign("POSITION.INSTRUMENTAL.FOCUS.TARGETPOS", FLT(12.5)),)),
    ]
    # INDI and SONG compare the text of a FLOAT: "1.0"
    assert format_value(1.0) == "1.0" and format_value(1, ValueType.FLOAT) == "1.0"


def test_song_style_fixed_ids_and_connection_number():
    """SONG's node reads the connection number as the 4th word of the greeting and reuses a
    fixed id per function (a representative exchange in its style)."""
    greeting = format_message(Greeting("2.1", 42, ("PLAIN",), (), "Welcome"))
    assert greeting.split(" ")[3] == "42"
    conn = Tpl2Connection()
    line = b"11 GET POSITION.EQUATORIAL.RA_J2000;POSITION.EQUATORIAL.DEC_J2000\n"
    assert conn.receive(line + line) == [conn.receive(line)[0]] * 2 == [
        Get(11, (dotted("POSITION.EQUATORIAL.RA_J2000"), dotted("POSITION.EQUATORIAL.DEC_J2000")))
    ] * 2


def test_rts2_crlf_replies_end_in_complete_cr():
    """RTS2 compares line tails with 'COMPLETE\\r' and 'OK\\r'."""
    conn = Tpl2Connection(line_ending=b"\r\n")
    assert conn.send(CommandComplete(3)).endswith(b"COMPLETE\r\n")
    assert conn.send(CommandOk(3)) == b"3 COMMAND OK\r\n"


def test_float_wire_text_never_has_an_exponent():
    for x in (1e-300, 1e300, 5e-324, 1.7976931348623157e308, 1e16, 1e15, 1e-4, 1e-5, 0.1):
        text = format_float(x)
        assert "e" not in text.lower() and "." in text
        assert float(text) == x


def test_quote_string_round_trip_simple():
    for s in ["", "a", 'x"y', "\\", "tab\t", "ünïcödé", "\x00\x01", "\ud800"]:
        assert unescape(quote_string(s)[1:-1]) == s


def test_get_reply_is_the_same_bytes_as_its_messages():
    from tcs.opentci_server.messages import CommandComplete, CommandOk, DataInline
    from tcs.opentci_server.protocol import Tpl2Connection, wire_object

    for le in (b"\n", b"\r\n"):
        conn = Tpl2Connection(line_ending=le)
        items = [("AZ.REALPOS", "1.0"), ("x\u00e9y!TYPE", "2"), ("NO.SUCH", "UNKNOWN")]
        expected = conn.send_all([CommandOk(7)] + [DataInline(7, o, (v,)) for o, v in items]
                                 + [CommandComplete(7)])
        assert conn.get_reply(7, [(wire_object(o), v) for o, v in items]) == expected
