"""tcs — a telescope control system serving OpenTCI over TPL2 on CiA-402 drives, Modbus PLCs
and GPS, with simulators of all that hardware.

Layers (see ``docs/architecture.md`` in the shared docs, and docs/development.md): ``opentci_server``
(TPL2 + variable tree), ``axes``, ``pointing``, ``drivers``, ``sim``, ``commission``,
``config``.
"""

__version__ = "0.1.0"
