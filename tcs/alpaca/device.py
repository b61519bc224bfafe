"""What every Alpaca device has: the common members, dispatch by member name, DeviceState.

How it works
------------
A device class declares its interface by its methods: ``get_<member>`` answers a GET of
``/api/v1/<type>/<n>/<member>``, ``put_<member>`` a PUT (member names in lower case, as in
the URL). A handler takes the :class:`~tcs.alpaca.protocol.AlpacaRequest`, may be a coroutine,
and returns the ``Value`` (GET) or nothing (PUT). ``MEMBERS`` lists every member of the ASCOM
interface: one that the interface has but this device does not implement answers
NotImplemented (0x400); a name outside the interface is a malformed request (HTTP 400).
``STATE`` names the members whose values make up ``DeviceState``.

A device holds no telescope state (``docs/architecture.md`` rule 0): it wraps parts of the
model and computes on every read; its setters call the model's own methods. Its only state is
the Alpaca connection flag (``Connected``, shared by all clients as the interface defines it).

What may touch it: the event loop (through :class:`tcs.alpaca.server.AlpacaServer`).
"""

from __future__ import annotations

import datetime as _dt
import inspect
import uuid
from typing import Any

from tcs import __version__ as TCS_VERSION
from tcs.alpaca.protocol import AlpacaRequest, AscomError, BadRequest, Code, from_tcs_error, not_implemented
from tcs.errors import TcsError

COMMON_GET = ("connected", "connecting", "description", "driverinfo", "driverversion",
              "interfaceversion", "name", "supportedactions", "devicestate")
COMMON_PUT = ("connect", "disconnect", "connected", "action", "commandblind", "commandbool",
              "commandstring")
#: The parameters of the common members: handler name -> ((name, kind), ...); kind is an
#: ``AlpacaRequest`` accessor (``float``, ``int``, ``bool``, ``text``), ``?`` = optional.
COMMON_PARAMETERS: dict[str, tuple[tuple[str, str], ...]] = {
    "put_connected": (("Connected", "bool"),),
    "put_action": (("Action", "text"), ("Parameters", "text")),
    **{f"put_{m}": (("Command", "text"), ("Raw", "bool?"))
       for m in ("commandblind", "commandbool", "commandstring")},
}
#: Members answered while not connected (everything else: NotConnected 0x407).
UNCONNECTED = {"connected", "connecting", "connect", "disconnect", "description", "driverinfo",
               "driverversion", "interfaceversion", "name", "supportedactions"}


def utc_iso(utc: float) -> str:
    """ISO 8601 UTC with 7 fractional digits and ``Z`` (the form ASCOM documents for UTCDate)."""
    t = _dt.datetime.fromtimestamp(utc, _dt.timezone.utc)
    return t.strftime("%Y-%m-%dT%H:%M:%S.") + f"{t.microsecond:06d}0Z"


class Device:
    """Base of every Alpaca device (see the module docstring)."""

    TYPE = ""              #: the URL's device type, lower case (``telescope``)
    NAME = ""              #: the ASCOM DeviceType (``Telescope``)
    INTERFACE_VERSION = 1
    MEMBERS: tuple[str, ...] = ()   #: the interface's own members (lower case)
    STATE: tuple[str, ...] = ()     #: members reported by DeviceState
    ALWAYS: frozenset[str] = frozenset()   #: members of this interface answered while not connected
    #: The parameters of this interface's members, as :data:`COMMON_PARAMETERS` (the ASCOM
    #: interface's own list): checked before anything else, so a missing or malformed one is
    #: HTTP 400 whatever the connection state.
    PARAMETERS: dict[str, tuple[tuple[str, str], ...]] = {}

    def __init__(self, number: int, name: str, description: str, telescope, *, commands=None,
                 unique_seed: str = ""):
        self.number = number
        self.name = name
        self.description = description
        self.telescope = telescope
        self.commands = commands    # tcs.alpaca.commands.CommandBridge or None
        self.connected = False
        self.unique_id = str(uuid.uuid5(uuid.NAMESPACE_URL, f"tcs-alpaca:{unique_seed}:{self.TYPE}:{number}"))

    # -- dispatch -------------------------------------------------------------------------------
    def knows(self, member: str) -> bool:
        return member in COMMON_GET or member in COMMON_PUT or member in self.MEMBERS

    async def call(self, method: str, member: str, request: AlpacaRequest) -> Any:
        """Run the handler of ``method`` ``member``; raise BadRequest / AscomError."""
        if not self.knows(member):
            raise BadRequest(f"{self.NAME} has no member {member!r}")
        handler = getattr(self, f"{method.lower()}_{member}", None)
        if handler is None:
            other = "put" if method == "GET" else "get"
            if getattr(self, f"{other}_{member}", None) is not None or member in COMMON_GET + COMMON_PUT:
                raise BadRequest(f"{member} does not accept {method}")
            raise not_implemented(f"{self.NAME}.{member}")
        self.check_parameters(handler.__name__, request)
        if member not in UNCONNECTED and member not in self.ALWAYS and not self.connected:
            raise AscomError(Code.NOT_CONNECTED, f"{self.NAME} {self.number} is not connected")
        try:
            result = handler(request)
            if inspect.isawaitable(result):
                result = await result
        except TcsError as exc:
            raise from_tcs_error(exc) from None
        return result

    def check_parameters(self, handler: str, request: AlpacaRequest) -> None:
        """BadRequest (HTTP 400) unless every parameter ``handler`` takes is there and parses
        (Alpaca API: a malformed request is 400 in any state, before NotConnected)."""
        for name, kind in self.PARAMETERS.get(handler) or COMMON_PARAMETERS.get(handler, ()):
            if kind.endswith("?"):
                if request.raw(name) is None:
                    continue
                kind = kind[:-1]
            getattr(request, kind)(name)

    # -- common members ---------------------------------------------------------------------------
    def get_connected(self, r: AlpacaRequest) -> bool:
        return self.connected

    def put_connected(self, r: AlpacaRequest) -> None:
        self.connected = r.bool("Connected")

    def get_connecting(self, r: AlpacaRequest) -> bool:
        return False    # Connect completes at once: the model is always there

    def put_connect(self, r: AlpacaRequest) -> None:
        self.connected = True

    def put_disconnect(self, r: AlpacaRequest) -> None:
        self.connected = False

    def get_description(self, r: AlpacaRequest) -> str:
        return self.description

    def get_driverinfo(self, r: AlpacaRequest) -> str:
        return f"tcs telescope control system, ASCOM Alpaca front end over the telescope model ({self.name})"

    def get_driverversion(self, r: AlpacaRequest) -> str:
        return str(TCS_VERSION)

    def get_interfaceversion(self, r: AlpacaRequest) -> int:
        return int(self.INTERFACE_VERSION)

    def get_name(self, r: AlpacaRequest) -> str:
        return self.name

    def get_supportedactions(self, r: AlpacaRequest) -> list[str]:
        return []

    def put_action(self, r: AlpacaRequest) -> str:
        name = r.text("Action")
        r.text("Parameters")
        raise AscomError(Code.ACTION_NOT_IMPLEMENTED, f"action {name!r} is not supported")

    async def _command(self, r: AlpacaRequest) -> str:
        command = r.text("Command")
        raw = r.raw("Raw")
        if raw is not None and raw.strip().lower() not in ("true", "false"):
            raise BadRequest(f"parameter Raw={raw!r} is not true or false")
        if self.commands is None:
            raise not_implemented("Command*")
        return await self.commands.run(command)

    async def put_commandblind(self, r: AlpacaRequest) -> None:
        await self._command(r)

    async def put_commandstring(self, r: AlpacaRequest) -> str:
        return await self._command(r)

    async def put_commandbool(self, r: AlpacaRequest) -> bool:
        text = (await self._command(r)).strip().strip('"').lower()
        if text in ("1", "true", "ok", "complete", "started"):
            return True
        if text in ("0", "false", ""):
            return False
        try:
            return float(text) != 0.0
        except ValueError:
            raise AscomError(Code.INVALID_OPERATION, f"{text!r} is not a boolean answer") from None

    async def get_devicestate(self, r: AlpacaRequest) -> list[dict[str, Any]]:
        out = []
        for member in self.STATE:
            getter = getattr(self, f"get_{member}", None)
            if getter is None:
                continue   # not implemented here: left out
            try:
                value = getter(r)
                if inspect.isawaitable(value):
                    value = await value
            except (AscomError, TcsError, BadRequest):
                continue   # not available now: left out, as the interface allows
            out.append({"Name": self._state_name(member), "Value": value})
        out.append({"Name": "TimeStamp", "Value": utc_iso(self.telescope.local.utc())})
        return out

    def _state_name(self, member: str) -> str:
        return self.STATE_NAMES.get(member, member)

    STATE_NAMES: dict[str, str] = {}

    # -- /setup --------------------------------------------------------------------------------
    def setup_rows(self) -> list[tuple[str, str]]:
        """(name, value) pairs for the /setup page: the DeviceState members, read now."""
        rows = []
        for member in self.STATE:
            getter = getattr(self, f"get_{member}", None)
            if getter is None:
                continue
            try:
                value = getter(AlpacaRequest("GET", {}))
                if inspect.isawaitable(value):
                    value.close()
                    continue
            except (AscomError, TcsError, BadRequest) as exc:
                value = f"({getattr(exc, 'message', exc)})"
            rows.append((self._state_name(member), str(value)))
        return rows

    def configured(self) -> dict[str, Any]:
        return {"DeviceName": self.name, "DeviceType": self.NAME, "DeviceNumber": self.number,
                "UniqueID": self.unique_id}


def need(condition: bool, code: int, message: str) -> None:
    if not condition:
        raise AscomError(code, message)


def axis_ready(axis, what: str) -> None:
    """InvalidOperation unless ``axis`` is powered and referenced."""
    if axis.power_state != 1.0 or axis.referenced < 1.0:
        raise AscomError(Code.INVALID_OPERATION, f"{what}: {axis.module_name} is not powered and referenced")
