"""Fresh virtual environments for the install tests that see the test run's dependencies.

``python -m venv --system-site-packages`` run by a venv's interpreter makes a venv over the
*base* interpreter: it sees the base's site-packages, not the running venv's, where the README's
command installed the dependencies. So the install tests make a plain venv and lend it the
running interpreter's site-packages through a ``.pth`` file of plain paths, after the venv's own.
A ``.pth`` line that is a path is only put on ``sys.path``; the ``.pth`` hooks inside it (this
tree's editable install among them) are not run, so ``import tcs`` in such a venv finds only what
was installed into it.
"""

from __future__ import annotations

import site
import subprocess
import sys
import sysconfig
from pathlib import Path


def lend_dependencies(venv: Path) -> None:
    """Let the venv at ``venv`` import what the running interpreter can (the dependencies)."""
    purelib = Path(subprocess.run([str(venv / "bin" / "python"), "-c",
                                   "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                                  capture_output=True, text=True, check=True, timeout=60).stdout.strip())
    paths = dict.fromkeys([*site.getsitepackages(), sysconfig.get_paths()["purelib"],
                           sysconfig.get_paths()["platlib"]])
    (purelib / "zz_test_dependencies.pth").write_text("".join(f"{p}\n" for p in paths if Path(p).is_dir()))


def make_venv(venv: Path) -> Path:
    """A new venv at ``venv`` that sees the running interpreter's packages; its ``bin``."""
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=120)
    lend_dependencies(venv)
    return venv / "bin"
