"""Issue 12, the SERVER module (TPL2 §9), over a real socket against the default service."""

from __future__ import annotations

import asyncio
import json
import os

from support.service import start_service
from support.tpl2 import RawClient


async def login(port: int, user: str, password: str) -> str:
    c = await RawClient.connect(port, login=None)
    await c.send(f'AUTH PLAIN "{user}" "{password}"')
    reply = await c.readline()
    await c.close()
    return reply


async def test_server_variables_exist_and_read(service):
    _, port = service
    c = await RawClient.connect(port)
    for i in range(30):  # some commands for COMMAND_RATE
        await c.get("SERVER.UPTIME", cmd_id=100 + i)
    assert float(await c.get("SERVER.CONNECTION.COMMAND_RATE")) > 0.0
    assert float(await c.get("SERVER.LOAD")) >= 0.0
    assert (await c.get("SERVER.LOAD_DETAIL")).startswith('"cpu ')
    assert await c.get("SERVER.INFO.FLAGS") == '""'  # a string: no optional features
    assert "OpenTCI 2.5" in await c.get("SERVER.INFO.INFO")
    assert int(await c.get("SERVER.SYSTEM.CPUS")) >= 1
    assert await c.get("SERVER.SYSTEM.OSTYPE") == '"Linux"'
    assert len(await c.get("SERVER.SYSTEM.HOSTNAME")) > 2
    assert float(await c.get("SERVER.SYSTEM.UPTIME")) > 0.0
    assert float(await c.get("SERVER.SYSTEM.STARTTIME")) < float(await c.get("SERVER.STARTTIME"))
    assert float(await c.get("SERVER.SYSTEM.LOAD")) >= 0.0
    assert (await c.get("SERVER.SYSTEM.ARCHITECTURE")).strip('"')
    assert await c.get("SERVER.SYSTEM.OSVERSION") != '""'
    assert await c.get("SERVER.CONNECTION.PASSWORD") == "DENIED"  # write-only
    # REBOOT and SHUTDOWN are refused unless the hardware file allows them
    for obj in ("SERVER.SHUTDOWN", "SERVER.SYSTEM.SHUTDOWN", "SERVER.SYSTEM.REBOOT"):
        lines = await c.command(1, f"SET {obj}=1")
        assert lines[-2:] == [f"1 DATA ERROR {obj} FAILED 6", "1 COMMAND COMPLETE"], lines
    await c.close()


async def test_clients_drop_and_block(service):
    _, port = service
    admin = await RawClient.connect(port)
    other = await RawClient.connect(port)
    assert int(await admin.get("SERVER.CLIENT!COUNT")) >= 64  # every connection slot
    ids = [int(x) for x in (await admin.get("SERVER.CLIENT[0-2].ID")).split(",")]
    assert ids[2] == 0 and ids[0] < ids[1]
    assert await admin.get("SERVER.CLIENT[1].USERNAME") == '"admin"'
    assert await admin.get("SERVER.CLIENT[1].ADDRESS") == '"127.0.0.1"'
    assert await admin.get("SERVER.CLIENT[1].EVENTMASK") == "15"
    assert float(await admin.get("SERVER.CLIENT[1].UPTIME")) > 0.0
    assert await admin.get("SERVER.CLIENT[5].UPTIME") == "0.0"
    weak = await RawClient.connect(port, login=None)
    await weak.send('AUTH PLAIN "admin" "admin" 1 1')
    assert await weak.readline() == "AUTH OK 1 1"
    assert (await weak.command(1, "SET SERVER.CLIENT[1].DROP=1"))[1] == "1 DATA ERROR SERVER.CLIENT[1].DROP DENIED"
    assert (await admin.command(2, "SET SERVER.CLIENT[1].DROP=1"))[1] == "2 DATA OK SERVER.CLIENT[1].DROP"
    assert await asyncio.wait_for(other.reader.read(), 10) == b""  # closed by the server
    assert (await admin.command(3, "SET SERVER.CLIENT[9].DROP=1"))[1] == "3 DATA ERROR SERVER.CLIENT[9].DROP RANGE"
    await admin.close()
    await other.close()
    await weak.close()


async def test_password_change_is_hashed_persisted_and_survives_a_restart(tmp_path):
    state = tmp_path / "state"
    svc, port = await start_service(state)
    try:
        c = await RawClient.connect(port)
        lines = await c.command(1, 'SET SERVER.CONNECTION.PASSWORD="n3w-secret"', timeout=30)
        assert lines[1] == "1 DATA OK SERVER.CONNECTION.PASSWORD", lines
        await c.close()
        assert (await login(port, "admin", "admin")) == "AUTH FAILED"
        assert (await login(port, "admin", "n3w-secret")).startswith("AUTH OK 0 0")
    finally:
        await svc.stop()
    text = (state / "accounts.json").read_text()
    assert "n3w-secret" not in text and "pbkdf2_sha256$" in text
    svc, port = await start_service(state)
    try:
        assert (await login(port, "admin", "n3w-secret")).startswith("AUTH OK 0 0")
        assert (await login(port, "admin", "admin")) == "AUTH FAILED"
    finally:
        await svc.stop()
    # the hardware file edited since (another hash for admin): the file wins
    data = json.loads(text)
    data["accounts"]["admin"]["file_hash"] = "pbkdf2_sha256$1$AAAA$BBBB"
    (state / "accounts.json").write_text(json.dumps(data))
    svc, port = await start_service(state)
    try:
        assert (await login(port, "admin", "admin")).startswith("AUTH OK 0 0")
    finally:
        await svc.stop()


async def test_accounts_add_block_modify_remove(tmp_path):
    state = tmp_path / "state"
    svc, port = await start_service(state)
    try:
        c = await RawClient.connect(port)
        assert await c.get("SERVER.ACCOUNTS.LIST") == '"admin:0:0:0:file"'
        lines = await c.command(1, 'SET SERVER.ACCOUNTS.ADD="obs:pw1:3:3"', timeout=30)
        assert lines[1] == "1 DATA OK SERVER.ACCOUNTS.ADD", lines
        assert (await login(port, "obs", "pw1")).startswith("AUTH OK 3 3")
        assert (await c.command(2, 'SET SERVER.ACCOUNTS.BLOCK="obs"'))[1] == "2 DATA OK SERVER.ACCOUNTS.BLOCK"
        assert (await login(port, "obs", "pw1")) == "AUTH FAILED"
        assert await c.get("SERVER.ACCOUNTS.LIST") == '"admin:0:0:0:file,obs:3:3:1:tpl2"'
        assert (await c.command(3, 'SET SERVER.ACCOUNTS.UNBLOCK="obs"'))[1] == "3 DATA OK SERVER.ACCOUNTS.UNBLOCK"
        m = "SERVER.ACCOUNTS.MODIFY"
        lines = await c.command(4, f'SET {m}.USERNAME="obs";{m}.MIN_RLEVEL=5;{m}.MIN_WLEVEL=9;{m}.UPDATE=1', timeout=30)
        assert lines[-2:] == [f"4 DATA OK {m}.UPDATE", "4 COMMAND COMPLETE"], lines
        assert (await login(port, "obs", "pw1")).startswith("AUTH OK 5 9")
        # never weaker than the hardware file: its users stay, with at most the file's privilege
        assert (await c.command(5, 'SET SERVER.ACCOUNTS.REMOVE="admin"'))[1] == \
            "5 DATA ERROR SERVER.ACCOUNTS.REMOVE RANGE"
        assert (await c.command(6, 'SET SERVER.ACCOUNTS.ADD="admin:x:0:0"'))[1] == \
            "6 DATA ERROR SERVER.ACCOUNTS.ADD RANGE"
        assert await c.get("SERVER.ACCOUNTS.ADD") == "DENIED"
        await c.close()
    finally:
        await svc.stop()
    svc, port = await start_service(state)  # survives a restart
    try:
        assert (await login(port, "obs", "pw1")).startswith("AUTH OK 5 9")
        c = await RawClient.connect(port)
        assert (await c.command(7, 'SET SERVER.ACCOUNTS.REMOVE="obs"'))[1] == "7 DATA OK SERVER.ACCOUNTS.REMOVE"
        assert (await login(port, "obs", "pw1")) == "AUTH FAILED"
        await c.close()
    finally:
        await svc.stop()


async def test_event_log_for_late_clients(service):
    _, port = service
    c = await RawClient.connect(port)
    await c.command(1, "SET AZ.TARGETPOS=10")  # refused, with its event ERROR AZ:5
    late = await RawClient.connect(port)
    log = await late.get("SERVER.LOG.EVENTS")
    assert " EVENT ERROR AZ:5 " in log, log
    line = [x for x in log.strip('"').split("\\n") if "AZ:5" in x][-1]
    stamp, ext, word = line.split(" ")[:3]
    assert float(stamp) > 1.6e9 and word == "EVENT"
    conn = int(await c.get("SERVER.CONNECTION.ID"))
    assert int(ext) == (conn << 32) | 1  # the command was running when it was sent
    assert int(await late.get("SERVER.LOG.COUNT")) >= 1
    assert (await late.command(2, "SET SERVER.LOG.CLEAR=1"))[1] == "2 DATA OK SERVER.LOG.CLEAR"
    assert await late.get("SERVER.LOG.COUNT") == "0"
    assert await late.get("SERVER.LOG.EVENTMASK") == "15"
    await c.close()
    await late.close()


async def test_blocked_user_is_refused_by_implicit_auth_too(tmp_path):
    """``implicit_auth`` logs a connection in without AUTH: once its user is blocked
    (SERVER.ACCOUNTS.BLOCK or CLIENT[].BLOCK), a new connection gets the answer a blocked
    AUTH gets (``AUTH FAILED``) and is not logged in; unblocked, it is again."""
    svc, port = await start_service(tmp_path / "state", implicit_auth=True, implicit_user="admin")
    try:
        c = await RawClient.connect(port, login=None)
        assert await c.readline() == "AUTH OK 0 0"
        assert (await c.command(1, 'SET SERVER.ACCOUNTS.BLOCK="admin"'))[1] == "1 DATA OK SERVER.ACCOUNTS.BLOCK"
        blocked = await RawClient.connect(port, login=None)
        assert await blocked.readline() == "AUTH FAILED"
        assert await blocked.command(2, "GET SERVER.UPTIME") == ["2 COMMAND ERROR UNAUTHENTICATED",
                                                                  "2 COMMAND FAILED"]
        await blocked.send('AUTH PLAIN "admin" "admin"')  # the same answer as a blocked AUTH
        assert await blocked.readline() == "AUTH FAILED"
        await blocked.close()
        assert (await c.command(3, 'SET SERVER.ACCOUNTS.UNBLOCK="admin"'))[1] == "3 DATA OK SERVER.ACCOUNTS.UNBLOCK"
        again = await RawClient.connect(port, login=None)
        assert await again.readline() == "AUTH OK 0 0"
        await again.close()
        await c.close()
    finally:
        await svc.stop()


async def test_accounts_are_the_same_on_the_opentci_and_opentsi_ports(tmp_path):
    """One set of accounts for every port of the service: a user blocked over the OpenTCI port
    cannot log in over the OpenTSI port (it could), an account added over OpenTSI logs in
    over OpenTCI, and neither port's save undoes the other's change."""
    state = tmp_path / "state"
    svc, port = await start_service(state)
    try:
        tsi = svc.opentsi_port
        assert tsi > 0
        # and one per-name login back-off (issue 22.9): guesses on one port slow the other too
        assert svc.server.guard.logins is svc.opentsi_server.guard.logins
        c = await RawClient.connect(port)
        t = await RawClient.connect(tsi)
        lines = await t.command(1, 'SET SERVER.ACCOUNTS.ADD="obs:pw1:3:3"', timeout=30)
        assert lines[1] == "1 DATA OK SERVER.ACCOUNTS.ADD", lines
        assert (await login(port, "obs", "pw1")).startswith("AUTH OK 3 3")
        assert (await c.command(2, 'SET SERVER.ACCOUNTS.BLOCK="admin"'))[1] == "2 DATA OK SERVER.ACCOUNTS.BLOCK"
        assert (await login(tsi, "admin", "admin")) == "AUTH FAILED"
        assert (await login(port, "admin", "admin")) == "AUTH FAILED"
        assert (await t.command(3, 'SET SERVER.ACCOUNTS.UNBLOCK="admin"'))[1] == "3 DATA OK SERVER.ACCOUNTS.UNBLOCK"
        assert (await login(port, "admin", "admin")).startswith("AUTH OK 0 0")
        await c.close()
        await t.close()
    finally:
        await svc.stop()
    saved = json.loads((state / "accounts.json").read_text())["accounts"]
    assert set(saved) == {"obs", "admin"} and not saved["admin"]["blocked"]


async def test_load_and_uptime_need_no_proc_files_and_a_refused_reboot_says_why(tmp_path, monkeypatch):
    """The unit's ProcSubset=pid hides /proc/loadavg and /proc/uptime: SYSTEM.LOAD and UPTIME
    come from sysinfo(2), so they are the host's figures, not 0. A REBOOT the system refuses
    (the unit's NoNewPrivileges: systemctl is denied) fails with systemctl's words instead of
    answering OK. (A stand-in systemctl on PATH: this test must never reboot the machine.)"""
    from tcs.opentci_server.server_module import host_sysinfo

    uptime, load = host_sysinfo()
    assert uptime > 0 and abs(load - os.getloadavg()[0]) < 5.0
    fake = tmp_path / "bin"
    fake.mkdir()
    (fake / "systemctl").write_text("#!/bin/sh\necho 'Failed to reboot system: Access denied' >&2\nexit 1\n")
    (fake / "systemctl").chmod(0o755)
    monkeypatch.setenv("PATH", f"{fake}:{os.environ['PATH']}")
    svc, port = await start_service(tmp_path / "state", allow_system_control=True)
    try:
        c = await RawClient.connect(port)
        assert float(await c.get("SERVER.SYSTEM.UPTIME")) >= uptime
        lines = await c.command(1, "SET SERVER.SYSTEM.REBOOT=1", timeout=60)
        assert "1 DATA ERROR SERVER.SYSTEM.REBOOT FAILED 2" in lines, lines
        assert any("Access denied" in line for line in lines), lines
        await c.close()
    finally:
        await svc.stop()
