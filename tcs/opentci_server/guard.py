"""Who may hold a TPL2 connection, and who may try a password: the server's exposure limits.

How it works
------------
One :class:`ConnectionGuard` per :class:`~tcs.opentci_server.server.Tpl2Server` (so every
listener of every tree gets the same protections, each with its own ``[server]`` settings).
The server asks it at every accepted connection (:meth:`ConnectionGuard.admit`) and at every
login attempt (:meth:`ConnectionGuard.locked_out`, :meth:`ConnectionGuard.failed`,
:meth:`ConnectionGuard.succeeded`). Nothing here does I/O or keeps time of its own: the clock
is :func:`time.monotonic` unless a test passes another.

Limits (all from the ``[server]`` section; README "Security" lists them with their defaults):

- ``max_connections`` ordinary connections; past that, ``admin_reserve`` more, only for a
  level-0 user: a connection admitted into the reserve is *reserved* and is dropped when it
  logs in as anyone else. Reserved slots ignore the per-address limits, so silent sockets from
  one host cannot keep an operator who comes through the same host (an SSH tunnel) out.
- ``max_per_address`` connections and ``max_pending_per_address`` not-yet-logged-in
  connections from one IP address.
- ``auth_lockout_failures`` failed logins from one address within ``auth_lockout_time``
  seconds lock the address out for ``auth_lockout_time``: every login from it fails, right
  password or not, without the password being checked.
"""

from __future__ import annotations

import time
from collections import deque
from typing import Callable, Iterable

from tcs.config.sections import ServerSection


def host_of(address: str) -> str:
    """The IP part of ``"host:port"`` (IPv6 ``"::1:5000"`` → ``"::1"``)."""
    host, sep, port = address.rpartition(":")
    return host if sep and port.isdigit() else address


class ConnectionGuard:
    """Admission and login-failure bookkeeping of one TPL2 server."""

    def __init__(self, settings: ServerSection, clock: Callable[[], float] = time.monotonic):
        self.settings = settings
        self.clock = clock
        self._failures: dict[str, deque] = {}
        self._locked_until: dict[str, float] = {}

    # -- connections ---------------------------------------------------------------------------
    def admit(self, host: str, sessions: Iterable) -> tuple[bool, bool, str]:
        """Decide about a new connection from ``host`` given the open ``sessions``.

        Returns
        -------
        (admitted, reserved, reason)
            ``reserved``: it took a slot of the level-0 reserve; ``reason``: why it was refused.
        """
        cfg = self.settings
        sessions = list(sessions)
        total = len(sessions)
        if total >= cfg.max_connections + cfg.admin_reserve:
            return False, False, "too many connections"
        if total >= cfg.max_connections:
            return True, True, ""
        same = [s for s in sessions if s.host == host]
        if len(same) >= cfg.max_per_address:
            return False, False, "too many connections from this address"
        if sum(1 for s in same if not s.authenticated) >= cfg.max_pending_per_address:
            return False, False, "too many connections from this address waiting to log in"
        return True, False, ""

    # -- logins --------------------------------------------------------------------------------
    def locked_out(self, host: str) -> bool:
        """True while ``host`` is locked out after too many failed logins."""
        until = self._locked_until.get(host)
        if until is None:
            return False
        if self.clock() < until:
            return True
        del self._locked_until[host]
        return False

    def failed(self, host: str) -> bool:
        """Count a failed login from ``host``; True when this failure locked the address out."""
        cfg = self.settings
        now = self.clock()
        times = self._failures.setdefault(host, deque())
        times.append(now)
        while times and times[0] < now - cfg.auth_lockout_time:
            times.popleft()
        if len(times) >= cfg.auth_lockout_failures:
            self._locked_until[host] = now + cfg.auth_lockout_time
            times.clear()
            return True
        self._prune(now)
        return False

    def succeeded(self, host: str) -> None:
        """A good login from ``host`` forgets its earlier failures."""
        self._failures.pop(host, None)

    def _prune(self, now: float) -> None:
        """Forget addresses whose failures are all outside the window (bounded memory)."""
        if len(self._failures) < 1024:
            return
        horizon = now - self.settings.auth_lockout_time
        for host in [h for h, t in self._failures.items() if not t or t[-1] < horizon]:
            del self._failures[host]
        for host in [h for h, u in self._locked_until.items() if u < now]:
            del self._locked_until[host]


__all__ = ["ConnectionGuard", "host_of"]
