"""Is another master on the bus? Listen before sending anything.

Two masters on one CAN bus — two SYNC producers, two heartbeats with one node id, two
CiA-402 state machines per drive — is never safe: the second one's boot puts every drive back
to pre-operational under the first one's feet. So whoever is about to become the master
(``tcs-server`` at start, ``tcs-commission``) opens the bus *without* producing its heartbeat,
calls :func:`other_master` and sends its first frame only when the bus was quiet.

Another master shows itself by SYNC frames (0x080) or by a heartbeat with the TCS's own node
id (0x700 + ``[can] node_id``). A process never receives its own frames back on socketcan,
socketcand or python-can's virtual bus, so what is heard is somebody else. Listening for
2–3 heartbeat periods is enough: a running master sends SYNC every cycle and its heartbeat
every period. Runs in the caller's thread (blocking, at start); the notifier thread only
appends to a list.

Listening cannot tell two masters apart that start within the same listening window (each
hears a quiet bus). On one machine :func:`machine_lock` closes that gap: an abstract Unix
socket named after the bus (``tcs-can:socketcan:can0``) can be bound by one process only, is
released by the kernel when that process ends, however it ends, and needs no file or
permission. :func:`claim` takes the lock, then listens.
"""

from __future__ import annotations

import errno
import socket
import time

from tcs.errors import CommunicationError, ErrorNumber

SYNC_COB_ID = 0x080
HEARTBEAT_BASE = 0x700


class AnotherMaster(CommunicationError):
    """The bus already has a master: this process must not send a single frame on it."""

    default_number = ErrorNumber.CONFAIL


def listen_window(heartbeat_period: float) -> float:
    """How long to listen: 2.5 heartbeat periods, at least 0.3 s."""
    return max(0.3, 2.5 * heartbeat_period)


def other_master(network, tcs_node_id: int, listen: float) -> str | None:
    """Listen ``listen`` seconds on a connected canopen ``network`` for another master.

    Returns
    -------
    str or None
        What was heard ("SYNC frames (0x080)" or the heartbeat with our node id), or None
        when the bus was quiet; returns as soon as something is heard.
    """
    seen: list[str] = []

    def on_sync(cob_id, data, timestamp):
        seen.append("SYNC frames (0x080)")

    def on_heartbeat(cob_id, data, timestamp):
        seen.append(f"a heartbeat of node {tcs_node_id} (0x{HEARTBEAT_BASE + tcs_node_id:03X}), "
                    "the TCS's own node id")

    hb = HEARTBEAT_BASE + tcs_node_id
    network.subscribe(SYNC_COB_ID, on_sync)
    network.subscribe(hb, on_heartbeat)
    try:
        deadline = time.monotonic() + listen
        while not seen and time.monotonic() < deadline:
            time.sleep(0.01)
    finally:
        network.unsubscribe(SYNC_COB_ID, on_sync)
        network.unsubscribe(hb, on_heartbeat)
    return seen[0] if seen else None


def lock_name(can) -> str:
    """The machine-wide name of the bus of the ``[can]`` section ``can``."""
    where = f"@{can.host}:{can.port}" if can.interface == "socketcand" else ""
    return f"tcs-can:{can.interface}:{can.channel}{where}"


def machine_lock(can) -> socket.socket | None:
    """Hold the bus of ``can`` for this process on this machine (None for the in-process
    ``virtual`` bus); keep the returned socket open as long as the bus is used.

    Raises
    ------
    AnotherMaster
        Another process of this machine (``tcs-server``, ``tcs-commission``) holds it.
    """
    if can.interface == "virtual":
        return None
    name = lock_name(can)
    lock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        lock.bind("\0" + name)
    except OSError as exc:
        lock.close()
        if exc.errno == errno.EADDRINUSE:
            raise AnotherMaster(name, "another process of this machine is the master of this bus "
                                "(is tcs-server already running? systemctl status tcs-server); "
                                "nothing was sent on the bus") from None
        raise
    return lock


def claim(can_drives) -> socket.socket | None:
    """Become the master of the bus of ``can_drives`` (a :class:`~tcs.drivers.can_system.
    CanDrives`, not yet open): take :func:`machine_lock`, open the bus without the TCS
    heartbeat and listen for another master (blocking). On success the bus is open and silent
    (start the heartbeat next) and the lock is returned.

    Raises
    ------
    AnotherMaster
        Another process holds the bus here, or another master was heard; nothing was sent and
        the bus is closed again.
    """
    section = can_drives.can
    lock = machine_lock(section)
    try:
        can_drives.open(False)  # no heartbeat yet: not a frame is sent
        try:
            busy = other_master(can_drives.bus.network, section.node_id,
                                listen_window(section.heartbeat_period))
        except BaseException:
            can_drives.close()
            raise
        if busy:
            can_drives.close()
            raise AnotherMaster(can_drives.bus.name, f"another master is active ({busy}): is "
                                "tcs-server already running (systemctl status tcs-server)? "
                                "Nothing was sent on the bus")
    except BaseException:
        if lock is not None:
            lock.close()
        raise
    return lock
