"""TPL2 and the OpenTCI variable tree, in two parts.

The TPL2 engine, which every TPL2 tree uses (OpenTCI here, OpenTSI in :mod:`tcs.opentsi`):

- ``values``, ``paths``, ``messages``, ``protocol``: the pure protocol core (text in, messages
  out; no sockets);
- ``tree``: the typed variable tree and its declaration helpers;
- ``session``, ``server``, ``scheduler``, ``guard``: the asyncio server, a thin adapter over
  the two, with its fairness and connection limits; ``server_module``: the ``SERVER`` module
  (TPL2 §9) every tree serves.

The OpenTCI declarations, in the subpackage ``opentci``: the one declaration of the OpenTCI
tree (``opentci/__init__``: ``build_tree``, ``LOCAL``, ``CONFIG``, ``SERVER``) and its parts
(``axes``, ``cabinet``, ``enclosure``, ``pointing``, ``common``). Nothing of the engine imports
them.

Importing the package imports neither: ``tcs-client`` needs only the pure core, and pulling
the server and the whole model (numpy, erfa, the pointing) into every client start cost half
a second of CPU a call — seconds in the CI's emulated guest, where a polling check starved the
telescope it watched. ``Tpl2Server`` and ``build_tree`` are loaded on first use.
"""

__all__ = ["Tpl2Server", "build_tree"]


def __getattr__(name: str):
    if name == "Tpl2Server":
        from tcs.opentci_server.server import Tpl2Server
        return Tpl2Server
    if name == "build_tree":
        from tcs.opentci_server.opentci import build_tree
        return build_tree
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
