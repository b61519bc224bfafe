"""Exposure limits of the TPL2 server over real sockets: login and idle time-outs, per-address
limits, the level-0 reserve, the login lock-out, name-blind failed logins, TLS, and the start-up
warnings about exposure.

The tree is the real SERVER module over a real :class:`Tpl2Server`; only the settings differ
per test (short time-outs so the tests stay fast).
"""

from __future__ import annotations

import asyncio
import dataclasses
import datetime
import logging
import ssl
import time

import pytest

from support.tpl2 import RawClient
from tcs.config.passwords import hash_password
from tcs.config.sections import ServerSection, UserSection
from tcs.model.events import EventHub
from tcs.opentci_server.opentci import SERVER
from tcs.opentci_server.server import Tpl2Server, exposure_problems, weak_users
from tcs.opentci_server.tree import Tree

USERS = (UserSection("admin", hash_password("admin-pw", iterations=1000), 0, 0),
         UserSection("observer", hash_password("obs-pw", iterations=1000), 2, 2))


class _Root:
    def __init__(self, server):
        self.server = server


async def start(users=USERS, **settings) -> Tpl2Server:
    hub = EventHub()
    hub.bind_loop()
    base = dict(port=0, auth_fail_delay=0.01, max_pending_per_address=1000)
    base.update(settings)
    server = Tpl2Server(ServerSection(**base), users, hub)
    server.tree = Tree.build((SERVER,), _Root(server))
    await server.start("127.0.0.1", 0)
    return server


@pytest.fixture
async def make_server():
    servers = []

    async def make(**kw):
        servers.append(await start(**kw))
        return servers[-1]

    yield make
    for s in servers:
        await s.stop()


async def closed_by_server(c: RawClient, timeout: float = 10.0) -> bool:
    """True when the server closes the connection (EOF or reset) within ``timeout``."""
    try:
        while await asyncio.wait_for(c.reader.read(65536), timeout):
            pass
    except asyncio.TimeoutError:
        return False
    except (ConnectionError, OSError):
        pass
    return True


async def login(port: int, user: str, password: str, **kw) -> tuple[RawClient, str]:
    c = await RawClient.connect(port, login=None, **kw)
    await c.send(f'AUTH PLAIN "{user}" "{password}"')
    return c, await c.readline()


# ------------------------------------------------------------------------------ item 4
async def test_silent_sockets_are_closed_and_an_operator_gets_in_again(make_server):
    server = await make_server(max_connections=6, admin_reserve=0, login_timeout=0.5)
    silent = [await RawClient.connect(server.port, login=None) for _ in range(6)]
    full = await RawClient.connect(server.port, login=None)
    assert "too many connections" in full.greeting
    assert await closed_by_server(full)
    for s in silent:  # none of them logged in: each is closed after the login time-out
        assert await closed_by_server(s)
    c, reply = await login(server.port, "observer", "obs-pw")
    assert reply == "AUTH OK 2 2"
    assert await c.get("SERVER.CONNECTION.USERNAME") == '"observer"'
    await asyncio.sleep(0.8)  # a logged-in connection is not subject to the login time-out
    assert await c.get("SERVER.CONNECTION.USERNAME") == '"observer"'
    for x in (*silent, full, c):
        await x.close()


async def test_pending_connections_per_address_are_limited(make_server):
    server = await make_server(max_pending_per_address=3, max_per_address=4)
    pending = [await RawClient.connect(server.port, login=None) for _ in range(3)]
    refused = await RawClient.connect(server.port, login=None)
    assert "waiting to log in" in refused.greeting
    assert await closed_by_server(refused)
    await pending[0].send('AUTH PLAIN "observer" "obs-pw"')  # a login frees a pending slot
    assert await pending[0].readline() == "AUTH OK 2 2"
    c, reply = await login(server.port, "observer", "obs-pw")
    assert reply == "AUTH OK 2 2"
    # four from this address now: the next is refused even though it would log in
    sixth = await RawClient.connect(server.port, login=None)
    assert "too many connections from this address" in sixth.greeting
    # another loopback address is not affected
    other = await open_from("127.0.0.2", server.port)
    assert "AUTH PLAIN" in other.greeting
    for x in (*pending, refused, c, sixth, other):
        await x.close()


async def open_from(local_host: str, port: int) -> RawClient:
    reader, writer = await asyncio.open_connection("127.0.0.1", port, local_addr=(local_host, 0))
    c = RawClient(reader, writer)
    c.greeting = await c.readline()
    return c


async def test_the_reserve_admits_only_a_level_0_user(make_server):
    server = await make_server(max_connections=2, admin_reserve=1)
    a, _ = await login(server.port, "observer", "obs-pw")
    b, _ = await login(server.port, "observer", "obs-pw")
    intruder, reply = await login(server.port, "observer", "obs-pw")  # lands in the reserve
    assert reply == "AUTH FAILED"
    assert await closed_by_server(intruder)
    admin, reply = await login(server.port, "admin", "admin-pw")
    assert reply == "AUTH OK 0 0"
    beyond = await RawClient.connect(server.port, login=None)  # reserve used up
    assert "too many connections" in beyond.greeting
    assert await admin.get("SERVER.CONNECTION.USERNAME") == '"admin"'
    assert await a.get("SERVER.CONNECTION.USERNAME") == '"observer"'
    for x in (a, b, intruder, admin, beyond):
        await x.close()


async def test_idle_connections_are_closed_when_asked(make_server):
    server = await make_server(idle_timeout=0.6)
    idle, _ = await login(server.port, "observer", "obs-pw")
    busy, _ = await login(server.port, "observer", "obs-pw")
    t0 = time.monotonic()
    while time.monotonic() - t0 < 1.5:  # the busy one keeps talking
        assert await busy.get("SERVER.CONNECTION.USERNAME") == '"observer"'
        await asyncio.sleep(0.15)
    assert await closed_by_server(idle, timeout=0.1)
    assert await busy.get("SERVER.CONNECTION.USERNAME") == '"observer"'
    for x in (idle, busy):
        await x.close()


def test_default_limits_serve_256_pollers():
    cfg = ServerSection()
    assert cfg.max_connections >= 256 and cfg.max_per_address >= 256
    assert 0 < cfg.login_timeout <= 30 and cfg.admin_reserve >= 1


# ------------------------------------------------------------------------------ item 7, issue 22.9
async def _hammer(port: int, user: str, stop: asyncio.Event, answered: list) -> None:
    """An attacker: connection after connection, wrong passwords for ``user`` until ``stop``."""
    i = 0
    while not stop.is_set():
        try:
            c = await RawClient.connect(port, login=None)
        except (ConnectionError, OSError):
            await asyncio.sleep(0.01)
            continue
        try:
            while not stop.is_set():
                i += 1
                await c.send(f'AUTH PLAIN "{user}" "guess{i}"')
                answered.append(await c.readline(timeout=WAIT_S))
        except (ConnectionError, OSError, asyncio.TimeoutError):
            pass  # dropped after auth_max_failures: the next connection
        finally:
            await c.close()


async def test_an_attacker_guessing_slows_himself_not_the_operator(make_server):
    """Issue 22.9: wrong passwords hammered from 127.0.0.1 (where every operator behind an SSH
    tunnel comes from) must not keep out the operator with the password: his login gets
    ``AUTH OK`` while the attack goes on (old code: the address was locked out after 10
    failures, every login from it refused unchecked for 300 s). The attacker is slowed: the
    name he guesses is under back-off (checked only after it, right or wrong password), his
    connections are dropped after ``auth_max_failures``, each failure of a connection waits
    twice as long as the one before; another name is not slowed."""
    server = await make_server(auth_fail_delay=0.02, auth_max_failures=3, auth_backoff_failures=4,
                               auth_backoff_max=0.3)
    stop, answered = asyncio.Event(), []
    attackers = [asyncio.create_task(_hammer(server.port, "admin", stop, answered)) for _ in range(3)]
    try:
        for _ in range(int(WAIT_S / 0.02)):
            if len(answered) >= 15:
                break
            await asyncio.sleep(0.02)
        assert len(answered) >= 15 and set(answered) == {"AUTH FAILED"}, answered
        logins = server.guard.logins
        assert logins.failures("admin") >= 15
        assert logins.backoff("admin") == pytest.approx(0.3)  # the attacker's name: full back-off
        for _ in range(3):  # the operator, while the attack goes on
            c, reply = await login(server.port, "admin", "admin-pw")
            assert reply == "AUTH OK 0 0"
            assert await c.get("SERVER.CONNECTION.USERNAME") == '"admin"'
            await c.close()
        assert not stop.is_set() and all(not t.done() for t in attackers)  # still attacking
        assert logins.backoff("observer") == 0.0  # another name is not slowed
        c, reply = await login(server.port, "observer", "obs-pw")
        assert reply == "AUTH OK 2 2"
        await c.close()
        # a connection's failures cost more each time, and it is dropped after the third
        assert [logins.fail_delay(n) for n in (1, 2, 3)] == pytest.approx([0.02, 0.04, 0.08])
        one = await RawClient.connect(server.port, login=None)
        for i in range(3):
            await one.send(f'AUTH PLAIN "observer" "nope{i}"')
            assert await one.readline(timeout=WAIT_S) == "AUTH FAILED"
        assert await closed_by_server(one)
        await one.close()
    finally:
        stop.set()
        await asyncio.wait(attackers, timeout=WAIT_S)


async def test_a_login_under_back_off_outlives_the_login_timeout(make_server):
    """The back-off is the server's own wait: a right password checked after it gets in even
    when that takes longer than ``login_timeout`` (which is for clients that say nothing)."""
    server = await make_server(login_timeout=0.5, auth_fail_delay=0.01, auth_backoff_failures=1,
                               auth_backoff_max=1.0, auth_max_failures=100)
    c = await RawClient.connect(server.port, login=None)
    for i in range(8):
        await c.send(f'AUTH PLAIN "admin" "guess{i}"')
        assert await c.readline(timeout=WAIT_S) == "AUTH FAILED"
    assert server.guard.logins.backoff("admin") == pytest.approx(1.0)
    operator, reply = await login(server.port, "admin", "admin-pw")
    assert reply == "AUTH OK 0 0"
    assert await operator.get("SERVER.CONNECTION.USERNAME") == '"admin"'
    for x in (c, operator):
        await x.close()


async def test_two_hundred_logins_at_once_from_one_address(make_server):
    """Issue 22.9: 200 clients logging in at once through one address (pollers behind one SSH
    tunnel after a restart) all get in with the default limits (old code: 136 refused by a
    per-address cap of 64 connections waiting to log in)."""
    default = ServerSection()
    server = await make_server(max_pending_per_address=default.max_pending_per_address)
    clients = await asyncio.gather(*(RawClient.connect(server.port, login=None) for _ in range(200)))
    refused = [c.greeting for c in clients if "AUTH PLAIN" not in c.greeting]
    assert not refused, refused[:3]
    for c in clients:
        await c.send('AUTH PLAIN "observer" "obs-pw"')
    replies = [await c.readline(timeout=WAIT_S) for c in clients]
    assert replies == ["AUTH OK 2 2"] * 200
    for c in clients:
        await c.close()


async def test_the_pending_refusal_names_the_limit(make_server):
    server = await make_server(max_pending_per_address=2)
    pending = [await RawClient.connect(server.port, login=None) for _ in range(2)]
    refused = await RawClient.connect(server.port, login=None)
    assert "max_pending_per_address 2" in refused.greeting and "retry" in refused.greeting
    for x in (*pending, refused):
        await x.close()


async def test_the_back_off_is_shared_by_the_opentci_and_opentsi_ports():
    """The ports of one telescope share one account table, so guesses on one port put the name
    under back-off on the other too (an attacker cannot double his rate with a second port);
    the right password still logs in on both."""
    import types

    telescope = types.SimpleNamespace(state_dir=None)
    servers = []
    for _ in range(2):
        hub = EventHub()
        hub.bind_loop()
        server = Tpl2Server(ServerSection(port=0, auth_fail_delay=0.01, auth_backoff_failures=2,
                                          auth_backoff_max=0.2, auth_max_failures=100), USERS, hub)
        root = _Root(server)
        root.telescope = telescope
        server.tree = Tree.build((SERVER,), root)
        await server.start("127.0.0.1", 0)
        servers.append(server)
    tci, tsi = servers
    try:
        c = await RawClient.connect(tci.port, login=None)
        for i in range(4):
            await c.send(f'AUTH PLAIN "admin" "guess{i}"')
            assert await c.readline(timeout=WAIT_S) == "AUTH FAILED"
        await c.close()
        assert tsi.guard.logins.failures("admin") == 4
        assert tsi.guard.logins.backoff("admin") > 0
        for port in (tsi.port, tci.port):
            c, reply = await login(port, "admin", "admin-pw")
            assert reply == "AUTH OK 0 0"
            await c.close()
    finally:
        for server in servers:
            await server.stop()


async def test_unknown_names_fail_as_slowly_as_wrong_passwords(make_server):
    """An unknown user name is checked against a dummy hash of the users' cost: the failure
    takes the time of a real check (old code answered at once, revealing which names exist)."""
    users = (UserSection("admin", hash_password("admin-pw", iterations=400_000), 0, 0),)
    server = await make_server(users=users, auth_fail_delay=0.0, auth_max_failures=100,
                               auth_lockout_failures=1000)
    c = await RawClient.connect(server.port, login=None)

    async def fastest(user: str) -> float:
        times = []
        for _ in range(3):
            t0 = time.perf_counter()
            await c.send(f'AUTH PLAIN "{user}" "wrong"')
            assert await c.readline() == "AUTH FAILED"
            times.append(time.perf_counter() - t0)
        return min(times)

    known = await fastest("admin")
    unknown = await fastest("nosuchuser")
    assert unknown > 0.5 * known, (unknown, known)
    await c.close()


def make_certificate(tmp_path):
    """A self-signed certificate for 127.0.0.1, made here (``cryptography``: a dependency of
    the test environment, skipped without it)."""
    pytest.importorskip("cryptography")
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID
    import ipaddress

    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "127.0.0.1")])
    now = datetime.datetime.now(datetime.timezone.utc)
    cert = (x509.CertificateBuilder().subject_name(name).issuer_name(name).public_key(key.public_key())
            .serial_number(x509.random_serial_number()).not_valid_before(now - datetime.timedelta(days=1))
            .not_valid_after(now + datetime.timedelta(days=1))
            .add_extension(x509.SubjectAlternativeName([x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]),
                           critical=False)
            .sign(key, hashes.SHA256()))
    cert_path, key_path = tmp_path / "cert.pem", tmp_path / "key.pem"
    cert_path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    key_path.write_bytes(key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                           serialization.NoEncryption()))
    return str(cert_path), str(key_path)


async def test_tls_only_listener(make_server, tmp_path):
    cert, key = make_certificate(tmp_path)
    server = await make_server(tls_cert=cert, tls_key=key, login_timeout=1.0)
    ctx = ssl.create_default_context(cafile=cert)
    reader, writer = await asyncio.open_connection("127.0.0.1", server.port, ssl=ctx)
    c = RawClient(reader, writer)
    c.greeting = await c.readline()
    assert c.greeting.startswith("TPL2 2.1 CONN ")
    await c.send('AUTH PLAIN "admin" "admin-pw"')
    assert await c.readline() == "AUTH OK 0 0"
    assert await c.get("SERVER.CONNECTION.USERNAME") == '"admin"'
    # a plain-text client gets nothing readable: no greeting, no login
    plain = await RawClient.connect(server.port, login=None, greeting=False)
    await plain.send('AUTH PLAIN "admin" "admin-pw"')
    data = b""
    try:
        while chunk := await asyncio.wait_for(plain.reader.read(4096), 5.0):
            data += chunk
    except (ConnectionError, OSError):
        pass
    assert b"TPL2" not in data and b"AUTH OK" not in data
    for x in (c, plain):
        await x.close()


async def test_bad_certificate_is_a_configuration_error(tmp_path):
    from tcs.errors import ConfigError

    (tmp_path / "c.pem").write_text("not a certificate")
    with pytest.raises(ConfigError, match="tls_cert"):
        await start(tls_cert=str(tmp_path / "c.pem"), tls_key=str(tmp_path / "c.pem"))


def test_exposure_warnings():
    shipped = UserSection("admin", hash_password("admin", iterations=1000), 0, 0)
    weak = weak_users((shipped, *USERS))
    assert weak == ["admin"]
    cfg = ServerSection(implicit_auth=True, implicit_user="admin")
    assert exposure_problems(cfg, "127.0.0.1", False, weak) == []
    problems = exposure_problems(cfg, "0.0.0.0", False, weak)
    assert any("well-known password" in p for p in problems)
    assert any("implicit_auth" in p for p in problems)
    assert any("clear text" in p for p in problems)
    assert exposure_problems(ServerSection(), "192.0.2.1", True, []) == []


async def test_start_warns_loudly_beyond_loopback(make_server, caplog):
    """The warning path as the server runs it at start (the bind itself stays on loopback)."""
    shipped = (UserSection("admin", hash_password("admin", iterations=1000), 0, 0),)
    server = await make_server(users=shipped)
    with caplog.at_level(logging.WARNING):
        await server._warn_exposure("0.0.0.0", tls=False)
    assert any("SECURITY" in r.message and "well-known password" in r.message for r in caplog.records)


def test_tls_settings_go_together():
    assert ServerSection(tls_cert="x").check()
    assert not dataclasses.replace(ServerSection(), tls_cert="x", tls_key="y").check()


# ------------------------------------------------------------------------------ item 5
class _Counter:
    """Domain object of a tiny module whose reads record their order."""

    def __init__(self, server):
        self.server = server
        self.order: list[str] = []

    def tick(self, who: str) -> int:
        self.order.append(who)
        return len(self.order)


async def start_counting(**settings) -> tuple[Tpl2Server, _Counter]:
    from tcs.opentci_server.tree import INT, module, var

    hub = EventHub()
    hub.bind_loop()
    base = dict(port=0, auth_fail_delay=0.01, max_pending_per_address=1000)
    base.update(settings)
    server = Tpl2Server(ServerSection(**base), USERS, hub)
    counter = _Counter(server)
    tree = (SERVER, module("COUNT", var("A", INT, get=lambda c: c.tick("A")),
                           var("B", INT, get=lambda c: c.tick("B")),
                           var("BIG", INT, get=lambda c: 10 ** 200 and 7), bind=lambda root: root))
    server.tree = Tree.build(tree, counter)
    await server.start("127.0.0.1", 0)
    return server, counter


async def test_pipelined_commands_of_one_client_take_turns_with_others():
    """6000 GETs pipelined by one client do not run as one burst: a GET another client sends
    meanwhile is handled long before the burst ends (old code: after the whole read chunk)."""
    server, counter = await start_counting()
    try:
        a, _ = await login(server.port, "observer", "obs-pw")
        b, _ = await login(server.port, "observer", "obs-pw")
        n = 6000
        a.writer.write(b"".join(b"%d GET COUNT.A\n" % (i + 1) for i in range(n)))
        await a.writer.drain()
        assert await a.readline() == "1 COMMAND OK"
        assert await b.get("COUNT.B") != ""
        position = counter.order.index("B")
        # B's GET goes out only after A's first reply reached this client (same event loop), a
        # few slices into the burst: 1,511-1,752 commands once the GETs got cheaper; the old
        # fault (a whole 64 KiB read chunk first) is ~3,800 of them
        assert position < n // 2, position
        for _ in range(3 * n - 1):  # every command of A is still answered, in order
            await a.readline()
        assert counter.order.count("A") == n
        for x in (a, b):
            await x.close()
    finally:
        await server.stop()


async def test_a_client_that_does_not_read_is_paused_then_dropped():
    """A client pipelines GETs and never reads: the server stops handling its commands once
    ``max_output`` bytes wait, keeps its unsent output bounded, serves everyone else, and drops
    it after ``output_stall_timeout`` (old code kept it for as long as it liked)."""
    server, counter = await start_counting(max_output=16384, max_output_hard=1 << 20,
                                           output_stall_timeout=1.0)
    try:
        hog, _ = await login(server.port, "observer", "obs-pw")
        other, _ = await login(server.port, "observer", "obs-pw")
        line = b"1 GET " + b";".join([b"COUNT.A"] * 200) + b"\n"   # ~3 kB of reply each
        sent = 0
        try:
            for _ in range(2000):
                hog.writer.write(line.replace(b"1 GET", b"%d GET" % (sent % 60000 + 1)))
                sent += 1
                await asyncio.wait_for(hog.writer.drain(), 0.5)
        except (asyncio.TimeoutError, ConnectionError):
            pass  # the server stopped reading from it: back-pressure reached the client
        hog_session = next(s for s in server.sessions.values() if s.address.endswith(
            str(hog.writer.get_extra_info("sockname")[1])))
        assert hog_session.transport.get_write_buffer_size() <= server.settings.max_output_hard
        handled = counter.order.count("A")
        assert await other.get("COUNT.B") != ""      # others are served meanwhile
        assert handled < sent * 200                  # the hog's backlog was not all processed
        for _ in range(int(10 / 0.02)):              # dropped after the stall time-out, unread
            if hog_session.id not in server.sessions:
                break
            await asyncio.sleep(0.02)
        assert hog_session.id not in server.sessions
        assert await closed_by_server(hog)
        assert await other.get("COUNT.B") != ""
        for x in (hog, other):
            await x.close()
    finally:
        await server.stop()


async def test_a_burst_of_logins_from_one_host_shares_one_password_check(make_server):
    """Pollers reconnecting at once (after a restart) with the same credentials wait for one
    password check together instead of queueing one check each (old code: 40 in a row)."""
    users = (UserSection("poller", hash_password("pw", iterations=1_000_000), 9, 9),)
    server = await make_server(users=users, auth_lockout_failures=1000)
    clients = [await RawClient.connect(server.port, login=None) for _ in range(40)]
    for c in clients:
        await c.send('AUTH PLAIN "poller" "pw"')
    for _ in range(int(WAIT_S / 0.01)):
        waiting = [s for s in server.sessions.values() if s._auth_task is not None]
        if len(waiting) == 40 or any(s.authenticated for s in server.sessions.values()):
            break
        await asyncio.sleep(0.01)
    assert len(server._inflight) == 1
    for c in clients:
        assert await c.readline(timeout=WAIT_S) == "AUTH OK 9 9"
        await c.close()


WAIT_S = 30.0


# ------------------------------------------------------------------------------ issue 27, item 1
async def _flood_rests(**server_kw) -> int:
    """Rests the scheduler took while one client's 3000 pipelined GETs were handled."""
    server, counter = await start_counting(**server_kw)
    try:
        a, _ = await login(server.port, "observer", "obs-pw")
        n = 3000
        a.writer.write(b"".join(b"%d GET COUNT.A\n" % (i + 1) for i in range(n)))
        await a.writer.drain()
        for _ in range(3 * n):  # every command answered
            await a.readline()
        assert counter.order.count("A") == n
        assert server.scheduler.slices > 1  # the work ran in slices, taking turns
        await a.close()
        return server.scheduler.rests
    finally:
        await server.stop()


async def test_the_server_does_not_rest_when_the_loop_has_its_own_process():
    """By default (``work_rest = -1``) a flood is served without rests when the control loop
    runs in its own process (old code rested as long as it worked: half the loop idle while
    clients waited); with the loop in this interpreter it still rests, and an explicit
    ``work_rest`` is kept."""
    from tcs.config import DEFAULT_CONFIG, load_config
    from tcs.opentci_server.server import loop_shares_interpreter

    assert ServerSection().work_rest == -1
    assert not loop_shares_interpreter(load_config(DEFAULT_CONFIG))  # control_process = true
    assert await _flood_rests() == 0
    assert await _flood_rests(work_rest=1.0) > 0


def test_the_rest_protects_a_control_loop_in_the_same_interpreter():
    from tcs.opentci_server.server import work_rest

    assert work_rest(ServerSection(), shares_interpreter=True) == 1.0
    assert work_rest(ServerSection(), shares_interpreter=False) == 0.0
    assert work_rest(ServerSection(work_rest=0.5), shares_interpreter=False) == 0.5


async def test_a_repeated_get_reads_live_values_with_the_levels_and_budget_of_each_connection():
    """The same GET text is parsed and looked up once, then answered from its plan: every
    answer still reads the value now, a connection's read level still denies, and
    ``max_objects`` still cuts the reply (issue 27: the plan caches lookups, never values;
    ``reuse_reply = 0``: no reply is reused either, see the test below)."""
    from tcs.opentci_server.tree import INT, module, var

    hub = EventHub()
    hub.bind_loop()
    server = Tpl2Server(ServerSection(port=0, auth_fail_delay=0.01, max_objects=3, reuse_reply=0.0),
                        USERS, hub)
    counter = _Counter(server)
    server.tree = Tree.build((SERVER, module(
        "COUNT", var("A", INT, get=lambda c: c.tick("A")),
        var("SECRET", INT, get=lambda c: 42, rlevel=1), bind=lambda root: root)), counter)
    await server.start("127.0.0.1", 0)
    try:
        admin, _ = await login(server.port, "admin", "admin-pw")
        observer, _ = await login(server.port, "observer", "obs-pw")
        line = "COUNT.A;COUNT.SECRET"
        first = await admin.command(7, f"GET {line}")
        second = await admin.command(7, f"GET {line}")
        assert first[1] != second[1] and first[1].startswith("7 DATA INLINE COUNT.A=")
        assert first[2] == second[2] == "7 DATA INLINE COUNT.SECRET=42"
        denied = await observer.command(7, f"GET {line}")
        assert denied[2] == "7 DATA INLINE COUNT.SECRET=DENIED"
        over = await admin.command(8, "GET COUNT.A;COUNT.A;COUNT.A;COUNT.A")
        assert [x.rpartition("=")[2] for x in over[1:5]][3] == "DIMENSION", over
        assert over[-1] == "8 COMMAND COMPLETE"
        for x in (admin, observer):
            await x.close()
    finally:
        await server.stop()


async def test_a_get_reply_is_reused_only_while_nothing_changed_and_never_across_connections_state():
    """``[server] reuse_reply``: the same GET line again answers with the kept reply (the
    value is not read again) — but not after anything changed (``tcs.state_epoch``: here a
    bump as readbacks and PLC polls make, and a SET another client sent), not for another read
    level, not for a line pipelined behind another, and never for a per-connection variable.
    (The age limit is set to an hour so that only these rules decide, never the clock.)"""
    from tcs import state_epoch
    from tcs.opentci_server.tree import INT, module, sysvar, var

    hub = EventHub()
    hub.bind_loop()
    server = Tpl2Server(ServerSection(port=0, auth_fail_delay=0.01), USERS, hub)
    server.replies.max_age = 3600.0
    counter = _Counter(server)
    counter.b = 0
    server.tree = Tree.build((SERVER, module(
        "COUNT", var("A", INT, get=lambda c: c.tick("A")),
        var("B", INT, get=lambda c: c.b, set=lambda c, v: setattr(c, "b", int(v))),
        var("SECRET", INT, get=lambda c: 42, rlevel=1),
        sysvar("MINE", INT, get=lambda conn: conn.id), bind=lambda root: root)), counter)
    await server.start("127.0.0.1", 0)
    try:
        admin, _ = await login(server.port, "admin", "admin-pw")
        other, _ = await login(server.port, "admin", "admin-pw")
        observer, _ = await login(server.port, "observer", "obs-pw")
        line = "GET COUNT.A;COUNT.SECRET"
        first = await admin.command(7, line)
        again = await other.command(7, line)  # another connection, same level: the kept reply
        assert again == first and server.replies.hits == 1 and counter.order == ["A"]
        denied = await observer.command(7, line)  # another read level: read for it
        assert denied[1] == "7 DATA INLINE COUNT.A=2" and denied[2] == "7 DATA INLINE COUNT.SECRET=DENIED"
        state_epoch.bump()  # what every readback batch, PLC poll and GPS line does
        assert (await admin.command(7, line))[1] == "7 DATA INLINE COUNT.A=3"
        assert (await other.command(7, line))[1] == "7 DATA INLINE COUNT.A=3"  # (kept again)
        assert await other.command(9, "SET COUNT.B=5") == ["9 COMMAND OK", "9 DATA OK COUNT.B",
                                                           "9 COMMAND COMPLETE"]
        assert (await admin.command(7, line))[1] == "7 DATA INLINE COUNT.A=4"  # a SET was answered
        # two lines in one chunk go the normal way, each read
        await admin.send_bytes(b"3 GET COUNT.A\n4 GET COUNT.A\n")
        lines = [await admin.readline() for _ in range(6)]
        assert "3 DATA INLINE COUNT.A=5" in lines and "4 DATA INLINE COUNT.A=6" in lines, lines
        # a per-connection variable: each connection its own answer, however often asked
        mine_admin = await admin.command(5, "GET COUNT.MINE")
        mine_other = await other.command(5, "GET COUNT.MINE")
        assert mine_admin[1] != mine_other[1], (mine_admin, mine_other)
        hits = server.replies.hits
        assert await admin.command(5, "GET COUNT.MINE") == mine_admin and server.replies.hits == hits
        for x in (admin, other, observer):
            await x.close()
    finally:
        await server.stop()


async def test_a_polled_reply_is_read_again_ahead_of_the_next_request_and_never_past_its_age():
    """A kept reply used past half its life is read again right after that answer, so the
    next request of a fast poller finds a new one instead of reading in its own round trip
    (issue 27) — and a reply still answers only while younger than ``reuse_reply``. The
    cache's clock is the test's, so only these rules decide."""
    from tcs.opentci_server.reply_cache import ReplyCache
    from tcs.opentci_server.tree import INT, module, var

    hub = EventHub()
    hub.bind_loop()
    server = Tpl2Server(ServerSection(port=0, auth_fail_delay=0.01), USERS, hub)
    now = [100.0]
    server.replies = ReplyCache(0.2, clock=lambda: now[0])
    counter = _Counter(server)
    server.tree = Tree.build((SERVER, module(
        "COUNT", var("A", INT, get=lambda c: c.tick("A")), bind=lambda root: root)), counter)
    await server.start("127.0.0.1", 0)
    try:
        client, _ = await login(server.port, "admin", "admin-pw")
        line = "GET COUNT.A"

        async def value() -> str:
            reply = await client.command(7, line)
            await asyncio.sleep(0.05)  # (a read ahead, if any, has run)
            return reply[1].rpartition("=")[2]

        assert await value() == "1"  # read, kept at 100.0
        now[0] = 100.05
        assert await value() == "1" and counter.order == ["A"]  # young: used, not read again
        now[0] = 100.15
        assert await value() == "1"  # past half its life: used, then read again (kept at 100.15)
        assert counter.order == ["A", "A"] and server.replies.refreshed == 1
        now[0] = 100.16
        assert await value() == "2" and len(counter.order) == 2  # the one read ahead
        now[0] = 100.5  # older than 0.2 s: read in the request, never answered from the cache
        assert await value() == "3" and server.replies.refreshed == 1
        await client.close()
    finally:
        await server.stop()
