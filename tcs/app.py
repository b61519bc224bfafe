"""The service: telescope model + TPL2 server, started and stopped together.

:class:`Service` is what ``tcs-server`` runs and what the end-to-end tests start in-process:
``await service.start()`` builds the telescope from the hardware file, brings the hardware
(or simulators) up, builds the OpenTCI tree and listens; ``await service.stop()`` ends
pending commands with ``COMMAND FAILED``, stops all motion, leaves the hardware safe and
closes every socket.
"""

from __future__ import annotations

import asyncio
import gc
import logging

from tcs.config import HwConfig
from tcs.model.telescope import Telescope
from tcs.notify import Notifier, serving_status
from tcs.opentci_server.opentci import build_tree
from tcs.opentci_server.server import Tpl2Server, loop_shares_interpreter

log = logging.getLogger(__name__)


class Service:
    """One running TCS."""

    def __init__(self, config: HwConfig, host: str | None = None, port: int | None = None,
                 opentsi_port: int | None = None, alpaca_port: int | None = None,
                 web_port: int | None = None, alpaca_discovery_port: int | None = None,
                 indi_port: int | None = None):
        self.config = config
        self.host = host
        self.port = port
        self.telescope: Telescope | None = None
        self.server: Tpl2Server | None = None
        #: The OpenTSI tree's listener (``[server] opentsi_port`` ≥ 0), same users and model.
        self.opentsi_server: Tpl2Server | None = None
        self.opentsi_port = config.server.opentsi_port if opentsi_port is None else opentsi_port
        #: The ASCOM Alpaca HTTP server (``[alpaca] port`` ≥ 0), same model.
        self.alpaca_server = None
        self.alpaca_port = config.alpaca.port if alpaca_port is None else alpaca_port
        #: Alpaca's UDP discovery port (``[alpaca] discovery_port``; -1: no discovery).
        self.alpaca_discovery_port = (config.alpaca.discovery_port if alpaca_discovery_port is None
                                      else alpaca_discovery_port)
        #: The read-only status page and /metrics (``[web] port`` ≥ 0; :mod:`tcs.web`).
        self.web_server = None
        self.web_port = config.web.port if web_port is None else web_port
        #: The INDI devices (``[indi] port`` ≥ 0; :mod:`tcs.indi`), same model.
        self.indi_server = None
        self.indi_port = config.indi.port if indi_port is None else indi_port

    async def start(self) -> int:
        """Start everything; returns the TPL2 port.

        Order: bind the TPL2 port and every other listening port (OpenTSI, Alpaca and its
        discovery, the web port; :mod:`tcs.listeners`) — a port that cannot be bound ends the
        start here with :class:`~tcs.listeners.PortInUse` naming its role, address and the flag
        or key that moves it, before the hardware is touched — then start the telescope (which
        refuses a CAN bus that already has a master before sending anything on it), build the
        tree, then accept connections, each front end taking over its reserved port.
        """
        from tcs.listeners import Reservation, listeners

        self.telescope = Telescope(self.config)
        self.server = Tpl2Server(self.config.server, self.config.users, self.telescope.events,
                                 manufacturer=self.config.cabinet.manufacturer,
                                 shares_interpreter=loop_shares_interpreter(self.config))
        wanted = {listener.role: listener for listener in listeners(self)}
        reserved = Reservation()
        try:
            await self._listen(wanted, "TPL2 (OpenTCI) port",
                               self.server.start(self.host, self.port, serve=False))
            await reserved.take([x for role, x in wanted.items() if role != "TPL2 (OpenTCI) port"])
            await self.telescope.start()  # its stop() on failure releases the state directory
        except BaseException:
            reserved.release_all()
            await self.server.stop()
            self.telescope.release_state_dir()
            raise
        self.server.tree = build_tree(self.telescope, self.server)
        try:
            reserved.release("TPL2 TLS port")
            port = await self._listen(wanted, "TPL2 TLS port", self.server.start(self.host, self.port))
            if self.opentsi_port >= 0:
                from tcs.opentsi import build_opentsi_server
                self.opentsi_server = build_opentsi_server(self.config, self.telescope)
                reserved.release("OpenTSI port")
                self.opentsi_port = await self._listen(
                    wanted, "OpenTSI port", self.opentsi_server.start(self.host, self.opentsi_port))
            if self.alpaca_port >= 0:
                from tcs.alpaca.start import start_alpaca
                reserved.release("Alpaca port")
                reserved.release("Alpaca discovery port (UDP)")
                self.alpaca_server = await self._listen(wanted, "Alpaca port", start_alpaca(self))
                self.alpaca_port = self.alpaca_server.port
            if self.web_port >= 0:
                from tcs.web.server import start_web
                reserved.release("web port")
                self.web_server = await self._listen(wanted, "web port", start_web(self))
                self.web_port = self.web_server.port
            if self.indi_port >= 0:
                from tcs.indi import start_indi
                reserved.release("INDI port")
                self.indi_server = await self._listen(wanted, "INDI port", start_indi(self))
                self.indi_port = self.indi_server.port
            return port
        except BaseException:
            reserved.release_all()
            await self.stop()
            raise

    @staticmethod
    async def _listen(wanted: dict, role: str, starting):
        """Await ``starting`` (a front end's start); an OSError of its bind becomes the
        :class:`~tcs.listeners.PortInUse` of ``role`` (or of the port the error names)."""
        from tcs.listeners import port_error

        try:
            return await starting
        except OSError as exc:
            text = str(exc)
            for listener in wanted.values():  # which port it was (Alpaca: HTTP or discovery)
                if f", {listener.port})" in text:
                    raise port_error(listener, exc) from None
            if role in wanted:
                raise port_error(wanted[role], exc) from None
            raise

    async def stop(self) -> None:
        if self.indi_server is not None:
            await self.indi_server.stop()
        if self.web_server is not None:
            await self.web_server.stop()
        if self.alpaca_server is not None:
            await self.alpaca_server.stop()
        if self.opentsi_server is not None:
            await self.opentsi_server.stop()
        if self.server is not None:
            await self.server.stop()
        if self.telescope is not None:
            await self.telescope.stop()

    async def __aenter__(self) -> "Service":
        await self.start()
        return self

    async def __aexit__(self, *exc) -> None:
        await self.stop()


def freeze_heap() -> None:
    """Collect once and freeze what exists now (the hardware model, the tree, every imported
    module) out of the garbage collector's reach, until :func:`thaw_heap`.

    For long-running processes only (``tcs-server``, ``tcs-sim``), once they are up: a full
    collection walks the whole heap with the GIL held — 20-50 ms here, several control cycles —
    and after this it walks only what was made since (about 1 ms).
    """
    gc.collect()
    gc.freeze()


def thaw_heap() -> None:
    """Undo :func:`freeze_heap` once stopped, so that what was frozen is collected as usual
    (nanobind, under ruckig, reports objects still alive at exit as leaks)."""
    gc.unfreeze()


async def serve_until_signalled(service: Service, stop: asyncio.Event, notifier: Notifier | None = None) -> None:
    """Run ``service`` until ``stop`` is set (by SIGINT/SIGTERM), telling systemd about it:
    ``READY=1`` once it serves, ``WATCHDOG=1`` while the control loop is healthy, ``STATUS=``
    lines, ``STOPPING=1``."""
    notifier = notifier or Notifier()
    notifier.send("STATUS=starting: booting the hardware")
    port = await service.start()
    freeze_heap()
    host = service.host or service.config.server.host
    notifier.send("READY=1", serving_status(service, host, port))
    watchdog = asyncio.get_running_loop().create_task(_watchdog(service, notifier))
    try:
        await stop.wait()
    finally:
        log.info("stopping")
        notifier.send("STOPPING=1", "STATUS=stopping: ending commands, stopping motion, disabling drives")
        watchdog.cancel()
        try:
            await watchdog
        except asyncio.CancelledError:
            pass
        await service.stop()
        thaw_heap()
        notifier.close()


async def _watchdog(service: Service, notifier: Notifier) -> None:
    interval = notifier.watchdog_interval()
    if interval is None or not notifier.enabled:
        return
    while True:
        await asyncio.sleep(interval)
        loop = service.telescope.control_loop if service.telescope else None
        # alive = the loop ran at all since the previous check (a busy host makes it late,
        # not dead); a loop that did not run for a whole interval is dead: no ping
        if loop is None or loop.healthy(within=interval):
            notifier.send("WATCHDOG=1")
        else:
            log.error("control loop has not run for %.1f s: withholding the systemd watchdog",
                      interval)
