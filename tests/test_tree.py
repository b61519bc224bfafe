"""The built variable tree in memory (no server): module arrays whose members are all
variables (``SERVER.CLIENT[]``, one element per connection slot) are built element by element
on first use, and answer exactly like the arrays built at once."""

from __future__ import annotations

from dataclasses import dataclass

import pytest

from tcs.errors import RequestRefused
from tcs.opentci_server.paths import parse_object
from tcs.opentci_server.tree import (ArrayNode, INT, ModuleNode, STRING, Tree, VarNode, module, module_array,
                                     var)


@dataclass
class Slot:
    id: int
    name: str


@dataclass
class Part:
    value: int


@dataclass
class Holder:
    slots: list
    parts: list


class Conn:
    rlevel = 0
    wlevel = 0


DECLARATION = (
    module_array("SLOT",
                 var("ID", INT, get="id"),
                 var("NAME", STRING, get="name"),
                 var("VERSION", INT, get="id", absent=0),
                 bind=lambda h: h.slots),
    module_array("PART",  # has a submodule: built at once
                 var("VALUE", INT, get="value"),
                 module("SUB", var("VALUE", INT, get="value")),
                 bind=lambda h: h.parts),
)


def build(n: int) -> Tree:
    slots = [Slot(i, f"s{i}") if i % 3 else None for i in range(n)]
    return Tree.build(DECLARATION, Holder(slots, [Part(7), None]))


def read(tree: Tree, text: str) -> list[str]:
    ref = parse_object(text)
    return [tree.read(t, ref.prop, Conn()) for t in tree.resolve(ref)]


def test_elements_of_a_variable_only_array_answer_like_built_ones():
    tree = build(1000)
    assert read(tree, "SLOT!COUNT") == ["1000"]
    assert read(tree, "SLOT[998].NAME") == ['"s998"']
    assert read(tree, "SLOT[999].ID") == ["FAILED 4"]  # no object at this index
    assert read(tree, "SLOT[999].VERSION") == ["0"]
    assert read(tree, "SLOT[1-3].ID") == ["1", "2", "FAILED 4"]
    assert read(tree, "SLOT[5]!NAME") == ['"SLOT[5]"']
    assert read(tree, "SLOT[5]!MEMBERS") == ["3"]
    assert read(tree, "SLOT[5].<1>") == ['"s5"']
    with pytest.raises(RequestRefused) as refused:
        read(tree, "SLOT[1000].ID")
    assert refused.value.reply == "DIMENSION"
    slots = tree.root.by_name["SLOT"]
    assert isinstance(slots, ArrayNode)
    assert slots.elements[7] is slots.elements[7]  # built once, kept
    assert slots.elements[-1].index == 999 and len(slots.elements[2:5]) == 3


def test_objectcount_and_walk_see_every_element():
    tree = build(40)
    paths = [p for p, _ in tree.walk()]
    assert paths[:5] == ["SLOT", "SLOT[0]", "SLOT[0].ID", "SLOT[0].NAME", "SLOT[0].VERSION"]
    assert "SLOT[39].VERSION" in paths and "PART[1].SUB.VALUE" in paths
    below_slot = sum(1 for p in paths if p.startswith("SLOT"))
    assert read(tree, "SLOT!OBJECTCOUNT") == [str(below_slot - 1)]
    assert read(tree, "!OBJECTCOUNT") == [str(len(paths))]
    walked = [n for p, n in tree.walk() if p.startswith("SLOT[") and isinstance(n, ModuleNode)]
    assert [n.index for n in walked] == list(range(40))
    assert all(isinstance(m, VarNode) and m.parent is n for n in walked for m in n.members)
    assert read(tree, "PART[0].SUB.VALUE") == ["7"] and read(tree, "PART[1].SUB.VALUE") == ["FAILED 4"]
