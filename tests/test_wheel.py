"""A normal (non-editable) install works: the wheel built from this tree, installed into a fresh
virtual environment outside the source tree, runs the simulated telescope (``tcs-server`` with
no ``--config``) and ``tcs-commission scan`` from there — the defaults are package data, not
paths into the source tree.

The build uses pip's isolated build environment (setuptools from the package index pip is
configured with). The wheel goes in with ``--no-deps``; its dependencies come from the
site-packages of the interpreter that runs the tests (``support.venvs``), so nothing is
downloaded and nothing installed by hand into the base Python is needed.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from support.venvs import make_venv
from test_cli_server import connect, free_port

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Path:
    """The ``bin`` directory of a fresh venv with the wheel of this tree installed."""
    base = tmp_path_factory.mktemp("wheel")
    src = base / "src"
    src.mkdir()
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
    for name in ("tcs", "hwconfig"):
        shutil.copytree(ROOT / name, src / name, ignore=ignore)
    for name in ("pyproject.toml", "setup.py", "README.md"):
        shutil.copy(ROOT / name, src / name)
    dist = base / "dist"
    build = subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(dist),
                            str(src)], capture_output=True, text=True, timeout=300)
    if build.returncode != 0 and "Could not find a version" in build.stderr:
        pytest.skip("setuptools for the isolated build is not available from the package index")
    assert build.returncode == 0, build.stderr
    wheel = next(dist.glob("tcs-*.whl"))
    venv = base / "venv"
    make_venv(venv)
    subprocess.run([str(venv / "bin" / "python"), "-m", "pip", "install", "-q", "--no-deps", str(wheel)],
                   check=True, timeout=300)
    shutil.rmtree(src)  # nothing of the source tree is left to lean on
    return venv / "bin"


def run_env(tmp_path) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env.update(XDG_STATE_HOME=str(tmp_path / "state"), PYTHONUNBUFFERED="1")
    return env


def test_the_installed_package_is_the_wheel(installed, tmp_path):
    out = subprocess.run([str(installed / "python"), "-c",
                          "import tcs, tcs.resources as r; print(tcs.__file__); print(r.HWCONFIG_DIR)"],
                         cwd=tmp_path, env=run_env(tmp_path), capture_output=True, text=True, check=True)
    module, hwconfig = out.stdout.split()
    venv = str(installed.parent)
    assert module.startswith(venv) and hwconfig.startswith(venv), out.stdout
    assert (Path(hwconfig) / "sim.toml").is_file()
    assert (Path(hwconfig) / "eds" / "tcs-sim-drive.eds").is_file()
    assert (Path(hwconfig) / "cabinet.toml").is_file()
    for script in ("tcs-server", "tcs-client", "tcs-commission", "tcs-passwd", "tcs-sim"):
        version = subprocess.run([str(installed / script), "--version"], capture_output=True,
                                 text=True, timeout=60)
        assert version.stdout.strip() == f"{script} 0.1.0", (script, version.stderr)
    # package data beside the modules: tcs-client's bright-star list (goto NAME)
    stars = subprocess.run([str(installed / "tcs-client"), "goto", "--list"], capture_output=True,
                           text=True, timeout=60, cwd=tmp_path, env=run_env(tmp_path))
    assert stars.returncode == 0 and "Sirius" in stars.stdout and "Polaris" in stars.stdout, stars.stderr


def test_tcs_server_runs_the_simulated_telescope_from_the_wheel(installed, tmp_path):
    port, web = free_port(), free_port()
    proc = subprocess.Popen([str(installed / "tcs-server"), "--port", str(port), "--opentsi-port", "0",
                             "--alpaca-port", "-1", "--web-port", str(web), "--indi-port", "-1"], cwd=tmp_path,
                            env=run_env(tmp_path), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    try:
        s = connect(port, timeout=60)
        f = s.makefile("rb")
        assert f.readline().startswith(b"TPL2 2.1 CONN ")
        s.sendall(b'AUTH PLAIN "admin" "admin"\n1 GET CONFIG.MOUNT\n')
        assert f.readline() == b"AUTH OK 0 0\n"
        assert [f.readline() for _ in range(3)][1] == b'1 DATA INLINE CONFIG.MOUNT="AZ-ZD"\n'
        # the status page's files are package data of the wheel
        import urllib.request
        for path, text in (("/", b'src="app.js"'), ("/app.js", b"EventSource"), ("/style.css", b"#sky")):
            with urllib.request.urlopen(f"http://127.0.0.1:{web}{path}", timeout=30) as r:
                assert text in r.read(), path
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(60) == 0
        f.close()
        s.close()
    finally:
        if proc.poll() is None:
            proc.kill()
        out, err = proc.communicate()
    assert "Traceback" not in err, err


def test_tcs_commission_scans_from_the_wheel(installed, tmp_path):
    shipped = subprocess.run([str(installed / "python"), "-c",
                              "from tcs.resources import HWCONFIG_DIR; print(HWCONFIG_DIR)"],
                             capture_output=True, text=True, check=True).stdout.strip()
    copy = tmp_path / "tcs.toml"  # a user's copy elsewhere still finds the simulated drive's EDS
    shutil.copy(Path(shipped) / "sim.toml", copy)
    for args in ([], ["--config", str(copy)]):
        proc = subprocess.run([str(installed / "tcs-commission"), "scan", "--json", *args], cwd=tmp_path,
                              env=run_env(tmp_path), capture_output=True, text=True, timeout=120)
        assert proc.returncode == 0, proc.stderr
        assert "Traceback" not in proc.stderr
        assert '"az"' in proc.stdout and '"m3"' in proc.stdout
