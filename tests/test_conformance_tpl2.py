"""Issue 12, protocol items 1-8: what an audit against TPL2 2.1 found, over a real socket.

Each test names the item it covers. They run against the default simulated telescope
(``hwconfig/sim.toml``: ``DEROTATOR[2]``/``[3]``, ``FILTER[2]``) unless they say otherwise.
"""

from __future__ import annotations

import asyncio
import re
from pathlib import Path

import pytest

from support.service import start_service
from support.tpl2 import RawClient

HW = Path(__file__).resolve().parent.parent / "hwconfig"


# ------------------------------------------------------------------ item 1: properties


async def test_members_is_the_number_of_members_and_walks_the_tree(service):
    _, port = service
    c = await RawClient.connect(port)
    n = int(await c.get("!MEMBERS"))
    names = [await c.get(f"<{i}>!NAME", cmd_id=i + 1) for i in range(n)]
    assert names[:3] == ['"SERVER"', '"LOCAL"', '"CONFIG"']
    local = await c.members("LOCAL")
    assert local[0] == "VERSION" and "LATITUDE" in local
    assert await c.get("CABINET.STATUS!MEMBERS") == "4"
    await c.close()


async def test_attached_callback_and_write_only_variables(service):
    _, port = service
    c = await RawClient.connect(port)
    assert await c.get("LOCAL!ATTACHED") == "0"
    assert await c.get("DEROTATOR!ATTACHED") == "0"
    assert await c.get("DEROTATOR[2]!ATTACHED") == "0"
    assert await c.get("!ATTACHED") == "UNKNOWN"  # the root is no module
    assert await c.get("LOCAL.UTC!CALLBACK") == '""'
    assert await c.get("LOCAL.UTC!CALLBACKTYPE") == "0"
    for obj in ("AZ.REINIT", "AZ.STOP", "CABINET.STOP", "CABINET.REINIT", "CABINET.STATUS.CLEAR",
                "POINTING.POINTINGPARAMS.SAMPLE", "POINTING.POINTINGPARAMS.SAVE",
                "POINTING.POINTINGPARAMS.ERASE", "POINTING.POINTINGPARAMS.LOADFILE"):
        assert await c.get(f"{obj}!RLEVEL") == "-1", obj
        assert await c.get(obj) == "DENIED", obj
    assert await c.command(5, "SET AZ.STOP=1") == ["5 COMMAND OK", "5 DATA OK AZ.STOP", "5 COMMAND COMPLETE"]
    await c.close()


# ------------------------------------------------------------------ item 2: module arrays


async def test_every_module_array_element_has_the_full_member_set(service):
    """DEROTATOR[0]/[1] have no hardware: the same members as DEROTATOR[2], VERSION 0 (the
    spec's availability test), every other variable FAILED 4; COUNT and indices stay the ports."""
    _, port = service
    c = await RawClient.connect(port)
    assert await c.get("DEROTATOR!COUNT") == "4"
    full = int(await c.get("DEROTATOR[2]!MEMBERS"))
    assert int(await c.get("DEROTATOR[0]!MEMBERS")) == full
    for i in range(full):
        assert await c.get(f"DEROTATOR[0].<{i}>!NAME", cmd_id=200 + i) == await c.get(
            f"DEROTATOR[2].<{i}>!NAME", cmd_id=300 + i)
    assert await c.get("DEROTATOR[0].VERSION") == "0"
    assert await c.get("DEROTATOR[0].TYPE") == "0"
    assert await c.get("DEROTATOR[2].VERSION") != "0"
    assert await c.get("DEROTATOR[1].REALPOS") == "FAILED 4"
    assert await c.get("DEROTATOR[1].REALPOS!TYPE") == "2"
    assert await c.get("DEROTATOR[1].TRAJECTORY.BUFFER!COUNT") == "0"
    assert await c.get("FILTER[0].MOTION_STATE") == "FAILED 4"
    assert await c.command(7, "SET DEROTATOR[0].TARGETPOS=10") == [
        "7 COMMAND OK", "7 DATA ERROR DEROTATOR[0].TARGETPOS FAILED 4", "7 COMMAND COMPLETE"]
    await c.close()


async def test_rollroof_dome_zero_has_members(tmp_path):
    svc, port = await start_service(tmp_path / "state", HW / "sim-rollroof.toml")
    try:
        c = await RawClient.connect(port)
        assert await c.get("DOME[0].VERSION") == "0"
        assert await c.get("DOME[0].REALPOS") == "FAILED 4"
        assert await c.get("DOME[1].VERSION") != "0"
        await c.close()
    finally:
        await svc.stop()


# ------------------------------------------------------------------ item 3: per element


async def test_ranges_answer_per_element(service):
    _, port = service
    c = await RawClient.connect(port)
    version = await c.get("DEROTATOR[2].VERSION")
    assert await c.get("DEROTATOR[0-3].VERSION") == f"0,0,{version},{version}"
    assert await c.get("DEROTATOR[0-3].REALPOS!TYPE") == "2,2,2,2"
    assert (await c.get("DEROTATOR[1-2].POWER_STATE")).startswith("FAILED 4,")
    # a member that some elements lack: UNKNOWN in their slots only
    lines = await c.command(3, "GET DOME[0-1].TRAJECTORY.FREEPOINTS")
    slots = lines[1].split("=", 1)[1].split(",")
    assert slots[1] == "UNKNOWN" and slots[0].isdigit(), lines
    # an index beyond the array is still the whole object's DIMENSION
    assert await c.get("DEROTATOR[0-4].VERSION") == "DIMENSION"
    await c.close()


async def test_multi_element_set_answers_and_writes_per_element(service):
    _, port = service
    c = await RawClient.connect(port)
    # BUFFER points: a TIME past the range of FLOAT is TYPE in its slot, the others are written
    assert await c.command(1, 'SET AZ.TRAJECTORY.BUFFER[0-2].TIME=100.5,"x",300.25') == [
        "1 COMMAND OK", "1 DATA ERROR AZ.TRAJECTORY.BUFFER[0-2].TIME OK,TYPE,OK", "1 COMMAND COMPLETE"]
    assert await c.get("AZ.TRAJECTORY.BUFFER[0].TIME") == "100.5"
    assert await c.get("AZ.TRAJECTORY.BUFFER[2].TIME") == "300.25"
    # absent derotators refuse in their slots, the real one is written
    assert await c.command(2, "SET DEROTATOR[1-2].CURRSPEED=1.5,1.5") == [
        "2 COMMAND OK", "2 DATA ERROR DEROTATOR[1-2].CURRSPEED FAILED 4,OK", "2 COMMAND COMPLETE"]
    # a value count that does not match is still the whole object's DIMENSION
    assert await c.command(3, "SET AZ.TRAJECTORY.BUFFER[0-2].TIME=1,2") == [
        "3 COMMAND OK", "3 DATA ERROR AZ.TRAJECTORY.BUFFER[0-2].TIME DIMENSION", "3 COMMAND COMPLETE"]
    await c.close()
