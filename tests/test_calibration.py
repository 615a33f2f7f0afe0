"""Calibration through the simulated camera: accuracy with noise, bracketing, every failure mode.

The calibration and each sample are plans of steps (goniofrost.capture.calibration_steps,
sample_steps) executed on a camera bench; calib only computes on the frames."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from calib.holder import SAMPLE_MARKER_IDS
from calib.roi import UPSAMPLE, expected_view, locate_patch, marker_offset_px, polygon_mask, read_markers
from drivers.rawfile import read_raw
from calib import (CalibrationError, CalibrationRecord, MarkerError, NotMeasured, NotMeasuredReason, PatchTooSmallError,
                   WrongTargetError, validate_camera_section)
from drivers.camera import CameraError
from drivers.rawfile import RawFileError
from goniofrost.capture.calibration_steps import calibration_steps
from goniofrost.capture.executor import BenchHardware, StepExecutor
from goniofrost.rig.hardware import open_camera
from goniofrost.capture.sample_steps import sample_steps
from goniofrost.capture.steps import drive
from goniofrost.core.errors import ConfigError
from sim.camera import SimCamera
from goniofrost.datasets import material_brdf
from sim.camera_bench import CameraBench
from sim.lamp_model import LampModel

RIG = Path(__file__).resolve().parents[1] / "config" / "rigs" / "sim.yaml"
# (theta_i, theta_o, phi_o) in degrees: near-specular, off-specular, grazing light and view
POSES = [(0.0, 20.0, 180.0), (30.0, 32.0, 180.0), (45.0, 10.0, 90.0), (20.0, 60.0, 150.0),
         (65.0, 40.0, 200.0), (10.0, 70.0, 30.0)]


@pytest.fixture(scope="module")
def rig():
    return yaml.safe_load(RIG.read_text())


@pytest.fixture(scope="module")
def spec(merl_npz):
    return lambda name: material_brdf(f"nbrdf:{merl_npz}:{name}")


class BenchPlans:
    """The calibration and sample plans run on a camera bench (frames into ``out_dir`` itself).

    ``measure`` hands the previous sample's value to the next bracket, as the session plan does.
    """

    def __init__(self, camera, lamp, settings, record=None, clock=None):
        self.hardware = BenchHardware(lamp, camera, clock)
        self.settings = validate_camera_section(settings, "camera settings")
        self.record, self.expected = record, None

    def calibrate(self, out_dir, white_pose=None):
        plan = calibration_steps(self.settings, white_pose, folder="")
        self.record = drive(plan, StepExecutor(self.hardware, out_dir))
        return self.record

    def measure(self, w_i, w_o, out_dir, sample_id):
        plan = sample_steps(self.settings, self.record, (w_i, w_o), sample_id, self.expected, folder="")
        m = drive(plan, StepExecutor(self.hardware, out_dir))
        self.expected = None if isinstance(m, NotMeasured) else np.maximum(m.rgb, 1e-6)
        return m


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory, rig, spec):
    """One calibration (seed 0 sensor) shared by the tests: its journal form, reloaded."""
    out = tmp_path_factory.mktemp("calibration")
    bench = CameraBench(spec("gold-metallic-paint2"), rig["sim"]["camera"], rig["camera"], seed=0)
    cal = BenchPlans(bench.camera, bench.lamp, rig["camera"], clock=bench.clock)
    record = cal.calibrate(out, white_pose=bench.pose)
    return json.loads(json.dumps(record.to_dict()))


def _calibrator(rig, calibrated, bench, **settings):
    return BenchPlans(bench.camera, bench.lamp, {**rig["camera"], **settings},
                      record=CalibrationRecord.from_dict(calibrated), clock=bench.clock)


def _errors(rig, calibrated, spec, name, tmp_path):
    bench = CameraBench(spec(name), rig["sim"]["camera"], rig["camera"], seed=0)   # the calibrated sensor
    bench.lamp.on()
    cal = _calibrator(rig, calibrated, bench)
    rel, norm = [], []
    for k, angles in enumerate(POSES):
        w_i, w_o = bench.set_angles(*angles)
        m = cal.measure(w_i, w_o, tmp_path, k)
        truth = bench.camera.ground_truth(w_i, w_o)
        rel.append(m.rgb / truth - 1)
        norm.append((m.rgb - truth) / m.sigma)
        assert m.frames_taken + m.frames_skipped == len(rig["camera"]["exposures_s"])
        assert m.frames_taken == len(m.raw_paths) == len(m.exposures_s) and all(p.is_file() for p in m.raw_paths)
        assert np.all(m.snr >= rig["camera"]["target_snr"]) and m.flags == []
    return np.abs(rel), np.abs(norm)


@pytest.mark.parametrize("name", ["white-diffuse-bball", "gold-metallic-paint2"])
def test_calibrated_brdf_within_2_percent_with_noise(rig, calibrated, spec, name, tmp_path):
    rel, norm = _errors(rig, calibrated, spec, name, tmp_path)
    assert np.all(np.median(rel, axis=0) <= 0.02), np.median(rel, axis=0)
    assert np.mean(norm <= 3.0) >= 0.8   # the reported uncertainty describes the error


def test_calibration_record_round_trip_and_tamper(rig, calibrated, tmp_path):
    record = CalibrationRecord.from_dict(calibrated)
    ladder = len(rig["camera"]["exposures_s"])
    width, height = rig["camera"]["intrinsics"]["image_size_px"]
    assert record.dark.shape == (ladder, height, width) and record.flat.shape == (height, width)
    green = np.concatenate([record.flat[0::2, 1::2].ravel(), record.flat[1::2, 0::2].ravel()])
    for plane in (record.flat[0::2, 0::2], green, record.flat[1::2, 1::2]):   # R, G, B: mean 1 each
        assert plane.mean() == pytest.approx(1.0, abs=1e-5)
    assert record.flat.min() < 0.9   # vignetting was measured, not assumed away
    assert np.all(record.scale > 0) and np.all(record.scale_sigma / record.scale < 0.01)
    assert record.to_dict() == calibrated
    copy = tmp_path / "calibration.npz"
    copy.write_bytes(Path(calibrated["arrays"]).read_bytes() + b"x")
    with pytest.raises(CalibrationError, match="changed since the record was written"):
        CalibrationRecord.from_dict({**calibrated, "arrays": str(copy)})
    with pytest.raises(CalibrationError, match="expected version 1"):
        CalibrationRecord.from_dict({**calibrated, "version": 9})


class _BrighterLamp(LampModel):
    """The lamp model after it has drifted 20 % brighter than at calibration."""

    def relative_intensity(self, t=None):
        return 1.2 * super().relative_intensity(t)


def _drifted_bench(spec, rig):
    bench = CameraBench(spec("white-diffuse-bball"), rig["sim"]["camera"], rig["camera"], seed=0)
    bench.model = bench.lamp.model = bench.camera.lamp = _BrighterLamp(bench.clock, 0.02, 0)
    bench.lamp.on()
    return bench


def test_lamp_drift_is_normalised_by_the_photodiode(rig, calibrated, spec, tmp_path):
    bench = _drifted_bench(spec, rig)
    w_i, w_o = bench.set_angles(30.0, 30.0, 120.0)
    m = _calibrator(rig, calibrated, bench).measure(w_i, w_o, tmp_path, 1)
    assert m.lamp_relative == pytest.approx(1.2, abs=0.01)
    np.testing.assert_allclose(m.rgb, bench.camera.ground_truth(w_i, w_o), rtol=0.02)


class _BlindLamp:
    """A lamp whose photodiode always reads nominal: drift goes uncorrected."""

    def __init__(self, lamp):
        self.lamp = lamp

    def on(self):
        self.lamp.on()

    def off(self):
        self.lamp.off()

    def photodiode(self):
        return 1.0


def test_without_the_photodiode_drift_biases_the_result(rig, calibrated, spec, tmp_path):
    bench = _drifted_bench(spec, rig)
    w_i, w_o = bench.set_angles(30.0, 30.0, 120.0)
    cal = BenchPlans(bench.camera, _BlindLamp(bench.lamp), rig["camera"], record=CalibrationRecord.from_dict(calibrated),
                     clock=bench.clock)
    m = cal.measure(w_i, w_o, tmp_path, 1)
    assert np.all(m.rgb / bench.camera.ground_truth(w_i, w_o) > 1.15)


def test_bracketing_takes_only_the_frames_it_needs(rig, calibrated, spec, tmp_path):
    bench = CameraBench(spec("gold-metallic-paint2"), rig["sim"]["camera"], rig["camera"], seed=0)
    bench.lamp.on()
    w_i, w_o = bench.set_angles(30.0, 50.0, 180.0)
    easy = _calibrator(rig, calibrated, bench, target_snr=20.0).measure(w_i, w_o, tmp_path, 1)
    ladder = len(rig["camera"]["exposures_s"])
    assert easy.frames_taken == 1 and easy.frames_skipped == ladder - 1 and easy.flags == []
    hard = _calibrator(rig, calibrated, bench, target_snr=1e6).measure(w_i, w_o, tmp_path, 2)
    # no exposure reaches SNR 1e6: longer frames until the next would saturate, then flagged
    assert hard.frames_taken > easy.frames_taken and hard.flags == ["low-snr"]
    assert hard.exposures_s == sorted(hard.exposures_s) and hard.exposures_s[-1] >= easy.exposures_s[-1]
    assert np.all(hard.snr > easy.snr)


def test_bright_specular_peak_steps_down_then_starts_from_the_last_sample(rig, calibrated, spec, tmp_path):
    bench = CameraBench(spec("gold-metallic-paint2"), rig["sim"]["camera"], rig["camera"], seed=0)
    bench.lamp.on()
    w_i, w_o = bench.set_angles(20.0, 20.0, 180.0)   # mirror direction: BRDF ~ 26 1/sr
    cal = _calibrator(rig, calibrated, bench)
    first, second = (cal.measure(w_i, w_o, tmp_path, k) for k in (3, 4))
    # the first start (a white-like guess) saturates: shorter frames until one is clean
    assert first.exposures_s[0] == 0.001 and first.frames_taken >= 3
    ladder = len(rig["camera"]["exposures_s"])
    assert second.frames_taken == 1 and second.frames_skipped == ladder - 1   # started from the last value
    truth = bench.camera.ground_truth(w_i, w_o)
    for m in (first, second):
        np.testing.assert_allclose(m.rgb, truth, rtol=0.02)


def test_saturated_scene_is_not_measured_with_a_lower_limit_below_the_truth(rig, calibrated, spec, tmp_path):
    params = {**rig["sim"]["camera"], "signal_e_s": 2.0e9}   # 10^4 x too bright a lamp
    bench = CameraBench(spec("gold-metallic-paint2"), params, rig["camera"], seed=0)
    bench.lamp.on()
    w_i, w_o = bench.set_angles(20.0, 20.0, 180.0)
    # the rig cannot measure it, which is a typed record (not an error): the shortest exposure was
    # taken, and the clipped pixels give a lower limit of the BRDF (below the
    # truth where the shortest exposure saturates it)
    bright = _calibrator(rig, calibrated, bench).measure(w_i, w_o, tmp_path, 4)
    assert isinstance(bright, NotMeasured) and bright.reason is NotMeasuredReason.SATURATED
    assert min(bright.exposures_s) == rig["camera"]["exposures_s"][0] == 1.5625e-05
    truth = bench.camera.ground_truth(w_i, w_o) * 1e4   # the calibration's lamp was 10^4 x dimmer
    assert np.all(bright.lower_limit > 0) and np.all(bright.lower_limit < truth)
    # the clipped pixels say 1.3 to 2.3 % of the truth here (saturated at about 1/50 of their level)
    assert np.all(np.isinf(bright.upper_limit)) and np.all(bright.lower_limit > truth / 100)
    assert bright.text() == (f"sample 4: not measured (saturated): patch pixels saturate even at the shortest exposure "
                             f"1.5625e-05 s; BRDF above {'/'.join(format(v, '.3g') for v in bright.lower_limit)} 1/sr (R/G/B)")


def test_dark_scene_is_not_measured_or_flagged(rig, calibrated, spec, tmp_path):
    bench = CameraBench(spec("gold-metallic-paint2"), rig["sim"]["camera"], rig["camera"], seed=0)
    bench.lamp.on()
    w_i, w_o = bench.set_angles(70.0, 50.0, 0.0)   # far from specular, grazing light: BRDF ~ 0.005
    short = {"exposures_s": [0.001]}
    # no channel reaches the minimum with the ladder's longest exposure: the rig cannot measure it,
    # which is a typed record (not an error), with an upper limit of the BRDF above the truth
    dark = _calibrator(rig, calibrated, bench, **short, min_snr=30.0).measure(w_i, w_o, tmp_path, 5)
    assert isinstance(dark, NotMeasured) and dark.reason is NotMeasuredReason.BELOW_DETECTION_LIMIT
    assert dark.sample_id == 5 and dark.min_snr == 30.0 and dark.longest_exposure_s == 0.001
    assert dark.best_snr < 30.0 and dark.frames_taken == 1 and len(dark.raw_paths) == 1
    truth = bench.camera.ground_truth(w_i, w_o)
    assert np.all(dark.upper_limit > truth) and np.all(dark.upper_limit < 30.0 / dark.snr * truth * 2)
    assert dark.text().startswith("sample 5: not measured (below-detection-limit): SNR ")
    # one channel below the minimum, others above: a measurement at its detection limit
    m = _calibrator(rig, calibrated, bench, **short).measure(w_i, w_o, tmp_path, 6)
    low = m.snr < 10.0
    assert 0 < low.sum() < 3 and m.flags == ["low-snr", "detection-limit"] and m.frames_skipped == 0
    np.testing.assert_allclose(m.sigma[low], m.rgb[low] / m.snr[low], rtol=0.05)   # its sigma is its noise
    m = _calibrator(rig, calibrated, bench, **short, min_snr=1.0).measure(w_i, w_o, tmp_path, 7)
    assert m.flags == ["low-snr"] and m.frames_skipped == 0


def test_too_grazing_a_view_and_the_wrong_card_are_marker_errors(rig, calibrated, spec, tmp_path):
    bench = CameraBench(spec("gold-metallic-paint2"), rig["sim"]["camera"], rig["camera"], seed=0)
    bench.lamp.on()
    w_i, w_o = bench.set_angles(20.0, 89.3, 40.0)
    with pytest.raises(PatchTooSmallError, match=r"sample 7: the sample patch keeps only \d+ pixels of channel [RB] \(need 24\)"):
        _calibrator(rig, calibrated, bench).measure(w_i, w_o, tmp_path, 7)
    assert len(list(tmp_path.glob("sample_0007_*.dng"))) == 1   # no point in other exposures
    bench.set_angles(20.0, 30.0)
    bench.camera.set_target("white")   # the wrong card mounted
    with pytest.raises(WrongTargetError, match=r"sample 8: .*saw markers \[4, 5, 6, 7\] of another target"):
        _calibrator(rig, calibrated, bench).measure(*bench.pose, tmp_path, 8)
    assert len(list(tmp_path.glob("sample_0008_*.dng"))) == 1   # no point in other exposures


class _TruncatingCamera(SimCamera):
    """A camera whose files arrive cut short (a full disk, a pulled cable)."""

    def capture(self, exposure_s, path):
        frame = super().capture(exposure_s, path)
        data = frame.path.read_bytes()
        frame.path.write_bytes(data[: len(data) // 3])
        return frame


def test_truncated_raw_file_fails_the_sample_naming_the_file(rig, calibrated, spec, tmp_path):
    bench = CameraBench(spec("gold-metallic-paint2"), rig["sim"]["camera"], rig["camera"], seed=0)
    bench.lamp.on()
    cam = _TruncatingCamera(bench.camera.material, bench.camera.brdf, lambda: bench.pose, bench.model, bench.clock,
                            rig["sim"]["camera"], 0, model=bench.camera_model)
    cam.connect()
    cal = BenchPlans(cam, bench.lamp, rig["camera"], record=CalibrationRecord.from_dict(calibrated), clock=bench.clock)
    with pytest.raises(RawFileError, match=r"sample_0009_e\d\.dng: cannot decode RAW file"):
        cal.measure(*bench.set_angles(20.0, 30.0), tmp_path, 9)


def test_measure_before_calibrate_and_light_below_are_errors(rig, spec, tmp_path):
    bench = CameraBench(spec("gold-metallic-paint2"), rig["sim"]["camera"], rig["camera"], seed=0)
    cal = BenchPlans(bench.camera, bench.lamp, rig["camera"], clock=bench.clock)
    with pytest.raises(CalibrationError, match="before calibrate"):
        cal.measure(*bench.pose, tmp_path, 0)


def test_ladder_outside_the_calibration_is_refused(rig, calibrated, spec, tmp_path):
    bench = CameraBench(spec("gold-metallic-paint2"), rig["sim"]["camera"], rig["camera"], seed=0)
    bench.lamp.on()
    cal = _calibrator(rig, calibrated, bench, exposures_s=[0.001, 0.002])
    with pytest.raises(CalibrationError, match=r"exposures \[0.002\] s have no dark frame.*calibrate again"):
        cal.measure(*bench.pose, tmp_path, 0)
    with pytest.raises(CalibrationError, match=r"sample 1: light below the sample plane"):
        _calibrator(rig, calibrated, bench).measure(-bench.pose[0], bench.pose[1], tmp_path, 1)


def test_camera_section_validation(rig):
    section = rig["camera"]
    full = validate_camera_section(section, "sim.yaml")
    assert full["exposures_s"] == section["exposures_s"] and full["white_reference"]["reflectance"] == 0.95
    with pytest.raises(ConfigError, match=r"sim\.yaml: camera\.exposures_s: expected a non-empty list of exposures > 0 s, shortest first"):
        validate_camera_section({**section, "exposures_s": [0.01, 0.001]}, "sim.yaml")
    with pytest.raises(ConfigError, match=r"camera\.kind: expected one of \['sim', 'rawfile', 'pylon'\], found 'webcam'"):
        validate_camera_section({**section, "kind": "webcam"}, "sim.yaml")
    with pytest.raises(ConfigError, match=r"camera\.white_reference\.reflectance: expected a number in \(0, 1\], found 1.5"):
        validate_camera_section({**section, "white_reference": {"reflectance": 1.5}}, "sim.yaml")
    with pytest.raises(ConfigError, match=r"rig file: camera\.folder: expected the folder the camera writes RAW files to"):
        open_camera({**section, "kind": "rawfile"})
    with pytest.raises(CameraError, match=r"camera kind 'sim': the simulated camera is built with the simulated rig"):
        open_camera(section)
    with pytest.raises(ConfigError, match=r"camera\.target_snr: expected a number > 0, found 'nothing'"):
        validate_camera_section({k: v for k, v in section.items() if k != "target_snr"}, "sim.yaml")


def test_open_camera_builds_a_folder_camera_that_runs_the_trigger(rig, spec, tmp_path):
    bench = CameraBench(spec("gold-metallic-paint2"), rig["sim"]["camera"], rig["camera"], seed=0)
    src = bench.camera.capture(0.004, tmp_path / "src.dng").path
    hot = tmp_path / "hot"
    hot.mkdir()
    cam = open_camera({**rig["camera"], "kind": "rawfile", "folder": str(hot), "timeout_s": 5.0,
                       "trigger_command": f"cp {src} {hot}/IMG_{{exposure_s}}.dng"})
    cam.connect()
    frame = cam.capture(0.004, tmp_path / "frame.dng")
    assert frame.path.read_bytes() == src.read_bytes() and frame.metadata["source"].endswith("IMG_0.004.dng")


def test_a_sample_whose_markers_sit_off_the_prediction_is_flagged(rig, calibrated, spec, tmp_path):
    """The pose the session believes in is 2 deg off the real one (an unaligned rig): the markers
    are read some pixels from the camera model's prediction, within the tolerance, and the sample
    says so; the region still comes from the markers."""
    import cv2
    bench = CameraBench(spec("gold-metallic-paint2"), rig["sim"]["camera"], rig["camera"], seed=0)
    bench.lamp.on()
    w_i, w_o = bench.set_angles(30.0, 45.0, 160.0)
    up = np.cross(w_i, w_o) / np.linalg.norm(np.cross(w_i, w_o))
    turn = cv2.Rodrigues(up * np.radians(2.0))[0]
    m = _calibrator(rig, calibrated, bench).measure(turn @ w_i, turn @ w_o, tmp_path, 3)
    assert m.roi_source == "markers" and 5.0 < m.marker_offset_px < 20.0 and "markers-off" in m.flags
    right = _calibrator(rig, calibrated, bench).measure(w_i, w_o, tmp_path, 4)
    assert right.roi_source == "markers" and right.marker_offset_px < 1.5 and right.flags == []


def test_a_region_placed_off_the_patch_is_flagged_or_refused_as_misaligned(rig, calibrated, spec, tmp_path):
    """At an 87.5 deg view no marker is read: the region comes from the camera model alone. Believed
    2 deg less grazing than it is, it takes in the card: flagged roi-mixed (its SNR passes), and with
    a minimum SNR it cannot meet, refused as misaligned rather than called too dark."""
    import cv2
    from calib import MisalignedError
    bench = CameraBench(spec("chrome"), rig["sim"]["camera"], rig["camera"], seed=0)
    bench.lamp.on()
    w_i, w_o = bench.set_angles(60.0, 87.5, 150.0)
    up = np.cross(w_i, w_o) / np.linalg.norm(np.cross(w_i, w_o))
    turn = cv2.Rodrigues(up * np.radians(-2.0))[0]
    right = _calibrator(rig, calibrated, bench).measure(w_i, w_o, tmp_path, 1)
    assert right.roi_source == "prediction" and "roi-mixed" not in right.flags
    # its SNR (about 10 on the longest exposure) passes a minimum of 5 whatever the frame's noise draws
    m = _calibrator(rig, calibrated, bench, min_snr=5.0).measure(turn @ w_i, turn @ w_o, tmp_path, 2)
    assert m.roi_source == "prediction" and "roi-mixed" in m.flags
    with pytest.raises(MisalignedError, match=r"sample 3: the region of interest is not uniform \(its pixels spread "
                                              r"\d+ times their median deviation\): .* the rig looks misaligned"):
        _calibrator(rig, calibrated, bench, min_snr=60.0).measure(turn @ w_i, turn @ w_o, tmp_path, 3)



def test_a_misread_marker_set_says_nothing_of_alignment(rig, tmp_path):
    """At this grazing pose (a sentinel of the shared model's 40-sample plan on sim.yaml: light and
    view at 86.7 and 85.4 deg, 16.384 s) builtin gold's four markers are read, but their corners
    disagree with one plane by about 5 px: a misread set. The region comes from the camera model,
    and the misread corners (5.7 px from the prediction on this aligned rig, past the markers-off
    limit of 5 px) count as no offset: a capture flagged such samples markers-off and told the
    operator the rig may be misaligned."""
    settings = validate_camera_section(rig["camera"], "camera")
    pose = (np.array([-0.95259442, 0.29890724, 0.05673037]), np.array([-0.90098138, 0.42624868, 0.08089883]))
    view = expected_view(settings, pose, SAMPLE_MARKER_IDS)
    bench = CameraBench(material_brdf("builtin:gold"), rig["sim"]["camera"], rig["camera"], seed=0)
    bench.lamp.on()
    bench.pose = pose
    bench.camera.capture(16.384, tmp_path / "frame.dng")
    raw = read_raw(tmp_path / "frame.dng")
    found = read_markers(raw.linear, SAMPLE_MARKER_IDS, (1, UPSAMPLE), 4, None)[0]
    assert sorted(found) == list(SAMPLE_MARKER_IDS) and marker_offset_px(found, view) > 5.0  # what was flagged
    mask, source, offset = locate_patch(raw.linear, SAMPLE_MARKER_IDS, settings["roi_margin"], "sample 6", view,
                                        settings["marker_tolerance_px"], raw.channels, settings["min_roi_pixels"])
    assert source == "prediction" and offset is None
    assert np.array_equal(mask, polygon_mask(view.patch, view.shape))
