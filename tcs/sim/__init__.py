"""Simulated hardware speaking the real wire protocols (never imports the TCS's drivers).

CiA-402 servo drives as CANopen nodes on a python-can bus: :class:`SimDrive` (one node),
:func:`start_sim_drives` / :class:`SimDriveNetwork` (several on one bus), described by
:class:`SimDriveParams` and the EDS ``hwconfig/eds/tcs-sim-drive.eds`` (:data:`DEFAULT_EDS`).
"""

from tcs.sim.cia402_drive import DEFAULT_EDS, FAULT_CODES, SimDrive
from tcs.sim.drive_network import SimDriveNetwork, start_sim_drives
from tcs.sim.drive_params import SimDriveParams

__all__ = ["DEFAULT_EDS", "FAULT_CODES", "SimDrive", "SimDriveNetwork", "SimDriveParams", "start_sim_drives"]
