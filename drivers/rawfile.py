"""Read a camera RAW file (DNG or any format LibRaw reads) into linear values with rawpy.

``linear`` = (sensor value - black level) / (white - black), per pixel; no demosaicing, gamma or
white balance (PROTOCOLS.md section 4).
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from goniofrost.core.errors import GoniofrostError

_CHANNEL_LETTERS = {ord("R"): 0, ord("G"): 1, ord("B"): 2}


class RawFileError(GoniofrostError, ValueError):
    """A RAW file that cannot be read (missing, corrupt, truncated, not a Bayer RGB raw)."""


@dataclass
class RawImage:
    """Linear sensor values of one RAW frame.

    ``linear``: float32 (H, W), (value - black[c]) / (white - black[c]), about [0, 1] (noise can
    make it slightly negative; it is not clipped so averages stay unbiased).
    ``channels``: uint8 (H, W), 0 = R, 1 = G, 2 = B. ``saturated``: bool (H, W), value >= white.
    ``black_levels``: float (3,) per channel; ``white_level``: int; ``metadata``: from the file.
    """

    path: Path
    linear: np.ndarray
    channels: np.ndarray
    saturated: np.ndarray
    black_levels: np.ndarray
    white_level: int
    metadata: dict = field(default_factory=dict)

    def clipped(self, saturation: float) -> np.ndarray:
        """bool (H, W): the pixels a measurement cannot use, at the white level or at
        ``saturation`` (a fraction of full scale: the camera section's) and above."""
        return self.saturated | (self.linear >= saturation)


def read_raw(path) -> RawImage:
    """Decode ``path`` into a RawImage; raise RawFileError naming the file on any failure."""
    import rawpy  # heavy: import on use

    path = Path(path)
    if not path.is_file():
        raise RawFileError(f"{path}: RAW file not found")
    try:
        with rawpy.imread(str(path)) as raw:
            values = raw.raw_image_visible.astype(np.float32)
            colors = raw.raw_colors_visible.copy()
            desc = raw.color_desc
            black4 = np.asarray(raw.black_level_per_channel, dtype=np.float32)
            white = int(raw.white_level)
    except (rawpy.LibRawError, OSError) as exc:
        raise RawFileError(f"{path}: cannot decode RAW file (corrupt or truncated?): {exc}") from exc
    channels = _rgb_channels(path, colors, desc)
    black = black4[colors]
    if white <= int(black4.max()):
        raise RawFileError(f"{path}: white level {white} is not above black levels {black4.tolist()}")
    linear = (values - black) / (white - black)
    black3 = np.array([black4[list(desc).index(c)] for c in b"RGB"], dtype=np.float64)
    return RawImage(path, linear.astype(np.float32), channels, values >= white, black3, white,
                    _metadata(path))


def _rgb_channels(path: Path, colors: np.ndarray, desc: bytes) -> np.ndarray:
    """Map LibRaw's per-pixel colour indices to 0=R, 1=G, 2=B; refuse non-RGB sensors."""
    try:
        lut = np.array([_CHANNEL_LETTERS[c] for c in desc], dtype=np.uint8)
    except KeyError:
        raise RawFileError(f"{path}: expected an RGB Bayer sensor, found colours {desc!r}") from None
    return lut[colors]


def _metadata(path: Path) -> dict:
    """JSON metadata from a TIFF/DNG ImageDescription when present (else {})."""
    import tifffile

    try:
        with tifffile.TiffFile(path) as tif:
            text = tif.pages[0].description
    except (tifffile.TiffFileError, OSError, IndexError, ValueError):
        return {}  # not a TIFF-based RAW: LibRaw read it, metadata simply is not ours
    try:
        meta = json.loads(text) if text else {}
    except json.JSONDecodeError:
        return {"description": text}
    return meta if isinstance(meta, dict) else {"description": text}


# a camera's serial number: EXIF BodySerialNumber, else the DNG CameraSerialNumber (TIFF tag 50735)
_DNG_SERIAL_TAG = 50735


def raw_identity(path) -> dict:
    """The camera a RAW file names: {"vendor", "model", "serial"} from its EXIF Make, Model and
    BodySerialNumber (a DNG's CameraSerialNumber); a key the file does not give is left out."""
    import exifread

    try:
        with open(path, "rb") as fh:
            tags = exifread.process_file(fh, details=False, extract_thumbnail=False)
    except OSError as exc:
        raise RawFileError(f"{path}: cannot read its EXIF tags: {exc}") from exc
    found = {"vendor": tags.get("Image Make"), "model": tags.get("Image Model"),
             "serial": tags.get("EXIF BodySerialNumber") or _dng_serial(path)}
    return {key: str(value).strip() for key, value in found.items() if value is not None and str(value).strip()}


def _dng_serial(path) -> str | None:
    import tifffile

    try:
        with tifffile.TiffFile(path) as tif:
            tag = tif.pages[0].tags.get(_DNG_SERIAL_TAG)
            return None if tag is None else str(tag.value)  # read while the file is open
    except (tifffile.TiffFileError, OSError, IndexError, ValueError):
        return None


def raw_exposure_s(path) -> float | None:
    """The exposure (s) a RAW file says it was taken with: its EXIF ExposureTime (in the EXIF
    directory, or in the first image directory as DNG writers put it); None if it has none."""
    import exifread

    try:
        with open(path, "rb") as fh:
            tags = exifread.process_file(fh, details=False, extract_thumbnail=False)
    except OSError as exc:
        raise RawFileError(f"{path}: cannot read its EXIF tags: {exc}") from exc
    for key in ("EXIF ExposureTime", "Image ExposureTime"):
        if key in tags and tags[key].values:
            value = tags[key].values[0]
            seconds = float(value.num) / float(value.den) if hasattr(value, "num") else float(value)
            if seconds > 0:
                return seconds
    return None


def bayer_rgb(linear: np.ndarray, channels: np.ndarray) -> np.ndarray:
    """Half-resolution RGB (H/2, W/2, 3) of a Bayer frame (``RawImage.linear`` and ``.channels``):
    each 2x2 cell's mean per channel (for pictures of a frame: the monitor, ``rig snap``)."""
    h, w = linear.shape[0] // 2 * 2, linear.shape[1] // 2 * 2
    cells = linear[:h, :w].reshape(h // 2, 2, w // 2, 2)
    colour = channels[:h, :w].reshape(h // 2, 2, w // 2, 2)
    out = [np.where(colour == c, cells, 0).sum((1, 3)) / np.maximum((colour == c).sum((1, 3)), 1) for c in range(3)]
    return np.stack(out, -1)
