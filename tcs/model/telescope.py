"""The telescope model: every domain object of one hardware file, built and owned in one place.

:class:`Telescope` is what the OpenTCI declaration binds to. It creates the event hub, the
persistent state store, LOCAL and CONFIG, and (as the hardware issues add them) the cabinet,
axes, dome, covers, sensors, switches, GPS and pointing. Hardware is started and stopped with
:meth:`start` / :meth:`stop` on the server's event loop; attributes that are ``None`` (or empty
lists) are modules the hardware file does not configure, and so do not exist in the tree.
"""

from __future__ import annotations

import logging

from tcs.config import HwConfig
from tcs.model.events import EventHub
from tcs.model.local import LocalTime
from tcs.model.mount_config import MountConfig
from tcs.model.state_store import StateStore

log = logging.getLogger(__name__)


class Telescope:
    """All domain objects of one telescope."""

    def __init__(self, config: HwConfig):
        self.config = config
        self.events = EventHub()
        self.state_dir = config.state_dir()
        self.store = StateStore(self.state_dir)
        self.local = LocalTime(config, self.store, self.events)
        self.mount_config = MountConfig(config, self.store, self.events)

    def modules_health(self):
        """Every domain object with an ERROR_STATE (for CABINET.ERROR_STATE)."""
        return [m for m in (self.local, self.mount_config) if m is not None]

    async def start(self) -> None:
        """Bring up the hardware (nothing yet in the foundation)."""
        self.events.bind_loop()

    async def stop(self) -> None:
        """Stop motion and leave the hardware safe (nothing yet in the foundation)."""
