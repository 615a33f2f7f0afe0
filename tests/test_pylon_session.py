"""Whole capture sessions through pylon's emulated camera (config/rigs/sim-pylon.yaml, made small).

The simulated rig's scene is rendered for each exposure into the image the emulated camera serves
(sim.pylon_scene), so every frame goes through the vendor SDK and the real driver. A session
matches the ground truth; a camera unplugged mid-session stops it with one line (exit 2),
nothing captured is lost, and ``--resume`` finishes with the samples an uninterrupted run gets.
"""
from __future__ import annotations

import json
import os
import sys

os.environ.setdefault("PYLON_CAMEMU", "1")

from pathlib import Path

import numpy as np
import pytest
import yaml

from goniofrost.app.cli import main
from goniofrost.capture.engine import SessionFault
from goniofrost.capture.journal import Journal
from goniofrost.capture.inputs import load_inputs
from goniofrost.capture.options import SessionOptions, StopRule
from goniofrost.capture.runner import capture
from goniofrost.datasets import shown_material
from goniofrost.rig.simulated import rig_devices

from test_session import MATERIAL, small_plan
from goniofrost.rig.hardware import SimOptions

REPO = Path(__file__).resolve().parents[1]
M = 4


def write_rig(path: Path) -> Path:
    """sim-pylon.yaml with a short calibration and a small sensor (as tests/test_session.py's)."""
    rig = yaml.safe_load((REPO / "config" / "rigs" / "sim-pylon.yaml").read_text())
    rig["camera"].update(exposures_s=[0.000015625, 0.002, 0.008, 0.032, 0.128], dark_frames=1, flat_frames=1)
    rig["camera"]["intrinsics"].update(image_size_px=[240, 180], focal_px=[2400.0, 2400.0],
                                       principal_point_px=[119.5, 89.5])
    path.write_text(yaml.safe_dump(rig, sort_keys=False))
    return path


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    folder = tmp_path_factory.mktemp("pylon-session")
    rig = write_rig(folder / "rig.yaml")
    plan, _ = small_plan(rig, M, folder / "plan.json")
    return folder, rig, plan


@pytest.fixture(scope="module")
def uninterrupted(setup):
    folder, rig, plan = setup
    session = folder / "whole"
    assert main(capture_args(rig, plan, session)) == 0
    return session


def capture_args(rig, plan, session, *extra) -> list[str]:
    return ["capture", "--rig", str(rig), "--plan", str(plan), "--session", str(session),
            "--material", MATERIAL, "--no-progress", "--speedup", "50", *extra]


def samples(session: Path) -> list:
    with Journal.open(session / "session.sqlite") as journal:
        return journal.samples()


def test_a_session_through_the_emulated_camera_measures_the_ground_truth(setup, uninterrupted):
    sys.path.insert(0, str(REPO / "benchmarks"))
    from camera_kinds import sample_errors  # the benchmark's measure, at its smallest setting

    folder, rig, plan = setup
    report = json.loads((uninterrupted / "report.json").read_text())
    assert report["samples"] == M
    errors = sample_errors(uninterrupted, rig, plan, MATERIAL)
    assert errors["samples"] == M and max(errors["median_per_channel"]) < 0.02
    # every frame came through the SDK: the DNGs carry the emulated camera's serial number and the
    # exposure it read back (15.625 us asked, 16 us taken)
    darks = sorted((uninterrupted / "calibration").glob("dark_e0_*.dng"))
    from drivers.rawfile import raw_exposure_s, read_raw
    meta = read_raw(darks[0]).metadata
    assert meta["serial"] == "0815-0000" and meta["requested_exposure_s"] == 0.000015625
    assert raw_exposure_s(darks[0]) == pytest.approx(16e-6, rel=1e-9)


def test_an_unplugged_camera_mid_session_is_one_line_then_resume_finishes(setup, uninterrupted, tmp_path, capsys):
    folder, rig, plan = setup
    calibration_frames = len(list((uninterrupted / "calibration").glob("*.dng")))
    session = tmp_path / "s"

    def unplug_in_the_samples(hardware):  # two frames into the second sample's bracket, or so
        hardware.extra["scene"].arm("unplug", calibration_frames + 4)

    with pytest.raises(SessionFault) as fault:
        capture(load_inputs(rig, plan), session, sim=SimOptions(material=shown_material(MATERIAL), speedup=50, on_ready=unplug_in_the_samples), devices=rig_devices,
                options=SessionOptions(progress=False))
    message = str(fault.value)
    assert "\n" not in message
    assert "pylon camera 0815-0000: the camera was unplugged (device removed) during a" in message
    done = samples(session)
    assert 1 <= len(done) < M
    assert main(capture_args(rig, plan, session, "--resume")) == 0
    capsys.readouterr()
    resumed, whole = samples(session), samples(uninterrupted)
    assert sorted(r.plan_index for r in resumed) == list(range(M))
    assert resumed[:len(done)] == done                       # nothing captured before the unplug was lost
    np.testing.assert_allclose([r.rgb for r in sorted(resumed, key=lambda r: r.plan_index)],
                               [r.rgb for r in sorted(whole, key=lambda r: r.plan_index)], rtol=0.03)


def test_a_grab_timeout_mid_session_exits_2_with_one_line(setup, uninterrupted, tmp_path):
    folder, rig, plan = setup
    calibration_frames = len(list((uninterrupted / "calibration").glob("*.dng")))
    raw = yaml.safe_load(rig.read_text())
    raw["camera"]["timeout_s"] = 0.5
    short = tmp_path / "rig.yaml"
    short.write_text(yaml.safe_dump(raw, sort_keys=False))

    def stall(hardware):
        hardware.extra["scene"].arm("stall", calibration_frames + 1)

    with pytest.raises(SessionFault, match=r"pylon camera 0815-0000: no frame within 0.5 s \(camera.timeout_s\) "
                                           r"beyond a [0-9.e-]+ s exposure"):
        capture(load_inputs(short, plan), tmp_path / "s", sim=SimOptions(material=shown_material(MATERIAL), speedup=50, on_ready=stall),
                devices=rig_devices, options=SessionOptions(progress=False))
    assert main(capture_args(short, plan, tmp_path / "s", "--resume")) == 0
    assert sorted(r.plan_index for r in samples(tmp_path / "s")) == list(range(M))


def test_a_ladder_outside_the_camera_s_range_is_refused_before_anything_moves(setup, tmp_path, capsys):
    folder, rig, plan = setup
    raw = yaml.safe_load(rig.read_text())
    raw["camera"]["exposures_s"] = [0.002, 0.008, 0.032, 0.128, 16.384]
    wide = tmp_path / "rig.yaml"
    wide.write_text(yaml.safe_dump(raw, sort_keys=False))
    assert main(capture_args(wide, plan, tmp_path / "s")) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].endswith("pylon camera 0815-0000: camera.exposures_s [16.384] outside the camera's exposure "
                            "range [1e-06, 10] s")
    assert not (tmp_path / "s").exists()  # refused before the first step: a refused run leaves nothing


def test_a_wrong_serial_is_one_line_naming_the_rig_file_and_the_serials_found(setup, tmp_path, capsys):
    folder, rig, plan = setup
    raw = yaml.safe_load(rig.read_text())
    raw["camera"]["serial"] = "40012345"
    wrong = tmp_path / "rig.yaml"
    wrong.write_text(yaml.safe_dump(raw, sort_keys=False))
    assert main(capture_args(wrong, plan, tmp_path / "s")) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].endswith(f"pylon camera: no camera with serial '40012345' (camera.serial of {wrong}) of device "
                            "class BaslerCamEmu; found ['0815-0000']")
    assert not (tmp_path / "s").exists()


def pylon_version_of(raw: dict) -> dict:
    """A simulated rig's file with its camera made the emulated pylon camera (12 bits)."""
    raw["camera"].update(kind="pylon", pixel_format="BayerRG12", timeout_s=5.0)
    raw["sim"]["camera"].update(black_level=64, white_level=4095)
    return raw


def test_align_recovers_the_misalignment_through_the_emulated_camera(tmp_path):
    from test_alignment import BUILT_WRONG, small_misaligned_rig

    from goniofrost.capture.align import align

    rig = small_misaligned_rig(tmp_path / "rig.yaml")
    rig.write_text(yaml.safe_dump(pylon_version_of(yaml.safe_load(rig.read_text())), sort_keys=False))
    doc = align(rig, tmp_path / "ALIGNMENT.json", progress=False, devices=rig_devices, sim=SimOptions(speedup=100))
    found = np.array([doc["offsets_deg"][n] for n in ("camera_arm", "sample_yaw", "sample_tilt")])
    assert np.all(np.abs(found - BUILT_WRONG) < 0.05), found
    assert doc["images"]["used"] == doc["images"]["poses"]


@pytest.mark.parametrize("kind, taken_s", [("sim", 0.000015625), ("pylon", 0.000016)])
def test_rig_snap_takes_a_frame_and_a_bracket_with_any_camera_kind(setup, tmp_path, kind, taken_s):
    """The console's exposure check through the simulated camera and through pylon's emulation: the
    frame carries the exposure the camera took (pylon rounds 15.625 us to 16 us), the bracket finds
    the white card's markers."""
    from goniofrost.rig.file import load_checked_rig
    from goniofrost.capture.snap import snap

    folder, rig, plan = setup
    raw = yaml.safe_load(rig.read_text())
    if kind == "sim":
        raw["camera"]["kind"] = "sim"
        for key in ("pixel_format", "gain_db"):
            raw["camera"].pop(key)
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    one = snap(load_checked_rig(path), target="white", exposure_s=0.000015625, out=tmp_path / "one.png",
               material=shown_material(MATERIAL), move_to={"camera_arm": 30.0}, devices=rig_devices)
    assert one.exposures_s == [pytest.approx(taken_s, abs=1e-12)] and (tmp_path / "one.png").is_file()
    bracket = snap(load_checked_rig(path), target="white", exposure_s=None, out=tmp_path / "bracket.png",
                   material=shown_material(MATERIAL), move_to={"camera_arm": 30.0}, devices=rig_devices)
    assert bracket.problem is None and bracket.markers_found == [4, 5, 6, 7], bracket
    assert bracket.capture_exposures_s and min(bracket.roi_pixels) > 0


def test_a_simulated_sensor_deeper_than_the_pixel_format_is_refused(setup, tmp_path, capsys):
    folder, rig, plan = setup
    raw = yaml.safe_load(rig.read_text())
    raw["sim"]["camera"]["white_level"] = 16383   # sim.yaml's 14-bit sensor behind a 12-bit format
    deep = tmp_path / "rig.yaml"
    deep.write_text(yaml.safe_dump(raw, sort_keys=False))
    assert main(capture_args(deep, plan, tmp_path / "s")) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1].endswith(
        "sim.camera.white_level: expected at most 4095 (the 12-bit camera.pixel_format), found 16383")
