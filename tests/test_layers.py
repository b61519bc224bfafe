"""The house a newcomer reads: no import circles between the modules of ``tcs`` (every import,
also those inside functions, ``tools/ci/import_cycles.py``): front ends → model → axes →
drivers, the simulators apart."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

#: Circles still to untie (none).
KNOWN: set[str] = set()


def test_no_import_circles():
    proc = subprocess.run([sys.executable, str(ROOT / "tools" / "ci" / "import_cycles.py")],
                          capture_output=True, text=True, timeout=120)
    found = set(proc.stdout.split("\n")) - {""}
    assert found <= KNOWN, f"new import circles: {sorted(found - KNOWN)}"
