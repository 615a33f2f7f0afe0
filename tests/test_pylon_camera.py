"""The pylon camera driver against pylon's own camera emulation (PYLON_CAMEMU), not a fake.

The emulated camera serves a 16-bit mosaic from a file (TestImageSelector Off, ImageFileMode On,
ImageFilename): served as BayerRG16 or Mono16 it arrives unchanged, as BayerRG12 or Mono12
shifted right by 4 bits. The tests check what the driver makes of it: the exposure set and read
back (the emulated camera keeps whole microseconds), the DNG that rawpy reads (linear values,
black and white levels, the colour tile, exposure, gain and serial number in its tags), and the
one-line refusals: no camera, the wrong serial, a ladder outside the exposure range, a camera
unplugged mid-session, a grab timeout.
"""
from __future__ import annotations

import json
import os

os.environ.setdefault("PYLON_CAMEMU", "1")  # before pylon enumerates its devices

import numpy as np
import pytest
import tifffile

from drivers.camera import CameraError
from drivers.pylon import PylonCamera
from drivers.rawfile import raw_exposure_s, read_raw

EMULATION = "BaslerCamEmu"
SIZE = (64, 48)  # width, height px


class PatternSource:
    """Serves one fixed 16-bit image through the emulated camera's image file (and the drills of
    sim.pylon_scene: an unplug, a stalled acquisition)."""

    def __init__(self, folder, image: np.ndarray, black_level: float = 64.0) -> None:
        self.path, self.image, self.black_level = folder / "pattern.tiff", image, black_level
        self.drill = None
        self.exposures: list[float] = []

    def prepare(self, device) -> None:
        device.TestImageSelector.Value = "Off"
        device.ImageFileMode.Value = "On"
        device.BlackLevel.Value = self.black_level
        device.ExposureAuto.Value = "Continuous"   # what the driver must switch off
        device.Gain.Value = 12.0                   # what the driver must set back to its gain

    def serve(self, device, exposure_s: float, target: str) -> None:
        self.exposures.append(exposure_s)
        if self.drill == "unplug":
            device.FirePnPCallback.Execute()
            return
        tifffile.imwrite(self.path, self.image, photometric="minisblack")
        device.ImageFilename.Value = str(self.path)

    def started(self, device) -> None:
        if self.drill == "stall":
            device.AcquisitionStop.Execute()


def pattern(max_value: int = 65535) -> np.ndarray:
    """A (48, 64) uint16 image with every value distinct up to ``max_value``, on a 16-multiple grid."""
    values = (np.arange(SIZE[0] * SIZE[1], dtype=np.int64) * 7919) % (max_value // 16)
    return (values.reshape(SIZE[1], SIZE[0]) * 16 + 16 * 64).clip(0, max_value).astype(np.uint16)


def camera(source, pixel_format: str = "BayerRG12", ladder=(0.000015625, 0.001, 0.1), **kw) -> PylonCamera:
    return PylonCamera(kw.pop("serial", None), pixel_format, kw.pop("gain_db", 0.0), list(ladder), SIZE,
                       kw.pop("timeout_s", 2.0), device_class=kw.pop("device_class", EMULATION),
                       image_source=source, **kw)


@pytest.fixture
def opened(tmp_path):
    made = []

    def open_(pixel_format="BayerRG12", image=None, **kw):
        source = PatternSource(tmp_path, pattern() if image is None else image)
        cam = camera(source, pixel_format, **kw)
        cam.connect()
        made.append(cam)
        return cam, source

    yield open_
    for cam in made:
        cam.close()


def test_exposure_is_set_in_microseconds_read_back_and_the_camera_s_value_used(opened, tmp_path):
    cam, source = opened()
    frame = cam.capture(0.000015625, tmp_path / "f.dng")
    # the emulated camera keeps whole microseconds: 15.625 us is taken as 16 us
    assert frame.exposure_s == pytest.approx(16e-6, abs=1e-12)
    assert source.exposures == [frame.exposure_s]        # what the scene was exposed for
    assert raw_exposure_s(frame.path) == pytest.approx(16e-6, rel=1e-9)   # the DNG's EXIF ExposureTime
    meta = read_raw(frame.path).metadata
    assert meta["exposure_s"] == frame.exposure_s and meta["requested_exposure_s"] == 0.000015625
    assert cam.capture(0.0625, tmp_path / "g.dng").exposure_s == pytest.approx(0.0625, abs=1e-12)  # exact: kept


def test_the_camera_is_set_up_autos_off_gain_fixed_software_trigger(opened):
    cam, _ = opened(gain_db=6.0)
    d = cam.device
    assert d.ExposureAuto.Value == "Off" and d.GainAuto.Value == "Off"   # the source switched it on
    assert d.Gain.Value == pytest.approx(6.0, abs=0.05)                  # the source set 12 dB
    assert (d.TriggerSelector.Value, d.TriggerMode.Value, d.TriggerSource.Value) == ("FrameStart", "On", "Software")
    assert (d.Width.Value, d.Height.Value) == SIZE
    assert cam.black_level == 64.0


@pytest.mark.parametrize("pixel_format, bits, cfa", [
    ("BayerRG12", 12, [[0, 1], [1, 2]]), ("BayerRG16", 16, [[0, 1], [1, 2]]),
    ("BayerBG12", 12, [[2, 1], [1, 0]]), ("BayerGR16", 16, [[1, 0], [2, 1]]),
    ("Mono12", 12, [[0, 1], [1, 2]]), ("Mono16", 16, [[0, 1], [1, 2]])])
def test_each_pixel_format_becomes_the_linear_image_of_its_bit_depth_and_black_level(opened, tmp_path, pixel_format,
                                                                                      bits, cfa):
    image = pattern()
    cam, _ = opened(pixel_format, image)
    raw = read_raw(cam.capture(0.001, tmp_path / "f.dng").path)
    served = image >> (16 - bits)                       # what the emulated camera makes of the file
    white = 2 ** bits - 1
    np.testing.assert_array_equal(raw.linear, ((served.astype(np.float32) - 64) / (white - 64)).astype(np.float32))
    assert raw.white_level == white and raw.black_levels.tolist() == [64.0, 64.0, 64.0]
    assert raw.channels[:2, :2].tolist() == cfa
    assert raw.metadata["monochrome"] is pixel_format.startswith("Mono")


def test_the_dng_carries_exposure_gain_and_serial_number_in_its_tags(opened, tmp_path):
    cam, _ = opened(gain_db=3.0)
    path = cam.capture(0.004, tmp_path / "f.dng").path
    with tifffile.TiffFile(path) as tif:
        tags = tif.pages[0].tags
        assert tags[50735].value == "0815-0000"                     # CameraSerialNumber
        assert tags[271].value == "Basler"                          # Make
        assert tags[33434].value == (1, 250)                        # ExposureTime
        description = json.loads(tags[270].value)                   # ImageDescription
    assert description["gain_db"] == 3.0 and description["serial"] == "0815-0000"
    assert description["pixel_format"] == "BayerRG12" and description["black_level"] == 64.0


def test_the_camera_is_opened_by_serial_number(opened):
    cam, _ = opened(serial="0815-0000")
    assert cam.info["serial"] == "0815-0000"


def test_a_wrong_serial_is_one_line_naming_what_was_found(tmp_path):
    cam = camera(PatternSource(tmp_path, pattern()), serial="40012345")
    with pytest.raises(CameraError, match=r"^pylon camera: no camera with serial '40012345' \(camera.serial\) of "
                                          r"device class BaslerCamEmu; found \['0815-0000'\]$"):
        cam.connect()
    assert cam.device is None


def test_no_camera_is_one_line(tmp_path):
    cam = camera(PatternSource(tmp_path, pattern()), device_class="BaslerUsb")  # none on this machine
    with pytest.raises(CameraError, match=r"^pylon camera: no camera found of device class BaslerUsb "
                                          r"\(is it plugged in and powered\?\)$"):
        cam.connect()


def test_a_ladder_outside_the_exposure_range_is_refused_when_connecting(tmp_path):
    source = PatternSource(tmp_path, pattern())
    cam = camera(source, ladder=[0.0000005, 0.001, 16.384])
    with pytest.raises(CameraError, match=r"^pylon camera 0815-0000: camera.exposures_s \[5e-07, 16.384\] outside "
                                          r"the camera's exposure range \[1e-06, 10\] s$"):
        cam.connect()
    assert source.exposures == [] and cam.device is None   # refused before any frame


def test_a_camera_unplugged_mid_session_is_one_line(opened, tmp_path):
    cam, source = opened()
    cam.capture(0.001, tmp_path / "a.dng")
    source.drill = "unplug"
    with pytest.raises(CameraError, match=r"^pylon camera 0815-0000: the camera was unplugged \(device removed\) "
                                          r"during a 0.001 s exposure$"):
        cam.capture(0.001, tmp_path / "b.dng")
    assert not (tmp_path / "b.dng").exists()
    cam.close()
    cam.close()  # twice, after an unplug: no error


def test_a_grab_timeout_is_one_line_and_the_next_frame_comes(opened, tmp_path):
    cam, source = opened(timeout_s=0.3)
    source.drill = "stall"
    with pytest.raises(CameraError, match=r"^pylon camera 0815-0000: no frame within 0.3 s \(camera.timeout_s\) "
                                          r"beyond a 0.001 s exposure$"):
        cam.capture(0.001, tmp_path / "a.dng")
    assert not (tmp_path / "a.dng").exists()
    source.drill = None
    assert cam.capture(0.001, tmp_path / "b.dng").path.is_file()
