"""The camera model: OpenCV's projection, the pose of the camera on its arm, the simulated camera
rendering with it, and the region of interest predicted by it and checked by the markers."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from calib.config import validate_camera_section
from calib.errors import MisalignedError, PatchTooSmallError, WrongTargetError
from calib.holder import SAMPLE_MARKER_IDS, WHITE_MARKER_IDS
from calib.roi import SEARCH_MARGIN_PX, locate_patch, polygon_thickness, predict_view, read_markers, search_box
from drivers.rawfile import read_raw
from goniofrost.core.camera_model import CameraModel
from goniofrost.core.errors import ConfigError
from goniofrost.datasets import material_brdf
from sim.camera_bench import CameraBench, direction, rig_like

RIG = Path(__file__).resolve().parents[1] / "config" / "rigs" / "sim.yaml"


@pytest.fixture(scope="module")
def rig():
    return yaml.safe_load(RIG.read_text())


@pytest.fixture(scope="module")
def model(rig):
    return CameraModel.from_section(validate_camera_section(rig["camera"], RIG))


def _bench(rig, camera=None, **params):
    sensor = {**rig["sim"]["camera"], **params}
    return CameraBench(material_brdf("builtin:red-plastic"), sensor, camera or rig["camera"], speedup=1e4)


def _turned(axis: np.ndarray, deg: float) -> np.ndarray:
    """Rodrigues rotation matrix (3, 3) about a unit axis."""
    import cv2
    return cv2.Rodrigues(np.asarray(axis, float) * np.radians(deg))[0]


def test_projection_is_opencvs_with_distortion_and_mount(rig):
    import cv2
    section = validate_camera_section({**rig["camera"], "intrinsics": {
        **rig["camera"]["intrinsics"], "distortion": [-0.2, 0.05, 0.001, -0.002, 0.01]},
        "mount": {"distance_mm": 900.0, "rotation_deg": [0.5, -0.3, 2.0]}}, "x")
    cam = CameraModel.from_section(section)
    rng = np.random.default_rng(1)
    pts = np.column_stack([rng.uniform(-40, 40, (30, 2)), np.zeros(30)])
    for _ in range(5):
        w_i, w_o = rig_like(direction(rng.uniform(0, 80), 0), direction(rng.uniform(0, 80), rng.uniform(0, 360)))
        R, t = cam.extrinsics(w_i, w_o)
        ours = cam.project(pts, R, t)
        theirs, _ = cv2.projectPoints(pts, cv2.Rodrigues(R)[0], t, cam.K, cam.dist)
        np.testing.assert_allclose(ours, theirs.reshape(-1, 2), atol=1e-6)
    # vectorised over poses: (P, 3) directions -> (P, N, 2) pixels, each as alone
    w_i = np.stack([direction(10, 0), direction(30, 0)])
    w_o = np.stack([direction(40, 170), direction(20, 200)])
    both = cam.project_plane(pts[:, :2], w_i, w_o)
    np.testing.assert_allclose(both[1], cam.project_plane(pts[:, :2], w_i[1], w_o[1]))


def test_the_camera_sits_on_its_arm_looking_at_the_centre_with_the_vertical_up(model):
    w_i, w_o = direction(30, 0), direction(50, 180)          # arm in the plane of w_i, w_o
    R, t = model.extrinsics(w_i, w_o)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(-R.T @ t, model.distance_mm * w_o, atol=1e-9)   # centre on the arm
    centre = model.project(np.zeros((1, 3)), R, t)[0]
    np.testing.assert_allclose(centre, [model.cx, model.cy], atol=1e-9)       # aimed at the centre
    up = np.cross(w_i, w_o) / np.linalg.norm(np.cross(w_i, w_o))              # the world vertical
    assert (R @ up) @ [0, -1, 0] == pytest.approx(1.0)                        # points up the image
    R_other, _ = model.extrinsics(w_i, w_o, arm_side=-1.0)                    # arm on the other side
    assert (R_other @ up) @ [0, 1, 0] == pytest.approx(1.0)


@pytest.mark.parametrize("theta_o, phi_o", [(0.0, 0.0), (40.0, 120.0), (70.0, 30.0), (82.0, 200.0)])
def test_the_simulated_camera_renders_the_markers_where_the_model_predicts(rig, model, theta_o, phi_o, tmp_path):
    bench = _bench(rig, noise=False)
    bench.lamp.on()
    w_i, w_o = bench.set_angles(20.0, theta_o, phi_o)
    frame = read_raw(bench.camera.capture(0.064, tmp_path / "f.dng").path)
    view = predict_view(model, w_i, w_o, SAMPLE_MARKER_IDS, 0.15)
    found, _ = read_markers(frame.linear, SAMPLE_MARKER_IDS, scales=(2,))
    assert len(set(view.readable) - set(found)) <= 1 and len(found) >= 2
    for i in found:
        assert np.max(np.linalg.norm(found[i] - view.markers[i], axis=1)) < 0.35   # sub-pixel agreement


def test_a_distorting_lens_and_a_tilted_mount_render_where_predicted(rig, tmp_path):
    camera = {**rig["camera"], "intrinsics": {**rig["camera"]["intrinsics"], "distortion": [-20.0, 0.0, 0.0, 0.0, 0.0]},
              "mount": {"distance_mm": 1000.0, "rotation_deg": [0.4, -0.3, 8.0]}}
    bench = _bench(rig, camera, noise=False)
    bench.lamp.on()
    w_i, w_o = bench.set_angles(10.0, 35.0, 150.0)
    frame = read_raw(bench.camera.capture(0.064, tmp_path / "d.dng").path)
    view = predict_view(bench.camera_model, w_i, w_o, SAMPLE_MARKER_IDS, 0.15)
    straight = predict_view(bench.camera_model.__class__(**{**bench.camera_model.__dict__,
                                                           "distortion": (0.0,) * 5}), w_i, w_o, SAMPLE_MARKER_IDS, 0.15)
    found, _ = read_markers(frame.linear, SAMPLE_MARKER_IDS, scales=(2,))
    assert len(found) >= 3
    errors = [np.max(np.linalg.norm(found[i] - view.markers[i], axis=1)) for i in found]
    bent = [np.max(np.linalg.norm(view.markers[i] - straight.markers[i], axis=1)) for i in found]
    assert max(errors) < 0.6 and min(bent) > 3.0   # the lens moves the corners, the model follows (edges bend)


def _frame_and_cover(rig, tmp_path, theta_o, phi_o, target="sample", theta_i=20.0):
    bench = _bench(rig)
    bench.lamp.on()
    bench.camera.set_target(target)
    w_i, w_o = bench.set_angles(theta_i, theta_o, phi_o)
    raw = read_raw(bench.camera.capture(0.064, tmp_path / f"{theta_o}_{phi_o}.dng").path)
    _, cover = bench.camera._renderer.view(w_i, w_o, WHITE_MARKER_IDS if target == "white" else SAMPLE_MARKER_IDS)
    return raw, cover, (w_i, w_o)


def test_markers_refine_the_predicted_region_and_agree_with_it(rig, model, tmp_path):
    raw, cover, (w_i, w_o) = _frame_and_cover(rig, tmp_path, 55.0, 140.0)
    view = predict_view(model, w_i, w_o, SAMPLE_MARKER_IDS, 0.15)
    mask, source, offset = locate_patch(raw.linear, SAMPLE_MARKER_IDS, 0.15, "s", view, 20.0, raw.channels, 24)
    predicted = locate_patch(raw.linear, SAMPLE_MARKER_IDS, 0.15, "s",
                             view.__class__(view.patch, view.markers, (), view.shape), 20.0, raw.channels, 24)
    assert source == "markers" and offset < 1.0 and predicted[1] == "prediction"
    assert np.all(cover[mask] == 1.0) and np.all(cover[predicted[0]] == 1.0)   # only pure patch pixels
    assert np.sum(mask ^ predicted[0]) <= 0.05 * mask.sum()                  # the same region


@pytest.mark.parametrize("theta_o", [87.5, 88.3])
def test_where_markers_are_unreadable_the_prediction_alone_places_the_patch(rig, model, tmp_path, theta_o):
    raw, cover, (w_i, w_o) = _frame_and_cover(rig, tmp_path, theta_o, 35.0)
    view = predict_view(model, w_i, w_o, SAMPLE_MARKER_IDS, 0.15)
    assert view.readable == ()
    mask, source, offset = locate_patch(raw.linear, SAMPLE_MARKER_IDS, 0.15, "s", view, 20.0, raw.channels, 24)
    assert source == "prediction" and offset is None
    assert min(np.sum(mask & (raw.channels == c)) for c in range(3)) >= 24 and np.all(cover[mask] == 1.0)


@pytest.mark.parametrize("theta_o, phi_o, scales", [(55.0, 140.0, (1,)), (70.0, 30.0, (1, 2)), (80.0, 160.0, (1, 2)),
                                                  (84.0, 200.0, (2,))])
def test_the_search_box_reads_the_markers_of_the_whole_frame(rig, model, tmp_path, theta_o, phi_o, scales):
    raw, _, (w_i, w_o) = _frame_and_cover(rig, tmp_path, theta_o, phi_o)
    view = predict_view(model, w_i, w_o, SAMPLE_MARKER_IDS, 0.15)
    box = search_box(view, view.readable, 20.0 + SEARCH_MARGIN_PX)
    assert box is not None and (box[2] - box[0]) * (box[3] - box[1]) < raw.linear.size
    whole, _ = read_markers(raw.linear, SAMPLE_MARKER_IDS, scales)
    boxed, _ = read_markers(raw.linear, SAMPLE_MARKER_IDS, scales, box=box)
    assert sorted(boxed) == sorted(whole) and len(whole) >= 2
    for i in whole:   # the same corners but for float32 rounding of the larger coordinates
        np.testing.assert_allclose(boxed[i], whole[i], atol=1e-3)


def test_markers_outside_the_search_box_are_still_read(rig, model, tmp_path):
    raw, _, (w_i, w_o) = _frame_and_cover(rig, tmp_path, 40.0, 160.0)
    view = predict_view(model, w_i, w_o, SAMPLE_MARKER_IDS, 0.15)
    x0, y0, x1, y1 = search_box(view, view.readable, 20.0 + SEARCH_MARGIN_PX)
    away = (0, 0, 16, 16) if x0 >= 16 or y0 >= 16 else (x1 - 16, y1 - 16, x1, y1)   # a box holding no marker
    found, _ = read_markers(raw.linear, SAMPLE_MARKER_IDS, (1,), box=away)
    assert sorted(found) == sorted(read_markers(raw.linear, SAMPLE_MARKER_IDS, (1,))[0]) and len(found) >= 2
    # a frame the bracket found too dark or too bright for markers: only the box (none in it)
    assert read_markers(raw.linear, SAMPLE_MARKER_IDS, (1,), box=away, whole_frame=False) == ({}, set())


def test_markers_far_from_the_prediction_mean_a_misaligned_rig(rig, model, tmp_path):
    raw, _, (w_i, w_o) = _frame_and_cover(rig, tmp_path, 40.0, 160.0)
    axis = np.cross(w_i, w_o) / np.linalg.norm(np.cross(w_i, w_o))   # the vertical: an arm or yaw zero error
    turn = _turned(axis, 8.0)
    view = predict_view(model, turn @ w_i, turn @ w_o, SAMPLE_MARKER_IDS, 0.15)
    with pytest.raises(MisalignedError, match=r"sample 3: the holder markers lie \d+\.\d px from where the camera "
                                              r"model puts them \(tolerance 20 px\): the rig looks misaligned"):
        locate_patch(raw.linear, SAMPLE_MARKER_IDS, 0.15, "sample 3", view, 20.0, raw.channels, 24)
    small = predict_view(model, _turned(axis, 0.6) @ w_i, _turned(axis, 0.6) @ w_o, SAMPLE_MARKER_IDS, 0.15)
    _, source, offset = locate_patch(raw.linear, SAMPLE_MARKER_IDS, 0.15, "s", small, 20.0, raw.channels, 24)
    assert source == "markers" and 1.0 < offset < 20.0   # a small error is seen, and tolerated


def test_the_wrong_card_and_too_few_pixels_are_refused(rig, model, tmp_path):
    raw, _, (w_i, w_o) = _frame_and_cover(rig, tmp_path, 30.0, 160.0, target="white")
    view = predict_view(model, w_i, w_o, SAMPLE_MARKER_IDS, 0.15)
    with pytest.raises(WrongTargetError, match=r"sample 4: expected holder markers \[0, 1, 2, 3\], read \[\] .*"
                                               r"saw markers \[4, 5, 6, 7\] of another target"):
        locate_patch(raw.linear, SAMPLE_MARKER_IDS, 0.15, "sample 4", view, 20.0, raw.channels, 24)
    raw, _, (w_i, w_o) = _frame_and_cover(rig, tmp_path, 89.2, 60.0)
    view = predict_view(model, w_i, w_o, SAMPLE_MARKER_IDS, 0.15)
    with pytest.raises(PatchTooSmallError, match=r"sample 5: the sample patch keeps only \d+ pixels of channel [RB] \(need 24\)"):
        locate_patch(raw.linear, SAMPLE_MARKER_IDS, 0.15, "sample 5", view, 20.0, raw.channels, 24)


def test_polygon_thickness_known_values():
    assert polygon_thickness(np.array([[0, 0], [10, 0], [10, 3], [0, 3]])) == pytest.approx(3.0)
    assert polygon_thickness(np.array([[0, 0], [10, 0], [14, 4], [4, 4]])) == pytest.approx(4.0)   # sheared
    assert polygon_thickness(np.array([[0, 0], [1, 1], [2, 2], [3, 3]])) == pytest.approx(0.0)


@pytest.mark.parametrize("key, value, message", [
    ("intrinsics", None, r"camera\.intrinsics: expected a mapping \(image_size_px, focal_px, principal_point_px, distortion\), found 'nothing'"),
    ("intrinsics.focal_px", [8000.0, -1.0], r"camera\.intrinsics\.focal_px: expected \[fx, fy\], numbers > 0 \(pixels\), found \[8000\.0, -1\.0\]"),
    ("intrinsics.image_size_px", [800], r"camera\.intrinsics\.image_size_px: expected \[width, height\], integers in \[16, 16384\], found \[800\]"),
    ("intrinsics.principal_point_px", [900.0, 300.0], r"camera\.intrinsics\.principal_point_px: expected a point inside the 800 x 600 image, found \[900\.0, 300\.0\]"),
    ("intrinsics.distortion", [0.1, 0.0], r"camera\.intrinsics\.distortion: expected \[k1, k2, p1, p2, k3\], five numbers \(OpenCV order\), found \[0\.1, 0\.0\]"),
    ("intrinsics.skew", 0.0, r"camera\.intrinsics\.skew: expected one of the keys image_size_px, focal_px, principal_point_px, distortion, found \"unknown key 'skew'\""),
    ("mount.distance_mm", 0, r"camera\.mount\.distance_mm: expected a number > 0 \(millimetres from the rotation centre\), found 0"),
    ("mount.rotation_deg", [0, 0, 45], r"camera\.mount\.rotation_deg: expected \[rx, ry, rz\], three numbers within \+-20 \(degrees\), found \[0, 0, 45\]"),
    ("min_roi_pixels", 2, r"camera\.min_roi_pixels: expected an integer in \[4, 100000\] \(pixels per colour channel\), found 2"),
    ("marker_tolerance_px", -1, r"camera\.marker_tolerance_px: expected a number > 0 \(pixels\), found -1"),
])
def test_a_bad_camera_model_is_refused_naming_the_key(rig, key, value, message):
    section = yaml.safe_load(yaml.safe_dump(rig["camera"]))
    *parents, last = key.split(".")
    target = section
    for part in parents:
        target = target[part]
    if value is None:
        del target[last]
    else:
        target[last] = value
    with pytest.raises(ConfigError, match=r"^rig\.yaml: " + message + "$"):
        validate_camera_section(section, "rig.yaml")


def test_markers_of_no_holder_card_are_misreads_not_another_card():
    """Thin, foreshortened markers can be misread as any id of the dictionary (chrome at 86 deg
    gave 17 and 37): only the other card's ids mean the wrong card is mounted."""
    import cv2
    from calib.errors import MarkerError
    from calib.roi import find_patch

    aruco = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    frame = np.full((240, 480), 0.8, dtype=np.float32)
    for k, marker in enumerate((17, 37, 5)):
        frame[60:180, 20 + 150 * k: 140 + 150 * k] = cv2.aruco.generateImageMarker(aruco, marker, 120) / 255 * 0.8 + 0.02
    found, others = read_markers(frame, SAMPLE_MARKER_IDS)
    assert found == {} and others == {5}
    with pytest.raises(MarkerError, match=r"read \[\] \(need at least 2\); saw markers \[5\] of another target$") as err:
        find_patch(frame, SAMPLE_MARKER_IDS, 0.15, "s")
    assert not isinstance(err.value, WrongTargetError)   # one marker of the white card is not the white card
