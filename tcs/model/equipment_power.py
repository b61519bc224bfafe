"""Powering an equipment axis (focuser, filter wheel, derotator) for a front end's move.

:func:`power_axis` switches one axis on (main power first when allowed), waiting for a READY
or POWER sequence that runs instead of superseding it; :func:`shielded` runs the model's long
SET so that a front end's Halt (cancelling the awaiting task) neither cancels the SET nor
leaves an "exception never retrieved". Used by the Alpaca and INDI front ends.

What may touch it: the event loop (the front ends' handlers).
"""

from __future__ import annotations

import asyncio

from tcs.errors import ErrorNumber, TcsError


async def power_axis(telescope, axis, main: bool = True, timeout: float = 60.0) -> None:
    """Power on ``axis`` alone (what connecting a focuser, filter wheel or rotator does): main
    power first when it is off and ``main`` allows it (``CABINET.POWER=1``: every component is
    switched on, nothing moves or is referenced), then the axis's power. A READY or POWER
    sequence already running is waited for, not superseded. Nothing happens to a powered axis."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    cab = telescope.cabinet
    while telescope.operations.running == "ready" or cab.job_running("POWER"):
        if loop.time() > deadline:
            raise TcsError("the READY sequence did not end", ErrorNumber.TIMEOUT)
        await asyncio.sleep(0.05)
    if axis.power_state == 1.0:
        return
    if not cab.main_power:
        if not main:
            raise TcsError(f"{axis.module_name}: main power (CABINET.POWER) is off", ErrorNumber.INVMODE)
        await shielded(cab.set_power(1))
    if axis.power_state != 1.0:
        await shielded(axis.power(True))


def shielded(awaitable):
    """``asyncio.shield`` of the model's long SET, whose outcome is retrieved even when the one
    awaiting it was cancelled (a Halt): no "exception never retrieved" noise."""
    fut = asyncio.ensure_future(awaitable)
    fut.add_done_callback(lambda f: f.cancelled() or f.exception())
    return asyncio.shield(fut)
