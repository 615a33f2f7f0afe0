"""The alignment fit: offsets recovered from synthetic noisy images, what is identifiable, and the
clear errors of too few images or a fit that does not describe the data."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from calib.holder import DEFAULT_LAYOUT, WHITE_MARKER_IDS
from goniofrost.rig.file import load_checked_rig
from goniofrost.core.errors import ConfigError
from planner.alignment import AlignmentError, Observation, alignment_poses, fit_alignment
from planner.kinematics import arm_side, forward
from goniofrost.rig.hardware import SimOptions

RIG_FILE = Path(__file__).resolve().parents[1] / "config" / "rigs" / "sim.yaml"
BUILT_WRONG = np.array([0.6, -1.1, 0.4])   # camera_arm, sample_yaw, sample_tilt (the rig)


@pytest.fixture(scope="module")
def rig():
    return load_checked_rig(RIG_FILE)


def synthetic(rig, offsets, *, px_noise=0.1, rate_noise=5e-4, lamp_elevation_deg=0.0, seed=0, poses=None):
    """Observations of the white card as a rig with these zero errors would give them: corners
    projected through the camera model at the physical pose (+ Gaussian pixel noise), the tile's
    brightness A n.L (+ relative noise), and no solvePnP rotations."""
    rng = np.random.default_rng(seed)
    corners = np.concatenate(list(DEFAULT_LAYOUT.marker_corners(WHITE_MARKER_IDS).values()))
    plane = np.column_stack([corners, np.zeros(len(corners))])
    cam, side = rig.view.camera, arm_side(rig)
    out = []
    for q in (alignment_poses(rig) if poses is None else poses):
        physical = q + offsets
        w_i, w_o = forward(rig, physical)
        R, t = cam.extrinsics(w_i, w_o, side)
        image = cam.project(plane, R, t) + rng.normal(0, px_noise, (len(corners), 2))
        e, tilt = np.radians(lamp_elevation_deg), np.radians(physical[2])
        cos_i = np.cos(e) * w_i[2] + np.sin(e) * np.sin(tilt)
        out.append(Observation(q, corners, image, 0.42 * cos_i * (1 + rng.normal(0, rate_noise))))
    return out


def test_offsets_are_recovered_from_noisy_images(rig):
    fit = fit_alignment(rig, rig.view.camera, synthetic(rig, BUILT_WRONG))
    assert np.all(np.abs(fit.offsets_deg - BUILT_WRONG) < 0.02), fit.offsets_deg
    assert np.all(fit.stderr_deg < 0.02) and np.all(fit.stderr_deg > 0)
    # the standard errors describe the scatter: the truth within 4 sigma
    assert np.all(np.abs(fit.offsets_deg - BUILT_WRONG) < 4 * fit.stderr_deg + 1e-3)
    assert 0.08 < fit.residual_px_rms < 0.2 and fit.photometric_rms < 1e-3
    assert abs(fit.lamp_elevation_deg) < 4 * fit.lamp_elevation_stderr_deg + 1e-3


def test_a_raised_lamp_is_measured_and_does_not_bias_the_axes(rig):
    fit = fit_alignment(rig, rig.view.camera, synthetic(rig, BUILT_WRONG, lamp_elevation_deg=0.5, seed=1))
    assert np.all(np.abs(fit.offsets_deg - BUILT_WRONG) < 0.02)
    assert fit.lamp_elevation_deg == pytest.approx(0.5, abs=0.05)


def test_without_the_tile_brightness_arm_and_yaw_cannot_be_told_apart(rig):
    """The marker corners alone fix only arm - yaw: the same images fit a rig whose arm and yaw
    zeros are both 1 deg further, to the last digit."""
    a = synthetic(rig, BUILT_WRONG, px_noise=0.0, rate_noise=0.0)
    b = synthetic(rig, BUILT_WRONG + [1.0, 1.0, 0.0], px_noise=0.0, rate_noise=0.0)
    np.testing.assert_allclose(np.concatenate([o.image_px for o in a]), np.concatenate([o.image_px for o in b]),
                               atol=1e-6)
    assert not np.allclose([o.rate for o in a], [o.rate for o in b], rtol=1e-3)   # the tile tells them apart
    with pytest.raises(AlignmentError, match=r"align: the white tile's brightness was measured in only 0 images "
                                             r"\(need 6\): the yaw and arm zeros cannot be told apart without it"):
        fit_alignment(rig, rig.view.camera, [dataclasses.replace(o, rate=None) for o in a])


def test_too_few_images_and_a_bad_fit_are_clear_errors(rig):
    few = synthetic(rig, BUILT_WRONG)[:5]
    with pytest.raises(AlignmentError, match=r"^align: only 5 images with a readable marker set \(need 8\)"):
        fit_alignment(rig, rig.view.camera, few)
    # a camera model 3 % off in focal length: the corners cannot be fitted
    wrong_lens = dataclasses.replace(rig.view.camera, fx=rig.view.camera.fx * 1.03, fy=rig.view.camera.fy * 1.03)
    with pytest.raises(AlignmentError, match=r"^align: the fitted offsets leave the marker corners \d+\.\d\d px RMS "
                                             r"from the model \(limit 1 px\): the camera model"):
        fit_alignment(rig, wrong_lens, synthetic(rig, BUILT_WRONG))
    # a lamp that flickers 3 % between images
    rng = np.random.default_rng(3)
    flicker = [dataclasses.replace(o, rate=o.rate * (1 + rng.normal(0, 0.03))) for o in synthetic(rig, BUILT_WRONG)]
    with pytest.raises(AlignmentError, match=r"^align: the white tile's brightness departs from cos\(theta_i\) by "
                                             r"\d+\.\d\d % RMS \(limit 1 %\)"):
        fit_alignment(rig, rig.view.camera, flicker)


def test_the_poses_spread_over_every_axis_and_stay_in_limits(rig):
    q = alignment_poses(rig)
    assert 24 <= len(q) <= 36
    for axis, (lo, hi) in enumerate(a.limits_deg for a in rig.ordered_axes):
        assert np.all((q[:, axis] >= lo) & (q[:, axis] <= hi)) and np.ptp(q[:, axis]) >= 60
    assert np.any(q[:, 1] < 0) and np.any(q[:, 1] > 0) and np.any(q[:, 2] < 0) and np.any(q[:, 2] > 0)
    w_i, w_o = forward(rig, q)
    assert np.all(np.degrees(np.arccos(w_o[:, 2])) <= 62.0 + 1e-9)
    np.testing.assert_array_equal(q, alignment_poses(rig))   # deterministic


# ----- goniofrost align on the simulated rig built wrong on purpose ----------------------------------
def small_misaligned_rig(path: Path, **camera) -> Path:
    """config/rigs/sim-misaligned.yaml with a smaller sensor (4 px/mm, 400 x 300) and a short ladder."""
    import yaml
    raw = yaml.safe_load((RIG_FILE.parent / "sim-misaligned.yaml").read_text())
    raw["camera"]["intrinsics"].update(image_size_px=[400, 300], focal_px=[4000.0, 4000.0],
                                       principal_point_px=[199.5, 149.5])
    raw["camera"].update(exposures_s=[0.004, 0.016, 0.064], **camera)
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    return path


def test_align_recovers_the_injected_misalignment_and_writes_the_file(tmp_path, capsys):
    import json
    from goniofrost.app.cli import main
    from planner.alignment_file import load_alignment

    rig = small_misaligned_rig(tmp_path / "rig.yaml")
    out = tmp_path / "ALIGNMENT.json"
    assert main(["align", "--rig", str(rig), "--out", str(out), "--no-progress", "--speedup", "100"]) == 0
    doc = json.loads(out.read_text())
    found = np.array([doc["offsets_deg"][n] for n in ("camera_arm", "sample_yaw", "sample_tilt")])
    assert np.all(np.abs(found - BUILT_WRONG) < 0.05), found
    assert doc["residual_px"]["rms"] < 0.3 and doc["images"]["used"] == doc["images"]["poses"] >= 24
    assert doc["lamp"]["applied"] is False and abs(doc["lamp"]["elevation_deg"]) < 0.1
    printed = capsys.readouterr().out
    assert "camera_arm" in printed and "+- " in printed and "--alignment" in printed
    # what plan and capture read back: the offsets, with the rig's axis names
    assert load_alignment(out, ["camera_arm", "sample_yaw", "sample_tilt"]).offsets_deg == doc["offsets_deg"]
    assert load_checked_rig(rig, alignment=out).alignment.offsets_deg == doc["offsets_deg"]   # its own rig
    assert doc["rig"]["name"] == "sim-rig-misaligned"
    # another rig with axes named alike (sim.yaml) refuses it: its zeros are another assembly's
    with pytest.raises(ConfigError) as refused:
        load_checked_rig(RIG_FILE, alignment=out)
    assert str(refused.value) == (f"{out}: rig.name: expected 'sim-rig', the rig it is used on (an alignment is "
                                  "measured per rig: run goniofrost align on this one), found 'sim-rig-misaligned'")


def test_align_refuses_bad_input_before_anything_moves(tmp_path, capsys):
    import yaml
    from goniofrost.app.cli import main

    raw = yaml.safe_load(RIG_FILE.read_text())
    del raw["camera"]
    (tmp_path / "nocam.yaml").write_text(yaml.safe_dump(raw))
    out = tmp_path / "ALIGNMENT.json"
    assert main(["align", "--rig", str(tmp_path / "nocam.yaml"), "--out", str(out)]) == 2
    assert (f"{tmp_path / 'nocam.yaml'}: camera: expected a camera section with the camera model (intrinsics, mount), "
            f"found 'nothing'") in capsys.readouterr().err
    (tmp_path / "a-file").write_text("keep me")   # the bottom layer's check: atomic_file.check_output_file
    assert main(["align", "--rig", str(RIG_FILE), "--out", str(tmp_path / "a-file" / "a.json")]) == 2
    assert capsys.readouterr().err == (f"goniofrost align: error: {tmp_path / 'a-file'}: cannot write: a part of the "
                                       f"path is a file, not a directory\n")
    assert main(["align", "--rig", str(RIG_FILE), "--out", str(out), "--speedup", "-1"]) == 2
    assert "command line: --speedup: expected a simulated clock speed-up > 0, found -1.0" in capsys.readouterr().err
    assert not out.exists()


def test_align_with_a_camera_unlike_its_model_fails_clearly_and_writes_nothing(tmp_path):
    from goniofrost.capture.align import align
    from goniofrost.rig.simulated import rig_devices
    from goniofrost.core.camera_model import CameraModel
    from sim.camera import HolderRenderer

    rig = small_misaligned_rig(tmp_path / "rig.yaml")
    out = tmp_path / "ALIGNMENT.json"

    def longer_lens(hardware):   # the real lens is 4 % longer than the rig file says
        model = hardware.camera.model
        truth = CameraModel(**{**model.__dict__, "fx": model.fx * 1.04, "fy": model.fy * 1.04})
        hardware.camera._renderer = HolderRenderer(truth, hardware.camera.arm_side)

    with pytest.raises(AlignmentError, match=r"^align: the fitted offsets leave the marker corners \d+\.\d\d px RMS "
                                             r"from the model \(limit 1 px\): the camera model"):
        align(rig, out, progress=False, sim=SimOptions(speedup=100, on_ready=longer_lens), devices=rig_devices)
    assert not out.exists()


def test_a_failed_align_stops_and_confirms_the_axes_switches_the_lamp_off_and_journals(tmp_path):
    from goniofrost.capture.align import align
    from goniofrost.rig.simulated import rig_devices
    from goniofrost.capture.journal import Journal
    from goniofrost.capture.plan_runner import SessionFault
    from goniofrost.capture.records import EventKind, RunStatus

    rig = small_misaligned_rig(tmp_path / "rig.yaml")
    out, frames, seen = tmp_path / "ALIGNMENT.json", tmp_path / "frames", {}

    def alarm_on_the_arm(hardware):  # the arm's drive is in alarm: the first move of the plan fails
        seen["lamp"] = hardware.simulation.lamp_model
        hardware.simulation.device("camera_arm").inject_fault("alarm")

    frames.mkdir()
    with pytest.raises(SessionFault) as caught:
        align(rig, out, progress=False, frames=frames, sim=SimOptions(on_ready=alarm_on_the_arm), devices=rig_devices)
    message = str(caught.value)
    assert message.startswith("device fault during Home: camera_arm")
    assert "Stopped camera_arm at " in message and "; the lamp is off. No alignment was written; the run is " \
           f"journaled in {frames / 'align.sqlite'}. Fix the cause, then run goniofrost align again" in message
    assert not out.exists() and seen["lamp"].is_on is False
    with Journal.open(frames / "align.sqlite") as journal:
        # a driver's log record (a "device" event) may fall between the engine's own
        (start, end), kinds = journal.last_run(), [e["kind"] for e in journal.events() if e["kind"] != EventKind.DEVICE]
    assert (start.program, end.status, end.reason, end.lamp_off) == ("align", RunStatus.FAULT, message, True)
    assert all(s.confirmed for s in end.stops) and kinds[-3:] == [EventKind.FAULT, EventKind.STOP, EventKind.LAMP]


# ----- Ctrl-C and rig stop during align: one line, exit 130 (issue 51, B2) ----------------------------
def _start_align(rig, out, frames):
    import subprocess
    import sys

    return subprocess.Popen([sys.executable, "-m", "goniofrost", "align", "--rig", str(rig), "--out", str(out),
                             "--frames", str(frames), "--no-progress", "--speedup", "10"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            cwd=Path(__file__).resolve().parents[1])


def _wait_for_moves(frames, proc, count: int = 2, timeout: float = 120.0) -> None:
    """Poll align's journal until ``count`` Move steps are done (the run is under way)."""
    import time

    from goniofrost.capture.journal import Journal

    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        if proc.poll() is not None:
            pytest.fail(f"align ended before its moves ({proc.returncode}): {proc.stderr.read()}")
        try:
            with Journal.open_read_only(frames / "align.sqlite") as journal:
                done = [s for s in journal.steps() if s["kind"] == "Move" and s["status"] == "done"]
        except Exception:  # noqa: BLE001 - not created yet
            done = []
        if len(done) >= count:
            return
        time.sleep(0.02)
    proc.kill()
    pytest.fail(f"no {count} moves within {timeout} s")


@pytest.mark.parametrize("how", ["ctrl-c", "rig stop"])
def test_a_stopped_align_says_so_in_one_line_and_exits_130(how, tmp_path, capsys):
    """A stop during align ended in a 45-85-line traceback (exit 1), though the axes and the lamp
    were handled: now one line, exit 130, as every other program."""
    import os
    import re
    import signal

    from goniofrost.app.cli import main
    from goniofrost.capture.journal import Journal
    from goniofrost.capture.records import RunStatus

    rig, out, frames = small_misaligned_rig(tmp_path / "rig.yaml"), tmp_path / "ALIGNMENT.json", tmp_path / "frames"
    frames.mkdir()
    proc = _start_align(rig, out, frames)
    try:
        _wait_for_moves(frames, proc)
        if how == "ctrl-c":
            proc.send_signal(signal.SIGINT)
        else:
            assert main(["rig", "stop", "--rig", str(rig)]) == 0
        assert proc.wait(timeout=60) == 130
        err = proc.stderr.read()
    finally:
        proc.kill()
    who = "SIGINT" if how == "ctrl-c" else f"a stop request from process {os.getpid()}"
    assert re.fullmatch(rf"goniofrost align: interrupted by {who} (during \w+|at plan sample \d+)\. Stopped camera_arm "
                        r"at -?[\d.]+ deg, sample_yaw at -?[\d.]+ deg, sample_tilt at -?[\d.]+ deg; the lamp is off\. "
                        rf"No alignment was written; the run is journaled in {re.escape(str(frames))}/align\.sqlite\. "
                        r"To carry on from here, run the same command again\n", err), err
    with Journal.open(frames / "align.sqlite") as journal:
        _start, end = journal.last_run()
    assert end.status is RunStatus.STOPPED_BY_OPERATOR and end.lamp_off is True and all(s.confirmed for s in end.stops)
    assert not out.exists()
