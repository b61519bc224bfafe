"""TPL2 and the OpenTCI variable tree.

- ``values``, ``paths``, ``messages``, ``protocol``: the pure protocol core (text in, messages
  out; no sockets).
- ``tree``: the typed variable tree and its declaration helpers; ``opentci``: the one
  declaration of the OpenTCI tree.
- ``session``, ``server``: the asyncio server, a thin adapter over the two.
"""

from tcs.opentci_server.opentci import build_tree
from tcs.opentci_server.server import Tpl2Server

__all__ = ["Tpl2Server", "build_tree"]
