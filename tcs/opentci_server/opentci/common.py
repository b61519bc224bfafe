"""The variables every OpenTCI module has (spec §3.2): ``VERSION``, ``TYPE``, ``ERROR_STATE``.

Part of the one declaration of the tree; the module declarations (``opentci.py``,
``opentci_axes.py``, ``opentci_cabinet.py``) splice :func:`common` into each module. The domain
objects provide them through :class:`tcs.model.health.ModuleHealth`.
"""

from __future__ import annotations

from tcs.opentci_server.tree import INT, var


def common(type_info: str = "hardware type (≥ 1)"):
    """VERSION, TYPE and ERROR_STATE, in that order."""
    return (
        var("VERSION", INT, get="version", absent=0,
            info="interface version 0x..IIAARR (version 24); 0: no hardware at this array index"),
        var("TYPE", INT, get="hw_type", info=type_info, absent=0),
        var("ERROR_STATE", INT, get="error_state", set="acknowledge_errors", min=0, max=0,
            info="error bits 0 PANIC, 1 ERROR, 2 WARNING, 3 INFO, 4 DEBUG; write 0 to acknowledge"),
    )
