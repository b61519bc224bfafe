"""POINTING numerical core (OpenTCI §14): astrometry, pointing model, orientation, files.

* :mod:`~tcs.pointing.astrometry` — ICRS ↔ observed Az/ZD and HA/Dec with pyerfa (steps 1–2).
* :mod:`~tcs.pointing.model` — TPOINT-named pointing model: apply, invert, fit (step 3).
* :mod:`~tcs.pointing.orientation` — normal/reverse orientation and cable-wrap choice.
* :mod:`~tcs.pointing.storage` — dump files and named saved models (atomic saves).
* :mod:`~tcs.pointing.demand` — the three steps joined: target → axis demands and back.

Nothing above knows the OpenTCI tree or the axes. The POINTING module is built on top:
:mod:`~tcs.pointing.pointing_module` (the domain object), :mod:`~tcs.pointing.tracker`
(tracking by streaming trajectories into the axes), :mod:`~tcs.pointing.pointing_params`
(POINTINGPARAMS), :mod:`~tcs.pointing.envelope` (the safety envelope: Sun cone, horizon table,
keep-outs on every planned path); import those from their modules.
"""

from tcs.pointing.astrometry import Astrometry, Observed, Refraction, Site, TimeBase
from tcs.pointing.demand import Demand, Pipeline, Place, field_angle
from tcs.pointing.model import (ALTAZ_TERMS, EQUATORIAL_TERMS, FitResult, PointingModel, Sample,
                                fit, fit_samples)
from tcs.pointing.orientation import AxisRange, MountPath, choose_path, mount_path, to_normal, to_reverse
from tcs.pointing.storage import DumpHeader, ModelStore, append_sample, load_dump, write_dump_header

__all__ = [
    "Astrometry", "Observed", "Refraction", "Site", "TimeBase",
    "Demand", "Pipeline", "Place", "field_angle",
    "ALTAZ_TERMS", "EQUATORIAL_TERMS", "FitResult", "PointingModel", "Sample", "fit", "fit_samples",
    "AxisRange", "MountPath", "choose_path", "mount_path", "to_normal", "to_reverse",
    "DumpHeader", "ModelStore", "append_sample", "load_dump", "write_dump_header",
]
