"""RAW files: DNG written with tifffile read back exactly through rawpy; bad files named."""
from __future__ import annotations

import threading

import numpy as np
import pytest

from drivers.camera import CameraError, FolderCamera
from drivers.rawfile import RawFileError, read_raw
from sim.dng import write_dng

BLACK, WHITE = 512, 16383


def _mosaic(seed=0, shape=(64, 96)):
    rng = np.random.default_rng(seed)
    m = rng.integers(0, WHITE + 1, shape).astype(np.uint16)
    m[0, 0], m[0, 1], m[1, 0], m[1, 1] = WHITE, BLACK, 0, WHITE - 1  # edge values
    return m


def test_dng_round_trip_is_exact_and_linear(tmp_path):
    m = _mosaic()
    path = write_dng(tmp_path / "a.dng", m, BLACK, WHITE, {"exposure_s": 0.004, "note": "x"})
    raw = read_raw(path)
    assert raw.linear.dtype == np.float32 and raw.linear.shape == m.shape
    expected = (m.astype(np.float64) - BLACK) / (WHITE - BLACK)
    np.testing.assert_allclose(raw.linear, expected, rtol=0, atol=1e-6)
    assert raw.white_level == WHITE and raw.black_levels.tolist() == [BLACK] * 3
    # RGGB: R at (even, even), G at (even, odd) and (odd, even), B at (odd, odd)
    assert raw.channels[:2, :2].tolist() == [[0, 1], [1, 2]]
    assert np.array_equal(raw.channels[::2, ::2], np.zeros((32, 48)))
    np.testing.assert_array_equal(raw.saturated, m >= WHITE)
    assert raw.metadata == {"exposure_s": 0.004, "note": "x"}
    assert list(tmp_path.iterdir()) == [path]  # no temporary file left behind


def test_linear_values_are_not_rescaled_near_white(tmp_path):
    """LibRaw's adjust_maximum_thr must not rescale a frame whose maximum is below white."""
    m = np.full((32, 32), BLACK + (WHITE - BLACK) // 2, dtype=np.uint16)
    raw = read_raw(write_dng(tmp_path / "h.dng", m, BLACK, WHITE, {"exposure_s": 1.0}))
    assert float(raw.linear.max()) == pytest.approx((m[0, 0] - BLACK) / (WHITE - BLACK), abs=1e-6)


@pytest.mark.parametrize("keep", [0.999, 0.5, 0.01])
def test_truncated_file_is_an_error_naming_it(tmp_path, keep):
    good = write_dng(tmp_path / "good.dng", _mosaic(), BLACK, WHITE, {"exposure_s": 0.01})
    data = good.read_bytes()
    bad = tmp_path / "cut.dng"
    bad.write_bytes(data[:int(len(data) * keep)])
    with pytest.raises(RawFileError, match=r"cut\.dng: cannot decode RAW file"):
        read_raw(bad)


def test_corrupt_and_missing_files_are_errors(tmp_path):
    junk = tmp_path / "junk.dng"
    junk.write_bytes(b"not a raw file" * 50)
    with pytest.raises(RawFileError, match=r"junk\.dng: cannot decode"):
        read_raw(junk)
    with pytest.raises(RawFileError, match=r"none\.dng: RAW file not found"):
        read_raw(tmp_path / "none.dng")


def test_write_dng_refuses_bad_mosaic_and_writes_nothing(tmp_path):
    with pytest.raises(ValueError, match="2-D uint16"):
        write_dng(tmp_path / "f.dng", np.zeros((4, 4), np.float32), BLACK, WHITE, {"exposure_s": 1.0})
    assert list(tmp_path.iterdir()) == []


def test_folder_camera_collects_the_new_file(tmp_path):
    src = write_dng(tmp_path / "src.dng", _mosaic(), BLACK, WHITE, {"exposure_s": 0.01})
    hot = tmp_path / "hot"
    hot.mkdir()
    (hot / "old.dng").write_bytes(src.read_bytes())   # already there: not this exposure's file

    def trigger(exposure_s):
        threading.Timer(0.05, lambda: (hot / "IMG_0001.dng").write_bytes(src.read_bytes())).start()

    cam = FolderCamera(hot, trigger, timeout_s=5.0, poll_s=0.01)
    cam.connect()
    frame = cam.capture(0.01, tmp_path / "sample_0001.dng")
    assert frame.path == tmp_path / "sample_0001.dng" and frame.exposure_s == 0.01
    assert np.array_equal(read_raw(frame.path).linear, read_raw(src).linear)
    assert sorted(p.name for p in hot.iterdir()) == ["old.dng"]


def test_folder_camera_times_out_clearly(tmp_path):
    cam = FolderCamera(tmp_path, lambda t: None, timeout_s=0.1, poll_s=0.01)
    with pytest.raises(CameraError, match=r"no new RAW file in .* within 0.1 s of a 0.5 s exposure"):
        cam.capture(0.5, tmp_path / "x.dng")
    with pytest.raises(CameraError, match="is not a directory"):
        FolderCamera(tmp_path / "missing", lambda t: None).connect()
