"""Import circles between the modules of ``tcs`` (every import, also those inside functions).

Prints each group of modules that import each other in a circle (a strongly connected
component of the import graph), one per line; exit status 1 when there is any. The layering
(front ends → model → axes → drivers; sim apart) has no circles; ``tests/test_layers.py`` runs
this and lists the ones still to untie.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imports(path: Path, modules: set[str]) -> set[str]:
    """The ``tcs`` modules ``path`` imports (a package's ``__init__`` counts as the package)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        names = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            # ``from pkg import mod`` imports the module (and runs pkg/__init__, which is
            # not a dependency of this module's code); ``from pkg import name`` the package
            subs = [f"{node.module}.{a.name}" for a in node.names]
            names = [m for m in subs if m in modules]
            if len(names) < len(subs):
                names.append(node.module)
        for name in names:
            if name in modules:
                found.add(name)
    return found


def graph() -> dict[str, set[str]]:
    files = {module_name(p): p for p in (ROOT / "tcs").rglob("*.py")}
    modules = set(files)
    return {m: imports(p, modules) - {m} for m, p in files.items()}


def circles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(edges.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                out.append(sorted(group))

    sys.setrecursionlimit(10000)
    for v in sorted(edges):
        if v not in index:
            visit(v)
    return sorted(out)


def main() -> int:
    found = circles(graph())
    for group in found:
        print(" <-> ".join(group))
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
