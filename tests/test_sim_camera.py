"""The simulated camera: exact noise-free signal, sensor statistics, saturation, markers, config."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from calib.errors import MarkerError
from calib.holder import SAMPLE_MARKER_IDS, WHITE_MARKER_IDS
from calib.roi import find_patch
from drivers.rawfile import read_raw
from goniofrost.core.errors import ConfigError
from sim.camera import WHITE_TILE_REFLECTANCE, validate_sim_camera_section
from goniofrost.datasets import material_brdf
from sim.camera_bench import CameraBench

RIG = Path(__file__).resolve().parents[1] / "config" / "rigs" / "sim.yaml"


@pytest.fixture(scope="module")
def params():
    return validate_sim_camera_section(yaml.safe_load(RIG.read_text())["sim"]["camera"], RIG)


@pytest.fixture(scope="module")
def camera():
    return yaml.safe_load(RIG.read_text())["camera"]


@pytest.fixture(scope="module")
def gold(merl_npz):
    return material_brdf(f"nbrdf:{merl_npz}:gold-metallic-paint2")


def _ideal(params, **over):
    return {**params, "noise": False, "prnu": 0.0, "vignetting": 0.0, "dark_current_e_s": 0.0, **over}


def _patch_centre(raw, channel):
    h, w = raw.linear.shape
    win = (slice(h // 2 - 4, h // 2 + 4), slice(w // 2 - 4, w // 2 + 4))
    return raw.linear[win][raw.channels[win] == channel]


def test_noise_free_patch_signal_is_the_ground_truth_radiance(tmp_path, gold, params, camera):
    bench = CameraBench(gold, _ideal(params), camera, speedup=1e4, drift_per_hour=0.0)
    bench.lamp.on()
    w_i, w_o = bench.set_angles(35.0, 20.0, 150.0)
    raw = read_raw(bench.camera.capture(0.016, tmp_path / "f.dng").path)
    truth = bench.camera.ground_truth(w_i, w_o)
    lamp = raw.metadata["sim_lamp_relative"]   # the lamp level during this exposure
    for c in range(3):
        electrons = truth[c] * w_i[2] * np.pi * params["signal_e_s"] * params["channel_gain"][c] * 0.016 * lamp
        dn = np.rint(electrons * (params["white_level"] - params["black_level"]) / params["full_well_e"])
        expected = dn / (params["white_level"] - params["black_level"])
        np.testing.assert_allclose(_patch_centre(raw, c), expected, rtol=1e-3, atol=1e-6)
    assert raw.metadata["exposure_s"] == 0.016 and raw.metadata["target"] == "sample"


def test_dark_frame_statistics(tmp_path, gold, params, camera):
    bench = CameraBench(gold, params, camera, speedup=1e4)
    bench.lamp.off()
    raw = read_raw(bench.camera.capture(0.256, tmp_path / "d.dng").path)
    scale = (params["white_level"] - params["black_level"]) / params["full_well_e"]   # DN per electron
    dark_e = params["dark_current_e_s"] * 0.256
    lin_per_e = scale / (params["white_level"] - params["black_level"])
    assert raw.linear.mean() == pytest.approx(dark_e * lin_per_e, abs=0.05 * lin_per_e)
    expected_sd = np.sqrt(params["read_noise_e"] ** 2 + dark_e + 1 / (12 * scale ** 2)) * lin_per_e
    assert raw.linear.std() == pytest.approx(expected_sd, rel=0.05)


def test_shot_noise_follows_the_photon_transfer_curve(tmp_path, gold, params, camera):
    """Variance of the difference of two flat frames = 2 (signal/gain + read^2) in electrons."""
    bench = CameraBench(gold, {**params, "vignetting": 0.0}, camera, speedup=1e4, drift_per_hour=0.0)
    bench.lamp.on()
    bench.camera.set_target("flat")
    a, b = (read_raw(bench.camera.capture(0.064, tmp_path / f"{k}.dng").path) for k in "ab")
    g = a.channels == 1
    per_e = 1.0 / params["full_well_e"]
    mean_e = a.linear[g].mean() / per_e
    diff_var_e = np.var((a.linear[g] - b.linear[g]) / per_e)
    assert diff_var_e / 2 == pytest.approx(mean_e + params["read_noise_e"] ** 2, rel=0.06)


def test_saturation_clips_at_the_white_level(tmp_path, gold, params, camera):
    bench = CameraBench(gold, params, camera, speedup=1e4)
    bench.lamp.on()
    bench.camera.set_target("flat")
    raw = read_raw(bench.camera.capture(10.0, tmp_path / "s.dng").path)
    assert raw.saturated.all() and np.allclose(raw.linear, 1.0)


def test_same_seed_same_frame_other_seed_other_noise(tmp_path, gold, params, camera):
    frames = []
    for seed in (3, 3, 4):
        bench = CameraBench(gold, params, camera, seed=seed, speedup=1e4, drift_per_hour=0.0)
        bench.lamp.off()   # dark frames: independent of the wall-clock-driven lamp wobble
        frames.append(read_raw(bench.camera.capture(0.064, tmp_path / f"{seed}.dng").path).linear)
    assert np.array_equal(frames[0], frames[1]) and not np.array_equal(frames[0], frames[2])


@pytest.mark.parametrize("theta_o", [0.0, 45.0, 70.0, 84.0])
@pytest.mark.parametrize("phi_o", [0.0, 45.0, 120.0])
def test_markers_locate_the_patch_up_to_84_degrees(tmp_path, gold, params, theta_o, phi_o, camera):
    bench = CameraBench(gold, params, camera, speedup=1e4)
    bench.lamp.on()
    w_i, w_o = bench.set_angles(20.0, theta_o, phi_o)
    raw = read_raw(bench.camera.capture(0.064, tmp_path / "m.dng").path)
    mask = find_patch(raw.linear, SAMPLE_MARKER_IDS, 0.15, "test frame")
    _, cover = bench.camera._renderer.view(w_i, w_o, SAMPLE_MARKER_IDS)
    assert mask.sum() >= 100 and np.all(cover[mask] == 1.0)   # only pure patch pixels


def test_grazing_view_and_wrong_target_are_marker_errors(tmp_path, gold, params, camera):
    bench = CameraBench(gold, params, camera, speedup=1e4)
    bench.lamp.on()
    bench.set_angles(20.0, 89.0, 30.0)   # markers about 3 px thin
    raw = read_raw(bench.camera.capture(0.064, tmp_path / "g.dng").path)
    with pytest.raises(MarkerError, match=r"sample 7: expected holder markers \[0, 1, 2, 3\]"):
        find_patch(raw.linear, SAMPLE_MARKER_IDS, 0.15, "sample 7")
    bench.set_angles(20.0, 30.0)
    bench.camera.set_target("white")
    raw = read_raw(bench.camera.capture(0.064, tmp_path / "w.dng").path)
    with pytest.raises(MarkerError, match=r"saw markers \[4, 5, 6, 7\] of another target"):
        find_patch(raw.linear, SAMPLE_MARKER_IDS, 0.15, "sample 8")
    assert find_patch(raw.linear, WHITE_MARKER_IDS, 0.15, "white").sum() > 500


def test_white_tile_is_lambertian(tmp_path, gold, params, camera):
    bench = CameraBench(gold, _ideal(params), camera, speedup=1e4, drift_per_hour=0.0)
    bench.lamp.on()
    bench.camera.set_target("white")
    values = []
    for theta_o in (10.0, 60.0):
        bench.set_angles(0.0, theta_o)
        raw = read_raw(bench.camera.capture(0.016, tmp_path / "w.dng").path)
        values.append(_patch_centre(raw, 1).mean() / raw.metadata["sim_lamp_relative"])
    assert values[0] == pytest.approx(values[1], rel=1e-3)
    expected = WHITE_TILE_REFLECTANCE * params["signal_e_s"] * 0.016 / params["full_well_e"]
    assert values[0] == pytest.approx(expected, rel=2e-3)


def test_sim_camera_section_validation(params):
    section = yaml.safe_load(RIG.read_text())["sim"]["camera"]
    assert params["black_level"] == section["black_level"] and params["noise"] is True
    # the image size is the camera model's (camera.intrinsics), not the sensor's
    with pytest.raises(ConfigError, match=r"rig\.yaml: sim\.camera\.width: expected one of the keys black_level, .*, noise, found \"unknown key 'width'\""):
        validate_sim_camera_section({**section, "width": 320}, "rig.yaml")
    with pytest.raises(ConfigError, match=r"rig\.yaml: sim\.camera\.read_noise_e: expected a number >= 0 \(electrons\), found 'x'"):
        validate_sim_camera_section({**section, "read_noise_e": "x"}, "rig.yaml")
    with pytest.raises(ConfigError, match=r"sim\.camera\.white_level: expected an integer in \(0, 65535\], found 'nothing'"):
        validate_sim_camera_section({k: v for k, v in section.items() if k != "white_level"}, "rig.yaml")
    with pytest.raises(ConfigError, match=r"sim\.camera\.gain: expected one of"):
        validate_sim_camera_section({**section, "gain": 2}, "rig.yaml")
    with pytest.raises(ConfigError, match=r"sim\.camera\.white_level: expected above black_level 512, found 100"):
        validate_sim_camera_section({**section, "white_level": 100}, "rig.yaml")


def test_gray_views_render_their_crops_as_the_crops_of_the_whole_views(tmp_path, gold, params, camera):
    """read_markers searches a box first: a view rendered from the crop alone must hold the whole
    view's pixels there (the percentile mappings are the whole frame's; the log view is cropped)."""
    from calib.roi import gray_views

    bench = CameraBench(gold, params, camera, speedup=1e4)
    bench.lamp.on()
    bench.set_angles(30.0, 40.0, 120.0)
    linear = read_raw(bench.camera.capture(0.064, tmp_path / "v.dng").path).linear
    g = np.maximum(linear, 0).astype(np.float32)
    whole, lazy = gray_views(linear), gray_views(linear)
    assert len(whole) == 4 and [v.shape for v in whole] == [linear.shape] * 4
    for k, q in enumerate((99.5, 90.0, 60.0)):   # one percentile call gives each call's value
        import cv2
        top = float(np.percentile(cv2.blur(g, (2, 2)), q))
        assert np.array_equal(whole[k], np.clip(cv2.blur(g, (2, 2)) * (230.0 / top), 0, 255).astype(np.uint8))
    box = (104, 56, 480, 392)
    for k in range(len(whole)):
        assert np.array_equal(lazy.crop(k, box), whole[k][56:392, 104:480]), k


def test_a_capture_returns_once_its_exposure_passed_with_the_frame_made_inside_it(tmp_path, gold, params, camera):
    """The frame is rendered while it is exposed: the capture still lasts the exposure (real
    seconds = simulated / speedup) and the nominal time advances by exactly the exposure."""
    import time

    bench = CameraBench(gold, params, camera, speedup=10.0)
    bench.lamp.on()
    bench.set_angles(20.0, 30.0, 90.0)
    before, start = bench.camera.clock.nominal_time(), time.monotonic()
    bench.camera.capture(4.0, tmp_path / "long.dng")
    assert time.monotonic() - start >= 0.4
    assert bench.camera.clock.nominal_time() == before + 4.0
