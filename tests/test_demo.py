"""``goniofrost demo`` at full size (slow: run with ``pytest -m slow tests/test_demo.py``)."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from goniofrost.core.grid import FULL_GRID
from goniofrost.brdf.merl_file import read_merl


@pytest.mark.slow
def test_demo_writes_a_full_merl_file_a_preview_and_a_report(tmp_path):
    out = tmp_path / "demo"
    proc = subprocess.run([sys.executable, "-m", "goniofrost", "demo", "--out", str(out), "--no-progress"],
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr
    brdf = read_merl(out / "session" / "brdf.binary", FULL_GRID)
    assert np.isfinite(brdf[FULL_GRID.valid_cells]).all() and np.isnan(brdf[~FULL_GRID.valid_mask]).all()
    import matplotlib.image
    assert matplotlib.image.imread(out / "preview.png").ndim == 3
    report = json.loads((out / "report.json").read_text())
    assert report["demo"]["material"] == "builtin:red-plastic" and report["demo"]["target_error"] == 0.005
    target = report["target_error"]  # a Bayesian plan of 40, measured batch by batch until the target
    assert report["samples"] == target["samples_used"] <= 40 and report["samples"] in target["batch_ends"]
    assert target["stopped"] in ("target reached", "plan used up") and target["confidence"] == 0.95
    if target["stopped"] == "target reached":  # what the bound promised holds for this material
        assert target["bound"] <= 0.005 and report["ground_truth"]["log_relative_mse"] <= 0.005
    assert "with 95 % confidence" in proc.stdout and "an RMS error of about 7 %" in proc.stdout
    truth = report["ground_truth"]
    # no more than 20 % above reconstructing the same cells from exact values (1.05 measured; 1.29
    # with the noisier simulated camera before the camera-model calibration)
    assert truth["log_relative_mse"] <= 1.2 * truth["log_relative_mse_exact_samples"]
    predicted = truth["point_prediction_before_centring"]
    assert predicted == report["prediction"]["point_prediction_before_centring"]
    assert 0.5 <= predicted / truth["log_relative_mse"] <= 2  # the "within a factor 2"
    assert (out / "session" / "brdf.std.binary").is_file()
    assert report["demo"]["rendering_snr_db"] > 10
    assert f"wrote {out / 'session' / 'brdf.binary'}" in proc.stdout


def test_demo_refuses_to_replace_a_folder_it_did_not_make(tmp_path, capsys):
    from goniofrost.app.cli import main

    keep = tmp_path / "session" / "notes.txt"
    keep.parent.mkdir()
    keep.write_text("mine")
    assert main(["demo", "--out", str(tmp_path), "--no-progress"]) == 2
    assert (f"{tmp_path / 'session'}: exists but holds no session.sqlite, so it is not a previous demo session; "
            "refusing to delete it") in capsys.readouterr().err
    assert keep.read_text() == "mine"


def test_the_demo_finds_its_packaged_rig_file():
    from goniofrost.app.demo import default_rig_path

    assert default_rig_path().is_file() and default_rig_path().name == "sim.yaml"


def test_ctrl_c_in_the_demo_is_one_line_exit_130_and_names_no_resume_option(tmp_path, monkeypatch, capsys):
    from goniofrost.app import demo
    from goniofrost.app.cli import main
    from goniofrost.capture import runner
    from goniofrost.capture.signals import SessionInterrupted
    from goniofrost.rig.hardware import NO_SIM

    def interrupted(*args, options=None, **kwargs):  # the engine's words after a Ctrl-C, with the given next step
        raise SessionInterrupted(f"interrupted by SIGINT at plan sample 3. Run {options.rerun} to continue")

    monkeypatch.setattr(runner, "capture", interrupted)
    monkeypatch.setattr(demo, "run_demo", lambda out, *request, **options: demo.capture_fresh(
        None, tmp_path / "session", NO_SIM, None, False))
    assert main(["demo", "--out", str(tmp_path), "--no-progress"]) == 130  # not a traceback
    assert capsys.readouterr().err == ("goniofrost demo: interrupted by SIGINT at plan sample 3. Run the demo again "
                                       "to continue\n")


def test_a_negative_target_error_is_refused_before_anything_runs(tmp_path, capsys):
    from goniofrost.app.cli import main

    assert main(["demo", "--out", str(tmp_path / "demo"), "--target-error", "-1", "--no-progress"]) == 2
    assert capsys.readouterr().err == ("goniofrost demo: error: command line: --target-error: expected a log-relative "
                                       "MSE >= 0 (0 captures the whole plan), found -1.0\n")
    assert not (tmp_path / "demo").exists()


def test_a_rig_another_program_drives_is_refused_before_the_training(tmp_path, monkeypatch, capsys):
    """The demo trained for 45 s, then its capture found the simulated rig held by another
    rehearsal; it refuses at once now, with the capture's own words, and writes nothing."""
    from goniofrost.app import demo
    from goniofrost.app.cli import main
    from goniofrost.rig.file import load_checked_rig
    from goniofrost.rig.lock import rig_lock

    monkeypatch.setattr(demo, "train_without", lambda *a, **k: pytest.fail("the demo trained"))
    with rig_lock(load_checked_rig(demo.default_rig_path()), "capture") as lock:
        assert main(["demo", "--out", str(tmp_path / "demo"), "--no-progress"]) == 2
    assert capsys.readouterr().err == (
        f"goniofrost demo: error: rig 'sim-rig' is in use by capture (process {os.getpid()} of {lock.holder.user}): one "
        f"program drives a device at a time; wait for it to finish or stop it (goniofrost rig stop, or Ctrl-C in its terminal)\n")
    assert not (tmp_path / "demo").exists()


@pytest.mark.parametrize("name", ["plan.json", "reference.binary", "preview.png", "report.json"])
def test_a_folder_in_the_way_of_a_demo_file_is_refused_before_the_training(name, tmp_path, monkeypatch, capsys):
    """A folder named report.json (or reference.binary, preview.png) in --out was found after the
    training and the whole capture, plan.json after the training. (Nothing in a previous demo's
    session folder is in the way: the demo replaces that folder whole, brdf.bsdf of --bsdf too.)"""
    import planner.reach

    from goniofrost.app import demo
    from goniofrost.app.cli import main

    monkeypatch.setattr(planner.reach, "is_cached", lambda *a, **k: True)   # nor the library tabulated beside it
    monkeypatch.setattr(planner.reach, "reachability", lambda *a, **k: pytest.fail("the rig's reach was computed"))
    monkeypatch.setattr(demo, "train_without", lambda *a, **k: pytest.fail("the demo trained"))
    (tmp_path / name).mkdir()
    assert main(["demo", "--out", str(tmp_path), "--bsdf", "--no-progress"]) == 2
    assert capsys.readouterr().err == (f"goniofrost demo: error: {tmp_path / name}: cannot write: it is a directory, "
                                       f"where the demo writes a file: move it away or choose another --out\n")
    assert [p.name for p in tmp_path.iterdir()] == [name] and not list((tmp_path / name).iterdir())
