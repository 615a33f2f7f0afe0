"""The folder camera for DSLRs: the README's gphoto2 recipe, the camera's own shutter speeds, and
every RAW file's own exposure read back (EXIF ExposureTime) and checked.

``gphoto2`` is a stand-in (tests/standins/gphoto2.py) on PATH that takes the command line of the
recipe and writes a DNG with the exposure in its EXIF, as the real one downloads the camera's.
"""
from __future__ import annotations

import os
import stat
import sys
from pathlib import Path

import pytest
from frame_script import CAMERA_MODEL

from calib.config import shutter_seconds, validate_camera_section
from drivers.camera import CameraError
from drivers.rawfile import raw_exposure_s
from goniofrost.rig.hardware import open_camera
from goniofrost.core.errors import ConfigError

REPO = Path(__file__).resolve().parents[1]
# the recipe of docs/explanations/camera.md: capture and download into the watched folder, the shutter set by its label
RECIPE = "gphoto2 --set-config shutterspeed={shutter} --capture-image-and-download --filename {folder}/%Y%m%d-%H%M%S-%n.%C"
SPEEDS = ["1/4000", "1/2000", "1/1000", "1/500", "1/250", "1/125", "1/60", "1/30", "1/15", "1/8", "1/4", "0.5",
          "1", "2", "4", "8", "15", "30"]


@pytest.fixture
def gphoto2(tmp_path, monkeypatch):
    """Put the stand-in first on PATH as ``gphoto2``; return the watched folder."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    script = bin_dir / "gphoto2"
    script.write_text(f"#!/bin/sh\nexec {sys.executable} {REPO / 'tests' / 'standins' / 'gphoto2.py'} \"$@\"\n")
    script.chmod(script.stat().st_mode | stat.S_IXUSR)
    monkeypatch.setenv("PATH", f"{bin_dir}{os.pathsep}{os.environ['PATH']}")
    monkeypatch.setenv("PYTHONPATH", str(REPO))
    hot = tmp_path / "hot"
    hot.mkdir()
    return hot


def section(folder, **extra) -> dict:
    return {"kind": "rawfile", "exposures_s": [0.001, 0.004, 0.016, 0.064], "target_snr": 50.0,
            "folder": str(folder), "trigger_command": RECIPE, "shutter_speeds": SPEEDS, "timeout_s": 10.0,
            **CAMERA_MODEL, **extra}


def test_shutter_speed_labels_are_read_as_seconds():
    assert [shutter_seconds(x) for x in ("1/4000", "0.5", "30", "2.5s", "1/0", "fast", 4)] == \
        [0.00025, 0.5, 30.0, 2.5, None, None, None]


def test_the_ladder_moves_onto_the_camera_s_own_shutter_speeds():
    settings = validate_camera_section(section("/tmp"), "rig.yaml")
    # 0.004 s is nearest 1/250, 0.016 nearest 1/60, 0.064 nearest 1/15
    assert settings["exposures_s"] == [0.001, 0.004, 1 / 60, 1 / 15]


def test_two_rungs_on_one_shutter_speed_are_refused():
    with pytest.raises(ConfigError, match=r"^rig.yaml: camera.exposures_s: expected rungs on different shutter "
                                          r"speeds of camera.shutter_speeds \(0.001 and 0.0011 s both fall on "
                                          r"'1/1000'\), found \[0.001, 0.0011\]$"):
        validate_camera_section(section("/tmp", exposures_s=[0.001, 0.0011]), "rig.yaml")
    with pytest.raises(ConfigError, match=r"camera.shutter_speeds: expected a list of shutter speed labels"):
        validate_camera_section(section("/tmp", shutter_speeds=["1/4000", "bulb"]), "rig.yaml")


def test_a_rung_beyond_the_camera_s_shutter_speeds_is_refused_not_clamped():
    # 1e-5 s became 1/4000 (25 times longer: the specular peaks saturate) and 120 s became 30 s
    with pytest.raises(ConfigError) as refused:
        validate_camera_section(section("/tmp", exposures_s=[0.00001, 0.001, 0.004, 120]), "rig.yaml")
    assert str(refused.value) == (
        "rig.yaml: camera.exposures_s: expected rungs within half a stop of the range of camera.shutter_speeds, "
        "'1/4000' to '30' (0.00025 to 30 s); outside it: [1e-05, 120.0], found [1e-05, 0.001, 0.004, 120.0]")
    # up to half a stop beyond an end is the end speed, as within the range the nearest speed
    ends = validate_camera_section(section("/tmp", exposures_s=[0.0002, 0.001, 40.0]), "rig.yaml")["exposures_s"]
    assert ends == [0.00025, 0.001, 30.0]


@pytest.mark.parametrize("kind, key, value, readers", [
    ("rawfile", "serial", "40012345", "pylon"),            # a DSLR rig copied from a pylon one
    ("rawfile", "gain_db", 12, "pylon"),
    ("pylon", "target_command", "changer {target}", "rawfile"),  # pylon asks the operator
    ("pylon", "exposure_tolerance", 0.2, "rawfile or sim"),
    ("sim", "trigger_command", "gphoto2 {shutter}", "rawfile"),
])
def test_a_key_the_camera_kind_never_reads_is_refused_not_ignored(kind, key, value, readers):
    given = {"kind": kind, "exposures_s": [0.001, 0.004], "target_snr": 50.0, **CAMERA_MODEL, key: value,
             **({"folder": "/tmp"} if kind == "rawfile" else {})}
    with pytest.raises(ConfigError) as refused:
        validate_camera_section(given, "rig.yaml")
    assert str(refused.value) == (f"rig.yaml: camera.{key}: expected no {key} for camera kind {kind!r} "
                                  f"(only kind {readers} reads it), found {value!r}")
    # a section checked before (every default filled in, serial None included) passes again
    checked = validate_camera_section({**given, key: None} if key == "serial" else
                                      {k: v for k, v in given.items() if k != key}, "rig.yaml")
    assert validate_camera_section(checked, "rig.yaml") == checked


def test_the_gphoto2_recipe_captures_into_the_folder_with_the_camera_s_label(gphoto2, tmp_path):
    assert RECIPE in (REPO / "docs/explanations/camera.md").read_text() and RECIPE in (REPO / "config/rigs/template.yaml").read_text()
    settings = validate_camera_section(section(gphoto2), "rig.yaml")
    cam = open_camera(section(gphoto2))
    cam.connect()
    frame = cam.capture(settings["exposures_s"][2], tmp_path / "f.dng")
    # the label 1/60 went to the camera, and its file's own exposure is the frame's
    assert frame.exposure_s == pytest.approx(1 / 60, rel=1e-6)
    assert raw_exposure_s(frame.path) == pytest.approx(1 / 60, rel=1e-6)
    assert frame.path == tmp_path / "f.dng" and frame.path.is_file()
    assert Path(frame.metadata["source"]).parent == gphoto2 and frame.metadata["source"].endswith("-0001.dng")


def test_a_file_with_the_wrong_exif_exposure_is_refused_naming_it_and_both_values(gphoto2, tmp_path, monkeypatch):
    cam = open_camera(section(gphoto2))
    cam.connect()
    monkeypatch.setenv("STANDIN_EXPOSURE_S", "0.002")   # the camera took 1/500 when asked for 1/1000
    with pytest.raises(CameraError) as refused:
        cam.capture(0.001, tmp_path / "f.dng")
    [left] = list(gphoto2.glob("*.dng"))                # refused files stay where they are
    assert str(refused.value) == (f"folder camera: {left} was exposed 0.002 s (EXIF ExposureTime), asked for "
                                  f"0.001 s: more than camera.exposure_tolerance 0.05 apart")
    assert not (tmp_path / "f.dng").exists()


def test_an_exposure_within_the_tolerance_is_taken_with_the_file_s_value(gphoto2, tmp_path, monkeypatch):
    cam = open_camera(section(gphoto2))
    cam.connect()
    monkeypatch.setenv("STANDIN_EXPOSURE_S", "0.00102")
    assert cam.capture(0.001, tmp_path / "f.dng").exposure_s == pytest.approx(0.00102, rel=1e-6)


def test_a_file_that_is_not_new_is_refused(gphoto2, tmp_path, monkeypatch):
    cam = open_camera(section(gphoto2))
    cam.connect()
    first = cam.capture(0.004, tmp_path / "a.dng")
    monkeypatch.setenv("STANDIN_REPEAT", "1")           # the camera downloads the previous picture again
    with pytest.raises(CameraError, match=rf"^folder camera: {gphoto2}/\S+-0002.dng is not new: the same file as "
                                          rf"frame {first.path} \(asked for 0.004 s\)$"):
        cam.capture(0.004, tmp_path / "b.dng")


def test_a_file_without_an_exposure_is_refused(tmp_path):
    import numpy as np
    import tifffile

    hot = tmp_path / "hot"
    hot.mkdir()
    plain = tmp_path / "plain.dng"
    tifffile.imwrite(plain, np.zeros((8, 8), np.uint16))
    cam = open_camera(section(hot, trigger_command=f"cp {plain} {{folder}}/IMG_{{exposure_s}}.dng", shutter_speeds=None))
    cam.connect()
    with pytest.raises(CameraError, match=rf"^folder camera: {hot}/IMG_0.001.dng has no exposure time \(EXIF "
                                          rf"ExposureTime\) to check against the 0.001 s asked for$"):
        cam.capture(0.001, tmp_path / "f.dng")


def test_a_trigger_that_cannot_run_is_one_line(tmp_path):
    cam = open_camera(section(tmp_path, trigger_command="no-such-gphoto2 {shutter}"))
    with pytest.raises(CameraError, match=r"^camera trigger 'no-such-gphoto2' cannot run: \[Errno 2\] No such file or directory"):
        cam.capture(0.001, tmp_path / "f.dng")


def test_the_session_s_frame_carries_the_exposure_the_file_was_taken_with(gphoto2, tmp_path, monkeypatch):
    """The executor (what every capture, align and snap goes through) hands the bracket the RAW
    file's own exposure, not the one asked for."""
    from types import SimpleNamespace

    from goniofrost.capture.executor import StepExecutor
    from goniofrost.capture.steps import Expose

    class Lamp:
        def photodiode(self) -> float:
            return 1.0

    class Clock:
        def now(self) -> float:
            return 0.0

    cam = open_camera(section(gphoto2))
    cam.connect()
    hardware = SimpleNamespace(axes={}, lamp=Lamp(), camera=cam, clock=Clock(), simulated=False, simulation=None)
    monkeypatch.setenv("STANDIN_EXPOSURE_S", "0.00103")   # 3 % long: within the tolerance
    frame = StepExecutor(hardware, tmp_path)(Expose(0.001, "raw/f.dng"))
    assert frame.exposure_s == pytest.approx(0.00103, rel=1e-6) and frame.path == tmp_path / "raw" / "f.dng"
    assert frame.raw.linear.shape == (64, 64)
