"""The OpenTSI front end: the newer ASTELCO variable tree, served on a TCP port of its own by
the same TPL2 engine, over the same telescope model as the OpenTCI tree.

- ``declaration``: the one declaration of the tree; ``views``: stateless computed views.
- :func:`build_opentsi_server`: a second :class:`~tcs.opentci_server.server.Tpl2Server` (same
  users, limits and event hub) with this tree and OpenTSI module names in its events.
"""

from __future__ import annotations

from tcs.opentsi.declaration import OPENTSI, build_opentsi_tree
from tcs.opentsi.views import event_source


def build_opentsi_server(config, telescope):
    """The OpenTSI listener for ``telescope`` (not started)."""
    from tcs.opentci_server.server import Tpl2Server, loop_shares_interpreter

    server = Tpl2Server(config.server, config.users, telescope.events,
                        manufacturer=config.cabinet.manufacturer, event_source=event_source,
                        shares_interpreter=loop_shares_interpreter(config))
    server.device = "OpenTSI telescope control system"
    server.tree = build_opentsi_tree(telescope, server)
    return server


__all__ = ["OPENTSI", "build_opentsi_server", "build_opentsi_tree", "event_source"]
