"""The bundled simulated equatorial telescope (hwconfig/sim-equatorial.toml) serves HA and DEC
instead of AZ and ZD, and moves them."""

from __future__ import annotations

import asyncio

from support.service import start_service
from support.tpl2 import RawClient
from tcs.config.hwconfig import PACKAGE_ROOT

EQUATORIAL = PACKAGE_ROOT / "hwconfig" / "sim-equatorial.toml"


async def test_equatorial_telescope_moves_dec(tmp_path):
    svc, port = await start_service(tmp_path / "state", EQUATORIAL)
    try:
        c = await RawClient.connect(port)
        members = await c.members()
        assert {"HA", "DEC", "POINTING"} <= set(members) and "AZ" not in members
        assert await c.get("CONFIG.MOUNT") == '"RA-DEC"'
        assert (await c.command(1, "SET CABINET.POWER=1", timeout=60))[-2:] == [
            "1 DATA OK CABINET.POWER", "1 COMMAND COMPLETE"]
        await c.command(2, "SET DEC.REINIT=1")
        for _ in range(400):
            if await c.get("DEC.REFERENCED") == "1.0":
                break
            await asyncio.sleep(0.05)
        start = float(await c.get("DEC.REALPOS"))
        lines = await c.command(3, f"SET DEC.TARGETPOS={start + 1.0}", timeout=60)
        assert lines[-2:] == ["3 DATA OK DEC.TARGETPOS", "3 COMMAND COMPLETE"]
        assert abs(float(await c.get("DEC.REALPOS")) - (start + 1.0)) < 0.01
        await c.close()
    finally:
        await svc.stop()
