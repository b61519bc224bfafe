"""The socketcand server of the simulated cabinet against python-can's own socketcand client:
frames both ways, no echo to the sender, malformed lines answered, several clients."""

from __future__ import annotations

import asyncio
import logging
import uuid

import can
import pytest

from tcs.sim.socketcand_server import SocketcandServer, parse_send

logging.getLogger("can.interfaces.socketcand").setLevel(logging.ERROR)


@pytest.fixture
async def bridge():
    channel = f"tcs-sc-{uuid.uuid4().hex[:8]}"
    server = SocketcandServer(channel)
    port = await server.start()
    peer = can.Bus(interface="virtual", channel=channel)
    try:
        yield server, port, peer
    finally:
        peer.shutdown()
        await server.stop()


def client_bus(port: int) -> can.BusABC:
    return can.Bus(interface="socketcand", host="127.0.0.1", port=port, channel="can0")


async def recv(bus: can.BusABC, timeout: float = 5.0) -> can.Message | None:
    return await asyncio.to_thread(bus.recv, timeout)


async def test_frames_both_ways(bridge):
    server, port, peer = bridge
    client = await asyncio.to_thread(client_bus, port)
    try:
        await asyncio.sleep(0.3)  # rawmode settles
        client.send(can.Message(arbitration_id=0x601, data=[0x40, 0x18, 0x10, 0x01, 0, 0, 0, 0],
                                is_extended_id=False))
        got = await recv(peer)
        assert got.arbitration_id == 0x601 and bytes(got.data) == bytes([0x40, 0x18, 0x10, 1, 0, 0, 0, 0])
        peer.send(can.Message(arbitration_id=0x581, data=[0x43, 1, 2, 3], is_extended_id=False))
        got = await recv(client)
        assert got.arbitration_id == 0x581 and bytes(got.data) == bytes([0x43, 1, 2, 3])
        peer.send(can.Message(arbitration_id=0x1ABCDEF0, data=[], is_extended_id=True))
        got = await recv(client)
        assert got.is_extended_id and got.arbitration_id == 0x1ABCDEF0 and got.dlc == 0
    finally:
        await asyncio.to_thread(client.shutdown)
    for _ in range(100):
        if not server.clients:
            break
        await asyncio.sleep(0.02)


async def test_other_clients_see_a_frame_but_not_the_sender(bridge):
    server, port, peer = bridge
    a = await asyncio.to_thread(client_bus, port)
    b = await asyncio.to_thread(client_bus, port)
    try:
        await asyncio.sleep(0.3)
        a.send(can.Message(arbitration_id=0x080, data=[], is_extended_id=False))
        got = await recv(b)
        assert got.arbitration_id == 0x080
        assert await recv(a, timeout=0.3) is None
    finally:
        await asyncio.to_thread(a.shutdown)
        await asyncio.to_thread(b.shutdown)
    for _ in range(100):
        if not server.clients:
            break
        await asyncio.sleep(0.02)


@pytest.mark.parametrize("body", ["send 800 0", "send 123 2 01", "send 123 9 1 2 3 4 5 6 7 8 9",
                                  "send xyz 1 00", "send 20000000 0"])
def test_malformed_send_is_refused(body):
    assert parse_send(body) is None


async def test_malformed_lines_are_ignored_and_the_connection_goes_on(bridge):
    server, port, peer = bridge
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    assert await reader.readexactly(6) == b"< hi >"
    writer.write(b"< open can0 >< rawmode >")
    assert await reader.readexactly(12) == b"< ok >< ok >"
    await asyncio.sleep(0.3)
    writer.write(b"< send 123 2 00 >< frob >< send 123 1 7f >")
    got = await recv(peer)
    assert got.arbitration_id == 0x123 and bytes(got.data) == b"\x7f"
    assert server.refused == 2
    writer.close()
    await writer.wait_closed()


async def test_many_threads_send_through_our_bus_while_the_gateway_stalls(bridge):
    """The TCS sends from several threads at once (cycle, SDO worker, heartbeat task); over
    socketcand every frame must arrive intact and in each sender's order, also when the
    gateway stops reading for a while and then gets a burst of hundreds of KiB (it dropped the
    connection on such a burst: "64 KiB without a frame"). Our bus serializes sends there."""
    import threading
    import time

    from tcs.config.can import CanSection
    from tcs.drivers.canbus import CanBus

    server, port, peer = bridge
    got: list[can.Message] = []
    listener = can.Notifier(peer, [got.append], timeout=0.1)
    section = CanSection(interface="socketcand", channel="can0", port=port, heartbeat_period=0.01)
    bus = await asyncio.to_thread(CanBus(section).open)   # (its heartbeat task sends too)
    threads, count = 6, 1500
    try:
        await asyncio.sleep(0.3)  # rawmode settles

        def sender(k: int) -> None:
            for i in range(count):
                data = bytes([k, i >> 8, i & 0xFF, 0xA5, 0x5A, k, 0xC3, 0x3C])
                if i % 2:
                    bus.send(0x200 + k, data)                    # the cycle's path
                else:
                    bus.network.send_message(0x200 + k, data)    # canopen's (SDO) path

        workers = [threading.Thread(target=sender, args=(k,)) for k in range(threads)]
        for w in workers:
            w.start()
        time.sleep(1.0)  # the gateway (this event loop) is busy: nothing is read meanwhile
        while any(w.is_alive() for w in workers):
            await asyncio.sleep(0.01)
        deadline = time.monotonic() + 30
        while sum(1 for m in got if 0x200 <= m.arbitration_id < 0x200 + threads) < threads * count:
            assert time.monotonic() < deadline, f"{len(got)} frames arrived"
            await asyncio.sleep(0.05)
    finally:
        await asyncio.to_thread(bus.close)
        listener.stop()
    frames = [m for m in got if 0x200 <= m.arbitration_id < 0x200 + threads]
    for k in range(threads):
        mine = [bytes(m.data) for m in frames if m.arbitration_id == 0x200 + k]
        assert mine == [bytes([k, i >> 8, i & 0xFF, 0xA5, 0x5A, k, 0xC3, 0x3C]) for i in range(count)]
    heartbeats = [m for m in got if m.arbitration_id == 0x700 + section.node_id]
    assert heartbeats and all(bytes(m.data) == b"\x05" for m in heartbeats)
    assert server.refused == 0 and bus.reconnects == 0
