"""Persistent state that must survive a restart of the service (values written by clients,
the operator's status list, …), kept as one JSON document per store in the state directory.

Writes are atomic: the new document goes to a temporary file in the same directory, is
flushed and fsync'ed, then renamed over the old one, so a kill at any moment leaves either
the old or the new file, never a broken one. A file that cannot be parsed at start is moved
aside (``name.json.corrupt-<time>``) and reported in the log; the service starts with defaults
rather than refusing to run. A kill at the wrong moment can leave the temporary file
(``.name.json.<random>``) behind: the store deletes such orphans when it opens (one process
owns a state directory: a second ``tcs-server`` is refused).

Owners (LOCAL, CABINET.STATUS, …) call :meth:`StateStore.get` at start and
:meth:`StateStore.update` when a value changes; nothing else touches the files.
"""

from __future__ import annotations

import json
import logging
import os
import re
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)


class StateStore:
    """A small JSON key/value document at ``directory/name.json``."""

    def __init__(self, directory: Path, name: str = "state"):
        self.path = Path(directory) / f"{name}.json"
        self._lock = threading.Lock()
        self._remove_orphans()
        self._data: dict[str, Any] = self._load()

    def _remove_orphans(self) -> None:
        """Delete temporary files a killed writer left (exactly the names :meth:`_write` makes)."""
        pattern = re.compile(rf"\.{re.escape(self.path.name)}\.[A-Za-z0-9_]{{6,12}}")
        try:
            names = os.listdir(self.path.parent)
        except OSError:
            return
        for name in names:
            if pattern.fullmatch(name):
                try:
                    os.unlink(self.path.parent / name)
                    log.info("removed %s, left by an interrupted write", self.path.parent / name)
                except OSError as exc:
                    log.warning("cannot remove the orphan %s: %s", name, exc)

    def _load(self) -> dict[str, Any]:
        try:
            text = self.path.read_text(encoding="utf-8")
        except FileNotFoundError:
            return {}
        except OSError as exc:
            log.error("cannot read state file %s: %s; starting with defaults", self.path, exc)
            return {}
        try:
            data = json.loads(text)
            if not isinstance(data, dict):
                raise ValueError("not a JSON object")
            return data
        except ValueError as exc:
            aside = self.path.with_name(f"{self.path.name}.corrupt-{int(time.time())}")
            log.error("state file %s is unreadable (%s); moved to %s, starting with defaults",
                      self.path, exc, aside)
            try:
                os.replace(self.path, aside)
            except OSError:
                pass
            return {}

    def get(self, key: str, default: Any = None) -> Any:
        with self._lock:
            return self._data.get(key, default)

    def update(self, **values: Any) -> None:
        """Set keys and write the document atomically."""
        with self._lock:
            self._data.update(values)
            self._write()

    def _write(self) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", dir=self.path.parent)
        try:
            with os.fdopen(fd, "w", encoding="utf-8") as f:
                json.dump(self._data, f, indent=1, sort_keys=True)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, self.path)
        except BaseException:
            try:
                os.unlink(tmp)
            except OSError:
                pass
            raise
        try:  # make the rename itself durable
            dfd = os.open(self.path.parent, os.O_DIRECTORY)
            try:
                os.fsync(dfd)
            finally:
                os.close(dfd)
        except OSError:
            pass


class StateDirectoryLock:
    """This process's claim on a state directory: an exclusive ``flock`` on ``<dir>/.lock``.

    Two services that share a state directory (two ``tcs-server`` started from files named
    ``sim.toml`` by one user, say) would overwrite each other's state, status list, pointing
    model and accounts. The kernel drops the lock whenever its holder ends, so a crash leaves
    nothing to clean up. The file holds the holder's pid, for the message to the second one.
    """

    def __init__(self, directory: Path):
        import fcntl

        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        path = self.directory / ".lock"
        self._file = open(path, "a+", encoding="ascii")
        try:
            fcntl.flock(self._file, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            self._file.seek(0)
            holder = self._file.read().strip() or "?"
            self._file.close()
            from tcs.errors import TcsError
            raise TcsError(f"the state directory {self.directory} is in use by another tcs-server "
                           f"(pid {holder}): give this one its own with [state] path in the hardware "
                           "file or another XDG_STATE_HOME") from None
        self._file.seek(0)
        self._file.truncate()
        self._file.write(f"{os.getpid()}\n")
        self._file.flush()

    def release(self) -> None:
        if not self._file.closed:
            self._file.close()  # closing the file drops the lock
