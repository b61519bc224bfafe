"""Issue 14 item 1: one command's work is bounded (TPL2 over a real socket, the full service).

A range is checked against the array *before* it is expanded, so ``[0-999999999]`` answers
``DIMENSION`` at once instead of building a billion indices in the event loop (which stalled the
control loop for seconds). The work of one command is bounded by ``[server] max_objects``
(elements addressed) and ``max_reply_bytes``; an object past either answers ``DIMENSION``.
The time-outs below only keep the test from hanging on a server that stalls: they are far
beyond what a correct server needs.
"""

from __future__ import annotations

import pytest

from support.service import start_service
from support.tpl2 import RawClient


@pytest.mark.timeout(20, method="signal")  # the old server builds 10**9 indices: fail, do not hang
async def test_huge_range_is_dimension_without_expanding_it(service):
    _, port = service
    c = await RawClient.connect(port)
    observer = await RawClient.connect(port)
    await c.send("1 GET AZ.TRAJECTORY.BUFFER[0-999999999].TIME;AZ.TRAJECTORY.BUFFER[0,5-999999999].TIME;"
                 "AZ.TRAJECTORY.BUFFER[0].TIME[0-999999999]")
    assert await c.until(1, timeout=10) == [
        "1 COMMAND OK",
        "1 DATA INLINE AZ.TRAJECTORY.BUFFER[0-999999999].TIME=DIMENSION",
        "1 DATA INLINE AZ.TRAJECTORY.BUFFER[0,5-999999999].TIME=DIMENSION",
        "1 DATA INLINE AZ.TRAJECTORY.BUFFER[0].TIME[0-999999999]=INVALID",
        "1 COMMAND COMPLETE",
    ]
    # the same for a SET, and the server keeps serving everybody
    assert await c.command(2, "SET AZ.TRAJECTORY.BUFFER[0-999999999].TIME=1", timeout=10) == [
        "2 COMMAND OK", "2 DATA ERROR AZ.TRAJECTORY.BUFFER[0-999999999].TIME DIMENSION", "2 COMMAND COMPLETE"]
    assert (await observer.get("AZ.TRAJECTORY.BUFFER!COUNT")) == "120"
    await c.close()
    await observer.close()


async def test_objects_per_command_are_bounded(tmp_path):
    svc, port = await start_service(tmp_path / "state", max_objects=100)
    try:
        c = await RawClient.connect(port)
        # 100 elements are within the budget; the next object is past it
        lines = await c.command(1, "GET AZ.TRAJECTORY.BUFFER[0-99].TIME;AZ.REALPOS")
        assert lines[1].startswith("1 DATA INLINE AZ.TRAJECTORY.BUFFER[0-99].TIME=")
        assert lines[1].count(",") == 99
        assert lines[2] == "1 DATA INLINE AZ.REALPOS=DIMENSION"
        # one object selecting more than the budget: refused before it is expanded
        assert await c.command(2, "GET AZ.TRAJECTORY.BUFFER[0-100].TIME;AZ.REALPOS!NAME") == [
            "2 COMMAND OK", "2 DATA INLINE AZ.TRAJECTORY.BUFFER[0-100].TIME=DIMENSION",
            '2 DATA INLINE AZ.REALPOS!NAME="REALPOS"', "2 COMMAND COMPLETE"]
        # the budget is per command: the next command has its own
        assert (await c.get("AZ.REALPOS!NAME", cmd_id=3)) == '"REALPOS"'
        await c.close()
    finally:
        await svc.stop()


async def test_reply_size_is_bounded(tmp_path):
    svc, port = await start_service(tmp_path / "state", max_reply_bytes=2048)
    try:
        c = await RawClient.connect(port)
        objs = ";".join(["AZ.TRAJECTORY.BUFFER[0-119].TIME"] * 4)
        lines = await c.command(1, f"GET {objs}")
        data = lines[1:-1]
        assert len(data) == 4
        assert sum(len(x) for x in data) < 2048 + 4 * 64  # the reply stayed near the limit
        assert data[-1] == "1 DATA INLINE AZ.TRAJECTORY.BUFFER[0-119].TIME=DIMENSION"
        assert not data[0].endswith("=DIMENSION")
        await c.close()
    finally:
        await svc.stop()
