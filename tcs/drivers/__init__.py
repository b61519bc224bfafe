"""Drivers: the TCS's side of the hardware protocols (CANopen / CiA-402, Modbus, NMEA).

Each driver sits behind a small interface its user sees (for drives:
:mod:`tcs.drivers.drive`); the implementation is chosen by the hardware file. Nothing here
knows OpenTCI, and nothing here imports the simulators (``tcs.sim``).

CANopen / CiA-402: :mod:`~tcs.drivers.canbus` (bus, TCS heartbeat, bus health),
:mod:`~tcs.drivers.cycle` (SYNC and the per-cycle runner), :mod:`~tcs.drivers.cia402`
(state-machine tables), :mod:`~tcs.drivers.cia402_drive` (the drive), :mod:`~tcs.drivers.boot`
(boot and SDO configuration), :mod:`~tcs.drivers.pdo`, :mod:`~tcs.drivers.emcy`,
:mod:`~tcs.drivers.worker`, :mod:`~tcs.drivers.bus_check` (another master on the bus?),
:mod:`~tcs.drivers.takeover` (a drive still powered at boot is stopped first), and
:mod:`~tcs.drivers.can_system` (all of it from the hardware file).
"""
