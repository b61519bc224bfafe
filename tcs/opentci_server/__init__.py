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
"""

from tcs.opentci_server.opentci import build_tree
from tcs.opentci_server.server import Tpl2Server

__all__ = ["Tpl2Server", "build_tree"]
