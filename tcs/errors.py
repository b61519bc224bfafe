"""The one root error type of the TCS and the OpenTCI error/event numbers (spec Appendix B).

Every layer raises :class:`TcsError` (or a subclass) for anything a client or an operator must
hear about. An error carries

* ``number`` — the OpenTCI Appendix B number (``ErrorNumber``), used in ``DATA ERROR … FAILED n``
  replies and in events, and
* ``keyword`` — optionally a TPL2 error keyword (``RANGE``, ``TYPE``, ``DENIED``, ``INVALID``,
  ``UNKNOWN``, ``DIMENSION``, ``BUSY``) when the request itself was refused rather than failed.

The TPL2 server turns these into reply text at exactly one place (``TcsError.reply``); drivers
and the telescope model never format protocol lines themselves.
"""

from __future__ import annotations

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


class CommunicationError(HardwareError):
    """No communication with a device (timeout, closed connection, missing heartbeat)."""

    default_number = ErrorNumber.NOCON
