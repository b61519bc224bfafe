"""CONFIG: the telescope's configuration as clients see it (OpenTCI §7).

``MOUNTOPTIONS`` and ``MOUNT`` come from the hardware file. The tree of modules is built from
the active mount at start, so switching mounts at run time is not supported: writing the
active mount again succeeds, writing another listed option fails with 5 (invmode) and an
event saying that the hardware file and a restart change it, anything else is ``RANGE``.
``ORIENTATION`` (ZD-ZD tube orientation) is writable and persisted.
"""

from __future__ import annotations

from tcs.config import HwConfig
from tcs.errors import ErrorNumber, RangeRefused, TcsError
from tcs.model.health import ModuleHealth
from tcs.model.state_store import StateStore


class MountConfig(ModuleHealth):
    """Domain object of the CONFIG module."""

    def __init__(self, config: HwConfig, store: StateStore, events=None):
        super().__init__("CONFIG", events)
        self._store = store
        self.mount = config.mount.type
        self.options = config.mount_options
        saved = store.get("config", {}) or {}
        configured = config.mount.orientation
        self._orientation = saved.get("orientation", configured) if saved.get(
            "orientation_config") == configured else configured
        self._orientation_config = configured
        #: Set by the dome issue's code: the CONFIG.DOME sub-module object, or None.
        self.dome = None

    @property
    def mount_options(self) -> str:
        return ",".join(self.options)

    def set_mount(self, value: str) -> None:
        value = value.strip().upper()
        if value not in self.options:
            raise RangeRefused(f"mount {value!r} is not one of {self.mount_options}")
        if value != self.mount:
            raise TcsError(f"switching the mount to {value} needs the hardware file and a restart",
                           ErrorNumber.INVMODE)

    @property
    def orientation(self) -> float:
        return self._orientation

    def set_orientation(self, value: float) -> None:
        self._orientation = float(value)
        self._store.update(config={"orientation": self._orientation,
                                   "orientation_config": self._orientation_config})
