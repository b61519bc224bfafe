"""The ports of ``tcs-server`` with no arguments (hwconfig/sim.toml), which tests/conftest.py
holds while the suite runs. A module of its own: ``from conftest import …`` in a test file finds
whichever ``conftest`` module its worker imported first (tests/vcan has one too)."""

#: TCP: TPL2, OpenTSI, Alpaca, the web port, INDI; UDP: Alpaca discovery.
DEFAULT_TCP_PORTS = (65432, 65433, 11111, 8088, 7624)
DEFAULT_UDP_PORTS = (32227,)
