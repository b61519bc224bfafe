"""Print the OpenTCI (or OpenTSI) variable reference of a hardware file, derived from the one declaration.

    python3 tools/opentci_reference.py [--config hwconfig/sim.toml] > opentci-reference.md
    python3 tools/opentci_reference.py --tree opentsi > opentsi-reference.md

Every object of the built tree with its class, type, access levels, range and description —
what a client will find when it walks the tree with ``!MEMBERS``. Nothing here is written by
hand: add a variable to ``tcs/opentci_server/opentci/`` and it appears. The documentation
build uses :func:`reference_service` and :func:`rows` for its reference pages
(``tools/docs/gen_frontend_reference.py``). The service it starts listens on free loopback
ports and serves no Alpaca (it would take port 11111 from a running server).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import re
import tempfile
from pathlib import Path

from tcs.config import DEFAULT_CONFIG, load_config
from tcs.config.sections import StateSection
from tcs.errors import EVENT_MEANINGS
from tcs.opentci_server.tree import ArrayNode, ModuleNode, NOBODY, VarNode

TYPE_NAMES = {0: "NULL", 1: "INT", 2: "FLOAT", 3: "STRING"}


def _shown_element(array: ArrayNode) -> int | None:
    """The element an array's rows show: the first one with hardware (members answer)."""
    for element in array.elements:
        if not any(getattr(m, "absent", False) for m in element.members):
            return element.index
    return array.elements[0].index if array.elements else None


def cells(tree):
    """One tuple per shown object: (object, type, access, range, notes, description)."""
    shown: dict[str, int | None] = {}
    for path, node in tree.walk():
        if not _is_shown(path, shown):
            continue
        if isinstance(node, ArrayNode):
            shown[path] = _shown_element(node)
            absent = [e.index for e in node.elements if e.index != shown[path] and any(
                getattr(m, "absent", False) for m in e.members)]
            note = f"; no hardware at {absent} (VERSION 0, else FAILED 4)" if absent else ""
            yield (f"{path}[]", f"module array ({len(node.elements)}{note})", "", "", "", node.info)
            continue
        if isinstance(node, ModuleNode):
            yield (path, "module", "", "", "", node.info)
        elif isinstance(node, VarNode):
            spec = node.spec
            wlevel = node.wlevel
            if spec.rlevel == NOBODY:
                access = f"WO (w<={wlevel})"
            else:
                access = "RO" if wlevel == NOBODY else f"RW (w<={wlevel})"
            lo, hi = node.limit("min"), node.limit("max")
            rng = "" if lo is None and hi is None else f"{'' if lo is None else lo} … {'' if hi is None else hi}"
            kind = "per connection" if spec.per_connection else ("long SET" if spec.long else "")
            yield (path, TYPE_NAMES[int(spec.type)], access, rng, kind, spec.info)


def md_cell(text) -> str:
    """Text safe in a Markdown table cell (no HTML, emphasis, links or cell breaks)."""
    text = re.sub(r"([\\`*_\[\]|])", r"\\\1", str(text))
    return text.replace("<", "&lt;").replace(">", "&gt;").replace("\n", " ")


def rows(tree):
    for obj, *rest in cells(tree):
        yield "| `" + obj + "` | " + " | ".join(md_cell(c) for c in rest) + " |"


@contextlib.asynccontextmanager
async def reference_service(config_path: Path):
    """The service of ``config_path`` on free loopback ports (OpenTSI too, Alpaca off: only
    the trees are read) with a throw-away state directory; stopped on exit."""
    import dataclasses

    from tcs.app import Service

    config = load_config(config_path)
    with tempfile.TemporaryDirectory() as state:
        cfg = dataclasses.replace(config, server=dataclasses.replace(config.server, port=0, opentsi_port=0),
                                  state=StateSection(path=state))
        object.__setattr__(cfg, "source", config.source)
        service = Service(cfg, host="127.0.0.1", port=0, alpaca_port=-1, web_port=-1, indi_port=-1)
        await service.start()
        try:
            yield service
        finally:
            await service.stop()


async def build(config_path: Path, tree: str = "opentci"):
    async with reference_service(config_path) as service:
        server = service.opentsi_server if tree == "opentsi" else service.server
        return list(rows(server.tree))


def _is_shown(path: str, shown: dict[str, int | None]) -> bool:
    """Only the shown element of each array (``DEROTATOR[2]`` when 0 and 1 have no hardware)."""
    for array, index in shown.items():
        prefix = array + "["
        if path.startswith(prefix) and not path.startswith(f"{array}[{index}]"):
            return False
    return True


def event_rows():
    for number, meaning in sorted(EVENT_MEANINGS.items()):
        yield f"| {number} | {meaning} |"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--config", default=str(DEFAULT_CONFIG))
    p.add_argument("--tree", choices=("opentci", "opentsi"), default="opentci",
                   help="which tree (OpenTSI: tcs/opentsi/declaration.py)")
    args = p.parse_args()
    name = "OpenTSI" if args.tree == "opentsi" else "OpenTCI"
    source = "tcs/opentsi/declaration.py" if args.tree == "opentsi" else "tcs/opentci_server/opentci/"
    print(f"# {name} variables served for `{Path(args.config).name}`\n")
    print(f"Generated by `tools/opentci_reference.py --tree {args.tree}` from the declaration in "
          f"`{source}`. Arrays show their first element.\n")
    print("| object | type | access | range | notes | description |")
    print("|---|---|---|---|---|---|")
    for row in asyncio.run(build(Path(args.config), args.tree)):
        print(row)
    print("\n## Event and error numbers\n")
    print("`<id> EVENT <LEVEL> <module>:<number> <text>`; `FAILED <number>` in DATA replies. "
          "1-32: OpenTCI Appendix B; from 1000: this server's own.\n")
    print("| number | meaning |")
    print("|---|---|")
    for row in event_rows():
        print(row)


if __name__ == "__main__":
    main()
