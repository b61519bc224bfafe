"""The domain object of the ``SERVER`` module (TPL2 §9): the server, its host, its clients,
its accounts and its event log.

How it works
------------
One :class:`ServerModule` per :class:`~tcs.opentci_server.server.Tpl2Server` (see
:meth:`ServerModule.of`); the declaration in ``opentci/__init__.py`` binds ``SERVER`` to it. It reads
the server (sessions, settings, users) and the host (``os``, ``platform``, ``/proc``), keeps
the event log (``LOG.*``: the recent events a client that connects late can read), and owns
the accounts written over TPL2.

Accounts: the hardware file's ``[[users]]`` are the base. ``SERVER.CONNECTION.PASSWORD`` (one's
own password) and ``SERVER.ACCOUNTS.*`` (level 0) change them; every change is kept **hashed**
in ``accounts.json`` in the state directory (never in the hardware file) and survives a restart.
A change never weakens the hardware file: a file user cannot be removed, nor given more
privilege than the file gives, and a password changed over TPL2 is dropped once the file's
hash for that user was edited (the file wins, as for every persisted value). A changed account
takes effect in the user table of every server of the telescope (OpenTCI and OpenTSI ports:
one module per server, one set of accounts) at once (the next login); a connection logged in
stays logged in. A blocked user keeps its entry with a hash no password matches
(:data:`BLOCKED_HASH`); implicit authentication, which checks no password, refuses a blocked
``implicit_user`` with ``AUTH FAILED`` too (the session looks for that hash).

``REBOOT`` and ``SHUTDOWN`` are refused (``FAILED 6``, localmode) unless the hardware file
sets ``[server] allow_system_control``; then ``SERVER.SHUTDOWN`` and ``SYSTEM.SHUTDOWN`` stop
this service (SIGTERM to itself, a clean stop) and ``SYSTEM.REBOOT`` asks systemd to reboot:
the SET completes once ``systemctl reboot`` accepted it and fails with systemd's answer when
it refused (the hardened unit runs as user ``tcs`` with ``NoNewPrivileges``, so a reboot needs
a polkit rule allowing ``org.freedesktop.login1.reboot`` for that user).

``SYSTEM.LOAD`` and ``UPTIME`` come from ``/proc`` and, where the unit hides it
(``ProcSubset=pid``), from the ``sysinfo`` system call: never a made-up 0.

Everything runs on the event loop; password hashing runs in a worker thread.
"""

from __future__ import annotations

import asyncio
import logging
import os
import platform
import re
import signal
import socket
import subprocess
import time
from collections import deque
from dataclasses import dataclass
from typing import Any

from tcs.config.passwords import hash_password
from tcs.config.sections import UserSection
from tcs.errors import ErrorNumber, RequestRefused, TcsError
from tcs.model.events import LEVEL_BITS, Event
from tcs.model.state_store import StateStore

log = logging.getLogger(__name__)

LOG_CAPACITY = 200          # events kept for LOG.EVENTS
RATE_WINDOW = 10.0          # s over which COMMAND_RATE counts
BLOCKED_HASH = "blocked"    # not a valid hash: verify_password() is False for every password
_NAME = re.compile(r"[A-Za-z0-9_.-]{1,64}\Z")


@dataclass(frozen=True)
class Account(UserSection):
    """A user as the server's user table holds it: the hardware file's ``[[users]]`` entry
    (``rlevel``/``wlevel``: the most privileged levels a login may ask for, TPL2's MIN_ levels)
    plus what ``ACCOUNTS.MODIFY`` adds: the levels a login that asks for none gets, and a
    descriptive name."""

    default_rlevel: int = 0
    default_wlevel: int = 0
    fullname: str = ""


class AccountForm:
    """``SERVER.ACCOUNTS.MODIFY`` of one connection (each connection has its own form):
    writing ``USERNAME`` loads that account (a name without an account keeps the form for
    ``ADD``), the other fields are staged, then ``ADD=1``, ``UPDATE=1`` or ``REMOVE=1``."""

    def __init__(self) -> None:
        self.username = ""
        self.fullname = ""
        self.type = 0
        self.password: str | None = None
        self.default_rlevel = self.default_wlevel = 9
        self.min_rlevel = self.min_wlevel = 9
        self.blocked = 0


def account_form(conn: Any) -> AccountForm:
    """The MODIFY form of connection ``conn`` (made on first use)."""
    form = getattr(conn, "account_form", None)
    if form is None:
        form = AccountForm()
        conn.account_form = form
    return form


class ServerModule:
    """``SERVER.*`` of one server (and its telescope's state directory)."""

    @classmethod
    def of(cls, server: Any, telescope: Any = None) -> "ServerModule":
        """The one module of ``server`` (made on first use, kept on the server object)."""
        module = getattr(server, "_server_module", None)
        if module is None:
            module = cls(server, telescope)
            server._server_module = module
        return module

    def __init__(self, server: Any, telescope: Any = None):
        self.server = server
        self.settings = server.settings
        self.file_users = dict(server.users)  # the hardware file's, as loaded
        state_dir = getattr(telescope, "state_dir", None)
        # the servers of one telescope (OpenTCI and OpenTSI ports) share one set of accounts:
        # a user blocked (added, changed) on one port is so on every port at once, and the
        # failed logins of a name on one port slow its logins on every port (guard.py)
        peers = getattr(telescope, "_server_modules", None)
        if peers is None and telescope is not None:
            peers = []
            try:
                telescope._server_modules = peers
            except AttributeError:
                peers = None
        self._peers: list[ServerModule] = peers if peers is not None else []
        self._peers.append(self)
        if len(self._peers) > 1:
            first = self._peers[0]
            self.store, self.accounts = first.store, first.accounts  # (the same objects)
            guard = getattr(server, "guard", None)
            if guard is not None and getattr(first.server, "guard", None) is not None:
                guard.logins = first.server.guard.logins  # one per-name back-off for all ports
            self._apply_all()
        else:
            self.store = StateStore(state_dir, "accounts") if state_dir is not None else None
            self.accounts: dict[str, dict] = {}
            self._load_accounts()
        self.log: deque[str] = deque(maxlen=LOG_CAPACITY)
        self.log_total = 0
        self.log_eventmask = 15
        self._cpu_sample = (time.monotonic(), time.process_time())
        self._cpu_load = 0.0
        events = getattr(server, "events", None)
        if events is not None:
            events.subscribe(self._on_event)

    # -- identification --------------------------------------------------------------------
    @property
    def uptime(self) -> float:
        return self.server.uptime

    @property
    def starttime(self) -> float:
        return self.server.starttime

    @property
    def version(self) -> str:
        return self.server.version

    @property
    def device(self) -> str:
        return self.server.device

    @property
    def vendor(self) -> str:
        return self.server.vendor

    @property
    def manufacturer(self) -> str:
        return self.server.manufacturer

    flags = ""  # INFO.FLAGS: the optional TPL2 features offered, comma-separated: none (no ENC,
    # no sub-servers)

    @property
    def info(self) -> str:
        return (f"OpenTCI 2.5 over TPL2 2.1; {self.server.version}; "
                f"Python {platform.python_version()}")

    # -- load ----------------------------------------------------------------------------------
    @property
    def load(self) -> float:
        """CPU time this process used per second of wall time, since the previous read (≥ 1 s
        apart; 1.0 = one core busy)."""
        now, cpu = time.monotonic(), time.process_time()
        then, cpu_then = self._cpu_sample
        if now - then >= 1.0:
            self._cpu_load = max(0.0, (cpu - cpu_then) / (now - then))
            self._cpu_sample = (now, cpu)
        elif self._cpu_load == 0.0 and now > then:
            return round(max(0.0, (cpu - cpu_then) / (now - then)), 3)
        return round(self._cpu_load, 3)

    @property
    def load_detail(self) -> str:
        sessions = list(self.server.sessions.values())
        rate = sum(command_rate(s) for s in sessions)
        return (f"cpu {self.load:.3f}, connections {len(sessions)}/{self.settings.max_connections}, "
                f"commands {rate:.1f}/s, commands running "
                f"{sum(len(s.commands) for s in sessions)}")

    # -- SYSTEM ------------------------------------------------------------------------------
    architecture = platform.machine()
    ostype = platform.system()
    osversion = platform.release()
    cpus = os.cpu_count() or 1

    @property
    def hostname(self) -> str:
        return socket.gethostname()

    @property
    def system_load(self) -> float:
        """The 1-minute load average, from sysinfo(2): the unit's ``ProcSubset=pid`` hides
        /proc/loadavg (``os.getloadavg`` then fails), the system call still answers."""
        info = host_sysinfo()
        if info is not None:
            return round(info[1], 2)
        try:
            return round(os.getloadavg()[0], 2)
        except OSError:
            raise TcsError("the host does not tell its load average", ErrorNumber.NOCON) from None

    @property
    def system_uptime(self) -> float:
        info = host_sysinfo()
        if info is not None:
            return float(info[0])
        return time.clock_gettime(time.CLOCK_BOOTTIME)

    @property
    def system_starttime(self) -> float:
        return round(time.time() - self.system_uptime, 2)

    def shutdown(self, value: int) -> None:
        """SERVER.SHUTDOWN / SYSTEM.SHUTDOWN: stop this service (when allowed)."""
        self._allowed("shutdown")
        log.warning("SHUTDOWN requested over TPL2: stopping the service")
        asyncio.get_running_loop().call_later(0.1, os.kill, os.getpid(), signal.SIGTERM)

    async def reboot(self, value: int) -> None:
        """SYSTEM.REBOOT: ask systemd to reboot the computer (when allowed). The SET completes
        when systemd took the request and fails with systemctl's own words when it did not
        (the shipped unit runs with ``NoNewPrivileges``, without the right to reboot: a
        cabinet that wants this grants it to the user ``tcs`` with a polkit rule)."""
        self._allowed("reboot")
        log.warning("REBOOT requested over TPL2")
        try:
            proc = await asyncio.create_subprocess_exec(
                "systemctl", "reboot", stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT)
            out, _ = await asyncio.wait_for(proc.communicate(), 60)
        except (OSError, asyncio.TimeoutError) as exc:
            raise TcsError(f"reboot: systemctl could not be run: {exc}", ErrorNumber.LIBFAIL) from None
        if proc.returncode != 0:
            text = " ".join(out.decode(errors="replace").split()) or f"exit status {proc.returncode}"
            log.warning("REBOOT refused by the system: %s", text)
            raise TcsError(f"reboot refused by the system: {text} (the service's user needs a polkit "
                           "rule for org.freedesktop.login1.reboot)", ErrorNumber.LIBFAIL)

    def _allowed(self, what: str) -> None:
        if not getattr(self.settings, "allow_system_control", False):
            raise TcsError(f"{what} over TPL2 is not allowed by the hardware file "
                           "([server] allow_system_control)", ErrorNumber.LOCALMODE)

    # -- LOG -----------------------------------------------------------------------------------
    def _on_event(self, event: Event) -> None:
        if not self.log_eventmask & LEVEL_BITS.get(event.level, 0):
            return
        cid = 0
        cause = event.cause
        if cause is not None:
            owner = self.server.sessions.get(cause[0])
            if owner is not None and owner.executing(cause):
                cid = (cause[0] << 32) | cause[1]
        line = f"{time.time():.3f} {cid} EVENT {event.level} {event.source}:{event.number}"
        self.log.append(f"{line} {event.text}" if event.text else line)
        self.log_total += 1

    @property
    def log_events(self) -> str:
        """The logged events, oldest first, one ``<unix time> <extended id> EVENT …`` per line."""
        return "\n".join(self.log)

    @property
    def log_count(self) -> int:
        return len(self.log)

    def clear_log(self, value: int) -> None:
        self.log.clear()

    def set_log_eventmask(self, value: int) -> None:
        self.log_eventmask = int(value)

    # -- CLIENT[] --------------------------------------------------------------------------------
    def client_slots(self) -> list["ClientSlot"]:
        return [ClientSlot(self, i) for i in range(self.settings.max_connections)]

    def session_at(self, slot: int):
        """The ``slot``-th open connection by connection number, or None."""
        sessions = sorted(self.server.sessions.values(), key=lambda s: s.id)
        return sessions[slot] if slot < len(sessions) else None

    # -- accounts --------------------------------------------------------------------------------
    def _load_accounts(self) -> None:
        saved = self.store.get("accounts", {}) if self.store is not None else {}
        for name, entry in (saved or {}).items():
            base = self.file_users.get(name)
            if base is not None and entry.get("file_hash") != base.password:
                log.warning("account %s: the hardware file changed since it was edited over TPL2; "
                            "the file wins", name)
                continue
            self.accounts[name] = dict(entry)
        self._apply_all()

    def _save(self) -> None:
        if self.store is not None:
            self.store.update(accounts=self.accounts)

    def _apply_all(self) -> None:
        users = self.server.users
        for name, base in self.file_users.items():
            users[name] = base
        for name, entry in self.accounts.items():
            self._apply(name, entry)

    def _apply(self, name: str, entry: dict | None) -> None:
        """Put ``name``'s effective account into the server's user table (the next login)."""
        users = self.server.users
        base = self.file_users.get(name)
        verified = getattr(self.server, "_verified", None)
        if verified is not None:  # a remembered good password may be the old one
            verified.pop(name, None)
        if entry is None:
            if base is not None:
                users[name] = base
            else:
                users.pop(name, None)
            return
        # a blocked user stays in the table (other code may look it up) with a hash that no
        # password matches: every login fails
        password = BLOCKED_HASH if entry.get("blocked") else entry["password"]
        users[name] = Account(name=name, password=password, rlevel=int(entry["rlevel"]),
                              wlevel=int(entry["wlevel"]),
                              default_rlevel=int(entry.get("default_rlevel", entry["rlevel"])),
                              default_wlevel=int(entry.get("default_wlevel", entry["wlevel"])),
                              fullname=str(entry.get("fullname", "")))

    def _entry(self, name: str) -> dict:
        entry = self.accounts.get(name)
        if entry is not None:
            return entry
        base = self.file_users.get(name)
        if base is None:
            raise RequestRefused(f"no account {name!r}", keyword="RANGE")
        return {"password": base.password, "rlevel": base.rlevel, "wlevel": base.wlevel,
                "blocked": False, "file_hash": base.password}

    def _commit(self, name: str, entry: dict | None) -> None:
        if entry is None:
            self.accounts.pop(name, None)
        else:
            self.accounts[name] = entry
        self._save()
        for module in self._peers:
            module._apply(name, entry)

    async def change_password(self, name: str, password: str) -> None:
        """Set ``name``'s password (hashed off the loop, persisted, effective at once)."""
        if not password:
            raise RequestRefused("an empty password is not allowed", keyword="RANGE")
        entry = dict(self._entry(name))
        entry["password"] = await asyncio.to_thread(hash_password, password)
        self._commit(name, entry)
        log.info("account %s: password changed over TPL2", name)

    @property
    def account_list(self) -> str:
        """``name:rlevel:wlevel:blocked:source`` per account, comma-separated."""
        names = sorted(set(self.file_users) | set(self.accounts))
        out = []
        for name in names:
            entry = self._entry(name)
            source = "file" if name in self.file_users else "tpl2"
            out.append(f"{name}:{entry['rlevel']}:{entry['wlevel']}:{int(bool(entry.get('blocked')))}:{source}")
        return ",".join(out)

    def add_account(self, spec: str):
        """``ACCOUNTS.ADD="name:password:rlevel:wlevel"`` — a new user (not one of the file's)."""
        parts = spec.split(":")
        if len(parts) != 4 or not _NAME.match(parts[0]) or not parts[1]:
            raise RequestRefused("ADD takes name:password:rlevel:wlevel", keyword="RANGE")
        name, password, rlevel, wlevel = parts[0], parts[1], _level(parts[2]), _level(parts[3])
        if name in self.file_users or name in self.accounts:
            raise RequestRefused(f"account {name!r} exists", keyword="RANGE")

        async def add():
            hashed = await asyncio.to_thread(hash_password, password)
            self._commit(name, {"password": hashed, "rlevel": rlevel, "wlevel": wlevel, "blocked": False})
        return add()

    def remove_account(self, name: str) -> None:
        if name in self.file_users:
            raise RequestRefused(f"{name!r} is a user of the hardware file: block it instead", keyword="RANGE")
        if name not in self.accounts:
            raise RequestRefused(f"no account {name!r}", keyword="RANGE")
        self._commit(name, None)

    def block_account(self, name: str) -> None:
        entry = dict(self._entry(name))
        entry["blocked"] = True
        self._commit(name, entry)

    def unblock_account(self, name: str) -> None:
        entry = dict(self._entry(name))
        entry["blocked"] = False
        self._commit(name, entry)

    # -- the TPL2 §9 form: USERNAMES, BLOCKED, UNBLOCKED and the MODIFY submodule ------------
    def _names(self) -> list[str]:
        return sorted(set(self.file_users) | set(self.accounts))

    @property
    def usernames(self) -> str:
        """``ACCOUNTS.USERNAMES``: every account's name, comma-separated."""
        return ",".join(self._names())

    @property
    def blocked_names(self) -> str:
        return ",".join(n for n in self._names() if self._entry(n).get("blocked"))

    @property
    def unblocked_names(self) -> str:
        return ",".join(n for n in self._names() if not self._entry(n).get("blocked"))

    def set_blocked(self, names: str) -> None:
        """``ACCOUNTS.BLOCKED="a,b"``: block these users (the others stay as they are)."""
        for name in self._name_list(names):
            self.block_account(name)

    def set_unblocked(self, names: str) -> None:
        for name in self._name_list(names):
            self.unblock_account(name)

    def _name_list(self, names: str) -> list[str]:
        out = [n.strip() for n in names.split(",") if n.strip()]
        for name in out:  # all or nothing
            self._entry(name)
        return out

    def load_form(self, conn: Any, name: str) -> None:
        """``MODIFY.USERNAME`` written: the form shows that account (a new name: the form
        keeps what was staged, for ``ADD``)."""
        if not _NAME.match(name):
            raise RequestRefused(f"{name!r} is not a user name (letters, digits, _ . -)", keyword="RANGE")
        form = account_form(conn)
        form.username = name
        form.password = None
        if name in self.file_users or name in self.accounts:
            entry = self._entry(name)
            form.fullname = str(entry.get("fullname", ""))
            form.min_rlevel, form.min_wlevel = int(entry["rlevel"]), int(entry["wlevel"])
            form.default_rlevel = int(entry.get("default_rlevel", entry["rlevel"]))
            form.default_wlevel = int(entry.get("default_wlevel", entry["wlevel"]))
            form.blocked = int(bool(entry.get("blocked")))

    @staticmethod
    def _form_entry(form: AccountForm) -> dict:
        # a default more privileged than the minimum is the minimum (as a login asking for it)
        return {"rlevel": form.min_rlevel, "wlevel": form.min_wlevel,
                "default_rlevel": max(form.default_rlevel, form.min_rlevel),
                "default_wlevel": max(form.default_wlevel, form.min_wlevel),
                "fullname": form.fullname, "blocked": bool(form.blocked)}

    def form_add(self, conn: Any):
        """``MODIFY.ADD=1``: the form as a new account (FAILED 5 when the name exists, is
        not set, or no password was staged)."""
        form = account_form(conn)
        name = form.username
        if not name:
            raise TcsError("MODIFY.ADD: write MODIFY.USERNAME first", ErrorNumber.INVMODE)
        if name in self.file_users or name in self.accounts:
            raise TcsError(f"MODIFY.ADD: account {name!r} exists (UPDATE changes it)", ErrorNumber.INVMODE)
        if not form.password:
            raise TcsError(f"MODIFY.ADD: account {name!r} needs a PASSWORD", ErrorNumber.INVMODE)
        entry = self._form_entry(form)
        password, form.password = form.password, None

        async def add():
            entry["password"] = await asyncio.to_thread(hash_password, password)
            self._commit(name, entry)
            log.info("account %s added over TPL2", name)
        return add()

    def form_update(self, conn: Any):
        """``MODIFY.UPDATE=1``: the form written to the existing account (its password only
        when one was staged); never more privilege than the hardware file gives."""
        form = account_form(conn)
        name = form.username
        if name not in self.file_users and name not in self.accounts:
            raise TcsError(f"MODIFY.UPDATE: no account {name!r} (ADD makes one)", ErrorNumber.INVMODE)
        base = self.file_users.get(name)
        if base is not None and (form.min_rlevel < base.rlevel or form.min_wlevel < base.wlevel):
            raise TcsError(f"MODIFY.UPDATE: {name!r}: the hardware file gives at most levels "
                           f"{base.rlevel} {base.wlevel}", ErrorNumber.INVMODE)
        entry = dict(self._entry(name))
        entry.update(self._form_entry(form))
        password, form.password = form.password, None

        async def update():
            if password:
                entry["password"] = await asyncio.to_thread(hash_password, password)
            self._commit(name, entry)
            log.info("account %s updated over TPL2", name)
        return update()

    def form_remove(self, conn: Any) -> None:
        """``MODIFY.REMOVE=1``: remove the account USERNAME (one added over TPL2)."""
        name = account_form(conn).username
        if name in self.file_users:
            raise TcsError(f"MODIFY.REMOVE: {name!r} is a user of the hardware file: block it instead",
                           ErrorNumber.INVMODE)
        if name not in self.accounts:
            raise TcsError(f"MODIFY.REMOVE: no account {name!r}", ErrorNumber.INVMODE)
        self._commit(name, None)


def _level(text: str) -> int:
    try:
        level = int(text)
    except ValueError:
        raise RequestRefused(f"level {text!r} is not 0..9", keyword="RANGE") from None
    if not 0 <= level <= 9:
        raise RequestRefused(f"level {level} is not 0..9", keyword="RANGE")
    return level


def command_rate(session: Any) -> float:
    """Commands per second the connection sent over the last :data:`RATE_WINDOW` seconds."""
    times = getattr(session, "command_times", None)
    if not times:
        return 0.0
    horizon = time.monotonic() - RATE_WINDOW
    while times and times[0] < horizon:
        times.popleft()
    return round(len(times) / min(RATE_WINDOW, max(1.0, session.uptime)), 2)


class ClientSlot:
    """``SERVER.CLIENT[i]``: the i-th open connection (by connection number), or empty."""

    def __init__(self, module: ServerModule, slot: int):
        self.module = module
        self.slot = slot

    @property
    def session(self):
        return self.module.session_at(self.slot)

    def _get(self, attr: str, empty):
        s = self.session
        return getattr(s, attr) if s is not None else empty

    @property
    def id(self) -> int:
        return self._get("id", 0)

    @property
    def address(self) -> str:
        s = self.session
        return s.address.rpartition(":")[0] if s is not None and ":" in s.address else self._get("address", "")

    @property
    def username(self) -> str:
        return self._get("username", "")

    @property
    def rlevel(self) -> int:
        return self._get("rlevel", -1) if self.session is not None and self.session.authenticated else -1

    @property
    def wlevel(self) -> int:
        return self._get("wlevel", -1) if self.session is not None and self.session.authenticated else -1

    @property
    def starttime(self) -> float:
        return self._get("starttime", 0.0)

    @property
    def uptime(self) -> float:
        return self._get("uptime", 0.0)

    @property
    def eventmask(self) -> int:
        return self._get("eventmask", 0)

    @property
    def abort_on_disconnect(self) -> int:
        return self._get("abort_on_disconnect", 0)

    @property
    def command_rate(self) -> float:
        s = self.session
        return command_rate(s) if s is not None else 0.0

    def drop(self, value: int) -> None:
        """DROP=1: close this connection (its running commands go on unless it asked
        ABORT_ON_DISCONNECT)."""
        s = self.session
        if s is None:
            raise RequestRefused(f"CLIENT[{self.slot}] is not connected", keyword="RANGE")
        log.warning("connection %d (%s) dropped over TPL2", s.id, s.address)
        s.close()

    def block(self, value: int) -> None:
        """BLOCK=1: block the user logged in on this connection (no new logins) and drop it."""
        s = self.session
        if s is None or not s.username:
            raise RequestRefused(f"CLIENT[{self.slot}] has no logged-in user", keyword="RANGE")
        self.module.block_account(s.username)
        self.drop(1)


__all__ = ["ServerModule", "ClientSlot", "Account", "AccountForm", "account_form", "command_rate"]


def host_sysinfo() -> tuple[int, float] | None:
    """(uptime in s, 1-minute load average) from the sysinfo(2) system call, or None where it
    cannot be called (not Linux)."""
    import ctypes

    class SysInfo(ctypes.Structure):  # struct sysinfo, the fields up to the loads
        _fields_ = [("uptime", ctypes.c_long), ("loads", ctypes.c_ulong * 3),
                    ("rest", ctypes.c_char * 256)]

    try:
        libc = ctypes.CDLL(None, use_errno=True)
        info = SysInfo()
        if libc.sysinfo(ctypes.byref(info)) != 0:
            return None
    except (OSError, AttributeError):
        return None
    return info.uptime, info.loads[0] / 65536.0  # SI_LOAD_SHIFT = 16
