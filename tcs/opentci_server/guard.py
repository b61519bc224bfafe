"""Who may hold a TPL2 connection, and who may try a password: the server's exposure limits.

How it works
------------
One :class:`ConnectionGuard` per :class:`~tcs.opentci_server.server.Tpl2Server` (so every
listener of every tree gets the same protections, each with its own ``[server]`` settings).
The server asks it at every accepted connection (:meth:`ConnectionGuard.admit`); its
:class:`LoginThrottle` (:attr:`ConnectionGuard.logins`) at every login attempt
(:meth:`LoginThrottle.wait_before_check`, :meth:`LoginThrottle.failed`,
:meth:`LoginThrottle.fail_delay`). The servers of one telescope (OpenTCI and OpenTSI ports)
share one account table and therefore one throttle (``server_module.py`` joins them). Nothing
here does I/O or keeps time of its own: the clock is :func:`time.monotonic` unless a test
passes another.

Limits (all from the ``[server]`` section; docs/security.md lists them with their defaults):

- ``max_connections`` ordinary connections; past that, ``admin_reserve`` more, only for a
  level-0 user: a connection admitted into the reserve is *reserved* and is dropped when it
  logs in as anyone else. Reserved slots ignore the per-address limits, so silent sockets from
  one host cannot keep an operator who comes through the same host (an SSH tunnel) out.
- ``max_per_address`` connections and ``max_pending_per_address`` not-yet-logged-in
  connections from one IP address.

Logins: the attacker is slowed, the user with the password is never refused
----------------------------------------------------------------------------
There is no address lock-out: operators behind one SSH tunnel or NAT share an address with
whoever guesses there, and a correct password is never refused because someone else guessed
wrong. Instead:

- *per connection*: the n-th failed login of a connection is answered after
  ``auth_fail_delay * 2**(n-1)`` seconds (at most ``auth_backoff_max``), and the connection is
  dropped after ``auth_max_failures``;
- *per user name*: past ``auth_backoff_failures`` failed logins of one name (any address, any
  port) within ``auth_backoff_window`` seconds, every further login of that name — right or
  wrong password — is checked only after a back-off that doubles with each further failure,
  from ``auth_fail_delay`` up to ``auth_backoff_max``. The right password then gets ``AUTH OK``
  (late, never refused); a wrong one gets the back-off and the connection's delay. Delaying
  the check itself, for right and wrong passwords alike, leaves no timing difference an
  attacker could read early and abandon the connection on. Unknown names are tracked like
  known ones (names stay secret); past :data:`MAX_NAMES` names tracked at once, further names
  share one entry.

An attacker's rate is then bounded by the connections it may hold waiting
(``max_pending_per_address`` per address, ``max_connections`` in all) over the back-off, and
by the one password-hashing thread of the server.
"""

from __future__ import annotations

import time
from collections import deque
from typing import Callable, Iterable

from tcs.config.sections import ServerSection

#: Names whose failed logins are tracked at once; further names share one entry.
MAX_NAMES = 4096
_OTHERS = "\0others"  # the shared entry (no user name contains NUL)


def host_of(address: str) -> str:
    """The IP part of ``"host:port"`` (IPv6 ``"::1:5000"`` → ``"::1"``)."""
    host, sep, port = address.rpartition(":")
    return host if sep and port.isdigit() else address


class ConnectionGuard:
    """Admission and login-failure bookkeeping of one TPL2 server."""

    def __init__(self, settings: ServerSection, clock: Callable[[], float] = time.monotonic):
        self.settings = settings
        self.clock = clock
        #: Failed-login bookkeeping; shared by the servers of one account table.
        self.logins = LoginThrottle(settings, clock)

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
            return False, False, (f"too many connections from this address ({len(same)}, "
                                  f"max_per_address {cfg.max_per_address}): close some and retry")
        pending = sum(1 for s in same if not s.authenticated)
        if pending >= cfg.max_pending_per_address:
            return False, False, (f"too many connections from this address waiting to log in "
                                  f"({pending}, max_pending_per_address {cfg.max_pending_per_address}): "
                                  "retry in a moment")
        return True, False, ""


class LoginThrottle:
    """Failed logins per user name and the delays they cost (see the module docstring)."""

    def __init__(self, settings: ServerSection, clock: Callable[[], float] = time.monotonic):
        self.settings = settings
        self.clock = clock
        self._failures: dict[str, deque] = {}
        #: Failed logins counted since start (all names): what the attacker has spent.
        self.total_failures = 0

    def _key(self, user: str) -> str:
        if user in self._failures or len(self._failures) < MAX_NAMES:
            return user
        self._prune(self.clock())
        return user if len(self._failures) < MAX_NAMES else _OTHERS

    def _recent(self, user: str, now: float) -> deque | None:
        times = self._failures.get(self._key(user))
        if times is not None:
            while times and times[0] < now - self.settings.auth_backoff_window:
                times.popleft()
        return times

    def failures(self, user: str) -> int:
        """Failed logins of ``user`` within the window."""
        times = self._recent(user, self.clock())
        return len(times) if times else 0

    def backoff(self, user: str) -> float:
        """Seconds a login of ``user`` waits before its password is checked (0: none)."""
        cfg = self.settings
        over = self.failures(user) - cfg.auth_backoff_failures
        if over < 0:
            return 0.0
        return min(cfg.auth_backoff_max, max(cfg.auth_fail_delay, 0.001) * 2.0 ** min(over, 30))

    def wait_before_check(self, user: str) -> float:
        """The back-off of ``user`` now (the session sleeps it, then checks the password)."""
        return self.backoff(user)

    def failed(self, user: str) -> int:
        """Count a failed login of ``user``; returns its failures within the window."""
        now = self.clock()
        key = self._key(user)
        times = self._recent(key, now)
        if times is None:
            times = self._failures[key] = deque()
        times.append(now)
        if len(times) > 100_000:
            times.popleft()
        self.total_failures += 1
        return len(times)

    def fail_delay(self, conn_failures: int) -> float:
        """Seconds before the ``conn_failures``-th ``AUTH FAILED`` of one connection."""
        cfg = self.settings
        return min(max(cfg.auth_backoff_max, cfg.auth_fail_delay),
                   cfg.auth_fail_delay * 2.0 ** min(max(conn_failures - 1, 0), 30))

    def _prune(self, now: float) -> None:
        """Forget names whose failures are all outside the window (bounded memory)."""
        horizon = now - self.settings.auth_backoff_window
        for user in [u for u, t in self._failures.items() if not t or t[-1] < horizon]:
            del self._failures[user]


__all__ = ["ConnectionGuard", "LoginThrottle", "host_of"]
