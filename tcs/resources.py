"""Files shipped with the package: the simulated telescopes' hardware files and the EDS of the
simulated drive.

They live in ``hwconfig/`` at the top of the source tree, which the build installs as the
package ``tcs_hwconfig`` (``setup.py`` maps it), so a wheel install finds them through
:mod:`importlib.resources` exactly like an editable one. Paths written inside a user's hardware
file are not resolved here: they stay relative to that file (:meth:`tcs.config.HwConfig.resolve`).
Only the defaults (``tcs-server`` without ``--config``, a drive without ``eds``) come from here.
"""

from __future__ import annotations

import importlib.resources
from pathlib import Path

__all__ = ["HWCONFIG_DIR", "hwconfig_file"]


def _hwconfig_dir() -> Path:
    try:
        return Path(str(importlib.resources.files("tcs_hwconfig")))
    except ModuleNotFoundError:
        # A source tree used without (re)installing it: the folder next to the package.
        return Path(__file__).resolve().parent.parent / "hwconfig"


#: The directory of the shipped hardware files (``sim.toml`` …) and of ``eds/``.
HWCONFIG_DIR: Path = _hwconfig_dir()


def hwconfig_file(name: str) -> Path:
    """A shipped file by its name under ``hwconfig/``, e.g. ``"sim.toml"`` or ``"eds/x.eds"``."""
    return HWCONFIG_DIR / name
