"""Waiting for a state: :func:`until` in blocking (thread-side) tests — the Alpaca tests drive
the telescope through alpyca's synchronous client, so they poll instead of awaiting — and
:func:`until_async` on a test's event loop (a driver's state that has no event to await)."""

from __future__ import annotations

import asyncio
import time


def until(condition, what: str, timeout: float, period: float = 0.05):
    """Poll ``condition()`` until it is true (its value is returned); fail naming ``what``
    after ``timeout`` s. Never a timing assertion: the time-out is a generous limit."""
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(period)


async def until_async(condition, what: str, timeout: float, period: float = 0.05):
    """:func:`until` on the event loop: the loop runs on between the looks."""
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        await asyncio.sleep(period)


def alpaca_address(live) -> str:
    """host:port of the Alpaca server of a :class:`support.live.LiveService`."""
    return f"127.0.0.1:{live.service.alpaca_port}"
