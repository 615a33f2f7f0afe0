"""RAW files: DNG written with tifffile read back exactly through rawpy; bad files named."""
from __future__ import annotations

import numpy as np
import pytest

from drivers.camera import CameraError, FolderCamera
from drivers.hot_folder import HotFolder
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


class PollClock:
    """The folder camera's clock and sleep: each sleep between two polls advances the clock and
    runs the next of ``between`` (what the tethering software does meanwhile); nothing waits."""

    def __init__(self, *between):
        self.t, self.between, self.sleeps = 0.0, list(between), 0

    def __call__(self) -> float:
        return self.t

    def sleep(self, seconds: float) -> None:
        self.t += seconds
        self.sleeps += 1
        if self.between:
            self.between.pop(0)()


def test_folder_camera_collects_a_file_only_once_it_is_complete(tmp_path):
    """The camera's software writes the file in place in two halves, pausing between them for
    longer than a poll: the half file is not collected, the whole one is, byte for byte."""
    data = write_dng(tmp_path / "src.dng", _mosaic(), BLACK, WHITE, {"exposure_s": 0.01}).read_bytes()
    hot = tmp_path / "hot"
    hot.mkdir()
    (hot / "old.dng").write_bytes(data)   # already there: not this exposure's file
    new = hot / "IMG_0001.dng"

    def rest():
        with open(new, "ab") as fh:
            fh.write(data[len(data) // 2:])

    clock = PollClock(lambda: None, rest)  # after poll 1 nothing; after poll 2 (the half stood still) the rest
    cam = FolderCamera(hot, lambda t: new.write_bytes(data[:len(data) // 2]), timeout_s=5.0, poll_s=0.01,
                       clock=clock, sleep=clock.sleep)
    cam.connect()
    frame = cam.capture(0.01, tmp_path / "sample_0001.dng")
    # poll 1: the half, new; 2: unchanged but incomplete; 3: grown; 4: unchanged and whole: taken
    assert clock.sleeps == 3
    assert frame.path == tmp_path / "sample_0001.dng" and frame.exposure_s == 0.01
    assert frame.path.read_bytes() == data
    assert sorted(p.name for p in hot.iterdir()) == ["old.dng"]


def test_the_hot_folder_takes_a_file_unchanged_over_two_polls_and_whole(tmp_path):
    data = write_dng(tmp_path / "src.dng", _mosaic(), BLACK, WHITE, {"exposure_s": 0.01}).read_bytes()
    hot = tmp_path / "hot"
    hot.mkdir()
    watch = HotFolder(hot, (".dng", ".cr3"))
    new = hot / "IMG_0001.DNG"
    new.write_bytes(data[:len(data) // 2])
    (hot / "IMG_0002.dng.part").write_bytes(data)   # a partial name, a dot-file: never looked at
    (hot / ".IMG_0003.dng").write_bytes(data)
    assert watch.poll() is None and watch.pending() == [new]       # new: not yet unchanged over two polls
    assert watch.poll() is None                                     # unchanged, but its data is cut
    assert watch.incomplete == {new: f"its image data ends at byte {len(data)}, the file has {len(data) // 2}"}
    with open(new, "ab") as fh:
        fh.write(data[len(data) // 2:])
    assert watch.poll() is None                                     # it grew since the last poll
    assert watch.poll() == new and watch.incomplete == {}
    # a format that is not TIFF-based (CR3: ISO media) is taken on rule 2 alone
    other = hot / "IMG_0004.cr3"
    other.write_bytes(b"\x00\x00\x00\x18ftypcrx " + bytes(100))
    assert watch.poll() == new and watch.poll() == other  # the newest complete one


def test_the_hot_folder_never_takes_an_empty_file_or_a_tiff_without_its_directory(tmp_path):
    data = write_dng(tmp_path / "src.dng", _mosaic(), BLACK, WHITE, {"exposure_s": 0.01}).read_bytes()
    watch = HotFolder(tmp_path, (".nef",))
    empty, header = tmp_path / "a.nef", tmp_path / "b.nef"
    empty.write_bytes(b"")
    header.write_bytes(data[:6])   # the TIFF header, its first directory's offset cut
    assert [watch.poll(), watch.poll()] == [None, None]
    assert list(watch.incomplete) == [header] and watch.incomplete[header].startswith(
        "its TIFF structure does not parse yet")


def test_folder_camera_times_out_clearly(tmp_path):
    clock = PollClock()
    cam = FolderCamera(tmp_path, lambda t: None, timeout_s=1.0, poll_s=0.25, clock=clock, sleep=clock.sleep)
    with pytest.raises(CameraError, match=rf"^folder camera: no new RAW file in {tmp_path} within 1.0 s of a "
                                          rf"0.5 s exposure$"):
        cam.capture(0.5, tmp_path / "x.dng")
    assert clock.sleeps == 4  # polls at 0, 0.25, 0.5, 0.75 and 1 s (binary-exact steps)
    # a file that came but never was whole is named, with why
    data = write_dng(tmp_path / "src.dng", _mosaic(), BLACK, WHITE, {"exposure_s": 0.5}).read_bytes()
    cut = tmp_path / "IMG_0009.dng"
    cam = FolderCamera(tmp_path, lambda t: cut.write_bytes(data[:1000]), timeout_s=1.0, poll_s=0.25,
                       clock=clock, sleep=clock.sleep)
    with pytest.raises(CameraError, match=rf"^folder camera: no complete new RAW file in {tmp_path} within 1.0 s "
                                          rf"of a 0.5 s exposure: IMG_0009.dng \(its image data ends at byte "
                                          rf"{len(data)}, the file has 1000\)$"):
        cam.capture(0.5, tmp_path / "x.dng")
    assert cut.read_bytes() == data[:1000]   # left where it is
    with pytest.raises(CameraError, match="is not a directory"):
        FolderCamera(tmp_path / "missing", lambda t: None).connect()
