"""The calibration references from their frames: dark maps, flat field and the white-tile scale.

Pure functions of frames (``drivers.rawfile.RawImage``) and the validated camera section; the
capture plan (``goniofrost.capture.calibration_steps``) takes the frames and calls these.
"""
from __future__ import annotations

import numpy as np

from .errors import CalibrationError, UnderexposedError


def dark_map(raws) -> np.ndarray:
    """Mean dark frame (H, W) float32 of the frames of one exposure, taken with the lamp off."""
    acc = None
    for raw in raws:
        acc = raw.linear.astype(np.float64) if acc is None else acc + raw.linear
    return (acc / len(raws)).astype(np.float32)


def flat_usable(raw, settings: dict) -> bool:
    """Whether a frame of the ``flat`` target stays below saturation (its 99.9th percentile)."""
    return bool(np.percentile(raw.linear, 99.9) < settings["saturation"])


def flat_field(raws, dark: np.ndarray, exposure_s: float) -> np.ndarray:
    """Gain per pixel (H, W) float32 with mean 1 per Bayer channel (vignetting and pixel response).

    ``raws``: frames of the ``flat`` target at one exposure (``exposure_s``, for messages);
    ``dark``: (H, W) dark map of that exposure. CalibrationError when pixels see almost no light.
    """
    acc = raws[0].linear - dark
    for raw in raws[1:]:
        acc += raw.linear - dark
    flat = np.empty_like(acc)
    channels = raws[0].channels
    for c in range(3):
        sel = channels == c
        flat[sel] = acc[sel] / acc[sel].mean()
    if not np.all(flat > 0.05):
        raise CalibrationError(f"flat field: {int(np.sum(flat <= 0.05))} pixels see almost no light "
                               f"(exposure {exposure_s} s): is the flat target in place?")
    return flat.astype(np.float32)


def nominal_white_pose(settings: dict) -> tuple[np.ndarray, np.ndarray]:
    """(w_i, w_o), each (3,), of the white tile at the settings' nominal ``white_reference`` angles."""
    wr = settings["white_reference"]
    ti, to = np.radians(wr["theta_i_deg"]), np.radians(wr["theta_o_deg"])
    return np.array([np.sin(ti), 0, np.cos(ti)]), np.array([-np.sin(to), 0, np.cos(to)])


def white_scale(mean: np.ndarray, se: np.ndarray, white_pose, settings: dict, exposures_s: list):
    """Absolute scale per channel from the white tile: rate / (rho/pi cos theta_i).

    ``mean``, ``se``: (3,) patch rate and its standard error; ``white_pose``: the actual
    (w_i, w_o) of the tile. Returns ``scale`` (3,), ``scale_sigma`` (3,) and the white-reference
    facts for the record.
    """
    if not np.all(mean > 0):
        # the white tile is the scale of every sample: a channel without signal is no reference
        raise UnderexposedError(f"white reference: no signal above the dark level in channel(s) "
                                f"{[c for c, m in zip('RGB', mean) if not m > 0]} with exposures up to "
                                f"{max(exposures_s)} s")
    wr = settings["white_reference"]
    w_i = unit(white_pose[0], "white reference w_i")
    rho = wr["reflectance"]
    scale = mean / (rho / np.pi * w_i[2])
    scale_sigma = scale * np.hypot(se / mean, settings["photodiode_rel_sigma"])
    white = {"reflectance": rho, "w_i": w_i.tolist(), "w_o": list(map(float, white_pose[1])),
             "exposures_s": list(exposures_s), "snr": (mean / se).tolist()}
    return scale, scale_sigma, white


def unit(v, what: str) -> np.ndarray:
    """``v`` as a unit vector (3,); CalibrationError naming ``what`` for anything else."""
    v = np.asarray(v, dtype=np.float64).reshape(-1)
    n = float(np.linalg.norm(v)) if v.size == 3 else 0.0
    if not n > 0 or not np.isfinite(n):
        raise CalibrationError(f"{what}: expected a non-zero direction vector (3,), found {v.tolist()}")
    return v / n
