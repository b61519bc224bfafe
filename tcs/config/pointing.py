"""The ``[pointing]`` table of a hardware file: the POINTING module (OpenTCI §14).

Safety limit, refraction defaults, how the tracker streams trajectory points into the axes,
which terms CALCULATE fits and where named models are kept. Every key has a default, so a
file without ``[pointing]`` gets a working POINTING module wherever the mount is AZ-ZD or
RA-DEC (ZD-ZD mounts have no POINTING module).

``refraction_mode`` / ``temperature`` / ``pressure`` are the values POINTING.REFRACTION starts
with; what a client writes there is persisted and wins until the file's value is edited (the
same rule as LOCAL).
"""

from __future__ import annotations

from dataclasses import dataclass

from tcs.config.schema import setting


@dataclass(frozen=True)
class PointingSection:
    min_altitude: float = setting(
        15.0, min=-5.0, max=89.0,
        doc="degrees: TRACK refuses a target below this observed altitude and ends tracking "
            "(event, FAILED 9) when the target sets below it")
    refraction_mode: int = setting(1, min=0, max=2, doc="REFRACTION.MODE at first start")
    temperature: float = setting(10.0, min=-100.0, max=100.0, doc="REFRACTION.TEMPERATURE at first start, °C")
    pressure: float = setting(1010.0, min=0.0, max=1200.0, doc="REFRACTION.PRESSURE at first start, hPa")
    sample_spacing: float = setting(1.0, min=0.1, max=10.0,
                                    doc="seconds between the trajectory points the tracker computes")
    horizon: float = setting(100.0, min=5.0, max=3600.0,
                             doc="seconds of path kept queued ahead (at most the axes' trajectory_buffer "
                                 "points)")
    refill_below: float = setting(75.0, min=1.0, max=3600.0,
                                  doc="seconds: the queue is refilled when less path than this remains "
                                      "(above 60 s the axes never report TRAJ_LOWPOINTS)")
    plan_horizon: float = setting(14400.0, min=60.0, max=86400.0,
                                  doc="seconds of path checked against the axis limits when TRACK "
                                      "chooses orientation and cable-wrap turn")
    tle_max_age: float = setting(
        30.0, min=0.5, max=3650.0,
        doc="days: a satellite's TLE whose epoch is further than this from now is refused "
            "(OBJECT.TLE.PASS.REASON says its age; TRACK=1 FAILED 9): SGP4 drifts kilometres a "
            "day from an old element set (docs/satellites.md)")
    fit_terms: list[str] = setting(
        factory=tuple, doc="terms CALCULATE fits (default: the standard 6 mount terms + TF of the mount)")
    model_directory: str = setting(
        "", doc="named models (LIST/LOAD/SAVE/ERASE) and dump files; default <state dir>/pointing")

    def check(self):
        problems = []
        if self.refill_below >= self.horizon:
            problems.append(("refill_below", f"must be less than horizon ({self.horizon} s)"))
        if self.horizon < 4 * self.sample_spacing:
            problems.append(("horizon", f"must hold at least 4 points of sample_spacing "
                                        f"({self.sample_spacing} s)"))
        return problems
