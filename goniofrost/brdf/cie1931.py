"""Spectra to linear sRGB: the CIE 1931 2 deg observer under illuminant D65.

``data/cie1931_d65.npy`` (471 x 5 float32): wavelength in nm (360-830 at 1 nm), x, y, z and D65,
as Mitsuba 3 tabulates them; XYZ -> sRGB is Mitsuba's Rec. 709 matrix. Why D65:
docs/decisions/0300-rgl-spectral-to-rgb.md.
"""
from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np

TABLE_PATH = Path(__file__).with_name("data") / "cie1931_d65.npy"
# XYZ -> linear sRGB (Rec. 709 primaries, D65 white), rows R, G, B: Mitsuba 3's xyz_to_srgb.
XYZ_TO_SRGB = np.array([[3.240479, -1.537150, -0.498535],
                        [-0.969256, 1.875991, 0.041556],
                        [0.055648, -0.204043, 1.057311]])


@lru_cache(maxsize=1)
def table() -> np.ndarray:
    """(471, 5) float64: nm, x, y, z, D65."""
    return np.load(TABLE_PATH).astype(np.float64)


def spectrum_to_srgb_weights(wavelengths, illuminant=None) -> np.ndarray:
    """W (n_lambda, 3): linear sRGB = values @ W of a spectrum given at its nodes (nm, ascending).

    The spectrum is linear between the nodes and constant beyond them (how Mitsuba's ``measured``
    interpolates a file's spectra), integrated at 1 nm against x, y, z times D65 and normalised so
    that a spectrum of 1 everywhere has Y = 1 (a perfect white reflector is RGB (1, 1, 1)).
    ``illuminant``: (471,) at the table's wavelengths instead of D65 (the decision record's comparison).
    """
    data = table()
    lam = np.asarray(wavelengths, dtype=np.float64)
    light = data[:, 4] if illuminant is None else np.asarray(illuminant, dtype=np.float64)
    weight = data[:, 1:4] * light[:, None] / np.sum(light * data[:, 2])
    hats = np.stack([np.interp(data[:, 0], lam, e) for e in np.eye(lam.size)])  # (n_lambda, 471)
    return hats @ weight @ XYZ_TO_SRGB.T
