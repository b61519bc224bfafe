"""Property-based fuzzing of a live server: any byte sequence from a logged-in client gets
well-formed 7-bit replies, the server keeps serving, other connections are undisturbed, and no
session or task is left behind."""

from __future__ import annotations

import asyncio
import socket
import threading

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from support.service import start_service

FRAGMENTS = [b"GET ", b"SET ", b"ABORT ", b"AUTH PLAIN ", b"ENC TLS", b"1 ", b"0 ", b"4294967296 ",
             b"LOCAL.HEIGHT", b"LOCAL.UT1-UTC", b"SERVER.CONNECTION.EVENTMASK", b"CONFIG.MOUNT",
             b"!TYPE", b"!MEMBERS", b"[0-3]", b"[1,2]", b"<1>.<2>", b"=", b";", b",", b'"', b"\\",
             b'"x\\n"', b"1.5", b"-7", b"NULL", b"\n", b"\r\n", b"\x00", b"\xff", b" ", b"."]

chunks = st.lists(st.one_of(st.sampled_from(FRAGMENTS), st.binary(max_size=12)), max_size=40)


@pytest.fixture(scope="module")
def live_server(tmp_path_factory):
    """A service on its own event-loop thread for the whole module (hypothesis runs many
    examples; starting a service per example would be slow)."""
    loop = asyncio.new_event_loop()
    ready = threading.Event()
    box = {}

    def run():
        asyncio.set_event_loop(loop)

        async def main():
            svc, port = await start_service(tmp_path_factory.mktemp("fuzz"), auth_fail_delay=0.0,
                                            auth_max_failures=1000)
            box["svc"], box["port"] = svc, port
            box["stop"] = asyncio.Event()
            ready.set()
            await box["stop"].wait()
            await svc.stop()

        loop.run_until_complete(main())
        loop.close()

    thread = threading.Thread(target=run, name="fuzz-server")
    thread.start()
    assert ready.wait(30)
    yield box
    loop.call_soon_threadsafe(box["stop"].set)
    thread.join(30)


@pytest.fixture(autouse=True)
def _no_leaked_threads():  # the module-scoped server thread is expected here
    yield


class Client:
    """A blocking TPL2 connection, logged in as admin."""

    def __init__(self, port: int):
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=10)
        self.file = self.sock.makefile("rb")
        try:
            assert self.file.readline().startswith(b"TPL2 ")
            self.sock.sendall(b'AUTH PLAIN "admin" "admin"\n')
            assert self.file.readline() == b"AUTH OK 0 0\n"
        except BaseException:
            self.close()
            raise

    def read_until(self, final: bytes) -> list[bytes]:
        lines = []
        while True:
            line = self.file.readline()
            if not line:
                return lines
            lines.append(line)
            if line.startswith(final):
                return lines

    def close(self) -> None:
        self.file.close()
        self.sock.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(chunks)
def test_any_bytes_get_clean_replies(live_server, parts):
    port = live_server["port"]
    with Client(port) as c:
        c.sock.sendall(b"".join(parts) + b"\n4000000000 GET LOCAL.HEIGHT\n")
        lines = c.read_until(b"4000000000 COMMAND COMPLETE")
    for line in lines:
        assert line.endswith(b"\n")
        text = line.decode("ascii")  # 7-bit ASCII only
        first = text.split(" ", 1)[0]
        assert first.isdigit() or first in ("AUTH", "DISCONNECT", "ENC"), text
    closed = not lines or not lines[-1].startswith(b"4000000000 COMMAND COMPLETE")
    if closed:  # only a DISCONNECT may end the connection
        assert b"DISCONNECT OK\n" in lines, lines
    with Client(port) as other:  # another connection is served as usual
        other.sock.sendall(b"1 GET LOCAL.LATITUDE\n")
        # (events of the service, "0 EVENT ...", may come in between at any time)
        replies = [x for x in other.read_until(b"1 COMMAND COMPLETE") if x.startswith(b"1 ")]
        assert replies == [b"1 COMMAND OK\n", b"1 DATA INLINE LOCAL.LATITUDE=28.7606\n", b"1 COMMAND COMPLETE\n"]


def test_nothing_left_behind(live_server):
    svc = live_server["svc"]
    with Client(live_server["port"]) as c:
        c.sock.sendall(b"1 GET LOCAL.HEIGHT\n")
        c.read_until(b"1 COMMAND COMPLETE")
    loop_sessions = lambda: len(svc.server.sessions)  # noqa: E731
    for _ in range(200):
        if loop_sessions() == 0 and not svc.server._tasks:
            break
        threading.Event().wait(0.01)
    assert loop_sessions() == 0
    assert not svc.server._tasks
