"""Issue 12, protocol items 1-8: what an audit against TPL2 2.1 found, over a real socket.

Each test names the item it covers. They run against the default simulated telescope
(``hwconfig/sim.toml``: ``DEROTATOR[2]``/``[3]``, ``FILTER[2]``) unless they say otherwise.
"""

from __future__ import annotations

import asyncio
import re
from pathlib import Path


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
    assert await c.get("CABINET.STATUS!MEMBERS") == "5"  # GLOBAL, LIST, CLEAR, LOG, TEXT
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
    # the same substructure down to the trajectory buffer's size (TPL2 §8.3), every element absent
    assert await c.get("DEROTATOR[1].TRAJECTORY.BUFFER!COUNT") == await c.get("DEROTATOR[2].TRAJECTORY.BUFFER!COUNT") == "120"
    assert await c.get("DEROTATOR[1].TRAJECTORY.BUFFER[119].TIME") == "FAILED 4"
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
        "1 COMMAND OK", "1 DATA ERROR AZ.TRAJECTORY.BUFFER[0-2].TIME ,TYPE,", "1 COMMAND COMPLETE"]
    assert await c.get("AZ.TRAJECTORY.BUFFER[0].TIME") == "100.5"
    assert await c.get("AZ.TRAJECTORY.BUFFER[2].TIME") == "300.25"
    # absent derotators refuse in their slots, the real one is written
    assert await c.command(2, "SET DEROTATOR[1-2].CURRSPEED=1.5,1.5") == [
        "2 COMMAND OK", "2 DATA ERROR DEROTATOR[1-2].CURRSPEED FAILED 4,", "2 COMMAND COMPLETE"]
    # a value count that does not match is still the whole object's DIMENSION
    assert await c.command(3, "SET AZ.TRAJECTORY.BUFFER[0-2].TIME=1,2") == [
        "3 COMMAND OK", "3 DATA ERROR AZ.TRAJECTORY.BUFFER[0-2].TIME DIMENSION", "3 COMMAND COMPLETE"]
    await c.close()


# ------------------------------------------------------------------ item 5: ABORT by extended id


async def test_abort_of_another_connections_extended_id(service):
    _, port = service
    a = await RawClient.connect(port)
    b = await RawClient.connect(port)
    weak = await RawClient.connect(port, login=None)
    await weak.send('AUTH PLAIN "admin" "admin" 5 5')  # asks for less privilege
    assert await weak.readline() == "AUTH OK 5 5"
    conn_a = int(await a.get("SERVER.CONNECTION.ID"))
    conn_b = int(await b.get("SERVER.CONNECTION.ID"))
    await a.send("4 SET CABINET.POWER=1")  # long-running
    assert await a.readline() == "4 COMMAND OK"
    extended = (conn_a << 32) | 4
    assert await weak.command(1, f"ABORT {extended}") == ["1 COMMAND ERROR DENIED", "1 COMMAND FAILED"]
    assert await b.command(7, f"ABORT {(conn_a << 32) | 5}") == [
        "7 COMMAND ERROR NOTRUNNING", "7 COMMAND FAILED"]
    assert await b.command(8, f"ABORT {extended}", timeout=30) == ["8 COMMAND OK", "8 COMMAND COMPLETE"]
    assert (await a.until(4, timeout=30))[-1] == f"4 COMMAND ABORTEDBY {(conn_b << 32) | 8}"
    # one's own extended id names one's own commands
    assert await a.command(6, f"ABORT {(conn_a << 32) | 99}") == ["6 COMMAND ERROR NOTRUNNING", "6 COMMAND FAILED"]
    for x in (a, b, weak):
        await x.close()


# ------------------------------------------------------------------ item 6: string slices


async def test_string_slices(service):
    _, port = service
    c = await RawClient.connect(port)
    assert await c.get("CONFIG.MOUNT") == '"AZ-ZD"'
    assert await c.get("CONFIG.MOUNT{0:1}") == '"AZ"'  # characters 0..1, inclusive
    assert await c.get("CONFIG.MOUNT{3:99}") == '"ZD"'  # clipped to the string
    assert await c.get("CONFIG.MOUNT{9:12}") == '""'
    # TPL2 §4.1.2: an omitted bound is the string's start or end; a start past the end is ""
    assert await c.get("CONFIG.MOUNT{:2}") == '"AZ-"'
    assert await c.get("CONFIG.MOUNT{3:}") == '"ZD"'
    assert await c.get("CONFIG.MOUNT{:}") == '"AZ-ZD"'
    assert await c.get("CONFIG.MOUNT{100:}") == '""'
    assert await c.get("LOCAL.LATITUDE{0:1}") == "TYPE"  # not a STRING
    assert await c.get("CONFIG.MOUNT{0:1}!NAME") == "TYPE"
    # a bad slice fails its object only, never the whole GET
    lines = await c.command(2, "GET CONFIG.MOUNT{3:1};CONFIG.MOUNT{x};CONFIG{0:1}.MOUNT;CONFIG.MOUNT{0:0};"
                               "SERVER.VERSION")
    assert lines[1:5] == ["2 DATA INLINE CONFIG.MOUNT{3:1}=DIMENSION", "2 DATA INLINE CONFIG.MOUNT{x}=DIMENSION",
                          "2 DATA INLINE CONFIG{0:1}.MOUNT=DIMENSION", '2 DATA INLINE CONFIG.MOUNT{0:0}="A"']
    assert lines[5].startswith('2 DATA INLINE SERVER.VERSION="tcs '), lines
    assert await c.command(3, 'SET CONFIG.MOUNT{0:1}="AZ"') == [
        "3 COMMAND OK", "3 DATA ERROR CONFIG.MOUNT{0:1} TYPE", "3 COMMAND COMPLETE"]
    await c.close()


# ------------------------------------------------------------------ item 7: error vocabulary


async def test_error_vocabulary(service):
    _, port = service
    c = await RawClient.connect(port)
    assert await c.command(1, "SET LOCAL.LATITUDE=NULL") == [
        "1 COMMAND OK", "1 DATA ERROR LOCAL.LATITUDE TYPE", "1 COMMAND COMPLETE"]
    # variables served as writable accept writes; where the part cannot, they are read-only
    assert await c.get("AZ.OFFSET!WLEVEL") == "3"
    assert await c.get("DOME[0].OFFSET!WLEVEL") == "3"  # the dome rotation takes an offset
    for obj in ("FILTER[2].OFFSET", "MIRROR.OFFSET", "COVER.OFFSET", "DOME[1].OFFSET",
                "DOME[0].CURRSPEED", "DOME[3].CURRSPEED", "COVER.CURRSPEED"):
        assert await c.get(f"{obj}!WLEVEL") == "-1", obj
    assert await c.command(2, "SET MIRROR.OFFSET=1") == [
        "2 COMMAND OK", "2 DATA ERROR MIRROR.OFFSET DENIED", "2 COMMAND COMPLETE"]
    assert await c.get("AZ.CURRSPEED!WLEVEL") == "3"
    # a value the variable cannot take: RANGE; a computation that cannot run: FAILED n
    lines = await c.command(3, 'SET POINTING.POINTINGPARAMS.DUMPFILE="../x"')
    assert lines[1] == "3 DATA ERROR POINTING.POINTINGPARAMS.DUMPFILE RANGE", lines
    lines = await c.command(4, 'SET POINTING.POINTINGPARAMS.LOAD="no-such-model"')
    assert lines[1] == "4 DATA ERROR POINTING.POINTINGPARAMS.LOAD RANGE", lines
    lines = await c.command(5, "SET POINTING.POINTINGPARAMS.CALCULATE=1", timeout=30)
    assert lines[-2] == "5 DATA ERROR POINTING.POINTINGPARAMS.CALCULATE FAILED 1013", lines
    # trajectory points: decreasing times are RANGE; ADDPOINTS of empty slots is FAILED 11
    lines = await c.command(6, "SET AZ.TRAJECTORY.ADDPOINTS=2")
    assert lines[-2] == "6 DATA ERROR AZ.TRAJECTORY.ADDPOINTS FAILED 11", lines
    await c.close()


# ------------------------------------------------------------------ item 8: ASCII on the wire


async def test_every_description_and_value_is_ascii(service):
    svc, port = service
    c = await RawClient.connect(port)
    objects = []
    for path, node in svc.server.tree.walk():
        objects.append(f"{path}!INFO")
        if hasattr(node, "spec") and node.spec.count is None:
            objects.append(path)
    raw = b""
    for i in range(0, len(objects), 200):
        await c.send(f"{10 + i} GET " + ";".join(objects[i:i + 200]))
        while True:
            line = await c.readraw()
            raw += line
            if line.startswith(f"{10 + i} COMMAND COMPLETE".encode()):
                break
    assert raw.isascii()
    octal = re.findall(rb"[^\n]{0,40}\\[0-7]{3}[^\n]{0,10}", raw)
    assert not octal, octal[:5]
    assert b'"degC"' in raw  # SENSOR[].UNIT "°C" of the hardware file
    assert await c.get("SERVER.CONNECTION.ADDRESS") == '"127.0.0.1"'
    await c.close()


# ------------------------------------------------------------------ item 14: value precision


async def test_sensor_values_print_at_their_resolution(service):
    """hwconfig/sim.toml scales its PLC registers by 0.1 and 0.01 and has a float32 point: a
    reading prints at its resolution (9.6, not 9.600000000000001; a float32 with the fewest
    digits that are the same float32), and nothing of it is lost."""
    _, port = service
    c = await RawClient.connect(port)
    count = int(await c.get("SENSOR!COUNT"))
    for _ in range(20):  # the simulated weather moves: several readings
        values = (await c.get(f"SENSOR[0-{count - 1}].VALUE")).split(",")
        floats = [v for v in values if "." in v]
        assert floats, values
        for v in floats:  # 0.1/0.01-scaled integers, and a float32 (at most 9 significant digits)
            assert len(v.lstrip("-").replace(".", "").strip("0")) <= 9, values
        await asyncio.sleep(0.05)
    await c.close()


# ------------------------------------------------------------------ pass 3, item 8


async def test_placeholder_elements_share_the_configured_elements_substructure(service):
    """TPL2 §8.3: the elements of a module array have one substructure. FILTER[2] (a discrete
    wheel) has no TRAJECTORY, so neither have the placeholders FILTER[0] and FILTER[1]; the
    derotators, which stream, have it in every element."""
    _, port = service
    c = await RawClient.connect(port)
    assert await c.get("FILTER[0]!MEMBERS") == await c.get("FILTER[2]!MEMBERS")
    assert await c.get("FILTER[2].TRAJECTORY.RUN") == await c.get("FILTER[0].TRAJECTORY.RUN")
    assert await c.get("FILTER[0].TRAJECTORY.RUN") in ("UNKNOWN", "INVALID")
    assert await c.get("DEROTATOR[0]!MEMBERS") == await c.get("DEROTATOR[2]!MEMBERS")
    assert await c.get("DEROTATOR[0].TRAJECTORY.FREEPOINTS") == "FAILED 4"
    await c.close()
