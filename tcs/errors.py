"""The one root error type of the TCS and the OpenTCI error/event numbers (spec Appendix B).

Every layer raises :class:`TcsError` (or a subclass) for anything a client or an operator must
hear about. An error carries

* ``number`` — the OpenTCI Appendix B number (``ErrorNumber``), used in ``DATA ERROR … FAILED n``
  replies and in events, and
* ``keyword`` — optionally a TPL2 error keyword (``RANGE``, ``TYPE``, ``DENIED``, ``INVALID``,
  ``UNKNOWN``, ``DIMENSION``, ``BUSY``) when the request itself was refused rather than failed.

The TPL2 server turns these into reply text at exactly one place (``TcsError.reply``); drivers
and the telescope model never format protocol lines themselves.

:func:`gather_all` awaits several requests (two axes of a slew) and raises the first error only
once all have ended, so no error is left unretrieved in a future nobody awaits.
"""

from __future__ import annotations

import asyncio
import enum


class ErrorNumber(enum.IntEnum):
    """OpenTCI Appendix B error and event numbers."""

    UNKNOWN = 1
    LIBFAIL = 2
    CONFAIL = 3
    NOCON = 4
    INVMODE = 5
    LOCALMODE = 6
    TIMEOUT = 7
    LIMIT = 8
    SOFTLIMIT = 9
    TARGETCHANGE = 10
    NOPOINTS = 11
    NOBUFFER = 12
    INTERNAL = 13
    LATCHCHANGE = 14
    ERRORCHANGE = 15
    MANUALCONTROL = 16
    MODECHANGE = 17
    REFERENCE_EXECUTE = 18
    REFERENCE_GOOD = 19
    REFERENCE_BAD = 20
    POWERCHANGE = 21
    LIMITCHANGE = 22
    MOTIONCHANGE = 23
    POSITION_LOOSE = 24
    POSITION_GOOD = 25
    TIME_LOOSE = 26
    TIME_GOOD = 27
    LEAPSEC = 28
    TRAJ_GOOD = 29
    TRAJ_LOOSE = 30
    TRAJ_LOWPOINTS = 31
    TRAJ_STOP = 32


#: Every event/error number the server sends, with its meaning: Appendix B (1-32) and the
#: project's own (from 1000; each defined beside the code that sends it). The text of an event
#: sent without one, and the table of the generated reference (``tools/opentci_reference.py``).
EVENT_MEANINGS: dict[int, str] = {
    1: "unknown error", 2: "a hardware library failed", 3: "communication error with the hardware",
    4: "no communication with the hardware", 5: "invalid operation mode (power off, not referenced, fault)",
    6: "local (manual) operation only", 7: "timeout while positioning", 8: "limit reached",
    9: "software limit reached", 10: "target changed (superseded, stopped or aborted)",
    11: "trajectory cannot start: no points", 12: "no more trajectory buffers", 13: "internal error",
    14: "TCS state change", 15: "errors changed", 16: "manual control setting changed",
    17: "operation mode changed", 18: "referencing started", 19: "referenced",
    20: "not referenced (referencing failed or stopped)", 21: "power changed",
    22: "limit switch state changed", 23: "movement state changed", 24: "GPS position uncertain",
    25: "GPS position good", 26: "clock uncertain", 27: "clock good", 28: "leap second inserted",
    29: "trajectory runs, accuracy good", 30: "trajectory runs but not accurate",
    31: "trajectory almost at its end", 32: "trajectory ended",
    1000: "trajectory points already in the past were dropped",
    1010: "POINTING: an axis cannot follow (zenith/limit), tracking limited",
    1011: "POINTING: the axis follows again", 1012: "POINTING: the dome does not follow",
    1013: "POINTING: the pointing-model fit cannot run (too few samples, inseparable terms)",
    1014: "POINTING: tracking started or changed (target, orientation, followers)",
    1015: "POINTING: tracking ended as asked",
    1020: "weather interlock changed", 1021: "weather: closing the enclosure",
}


def event_text(number: int, text: str = "") -> str:
    """``text``, or the meaning of ``number`` when there is no text (every event has one)."""
    return text or EVENT_MEANINGS.get(int(number), f"event {int(number)}")


class TcsError(Exception):
    """Root of every error the TCS reports.

    Parameters
    ----------
    message:
        Human-readable text (goes to logs, events and STATUS.LIST comments).
    number:
        OpenTCI Appendix B number; defaults to ``INTERNAL`` (13).
    keyword:
        TPL2 error keyword when the request was refused (``RANGE``, ``TYPE`` …); ``None`` means
        the action failed and the reply is ``FAILED <number>``.
    """

    default_number: int = ErrorNumber.INTERNAL
    default_keyword: str | None = None

    def __init__(self, message: str = "", number: int | None = None, keyword: str | None = None):
        super().__init__(message)
        self.message = message
        self.number = int(number if number is not None else self.default_number)
        self.keyword = keyword if keyword is not None else self.default_keyword

    @property
    def reply(self) -> str:
        """The TPL2 error text: the keyword, or ``FAILED <number>``."""
        return self.keyword if self.keyword else f"FAILED {self.number}"

    def __str__(self) -> str:  # pragma: no cover - trivial
        return self.message or self.reply


class RequestRefused(TcsError):
    """A request refused before anything happened; ``keyword`` is the TPL2 keyword."""

    default_keyword = "INVALID"


class RangeRefused(RequestRefused):
    default_keyword = "RANGE"


class TypeRefused(RequestRefused):
    default_keyword = "TYPE"


class AccessDenied(RequestRefused):
    default_keyword = "DENIED"


class UnknownObject(RequestRefused):
    default_keyword = "UNKNOWN"


class ConfigError(TcsError):
    """A hardware configuration file is wrong: ``file``, ``key`` path and ``problem``."""

    def __init__(self, file: str, key: str, problem: str):
        self.file, self.key, self.problem = file, key, problem
        where = f"{file}: {key}" if key else file
        super().__init__(f"{where}: {problem}", ErrorNumber.INTERNAL)


class ConfigErrors(TcsError):
    """Several configuration problems found in one pass (all are reported, not only the first)."""

    def __init__(self, errors: list[ConfigError]):
        self.errors = errors
        super().__init__("\n".join(e.message for e in errors), ErrorNumber.INTERNAL)


class HardwareError(TcsError):
    """A device failed or could not be reached; ``device`` names it (node, PLC, port)."""

    default_number = ErrorNumber.LIBFAIL

    def __init__(self, device: str, message: str, number: int | None = None):
        self.device = device
        super().__init__(f"{device}: {message}", number)


class ConfigMismatch(HardwareError):
    """The hardware file does not fit the drive, found when only the drive could tell (its
    0x6502 read at boot): the message names the object and the remedy; acknowledging the
    fault cannot help (``remedy_in_message``)."""

    remedy_in_message = True


class CommunicationError(HardwareError):
    """No communication with a device (timeout, closed connection, missing heartbeat)."""

    default_number = ErrorNumber.NOCON


async def gather_all(*awaitables) -> list:
    """Await every one of ``awaitables``; raise the first error after all have ended.

    ``asyncio.gather`` raises as soon as one fails and leaves the others' errors in futures
    nobody retrieves (``Future exception was never retrieved … drive left operation enabled``
    when a stop ends both axes of a slew)."""
    results = await asyncio.gather(*awaitables, return_exceptions=True)
    for result in results:
        if isinstance(result, BaseException):
            raise result
    return results
