"""A Basler camera through pypylon (the optional ``pylon`` extra): ``camera: kind: pylon``.

Opened by serial number and set up once (autos off, fixed gain, software trigger); each
``capture`` sets the exposure and archives the frame as a DNG. Failures are one ``CameraError``
line. More: docs/explanations/camera.md.
"""
from __future__ import annotations

import logging
from pathlib import Path
from typing import Callable

import numpy as np

from goniofrost.core.config_check import Key, is_number

from drivers.camera import TARGET_EXPLAINED, TARGETS, Camera, CameraError, OperatorPrompt, RawFrame
from drivers.dng import write_dng

log = logging.getLogger(__name__)

AUTO_FEATURES = ("ExposureAuto", "GainAuto", "BalanceWhiteAuto")  # each switched Off where the camera has it
# the first two colours of the pixel format name are the first row of the 2 x 2 tile
BAYER_TILES = {"BayerRG": "RGGB", "BayerGR": "GRBG", "BayerGB": "GBRG", "BayerBG": "BGGR"}
GAIN_TOLERANCE_DB = 0.05      # the gain read back may differ by this much (the camera's gain steps)
# the pixel formats a measurement can use (12 or 16 bits; Bayer for colour, Mono for grey)
PYLON_PIXEL_FORMATS = tuple(f"{cfa}{bits}" for bits in (12, 16)
                            for cfa in ("BayerRG", "BayerGR", "BayerGB", "BayerBG", "Mono"))


class PylonCamera(Camera):
    """A Basler camera through pypylon; implements ``drivers.camera.Camera``.

    ``serial``: the camera to open (None: the first found); ``pixel_format``: e.g. "BayerRG12"
    (PYLON_PIXEL_FORMATS); ``gain_db``: fixed gain; ``ladder_s``: the exposures (s)
    the session may ask for, checked against the camera's range in ``connect``; ``image_size``:
    (width, height) px of the camera model; ``timeout_s``: seconds a frame may take beyond its
    exposure; ``device_class``: only cameras of this pylon device class (e.g. "BaslerCamEmu");
    ``ask``: how the operator is asked to change the target (default: an OperatorPrompt);
    ``source``: the rig file the settings came from (named in the messages).
    """

    # the keys of the rig file's camera: section only kind pylon reads (drivers.rig_devices.CAMERA_CLASSES):
    # the camera's serial number (none: the first camera found), its pixel format and gain
    KEYS = {
        "serial": Key(lambda v: v is None or (isinstance(v, str) and v != ""), "a serial number (a string)", None),
        "pixel_format": Key(lambda v: v in PYLON_PIXEL_FORMATS, f"one of {list(PYLON_PIXEL_FORMATS)}", "BayerRG12"),
        "gain_db": Key(lambda v: is_number(v) and 0 <= v <= 48, "a number in [0, 48] (dB, fixed)", 0.0),
    }

    @classmethod
    def from_section(cls, section: dict, source, ask, *, image_source=None, device_class=None) -> "PylonCamera":
        """The camera of a checked ``camera:`` section (``image_source``, ``device_class``: an
        emulated camera's, see the class doc); ``ask``: the operator's prompt."""
        return cls(section["serial"], section["pixel_format"], section["gain_db"], section["exposures_s"],
                   section["intrinsics"]["image_size_px"], section["timeout_s"], device_class=device_class,
                   image_source=image_source, ask=ask, source=source)

    def __init__(self, serial: str | None, pixel_format: str, gain_db: float, ladder_s, image_size,
                 timeout_s: float = 30.0, *, device_class: str | None = None, image_source=None,
                 ask: Callable[..., None] | None = None, source: str | None = None) -> None:
        self.serial, self.pixel_format, self.gain_db = serial, pixel_format, float(gain_db)
        self.source = source  # the file the serial came from, for the messages (None: not named)
        self.ladder_s, self.image_size, self.timeout_s = list(ladder_s), tuple(image_size), float(timeout_s)
        self.device_class, self.image_source = device_class, image_source
        self.ask = ask or OperatorPrompt()
        self.bits = int(pixel_format[-2:])
        self.cfa = BAYER_TILES.get(pixel_format[:-2], "RGGB")  # Mono: archived in an RGGB container
        self.device = None
        self.black_level = 0.0
        self.info: dict = {}

    # ----- connect: find, open, set up, check -------------------------------------------------
    def connect(self) -> None:
        pylon, genicam = _pypylon()
        try:
            self.device = pylon.InstantCamera(self._create(pylon))
            self.device.Open()
            if self.image_source is not None:
                self.image_source.prepare(self.device)
            self._set_up()
        except genicam.GenericException as exc:
            self.close()
            raise CameraError(f"{self._name()}: {_first_line(exc)}") from None
        except CameraError:
            self.close()
            raise

    def _create(self, pylon):
        """The pylon device of the configured serial (or the first camera)."""
        factory = pylon.TlFactory.GetInstance()
        wanted = pylon.DeviceInfo()
        if self.device_class:
            wanted.SetDeviceClass(self.device_class)
        found = list(factory.EnumerateDevices([wanted]))
        if not found:
            raise CameraError(f"pylon camera: no camera found{self._class_text()} (is it plugged in and powered?)")
        if self.serial is None:
            return factory.CreateDevice(found[0])
        for info in found:
            if info.GetSerialNumber() == self.serial:
                return factory.CreateDevice(info)
        of = f" of {self.source}" if self.source else ""
        raise CameraError(f"pylon camera: no camera with serial {self.serial!r} (camera.serial{of}){self._class_text()}; "
                          f"found {[i.GetSerialNumber() for i in found]}")

    def _set_up(self) -> None:
        d = self.device
        for name in AUTO_FEATURES:
            node = d.GetNodeMap().GetNode(name)
            if node is not None and _available(node):
                node.SetValue("Off")
        self._set_pixel_format()
        self._set_size()
        if self.device_has("Gain"):
            d.Gain.Value = self.gain_db
            if abs(d.Gain.Value - self.gain_db) > GAIN_TOLERANCE_DB:
                raise CameraError(f"{self._name()}: gain {self.gain_db} dB asked (camera.gain_db), "
                                  f"the camera set {d.Gain.Value} dB")
        d.TriggerSelector.Value = "FrameStart"
        d.TriggerMode.Value = "On"
        d.TriggerSource.Value = "Software"
        self.black_level = float(d.BlackLevel.Value) if self.device_has("BlackLevel") else 0.0
        info = d.GetDeviceInfo()
        self.info = {"serial": info.GetSerialNumber(), "model": info.GetModelName(), "vendor": info.GetVendorName()}
        self._check_ladder()
        log.info("%s opened: %s, gain %s dB, black level %s", self._name(), self.pixel_format, d.Gain.Value,
                 self.black_level)

    def _set_pixel_format(self) -> None:
        formats = self.device.PixelFormat.Symbolics
        if self.pixel_format not in formats:
            raise CameraError(f"{self._name()}: pixel format {self.pixel_format!r} (camera.pixel_format) is not "
                              f"offered; it offers {[f for f in formats if f[-2:] in ('12', '16')]}")
        self.device.PixelFormat.Value = self.pixel_format

    def _set_size(self) -> None:
        d, (width, height) = self.device, self.image_size
        if width > d.Width.Max or height > d.Height.Max:
            raise CameraError(f"{self._name()}: the camera model's image {width} x {height} px "
                              f"(camera.intrinsics.image_size_px) is larger than the sensor's "
                              f"{d.Width.Max} x {d.Height.Max}")
        d.Width.Value, d.Height.Value = width, height

    def _check_ladder(self) -> None:
        """Every ladder rung within the camera's exposure range (refused before anything moves)."""
        lo, hi = self.device.ExposureTime.Min, self.device.ExposureTime.Max
        outside = [t for t in self.ladder_s if not lo <= t * 1e6 <= hi]
        if outside:
            raise CameraError(f"{self._name()}: camera.exposures_s {outside} outside the camera's exposure range "
                              f"[{lo * 1e-6:g}, {hi * 1e-6:g}] s")

    def exposure_range_s(self) -> tuple[float, float]:
        """The camera's exposure range (s), as it states it (after ``connect``)."""
        return float(self.device.ExposureTime.Min) * 1e-6, float(self.device.ExposureTime.Max) * 1e-6

    # ----- one frame --------------------------------------------------------------------------
    def capture(self, exposure_s: float, path: Path) -> RawFrame:
        """Set ``exposure_s``, read it back, trigger, grab and write the DNG at ``path``."""
        pylon, genicam = _pypylon()
        if self.device is None:
            raise CameraError(f"{self._name()}: capture before connect()")
        try:
            actual_s = self._set_exposure(exposure_s)
            mosaic = self._grab(pylon, genicam, actual_s)
        except genicam.GenericException as exc:
            raise self._failure(exc, exposure_s) from None
        meta = {"exposure_s": actual_s, "requested_exposure_s": float(exposure_s), "gain_db": self.gain_db,
                "pixel_format": self.pixel_format, "black_level": self.black_level, "target": self.target,
                "monochrome": self.pixel_format.startswith("Mono"), **self.info}
        white = 2 ** self.bits - 1
        write_dng(Path(path), mosaic, int(round(self.black_level)), white, meta, cfa=self.cfa,
                  model=f"{self.info['vendor']} {self.info['model']}", make=self.info["vendor"],
                  serial=self.info["serial"])
        return RawFrame(Path(path), actual_s, meta)

    def _set_exposure(self, exposure_s: float) -> float:
        """Set the exposure in microseconds; return the camera's own value in seconds."""
        self.device.ExposureTime.Value = float(exposure_s) * 1e6
        return float(self.device.ExposureTime.Value) * 1e-6

    def _grab(self, pylon, genicam, exposure_s: float) -> np.ndarray:
        """One software-triggered frame (H, W) uint16."""
        d = self.device
        if self.image_source is not None:
            self.image_source.serve(d, exposure_s, self.target)
        timeout_ms = int(1000 * (self.timeout_s + exposure_s))
        d.StartGrabbingMax(1)
        try:
            if self.image_source is not None:
                self.image_source.started(d)
            d.WaitForFrameTriggerReady(timeout_ms, pylon.TimeoutHandling_ThrowException)
            d.ExecuteSoftwareTrigger()
            result = d.RetrieveResult(timeout_ms, pylon.TimeoutHandling_ThrowException)
            try:
                if not result.GrabSucceeded():
                    raise CameraError(f"{self._name()}: the frame of a {exposure_s:g} s exposure failed: "
                                      f"{result.ErrorDescription} (error {result.ErrorCode:#x})")
                return np.array(result.Array, dtype=np.uint16)
            finally:
                result.Release()
        finally:
            if not d.IsCameraDeviceRemoved():
                d.StopGrabbing()

    def _failure(self, exc, exposure_s: float) -> CameraError:
        """The one-line CameraError of an SDK exception during a capture."""
        _, genicam = _pypylon()
        if self.device is not None and self.device.IsCameraDeviceRemoved():
            return CameraError(f"{self._name()}: the camera was unplugged (device removed) during a "
                               f"{exposure_s:g} s exposure")
        if isinstance(exc, genicam.TimeoutException):
            return CameraError(f"{self._name()}: no frame within {self.timeout_s:g} s (camera.timeout_s) beyond "
                               f"a {exposure_s:g} s exposure")
        if isinstance(exc, genicam.OutOfRangeException):
            return CameraError(f"{self._name()}: exposure {exposure_s:g} s outside the camera's range")
        return CameraError(f"{self._name()}: {_first_line(exc)}")

    # ----- the rest of the contract -----------------------------------------------------------
    def set_target(self, target: str) -> None:
        """An emulated camera's image source shows the target; a real rig asks the operator."""
        if target not in TARGETS:
            raise CameraError(f"camera target: expected one of {TARGETS}, found {target!r}")
        if target != self.target and self.image_source is None:
            self.ask(f"put the {target!r} target in front of the camera", why=TARGET_EXPLAINED[target])
        self.target = target

    def close(self) -> None:
        """Stop grabbing, close and release the device; safe twice and after an unplug."""
        device, self.device = self.device, None
        if device is None:
            return
        for action in (device.StopGrabbing, device.Close, device.DestroyDevice):
            try:
                action()
            except Exception as exc:  # noqa: BLE001 - an unplugged camera cannot be closed cleanly
                log.debug("%s: while closing: %s", self._name(), exc)

    def device_has(self, name: str) -> bool:
        node = self.device.GetNodeMap().GetNode(name)
        return node is not None and _available(node)

    def _name(self) -> str:
        serial = self.info.get("serial") or self.serial
        return f"pylon camera {serial}" if serial else "pylon camera"

    def _class_text(self) -> str:
        return f" of device class {self.device_class}" if self.device_class else ""


def _pypylon():
    """(pylon, genicam) of pypylon, imported on use; CameraError naming the extra without it."""
    try:
        from pypylon import genicam, pylon
    except ImportError:
        raise CameraError("camera kind pylon needs pypylon: pip install 'goniofrost[pylon]'") from None
    return pylon, genicam


def _available(node) -> bool:
    from pypylon import genicam

    return bool(genicam.IsAvailable(node))


def _first_line(exc) -> str:
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    return text.split(" : ")[0]  # GenICam appends "... thrown in node X (file Y, line Z)"
