"""The ``[opentsi]`` section: how the OpenTSI tree names what the model knows.

The OpenTSI tree (``tcs/opentsi``) is a view of the telescope model; this section only holds
the few translations its clients need and the model cannot know: the error names of
``TELESCOPE.STATUS.LIST`` (clients such as pyobs-pilar act on the name) and which ``SENSOR[j]``
each ``AUXILIARY.SENSOR[i]`` shows. Where the listener is (``[server] opentsi_port``) is in the
server section.
"""

from __future__ import annotations

from dataclasses import dataclass

from tcs.config.schema import setting

#: Defaults of ``[opentsi] errors`` (opentsi.md decision 5): ``"MODULE:condition"`` (or
#: ``"MODULE"`` for any condition of the module) -> OpenTSI error name.
DEFAULT_ERRORS = {
    "AZ": "ERR_Azimuth_ETELError",
    "HA": "ERR_Azimuth_ETELError",
    "ZD": "ERR_Elevation_ETELError",
    "DEC": "ERR_Elevation_ETELError",
    "GPS:no GPS data": "ERR_GPS_PositionLost",
    "GPS:no GPS fix": "ERR_GPS_TooFewSatellites",
    "FILTER": "ERR_FilterWheel_RefMismatch",
}


@dataclass(frozen=True)
class OpenTsiSection:
    errors: dict[str, str] = setting(
        factory=dict, doc="\"MODULE:condition\" or \"MODULE\" -> error name in TELESCOPE.STATUS.LIST "
                          "(added to the defaults; the first match, most specific first, wins)")
    error_default: str = setting("ERR_DeviceError", doc="name of an ERROR/PANIC condition not in errors")
    warning_default: str = setting("ERR_DeviceWarn", doc="name of a WARNING/INFO condition not in errors")
    sensors: list[int] = setting(factory=tuple, doc="AUXILIARY.SENSOR[i] shows SENSOR[sensors[i]] "
                                                    "(default: the same index)")

    def error_table(self) -> dict[str, str]:
        table = dict(DEFAULT_ERRORS)
        table.update(self.errors)
        return table
