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
model and computes on every read; its setters call the model's own methods. Its own state is
the Alpaca connection flag (``Connected``, shared by all clients as the interface defines it)
and the asynchronous operations its clients started:

* **Connect** (Platform 7, asynchronous): ``Connecting`` is True while :meth:`Device.prepare`
  runs (equipment: power on its own axis, :func:`power_axis`; a fraction of a second), then
  ``Connected`` is True — also when preparing failed (moves then say why they are refused).
  ``Connected=True`` (the older, synchronous way) waits for the same preparation.
  ``Disconnect`` never powers anything off.
* **Operations** (:meth:`Device.start_operation`): an initiator (Move, SlewToAzimuth, Park…)
  registers the awaitable of the model's long SET *before it replies*, so that the completion
  property read right after it (on any connection) already says "moving" — the axes' own
  motion bits follow a control cycle later. An operation that fails (anything but being
  superseded by a newer command or halted by the client) leaves its message for the next read
  of the completion property, which answers it once as a DriverError (0x500): a polling
  client learns that the operation failed instead of seeing it end silently.

Every handler returns within a control cycle or two (ConformU's targets: 0.1 s for state reads,
1 s for writes and initiators), except the synchronous members the interface defines as such
(``Connected=True``, the telescope's ``SlewTo…`` without Async, ``HaltCover``).

What may touch it: the event loop (through :class:`tcs.alpaca.server.AlpacaServer`).
"""

from __future__ import annotations

import asyncio
import datetime as _dt
import inspect
import logging
import time
import uuid
import weakref
from typing import Any

from tcs import __version__ as TCS_VERSION
from tcs.alpaca.protocol import AlpacaRequest, AscomError, BadRequest, Code, from_tcs_error, not_implemented
from tcs.errors import ErrorNumber, TcsError
from tcs.model.equipment_power import power_axis, shielded  # noqa: F401  (the equipment's)
from tcs.state_epoch import EPOCH, bump as bump_epoch

log = logging.getLogger(__name__)

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
#: What a client reads right after each common PUT (the rule of every member: ``RULES``).
COMMON_RULES: dict[str, str] = {
    "connect": "asynchronous: Connecting True until the device is prepared, then Connected True "
               "(at once when there is nothing to prepare)",
    "connected": "synchronous: True returns once prepared (Connected True right after); False at once",
    "disconnect": "synchronous: Connected False right after (nothing is powered off)",
    "action": "synchronous: done when the reply comes",
    "commandblind": "synchronous: the TPL2 SET has completed at the reply (STARTED after 25 s: poll its state)",
    "commandbool": "synchronous: as CommandBlind",
    "commandstring": "synchronous: as CommandBlind",
}
#: Members answered while not connected (everything else: NotConnected 0x407).
#: The PUT members a read-only server (``[alpaca] read_only``) still takes: the connection flag
#: (Connect then only sets it), without which a client cannot read.
READ_ONLY_PUTS = frozenset({"connect", "disconnect", "connected"})
UNCONNECTED = {"connected", "connecting", "connect", "disconnect", "description", "driverinfo",
               "driverversion", "interfaceversion", "name", "supportedactions"}


def utc_iso(utc: float) -> str:
    """ISO 8601 UTC with 7 fractional digits and ``Z`` (the form ASCOM documents for UTCDate)."""
    t = _dt.datetime.fromtimestamp(utc, _dt.timezone.utc)
    return t.strftime("%Y-%m-%dT%H:%M:%S.") + f"{t.microsecond:06d}0Z"


#: What a state read returns: never awaitable (no isawaitable check for them).
_PLAIN = frozenset((float, int, bool, str, type(None), list, dict))
#: What a state read may return to be reused (immutable).
_SCALARS = frozenset((float, int, bool, str, type(None)))

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
    #: Every PUT member of this interface: synchronous or asynchronous, and what a client reads
    #: right after the reply (the race suite checks the asynchronous ones). Every GET member is
    #: a state read computed at the request (within a control cycle) — or, for a member without
    #: parameters, the value read for it at most ``reuse_value`` seconds before while nothing
    #: changed (:mod:`tcs.state_epoch`: readbacks, PLC polls, every PUT once it has run).
    RULES: dict[str, str] = {}

    def rule(self, member: str) -> str:
        if getattr(self, f"put_{member}", None) is None:
            return "state read" if getattr(self, f"get_{member}", None) is not None else ""
        return self.RULES.get(member) or COMMON_RULES.get(member, "")

    def __init__(self, number: int, name: str, description: str, telescope, *, commands=None,
                 unique_seed: str = ""):
        self.number = number
        self.name = name
        self.description = description
        self.telescope = telescope
        self.commands = commands    # tcs.alpaca.commands.CommandBridge or None
        self.connected = False
        self._want_connected = False
        self._connecting: asyncio.Future | None = None
        self._operations: dict[str, asyncio.Future] = {}
        self._dropped: weakref.WeakSet = weakref.WeakSet()
        self._failure: str | None = None
        self._what: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()  # running task -> what
        self._quiet_failures = False   # DeviceState reads do not take a failure away
        self.referencing: asyncio.Future | None = None   # an axis referencing a first move started
        self.unique_id = str(uuid.uuid5(uuid.NAMESPACE_URL, f"tcs-alpaca:{unique_seed}:{self.TYPE}:{number}"))
        #: ``[server] reuse_reply``: seconds a state read's value answers the same member again
        self.reuse_value = 0.0
        #: ``[alpaca] read_only``: every PUT but the connection's own answers InvalidOperation
        #: (reads work; Connect sets the flag and powers nothing)
        self.read_only = False
        self._values: dict[str, tuple[int, float, Any]] = {}  # member -> (epoch, time, value)
        self._handlers: dict[tuple[str, str], Any] = {}  # (method, member) -> bound handler

    # -- dispatch -------------------------------------------------------------------------------
    def knows(self, member: str) -> bool:
        return member in COMMON_GET or member in COMMON_PUT or member in self.MEMBERS

    def begin(self, method: str, member: str, request: AlpacaRequest) -> tuple[bool, Any]:
        """Start the handler of ``method`` ``member`` now: ``(True, value)`` when it answered
        at once (every state read), ``(False, awaitable)`` for :meth:`finish` otherwise; raise
        BadRequest / AscomError. The server awaits only what needs awaiting (a task and a timer
        per state read were a quarter of a status poll's cost)."""
        handlers = self._handlers
        handler = handlers.get((method, member))
        if handler is None:
            if not self.knows(member):
                raise BadRequest(f"{self.NAME} has no member {member!r}")
            handler = getattr(self, f"{method.lower()}_{member}", None)
            if handler is None:
                other = "put" if method == "GET" else "get"
                if getattr(self, f"{other}_{member}", None) is not None or member in COMMON_GET + COMMON_PUT:
                    raise BadRequest(f"{member} does not accept {method}")
                raise not_implemented(f"{self.NAME}.{member}")
            handlers[(method, member)] = handler
        self.check_parameters(handler.__name__, request)
        if self.read_only and method == "PUT" and member not in READ_ONLY_PUTS:
            raise AscomError(Code.INVALID_OPERATION,
                             f"{self.NAME}.{member} refused: this Alpaca server is read-only "
                             f"([alpaca] read_only = true in the hardware file); it reads the "
                             f"telescope, moving and changing it is for OpenTCI/OpenTSI clients")
        if member not in UNCONNECTED and member not in self.ALWAYS and not self.connected:
            raise AscomError(Code.NOT_CONNECTED, f"{self.NAME} {self.number} is not connected")
        reusable = method == "GET" and self.reuse_value > 0 and not self._takes_parameters(handler.__name__)
        if reusable:  # a state read: the value just read, while nothing changed (tcs.state_epoch)
            kept = self._values.get(member)
            if kept is not None and kept[0] == EPOCH.value and time.monotonic() - kept[1] <= self.reuse_value:
                return True, kept[2]
            epoch, since = EPOCH.value, time.monotonic()
        try:
            result = handler(request)
        except TcsError as exc:
            raise from_tcs_error(exc) from None
        if reusable and type(result) in _SCALARS:
            self._values[member] = (epoch, since, result)
        if type(result) in _PLAIN or not inspect.isawaitable(result):
            return True, result
        return False, result

    @staticmethod
    async def finish(awaitable) -> Any:
        """The value of a handler's awaitable from :meth:`begin` (TcsError -> AscomError)."""
        try:
            return await awaitable
        except TcsError as exc:
            raise from_tcs_error(exc) from None

    def _takes_parameters(self, handler: str) -> bool:
        return bool(self.PARAMETERS.get(handler) or COMMON_PARAMETERS.get(handler))

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

    async def put_connected(self, r: AlpacaRequest) -> None:
        if not r.bool("Connected"):
            self._disconnect()
            return
        if not self.connected:
            await asyncio.shield(self._start_connect())

    def get_connecting(self, r: AlpacaRequest) -> bool:
        return self._connecting is not None and not self._connecting.done()

    def put_connect(self, r: AlpacaRequest) -> None:
        if not self.connected:
            self._start_connect()

    def put_disconnect(self, r: AlpacaRequest) -> None:
        self._disconnect()

    def _disconnect(self) -> None:
        self._want_connected = False
        self.connected = False

    def _start_connect(self) -> asyncio.Future:
        self._want_connected = True
        if self._connecting is not None and not self._connecting.done():
            return self._connecting
        if self.read_only or not self.needs_preparing():   # connected before the reply: nothing
            # to wait for (read-only: Connect powers nothing)
            self.connected = True
            done = asyncio.get_running_loop().create_future()
            done.set_result(None)
            return done

        async def run() -> None:
            try:
                await self.prepare()
            except Exception as exc:   # connected all the same: its moves say why they are refused
                log.warning("%s %s: preparing on connect failed: %s", self.NAME, self.number,
                            getattr(exc, "message", exc))
            finally:
                self.connected = self._want_connected

        self._connecting = asyncio.ensure_future(run())
        return self._connecting

    async def prepare(self) -> None:
        """What Connect does besides setting the flag: nothing here (see the equipment)."""

    def needs_preparing(self) -> bool:
        """True when :meth:`prepare` has something to do (Connect is then asynchronous)."""
        return False

    # -- asynchronous operations ------------------------------------------------------------------
    def start_operation(self, key: str, awaitable, what: str) -> None:
        """Run the model's long SET ``awaitable`` in the background as operation ``key``:
        :meth:`running` is True from now on until it ends (see the module docstring)."""
        if awaitable is None:
            return
        old = self._operations.get(key)
        if old is not None and not old.done():
            self._dropped.add(old)   # superseded by this one: its end is no failure
        task = asyncio.ensure_future(awaitable)
        self._operations[key] = task
        self._what[task] = what
        task.add_done_callback(self._settle)

    def _settle(self, f: asyncio.Future) -> None:
        """Record how operation ``f`` ended (its failure for the next completion read), once:
        from its done-callback, or earlier from :meth:`report_failure` — a read served between
        the task's end and its callback (the loop runs them in turn) must not find it neither
        running nor failed."""
        what = self._what.pop(f, None)
        if what is None or f.cancelled():
            return
        exc = f.exception()
        log.debug("%s %s: %s ended: %r", self.NAME, self.number, what, exc)
        if exc is None or f in self._dropped:
            return
        if isinstance(exc, TcsError) and exc.number == ErrorNumber.TARGETCHANGE:
            return   # superseded by a newer command
        self._failure = f"{what} failed: {getattr(exc, 'message', exc)}"
        bump_epoch()   # (a state read kept from before must not hide it)
        log.warning("%s %s: %s", self.NAME, self.number, self._failure)

    def running(self, key: str) -> bool:
        task = self._operations.get(key)
        return task is not None and not task.done()

    def drop_operation(self, key: str) -> None:
        """The client halted operation ``key``: it is no longer running, and its end is no failure
        (a sequence of steps of ours — power, reference, move — is cancelled: no later step runs)."""
        task = self._operations.pop(key, None)
        if task is not None:
            self._dropped.add(task)
            if isinstance(task, asyncio.Task):
                task.cancel()

    def halt_operation(self, key: str) -> None:
        """A Halt: operation ``key`` ends here (no later step runs). A referencing it started
        runs to its end — the drive's homing is not interrupted by the axis's stop — and stays
        the running operation ``key`` meanwhile (the completion read says moving until then)."""
        self.drop_operation(key)
        ref = self.referencing
        if ref is not None and not ref.done():
            self.start_operation(key, shielded(ref), "referencing")

    def report_failure(self) -> None:
        """Raise (once) the failure of the last operation that failed: a completion read calls it."""
        for task in [t for t in self._operations.values() if t.done()]:
            self._settle(task)   # (ended, its callback not yet run)
        if self._failure is not None and not self._quiet_failures:
            message, self._failure = self._failure, None
            raise AscomError(Code.DRIVER_ERROR, message)

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
                self._quiet_failures = True
                try:
                    value = getter(r)
                finally:
                    self._quiet_failures = False
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
                self._quiet_failures = True
                try:
                    value = getter(AlpacaRequest("GET", {}))
                finally:
                    self._quiet_failures = False
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


def make_ready_then(device, axis, move):
    """The awaitable of a move of an equipment axis: ``move()`` (the axis's long SET) at once
    when the axis is powered and referenced — so that its refusals are the request's — else a
    coroutine that powers the axis (not main power), references it, then starts ``move()``.
    The referencing is kept as ``device.referencing`` (see :meth:`Device.halt_operation`)."""
    telescope = device.telescope
    if axis.power_state == 1.0 and axis.referenced >= 1.0:
        return move()
    if not telescope.cabinet.main_power:
        raise AscomError(Code.INVALID_OPERATION, f"{axis.module_name}: main power (CABINET.POWER) is off")

    async def run():
        await power_axis(telescope, axis, main=False)
        if axis.referenced < 1.0:
            device.referencing = asyncio.ensure_future(axis.reference(False))
            await shielded(device.referencing)
        await shielded(move())
    return run()
