"""CommandBlind / CommandBool / CommandString: a TPL2 GET or SET of either variable tree.

Alpaca-only automation reaches ASTELCO-style telescopes this way (Astra sends
``CommandString("TELESCOPE.READY_STATE")``). The command text is one of::

    VARIABLE                 GET VARIABLE             (the reply is the wire text of the value)
    VARIABLE=VALUE           SET VARIABLE=VALUE       (the reply is "OK" once the SET completed,
                                                       "STARTED" if it still runs after ``timeout``)

optionally prefixed by ``OpenTCI:`` or ``OpenTSI:`` to choose the tree. Without a prefix the
OpenTSI tree is asked first (the tree Alpaca-side ASTELCO clients speak), then the OpenTCI
tree (``POINTING.TRACK`` exists in both with different meanings: use the prefix for it).

The trees are the same declarations the TPL2 listeners serve, over the same model: this bridge
only parses the text, resolves it and awaits a long SET for up to ``timeout`` seconds (a longer
one, such as READY=1 on a real telescope, goes on: poll its state variables). Reads and
writes run at operator level (read and write level 3: configuration variables are denied).
A refused SET is an ASCOM InvalidValue (RANGE, TYPE) or InvalidOperation (anything else) with
the TPL2 keyword in the message; an unknown variable is InvalidValue.
"""

from __future__ import annotations

import asyncio
import re

from tcs.alpaca.protocol import AscomError, Code
from tcs.errors import RangeRefused, TcsError, TypeRefused

OPERATOR_LEVEL = 3
_VALUE_KEYWORDS = {"UNKNOWN", "INVALID", "DENIED", "DIMENSION", "RANGE", "TYPE"}
_COMMAND = re.compile(r"\s*(?:(?P<tree>opentci|opentsi)\s*:\s*)?(?:(?P<verb>get|set)\s+)?(?P<rest>.*?)\s*\Z",
                      re.IGNORECASE | re.DOTALL)


class _Levels:
    """What the tree asks of a connection: its read and write levels."""

    rlevel = OPERATOR_LEVEL
    wlevel = OPERATOR_LEVEL
    user = "alpaca"


class CommandBridge:
    """GET/SET of the OpenTSI and OpenTCI trees (either may be None: not served)."""

    def __init__(self, opentci_tree=None, opentsi_tree=None, timeout: float = 25.0):
        self.trees = {"OPENTSI": opentsi_tree, "OPENTCI": opentci_tree}
        self.timeout = timeout
        self.conn = _Levels()

    def _order(self, name: str | None) -> list:
        if name:
            tree = self.trees.get(name.upper())
            if tree is None:
                raise AscomError(Code.INVALID_OPERATION, f"the {name} tree is not served")
            return [tree]
        return [t for t in (self.trees["OPENTSI"], self.trees["OPENTCI"]) if t is not None]

    def _resolve(self, trees: list, path: str):
        from tcs.opentci_server.paths import PathSyntaxError, parse_object

        try:
            ref = parse_object(path)
        except (PathSyntaxError, ValueError) as exc:
            raise AscomError(Code.INVALID_VALUE, f"{path!r} is not a variable: {exc}") from None
        last: TcsError | None = None
        for tree in trees:
            try:
                return tree, tree.resolve(ref)
            except TcsError as exc:
                last = exc
        raise AscomError(Code.INVALID_VALUE, f"{path}: {last.message if last else 'no tree'}")

    async def run(self, text: str) -> str:
        if len(text) > 4096:
            raise AscomError(Code.INVALID_VALUE, "command longer than 4096 characters")
        m = _COMMAND.match(text)
        trees = self._order(m["tree"])
        verb = (m["verb"] or "").upper()
        rest = m["rest"]
        if not trees:
            raise AscomError(Code.INVALID_OPERATION, "no TPL2 tree is served")
        if "=" in rest and verb != "GET":
            path, _, value = rest.partition("=")
            return await self._set(trees, path.strip(), value.strip())
        if verb == "SET":
            raise AscomError(Code.INVALID_VALUE, "SET needs VARIABLE=VALUE")
        if not rest:
            raise AscomError(Code.INVALID_VALUE, "empty command")
        tree, targets = self._resolve(trees, rest)
        return ",".join(tree.read(t, None, self.conn) for t in targets)

    async def _set(self, trees: list, path: str, text: str) -> str:
        from tcs.opentci_server.values import Value, ValueType, classify_bare

        if len(text) >= 2 and text[0] == text[-1] == '"':
            value = Value(ValueType.STRING, text[1:-1], True)
        elif not text:
            raise AscomError(Code.INVALID_VALUE, "SET needs a value")
        else:
            value = classify_bare(text)
        tree, targets = self._resolve(trees, path)
        try:
            values = tree.check_write(targets, None, tuple(value for _ in targets), self.conn)
            waits = [tree.write(t, v, self.conn) for t, v in zip(targets, values)]
            waits = [w for w in waits if w is not None]
            if waits:
                task = asyncio.ensure_future(asyncio.gather(*waits))
                task.add_done_callback(lambda f: f.cancelled() or f.exception())
                done, _ = await asyncio.wait([task], timeout=self.timeout)
                if not done:
                    return "STARTED"   # still running; its outcome shows in the state variables
                task.result()
        except (RangeRefused, TypeRefused) as exc:
            raise AscomError(Code.INVALID_VALUE, f"{exc.reply}: {exc.message}") from None
        except TcsError as exc:
            raise AscomError(Code.INVALID_OPERATION, f"{exc.reply}: {exc.message}") from None
        return "OK"
