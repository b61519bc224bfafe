"""Rules for a hardware file that runs the service, and safe edits of it: ``tcs-server`` refuses
a file without users and a real telescope without ``[site]`` (status 2, a clear message),
``--check-config`` validates without touching hardware, every failed login is logged, and
``tcs-commission``'s file writes keep mode, owner and group."""

from __future__ import annotations

import logging
import os
import stat
import subprocess
import sys
from pathlib import Path

import tomlkit

from support.tpl2 import RawClient
from tcs.commission.hwfile import update_values
from tcs.config import DEFAULT_CONFIG, load_config, parse_config

HERE = Path(__file__).parent
ROOT = HERE.parent

REAL = """
[[users]]
name = "observer"
password = "{hash}"
[can]
interface = "socketcan"
channel = "can-tcs-test-absent"
"""


def server(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "tcs.cli.server", *map(str, args)],
                          capture_output=True, text=True, timeout=60)


def without_users(tmp_path) -> Path:
    doc = tomlkit.parse(DEFAULT_CONFIG.read_text())
    del doc["users"]
    path = tmp_path / "nousers.toml"
    path.write_text(tomlkit.dumps(doc))
    (tmp_path / "eds").symlink_to(DEFAULT_CONFIG.parent / "eds")
    return path


def real_file(tmp_path, site: bool) -> Path:
    user = load_config(DEFAULT_CONFIG).users[0]
    text = REAL.format(hash=user.password)
    if site:
        text += "[site]\nlatitude = 47.3\nlongitude = 8.5\nheight = 500\n"
    path = tmp_path / ("real-site.toml" if site else "real.toml")
    path.write_text(text)
    return path


def test_server_without_users_refuses_to_start(tmp_path):
    path = without_users(tmp_path)
    proc = server("--config", path, "--port", "0")
    assert proc.returncode == 2
    assert f"{path}: users: no [[users]]: nobody could log in" in proc.stderr
    assert "tcs-passwd" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_site_is_required_unless_simulated(tmp_path):
    assert load_config(DEFAULT_CONFIG).service_problems() == []
    real = load_config(real_file(tmp_path, site=False))
    assert not real.simulated
    assert [(p.key, p.problem.split(":")[0]) for p in real.service_problems()] == [("site", "missing")]
    assert load_config(real_file(tmp_path, site=True)).service_problems() == []
    # a simulated telescope may leave the site to its defaults; the tools need no users
    sim = parse_config('[can]\ninterface = "virtual"\nchannel = "x"\n')
    assert sim.simulated and [p.key for p in sim.service_problems()] == ["users"]


def test_check_config_validates_without_touching_hardware(tmp_path):
    ok = server("--check-config", DEFAULT_CONFIG)
    assert ok.returncode == 0 and "valid" in ok.stderr
    # a real cabinet on a CAN interface that does not exist here: valid, nothing opened
    real = server("--check-config", real_file(tmp_path, site=True))
    assert real.returncode == 0, real.stderr
    bad = server("--check-config", real_file(tmp_path, site=False))
    assert bad.returncode == 2 and ": site: missing" in bad.stderr
    eds = tmp_path / "eds.toml"
    eds.write_text(DEFAULT_CONFIG.read_text().replace("[drives.az]\n", '[drives.az]\neds = "nope.eds"\n'))
    missing = server("--check-config", eds)
    assert missing.returncode == 2 and "drives.az.eds: EDS file" in missing.stderr
    assert "Traceback" not in bad.stderr + missing.stderr


async def test_each_failed_login_is_logged_without_the_password(service, caplog):
    _, port = service
    caplog.set_level(logging.WARNING, logger="tcs.opentci_server.session")
    c = await RawClient.connect(port, login=None)
    await c.send('AUTH PLAIN "admin" "secret-guess-1"')
    assert await c.readline() == "AUTH FAILED"
    await c.send('AUTH PLAIN "mallory" "secret-guess-2"')
    assert await c.readline() == "AUTH FAILED"
    await c.close()
    lines = [r.getMessage() for r in caplog.records if "failed login as" in r.getMessage()]
    assert len(lines) == 2, lines
    assert "'admin'" in lines[0] and "'mallory'" in lines[1]
    assert all("127.0.0.1:" in line for line in lines)
    assert not any("secret-guess" in r.getMessage() for r in caplog.records)


def test_hardware_file_write_keeps_mode_owner_and_group(tmp_path):
    path = tmp_path / "tcs.toml"
    path.write_text((HERE / "hw_commission.toml").read_text())
    path.chmod(0o640)
    owner = (1234, 4321) if os.geteuid() == 0 else (os.geteuid(), os.getegid())
    if os.geteuid() == 0:
        os.chown(path, *owner)
    update_values(path, {("axes", "az", "min"): -4.0})
    st = path.stat()
    assert stat.S_IMODE(st.st_mode) == 0o640
    assert (st.st_uid, st.st_gid) == owner
    assert load_config(path).axes["az"].min == -4.0
    assert [p.name for p in tmp_path.iterdir()] == ["tcs.toml"]  # no temporary file left
