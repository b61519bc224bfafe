"""POINTING numerical core (OpenTCI §14): astrometry, pointing model, orientation, files.

* :mod:`~tcs.pointing.astrometry` — ICRS ↔ observed Az/ZD and HA/Dec with pyerfa (steps 1–2).
* :mod:`~tcs.pointing.model` — TPOINT-named pointing model: apply, invert, fit (step 3).
* :mod:`~tcs.pointing.orientation` — normal/reverse orientation and cable-wrap choice.
* :mod:`~tcs.pointing.storage` — dump files and named saved models (atomic saves).

Nothing here knows the OpenTCI tree or the axes; the POINTING module is built on top.
"""

from tcs.pointing.astrometry import Astrometry, Observed, Refraction, Site, TimeBase
from tcs.pointing.model import (ALTAZ_TERMS, EQUATORIAL_TERMS, FitResult, PointingModel, Sample,
                                fit, fit_samples)
from tcs.pointing.orientation import AxisRange, MountPath, choose_path, mount_path, to_normal, to_reverse
from tcs.pointing.storage import DumpHeader, ModelStore, append_sample, load_dump, write_dump_header

__all__ = [
    "Astrometry", "Observed", "Refraction", "Site", "TimeBase",
    "ALTAZ_TERMS", "EQUATORIAL_TERMS", "FitResult", "PointingModel", "Sample", "fit", "fit_samples",
    "AxisRange", "MountPath", "choose_path", "mount_path", "to_normal", "to_reverse",
    "DumpHeader", "ModelStore", "append_sample", "load_dump", "write_dump_header",
]
