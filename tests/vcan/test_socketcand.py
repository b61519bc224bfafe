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
