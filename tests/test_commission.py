"""tcs-commission against the simulated drives: every subcommand, run as ``main(argv)`` and
through a subprocess, with real CANopen frames on a private virtual bus per test.

The hardware file is a copy of ``tests/hw_commission.toml`` (fast, short distances) with its
own virtual channel, so tests cannot hear each other.
"""

from __future__ import annotations

import io
import json
import math
import struct
import subprocess
import sys
import time
import uuid
import zlib
from pathlib import Path

import can
import canopen
import numpy as np
import pytest

from tcs.commission.cli import main
from tcs.commission.common import resolve_target
from tcs.commission.limits import SwitchWatch, propose
from tcs.commission.pointing import _spread
from tcs.commission.progress import ProgressBar
from tcs.commission.session import other_master
from tcs.config import load_config
from tcs.drivers.drive import DriveState, DriveStatus
from tcs.drivers.emcy import DriveFault
from tcs.pointing.astrometry import Astrometry, Refraction, Site, TimeBase
from tcs.pointing.model import PointingModel, Sample
from tcs.pointing.storage import DumpHeader, ModelStore, append_sample, write_dump_header
from tcs.sim import SimDriveParams, start_sim_drives

HERE = Path(__file__).parent
HW = HERE / "hw_commission.toml"
ROOT = HERE.parent


@pytest.fixture
def hw(tmp_path, monkeypatch) -> Path:
    """A private copy of the test hardware file (own virtual channel)."""
    monkeypatch.setattr(canopen.network.Network, "NOTIFIER_SHUTDOWN_TIMEOUT", 0.0)
    channel = f"tcs-cm-{uuid.uuid4().hex[:10]}"
    text = HW.read_text(encoding="utf-8").replace('channel = "tcs-commission-test"',
                                                  f'channel = "{channel}"')
    assert channel in text
    path = tmp_path / "hw.toml"
    path.write_text(text, encoding="utf-8")
    return path


def run(capsys, *argv) -> tuple[int, dict]:
    """``tcs-commission ARGV --json`` in-process: (exit code, JSON output)."""
    code = main([*map(str, argv), "--json"])
    out = capsys.readouterr().out
    return code, json.loads(out)


def png_ok(path: Path) -> tuple[int, int]:
    """Check a PNG file chunk by chunk (signature, CRCs, IHDR, IDAT inflates, IEND)."""
    data = Path(path).read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n", path
    pos, chunks, idat = 8, [], b""
    while pos < len(data):
        (length,) = struct.unpack(">I", data[pos:pos + 4])
        kind = data[pos + 4:pos + 8]
        body = data[pos + 8:pos + 8 + length]
        (crc,) = struct.unpack(">I", data[pos + 8 + length:pos + 12 + length])
        assert zlib.crc32(kind + body) == crc, f"{path}: bad CRC in {kind}"
        chunks.append(kind)
        if kind == b"IDAT":
            idat += body
        pos += 12 + length
    assert chunks[0] == b"IHDR" and chunks[-1] == b"IEND", chunks
    width, height = struct.unpack(">II", data[16:24])
    assert width > 100 and height > 100
    assert len(zlib.decompress(idat)) > width * height  # at least one byte per pixel
    return width, height


# ------------------------------------------------------------------------------ scan, info
def test_scan_identifies_every_configured_drive(hw, capsys):
    code, out = run(capsys, "scan", "--config", hw)
    assert code == 0, out
    assert out["ok"] and out["simulated"] and out["missing"] == []
    nodes = {n["node_id"]: n for n in out["nodes"]}
    assert sorted(nodes) == [1, 2, 5]
    az = nodes[1]
    assert az["drive"] == "az" and az["match"] == "ok" and az["cia402"]
    assert az["identity"] == {"vendor": 0xABC, "product": 0x00402001, "revision": 0x00010000,
                              "serial": 1}
    assert az["state"] == "switch on disabled" and az["error_register"] == 0
    assert az["offered"] == "PP, PV, HM, IP, CSP, CSV" and az["tcs_mode"] == "CSP"
    assert "0x6502" in az["tcs_mode_reason"]


def test_scan_says_discrete_axes_run_in_profile_position(capsys):
    """The shipped telescope's filter wheel and M3 make profile moves (PP), whatever their
    drives offer: scan says so instead of the streaming mode their drives would be given."""
    code, out = run(capsys, "scan", "--nodes", "1,6-7")
    assert code == 0, out
    nodes = {n["node_id"]: n for n in out["nodes"]}
    assert nodes[6]["drive"] == "filter" and nodes[7]["drive"] == "m3"
    for n in (6, 7):
        assert nodes[n]["tcs_mode"] == "PP", nodes[n]
        assert "discrete positions" in nodes[n]["tcs_mode_reason"]
    assert nodes[1]["tcs_mode"] == "CSP"      # the azimuth streams


def test_scan_reports_missing_and_foreign_nodes(hw, capsys, monkeypatch):
    # A configured drive nobody simulates (node 9), and at node 10 a device of another product.
    text = hw.read_text()
    channel = text.split('channel = "', 1)[1].split('"', 1)[0]
    extra = "\n".join(
        f"[drives.{name}]\nnode_id = {node}\nidentity = {{ vendor = 0xABC, product = 0x00402001, "
        f"revision = 0x00010000 }}\nincrements_per_unit = 1000.0\nmin_position = 0.0\n"
        f"max_position = 1.0\nfollowing_error_window = 1.0\nmax_velocity = 1.0\n"
        f"max_acceleration = 1.0\n" for name, node in (("spare", 9), ("other", 10)))
    hw.write_text(text.replace("# The axes:", extra + "\n# The axes:"))
    stranger = start_sim_drives({"interface": "virtual", "channel": channel},
                                {10: SimDriveParams(identity=(0xABC, 0x00402999, 0x00010000, 77))})
    try:
        code, out = run(capsys, "scan", "--config", hw, "--nodes", "1-12")
    finally:
        stranger.stop()
    assert code == 3, out                     # a configured drive is missing
    assert out["missing"] == [{"drive": "spare", "node_id": 9}]
    other = next(n for n in out["nodes"] if n["node_id"] == 10)
    assert other["drive"] == "other"
    assert other["match"].startswith("wrong identity: product 0x00402999 (file 0x00402001)")
    assert "spare (node 9)" in out["error"]


def test_scan_without_simulation_finds_nothing(hw, capsys):
    code, out = run(capsys, "scan", "--config", hw, "--no-simulate", "--nodes", "1-8")
    assert code == 3
    assert out["nodes"] == [] and len(out["missing"]) == 3


def test_info_reads_configuration_and_live_values(hw, capsys):
    code, out = run(capsys, "info", "focus", "--config", hw)
    assert code == 0, out
    assert out["drive"] == "focus" and out["node_id"] == 5 and out["identity_ok"]
    rows = {r["object"]: r for r in out["configuration"]}
    assert rows["0x6098:0"]["file"] == 17           # the file's homing method ...
    assert rows["0x6098:0"]["drive"] == 0           # ... not yet written to a fresh drive
    assert rows["0x60C2:2"]["match"]
    assert out["live"]["state"] == "switch on disabled"
    assert out["live"]["position"] == pytest.approx(10.0)   # the simulated motor's start
    assert out["live"]["negative_limit"] is False
    # A drive the service has not booted since its power-up holds its own defaults: that is
    # said, and its differences are not flagged as wrong.
    assert out["configured_by_service"] is False and "0x6098:0" in out["differing"]
    captured = main(["info", "focus", "--config", str(hw)])
    text = capsys.readouterr().out
    assert captured == 0 and "≠" not in text, text
    assert "· 0x6098:0" in text and "has not booted it since it powered up" in text, text


# ------------------------------------------------------------------------------ home
def test_home_all_in_safe_order_reports_timeout(hw, capsys):
    code, out = run(capsys, "home", "all", "--config", hw, "--keep-going")
    assert out["order"] == [["zd"], ["az"], ["focus"]]
    results = {r["drive"]: r for r in out["drives"]}
    assert results["zd"]["result"] == "done" and results["az"]["result"] == "done"
    assert results["az"]["position"] == pytest.approx(0.0, abs=0.05)
    focus = results["focus"]
    assert focus["result"] == "failed" and focus["method"] == 17 and focus["timeout"] == 1.0
    assert "did not finish within 1 s" in focus["error"]
    assert code == 1 and not out["ok"]
    assert out["error"].startswith("focus: ")


def test_home_failure_text_and_exit_code(hw, capsys):
    code = main(["home", "focus", "--config", str(hw)])
    captured = capsys.readouterr()
    assert code == 1
    assert "focus: homing FAILED: drive focus (node 5): homing (method 17) did not finish " \
           "within 1 s" in captured.out
    # the tool's own line (a library may log before it on a loaded machine, e.g. an SDO
    # answer that came after its time-out)
    assert captured.err.splitlines()[-1].startswith("tcs-commission home: focus:"), captured.err


def test_home_without_drives_is_hardware_error(hw, capsys):
    hw.write_text(hw.read_text().replace("boot_timeout = 3.0", "boot_timeout = 0.5"))
    code, out = run(capsys, "home", "zd", "--config", hw, "--no-simulate")
    assert code == 3, out
    assert "did not boot" in out["error"]


# ------------------------------------------------------------------------------ limits
def test_limit_search_writes_limits_keeping_comments(hw, capsys):
    before = hw.read_text()
    code, out = run(capsys, "limits", "az", "--config", hw, "--speed", "8", "--overtravel", "2",
                    "--margin", "0.5", "--write", "--force")   # --force: the file's are narrower
    assert code == 0, out
    sides = {s["side"]: s for s in out["sides"]}
    assert len(out["widening"]) == 4
    # Switches at physical ±6; homing put 0 at the home switch (physical 0.5).
    neg, pos = sides["negative"]["position"], sides["positive"]["position"]
    assert neg == pytest.approx(-6.5, abs=0.15) and pos == pytest.approx(5.5, abs=0.15)
    assert "0x60FD" in sides["positive"]["detected_by"] and "0x60FD" in sides["negative"]["detected_by"]
    assert out["proposal"] == {"axis": {"min": round(neg + 0.5, 4), "max": round(pos - 0.5, 4)},
                               "drive": {"min_position": round(neg + 0.25, 4),
                                         "max_position": round(pos - 0.25, 4)}}
    assert out["written"] == str(hw)
    after = hw.read_text()
    comments = [line.split("#", 1)[1] for line in before.splitlines() if "#" in line]
    for comment in comments:
        assert comment in after, f"comment lost: {comment!r}"
    assert "min = -4.5                  # cable wrap (test value)" not in after
    assert f"min = {round(neg + 0.5, 4)!r}" in after and "# cable wrap (test value)" in after
    config = load_config(hw)
    assert config.axes["az"].min == round(neg + 0.5, 4)
    assert config.drives["az"].max_position == round(pos - 0.25, 4)
    assert config.axes["zd"].min == -85.0                     # nothing else touched
    assert len(after.splitlines()) == len(before.splitlines())


def test_limit_search_never_widens_the_files_limits_without_force(hw, capsys):
    """The switch at +5.5 proposes max 5.0 (axis) and 5.25 (drive); the file's axis max 4.5 is
    narrower and stays, the drive's max_position 5.0 is narrower too: nothing is written."""
    before = hw.read_text()
    code, out = run(capsys, "limits", "az", "--config", hw, "--speed", "8", "--side", "positive",
                    "--margin", "0.5", "--write")
    assert code == 0, out
    assert out["sides"][0]["found"] and "0x60FD" in out["sides"][0]["detected_by"]
    widened = {w["key"] for w in out["widening"]}
    assert widened == {"axes.az.max", "drives.az.max_position"}, out["widening"]
    assert out["written"] is None and hw.read_text() == before
    assert out["sides"][0]["position"] == pytest.approx(5.5, abs=0.15)


def test_limit_search_never_writes_a_shipped_file(capsys):
    """--write on the shipped sim.toml (the default, or inside site-packages in a wheel install)
    is refused before any motion, with the way to do it on a copy; the file is unchanged."""
    from tcs.resources import hwconfig_file

    shipped = hwconfig_file("sim.toml")
    before = shipped.read_text()
    code, out = run(capsys, "limits", "az", "--config", shipped, "--write")
    assert code == 2, out
    assert "shipped with tcs" in out["error"] and "--config tcs.toml" in out["error"], out
    assert shipped.read_text() == before


def test_limit_search_says_how_long_it_may_take(hw, capsys):
    code = main(["limits", "zd", "--config", str(hw), "--no-home", "--side", "positive",
                 "--search", "25", "40", "--speed", "10", "--json"])
    captured = capsys.readouterr()
    assert "searching positive between 25.0000 and 40.0000 at 10/s: up to about 1 min" in captured.err, captured.err
    assert json.loads(captured.out)["worst_case_s"] == round(15 / 10 + 60)


def test_limit_search_without_switch_fails_and_writes_nothing(hw, capsys):
    before = hw.read_text()
    code, out = run(capsys, "limits", "zd", "--config", hw, "--no-home", "--side", "positive",
                    "--search", "25", "40", "--speed", "10", "--write")
    assert code == 1, out
    assert out["sides"][0]["found"] is False
    assert "no positive limit switch" in out["error"]
    assert out["written"] is None and hw.read_text() == before


def test_switch_watch_takes_input_or_limit_fault():
    # The two ways a drive reports its limit switch (the simulator faults, and sets 0x60FD).
    watch = SwitchWatch("limit_positive")
    assert not watch(DriveStatus("az", DriveState.OPERATION_ENABLED, position=1.0))
    assert watch(DriveStatus("az", DriveState.OPERATION_ENABLED, position=2.5, limit_positive=True))
    assert watch.position == 2.5 and "0x60FD" in watch.detected_by
    assert not watch(DriveStatus("az", DriveState.OPERATION_ENABLED, position=2.6,
                                 limit_positive=True))    # only the first cycle counts
    watch = SwitchWatch("limit_negative")
    fault = DriveFault("drive az (node 1)", 0x8612)
    assert watch(DriveStatus("az", DriveState.FAULT, position=-3.0, fault=fault))
    assert watch.position == -3.0 and "0x8612" in watch.detected_by
    # a limit fault alone is not a switch: only the input, seen once the drive stopped, is
    assert not watch.confirmed
    assert not watch.confirm(DriveStatus("az", DriveState.FAULT, position=-3.1, fault=fault))
    assert watch.confirm(DriveStatus("az", DriveState.FAULT, position=-3.1, fault=fault,
                                     limit_negative=True))
    assert watch.position == -3.0 and "0x60FD" in watch.detected_by
    other = SwitchWatch("limit_negative")
    assert not other(DriveStatus("az", DriveState.FAULT, position=-3.0,
                                 fault=DriveFault("drive az (node 1)", 0x8611)))


def test_proposal_keeps_margins():
    assert propose(-10.0, 20.0, 1.0) == {"axis": {"min": -9.0, "max": 19.0},
                                         "drive": {"min_position": -9.5, "max_position": 19.5}}
    assert propose(None, 20.0, 2.0) == {"axis": {"max": 18.0}, "drive": {"max_position": 19.0}}


# ------------------------------------------------------------------------------ jog
def test_jog_moves_inside_limits_and_refuses_beyond(hw, capsys):
    code, out = run(capsys, "jog", "az", "2.5", "--config", hw, "--speed", "10", "--unreferenced")
    assert code == 0, out
    assert out["start"] == pytest.approx(0.0, abs=1e-3)
    assert out["position"] == pytest.approx(2.5, abs=0.01)
    code, out = run(capsys, "jog", "az", "-7", "--config", hw, "--unreferenced")
    assert code == 2
    assert "outside the software limits [-4.5, 4.5]" in out["error"]
    code, out = run(capsys, "jog", "az", "1", "--speed", "500", "--config", hw)
    assert code == 2 and "--speed" in out["error"]


def test_jog_an_unreferenced_drive_only_creeps(hw, capsys):
    """Issue 22.10: an unreferenced drive counts its position from where it was switched on, so
    the software limits mean nothing: without --unreferenced it may only creep (creep_distance,
    default 1 % of the drive's range: 0.1 of AZ's 10 here), with a message saying why (old
    code: moved 2.5, limits checked in the arbitrary frame). --home or a configured creep
    distance lets it go further."""
    code, out = run(capsys, "jog", "az", "2.5", "--config", hw, "--speed", "10")
    assert code == 2, out
    assert "not referenced" in out["error"] and "--unreferenced" in out["error"]
    assert "--home" in out["error"] and "creep 0.1 " in out["error"]
    assert "position" not in out and out["referenced"] is False
    code, out = run(capsys, "jog", "az", "--", "-0.08", "--config", hw, "--speed", "10")
    assert code == 0, out  # a creep is allowed (and the limits are not what bounds it)
    assert out["position"] == pytest.approx(out["start"] - 0.08, abs=0.01)
    assert out["creep_distance"] == pytest.approx(0.1)
    code, out = run(capsys, "jog", "az", "2.5", "--config", hw, "--speed", "10", "--home")
    assert code == 0, out
    assert out["referenced"] is True
    assert out["position"] == pytest.approx(out["start"] + 2.5, abs=0.01)
    hw.write_text(hw.read_text(encoding="utf-8").replace(
        "following_error_window = 2.0\nmax_velocity = 20.0\nmax_acceleration = 100.0\nquick_stop",
        "following_error_window = 2.0\ncreep_distance = 3.0\nmax_velocity = 20.0\n"
        "max_acceleration = 100.0\nquick_stop", 1), encoding="utf-8")
    code, out = run(capsys, "jog", "az", "2.5", "--config", hw, "--speed", "10")
    assert code == 0, out
    assert out["creep_distance"] == 3.0 and out["referenced"] is False


def test_jog_a_profile_position_drive(hw, capsys):
    code, out = run(capsys, "jog", "focus", "-2", "--config", hw, "--speed", "4", "--unreferenced")
    assert code == 0, out
    assert out["start"] == pytest.approx(10.0) and out["position"] == pytest.approx(8.0, abs=0.01)


def test_info_of_a_silent_drive_is_hardware_error(hw, capsys):
    code, out = run(capsys, "info", "zd", "--config", hw, "--no-simulate")
    assert code == 3 and "node 2" in out["error"]


def test_drives_left_disabled_and_quiet_after_the_tool(hw, capsys):
    # The simulated drives run outside the tool here, as real hardware would.
    from tcs.sim.drive_network import start_simulated_drives

    sims = start_simulated_drives(load_config(hw))
    try:
        code, out = run(capsys, "jog", "az", "-1", "--config", hw, "--no-simulate", "--speed", "10",
                        "--unreferenced")
        assert code == 0, out
        time.sleep(0.5)            # past the heartbeat consumer time the tool had configured
        az = sims[1]
        assert az.logic.state.name == "SWITCH_ON_DISABLED"
        assert az.read_object(0x603F) == 0          # no fault (no 0x8130, no 0x8250)
        assert az.read_object(0x1016, 1) == 0       # heartbeat consumer switched off
        assert az.read_object(0x6064) == pytest.approx(-10000, abs=20)
    finally:
        sims.stop()


# ------------------------------------------------------------------------------ pointing
TRUE = {"IA": 40.0, "IE": -20.0, "CA": 10.0, "AN": 12.0, "AW": -8.0, "TF": 15.0}


def synthetic_dump(path: Path, n: int = 50, noise: float = 1.0) -> None:
    """A dump of a known AZ-ZD model (arcsec in TRUE) with noise on the sky."""
    site = Site(28.76, -17.88, 2326.0)
    header = DumpHeader("AZ-ZD", site, TimeBase(), Refraction())
    write_dump_header(path, header)
    rng = np.random.default_rng(7)
    az = rng.uniform(0, 360, n)
    zd = np.degrees(np.arccos(rng.uniform(math.sin(math.radians(15)), math.sin(math.radians(85)), n)))
    model = PointingModel("AZ-ZD", {k: v / 3600 for k, v in TRUE.items()}, site.latitude)
    m1, m2 = model.apply(az, zd)
    cos_e = np.cos(np.radians(90 - zd))
    m1 = m1 + rng.normal(0, noise / 3600, n) / cos_e
    m2 = m2 + rng.normal(0, noise / 3600, n)
    utc = 1.7e9 + 60 * np.arange(n)
    ra, dec = Astrometry(site).icrs_from_observed(az, zd, utc)
    for k in range(n):
        append_sample(path, Sample(utc[k], ra[k], dec[k], az[k], zd[k], m1[k], m2[k]))


def test_pointing_report_from_dump(hw, capsys, tmp_path):
    dump = tmp_path / "night.dump"
    synthetic_dump(dump)
    report = tmp_path / "report"
    code, out = run(capsys, "pointing", "--config", hw, "--dump", dump, "--out", report,
                    "--terms", "IA,IE,CA,AN,AW,TF")
    assert code == 0, out
    coefficients = out["coefficients"]
    for term, value in TRUE.items():
        c = coefficients[term]
        assert abs(c["arcsec"] - value) < max(4 * c["error_arcsec"], 0.5), (term, c)
    assert out["rms_arcsec"] < 2.5 < out["rms_before_arcsec"]
    names = {Path(f).name for f in out["files"]}
    assert names == {"report.md", "model.json", "pointing.model", "samples.dump",
                     "residuals_az.png", "residuals_el.png", "skymap.png"}
    for png in ("residuals_az.png", "residuals_el.png", "skymap.png"):
        png_ok(report / png)
    data = json.loads((report / "model.json").read_text())
    corr = np.array(data["correlation"]["matrix"])
    assert data["correlation"]["terms"] == ["IA", "IE", "CA", "AN", "AW", "TF"]
    assert np.allclose(np.diag(corr), 1.0) and np.allclose(corr, corr.T)
    assert len(data["samples"]) == 50
    md = (report / "report.md").read_text()
    assert "| IA |" in md and "![skymap](skymap.png)" in md and "## Correlations" in md
    loaded = ModelStore(report).load("pointing")
    assert loaded.get("IA") * 3600 == pytest.approx(coefficients["IA"]["arcsec"])


def test_pointing_synthetic_run_for_the_simulator(hw, capsys, tmp_path):
    code, out = run(capsys, "pointing", "--config", hw, "--synthetic", "30", "--out",
                    tmp_path / "pm", "--fix", "TX=0", "--no-plots", "--noise", "0.5")
    assert code == 0, out
    assert out["n_samples"] == 30
    assert out["coefficients"]["TX"]["fixed"] is True
    assert out["coefficients"]["AN"]["arcsec"] == pytest.approx(12.0, abs=1.0)
    assert not list((tmp_path / "pm").glob("*.png"))


def test_pointing_refuses_bad_terms_and_files(hw, capsys, tmp_path):
    code, out = run(capsys, "pointing", "--config", hw, "--synthetic", "10", "--terms", "IA,XX",
                    "--out", tmp_path / "x")
    assert code == 2 and "XX" in out["error"]
    code, out = run(capsys, "pointing", "--config", hw, "--dump", tmp_path / "missing.dump")
    assert code == 2 and "missing.dump" in out["error"]
    code, out = run(capsys, "pointing", "--config", hw, "--synthetic", "3", "--out", tmp_path / "y")
    assert code == 1 and "too few" in out["error"]


def test_pointing_guided_run_reads_the_operator(hw, capsys, tmp_path, monkeypatch):
    # Stars placed where they are now (so they are visible); the operator skips the first
    # star offered and types positions for the others until the input ends.
    config = load_config(hw)
    site = Site(config.site.latitude, config.site.longitude, config.site.height)
    az = np.array([10.0, 100.0, 190.0, 280.0, 45.0, 225.0])
    zd = np.array([30.0, 50.0, 40.0, 60.0, 20.0, 35.0])
    ra, dec = Astrometry(site).icrs_from_observed(az, zd, np.full(6, time.time()))
    stars = tmp_path / "stars.txt"
    stars.write_text("# name ra dec\n" + "".join(f"star {i} {float(r)!r} {float(d)!r}\n"
                                                   for i, (r, d) in enumerate(zip(ra, dec))))
    order = _spread(az, 90.0 - zd, 6)               # the order the stars are offered in
    assert order[0] == 4                            # the highest first
    answers = "".join(f"{float(az[k]) + 0.01!r} {float(zd[k]) - 0.005!r}\n" for k in order[1:])
    monkeypatch.setattr(sys, "stdin", io.StringIO("s\n" + answers))
    code, out = run(capsys, "pointing", "--config", hw, "--guided", stars, "--count", "6",
                    "--terms", "IA", "--out", tmp_path / "g", "--no-plots")  # 5 samples: 1 term
    assert code == 0, out
    assert out["n_samples"] == 5
    assert (tmp_path / "g" / "samples.dump").read_text().count("\n") == 6 + 5
    data = json.loads((tmp_path / "g" / "model.json").read_text())
    for sample, k in zip(data["samples"], order[1:]):   # ideal = the star where it is now
        assert sample["ideal"][0] == pytest.approx(az[k], abs=0.5)
        assert sample["ideal"][1] == pytest.approx(zd[k], abs=0.5)
        assert sample["measured"] == [float(az[k]) + 0.01, float(zd[k]) - 0.005]


# ------------------------------------------------------------------------------ CLI
def test_subprocess_scan_and_home(hw):
    env_cmd = [sys.executable, "-m", "tcs.commission"]
    proc = subprocess.run([*env_cmd, "scan", "--config", str(hw), "--json", "--nodes", "1-6"],
                          capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    data = json.loads(proc.stdout)
    assert data["command"] == "scan" and [n["drive"] for n in data["nodes"]] == ["az", "zd", "focus"]
    proc = subprocess.run([*env_cmd, "scan", "--config", str(hw), "--json", "--nodes", "1-3"],
                          capture_output=True, text=True, timeout=120, cwd=ROOT)
    data = json.loads(proc.stdout)
    assert proc.returncode == 0 and data["missing"] == [] and data["not_probed"] == ["focus"]
    proc = subprocess.run([*env_cmd, "home", "focus", "--config", str(hw)],
                          capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert proc.returncode == 1
    assert "homing FAILED" in proc.stdout and "did not finish within 1 s" in proc.stderr


def test_usage_and_configuration_errors(hw, capsys, tmp_path):
    code, out = run(capsys, "home", "nosuch", "--config", hw)
    assert code == 2 and "neither an axis nor a drive" in out["error"] and "focus" in out["error"]
    bad = tmp_path / "bad.toml"
    bad.write_text(hw.read_text().replace("max_velocity = 20.0", "max_velocity = -1.0", 1))
    code, out = run(capsys, "scan", "--config", bad)
    assert code == 2 and "drives.az.max_velocity" in out["error"]
    assert main(["jog"]) == 2          # argparse usage error
    capsys.readouterr()


def test_other_master_is_heard(hw):
    channel = {"interface": "virtual", "channel": f"tcs-cm-{uuid.uuid4().hex[:8]}"}
    listener = can.Bus(**channel)
    network = canopen.Network(listener)
    network.NOTIFIER_SHUTDOWN_TIMEOUT = 0.0
    network.connect()
    master = can.Bus(**channel)
    try:
        assert other_master(network, 127, 0.1) is None
        task = master.send_periodic(can.Message(arbitration_id=0x080, data=b"",
                                                is_extended_id=False), 0.01)
        try:
            assert "SYNC" in other_master(network, 127, 2.0)
        finally:
            task.stop()
        # frames already queued may still arrive: the bus goes quiet within a few windows
        assert any(other_master(network, 127, 0.1) is None for _ in range(20))
        task = master.send_periodic(can.Message(arbitration_id=0x77F, data=b"\x05",
                                                is_extended_id=False), 0.02)
        try:
            assert "heartbeat of node 127" in other_master(network, 127, 2.0)
        finally:
            task.stop()
    finally:
        network.disconnect()
        master.shutdown()


async def test_refuses_a_bus_with_another_master_over_socketcand(hw, capsys):
    # The drives behind a socketcand gateway (the tcs-sim shape); a running "service" sends
    # SYNC on that bus. The tool hears it and refuses; once it is gone, the tool works.
    import asyncio

    from tcs.sim.drive_network import start_simulated_drives
    from tcs.sim.socketcand_server import SocketcandServer

    config = load_config(hw)
    server = SocketcandServer(config.can.channel)
    port = await server.start()
    remote = hw.with_name("remote.toml")
    remote.write_text(hw.read_text().replace('interface = "virtual"',
                                             f'interface = "socketcand"\nport = {port}'))
    sims = start_simulated_drives(config)
    service = can.Bus(interface="virtual", channel=config.can.channel)
    sync = service.send_periodic(can.Message(arbitration_id=0x080, data=b"", is_extended_id=False), 0.01)
    try:
        code = await asyncio.to_thread(main, ["scan", "--config", str(remote), "--json",
                                              "--nodes", "1-3"])
        out = json.loads(capsys.readouterr().out)
        assert code == 3 and "another master is active (SYNC frames" in out["error"]
        assert "stop the service (systemctl stop tcs-server)" in out["error"]
        # --force goes on beside the running master and still finds every drive
        code = await asyncio.to_thread(main, ["scan", "--config", str(remote), "--json",
                                              "--nodes", "1-6", "--force"])
        out = json.loads(capsys.readouterr().out)
        assert code == 0, out
        assert [n["drive"] for n in out["nodes"]] == ["az", "zd", "focus"]
        sync.stop()
        code = await asyncio.to_thread(main, ["scan", "--config", str(remote), "--json",
                                              "--nodes", "1-6"])
        out = json.loads(capsys.readouterr().out)
        assert code == 0, out
        assert [n["drive"] for n in out["nodes"]] == ["az", "zd", "focus"]
    finally:
        sync.stop()
        service.shutdown()
        sims.stop()
        await server.stop()


def test_progress_bar_draws_one_line():
    stream = io.StringIO()
    bar = ProgressBar(stream=stream, enabled=True, width=10)
    bar.update("az", 0.5, "1.000", force=True)
    bar.update("zd", 1.0, force=True)
    bar.close()
    text = stream.getvalue()
    assert "\raz [#####-----]  50% 1.000 | zd [##########] 100%" in text
    assert text.endswith("\n")
    quiet = io.StringIO()
    ProgressBar(stream=quiet).update("az", 0.5)   # not a terminal: draws nothing
    assert quiet.getvalue() == ""


# ------------------------------------------------------------------ command-line fixes
def test_too_few_pointing_samples_refused_unless_forced(hw, capsys, tmp_path):
    # 6 samples for the 8 alt-az terms: a fit that follows the noise
    code, out = run(capsys, "pointing", "--config", hw, "--synthetic", "6", "--no-plots",
                    "--out", tmp_path / "refused")
    assert code == 1
    assert "too few samples: 6 for 8 terms" in out["error"] and "--force" in out["error"]
    assert not (tmp_path / "refused").exists()
    code, out = run(capsys, "pointing", "--config", hw, "--synthetic", "6", "--no-plots",
                    "--out", tmp_path / "forced", "--force")
    assert code == 0, out
    assert any("not trustworthy" in w for w in out["warnings"])
    assert "> **Warning:** only 6 samples for 8 fitted terms" in (tmp_path / "forced" / "report.md").read_text()
    # enough samples for fewer terms: no refusal, no sample warning
    code, out = run(capsys, "pointing", "--config", hw, "--synthetic", "9", "--no-plots",
                    "--terms", "IA,IE,CA", "--out", tmp_path / "few-terms")
    assert code == 0, out
    assert not any("not trustworthy" in w for w in out["warnings"])


def test_strong_correlations_are_warned_about():
    from tcs.commission.pointing_report import warnings_of

    info = {"n_samples": 40, "correlation": {"terms": ["IA", "CA"]},
            "strong_correlations": [{"terms": ["IA", "CA"], "r": 0.97}]}
    [warning] = warnings_of(info)
    assert "strongly correlated terms" in warning and "IA/CA (+0.970)" in warning


def test_axis_names_in_any_case_and_negative_distance_before_options(hw, capsys):
    config = load_config(hw)
    assert resolve_target(config, "AZ").drive == "az" == resolve_target(config, "Az").drive
    code, out = run(capsys, "jog", "AZ", "--", "-1.5", "--speed", "10", "--config", hw, "--unreferenced")
    assert code == 0, out
    assert out["drive"] == "az" and out["position"] == pytest.approx(-1.5, abs=0.01)
    code, out = run(capsys, "home", "ZD", "--config", hw)
    assert code == 0, out


def test_help_is_plain_text_and_every_tool_has_a_version(capsys):
    for argv in (["--help"], ["jog", "--help"], ["scan", "--help"], ["pointing", "--help"]):
        assert main(argv) == 0
        text = capsys.readouterr().out
        assert "``" not in text and ":mod:" not in text and ":class:" not in text, text
    assert main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == "tcs-commission 0.1.0"
    for tool in ("tcs.cli.server", "tcs.cli.passwd", "tcs.cli.sim", "tcs.cli.client"):
        proc = subprocess.run([sys.executable, "-m", tool, "--version"], capture_output=True,
                              text=True, timeout=60)
        assert proc.returncode == 0 and proc.stdout.strip().endswith(" 0.1.0"), (tool, proc.stderr)
    proc = subprocess.run([sys.executable, "-m", "tcs.cli.passwd", "--help"], capture_output=True,
                          text=True, timeout=60)
    assert "read level" in proc.stdout and "write level" in proc.stdout


def test_progress_fits_the_terminal_and_prints_plain_lines_elsewhere():
    wide = {f"drive{i}": (i / 7, f"{i * 123.456:.3f}") for i in range(7)}
    tty = io.StringIO()
    bar = ProgressBar(stream=tty, enabled=True, columns=80)
    for name, (fraction, text) in wide.items():
        bar.update(name, fraction, text, force=True)
    assert len(bar.line()) > 150                           # what did not fit before
    drawn = tty.getvalue().split("\r")[-1].rstrip()
    assert 0 < len(drawn) <= 79 and "drive0" in drawn
    log = io.StringIO()                                    # not a terminal: plain lines
    plain = ProgressBar(stream=log, plain_every=0.0)
    plain.update("az", 0.25, "1.000")
    plain.update("az", 0.5, "2.000")
    plain.close()
    lines = log.getvalue().splitlines()
    assert len(lines) == 3 and "\r" not in log.getvalue()
    assert lines[0].endswith("az  25% 1.000") and lines[-1].endswith("az  50% 2.000")
    assert lines[0].startswith("[  0 s]")


def test_machine_lock_one_holder_per_bus(hw):
    """The machine-wide bus lock: one holder per bus name, released when closed (or when
    the holder's process ends); the in-process virtual bus needs none."""
    import dataclasses

    from tcs.drivers.bus_check import AnotherMaster, machine_lock

    port = 20000 + uuid.uuid4().int % 20000  # a bus name of its own (tests run in parallel)
    section = dataclasses.replace(load_config(hw).can, interface="socketcand", port=port)
    assert machine_lock(dataclasses.replace(section, interface="virtual")) is None
    lock = machine_lock(section)
    try:
        with pytest.raises(AnotherMaster, match="another process of this machine"):
            machine_lock(section)
        other = machine_lock(dataclasses.replace(section, port=section.port + 1))  # another bus
        other.close()
    finally:
        lock.close()
    machine_lock(section).close()
