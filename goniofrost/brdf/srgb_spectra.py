"""Linear sRGB values -> smooth spectra: the sigmoid-polynomial model of Jakob and Hanika 2019.

scale * model(rgb / scale)(lambda), scale = 2 max(r, g, b), read from ``data/srgb_half.npy``
(3 x 64 x 64 x 3 float32, a slice of Mitsuba 3's ``srgb.coeff``). More:
docs/explanations/mitsuba-export.md.
"""
from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np

TABLE_PATH = Path(__file__).with_name("data") / "srgb_half.npy"
# rgb2spec's file: b"SPEC", uint32 resolution, float32 z nodes (res), float32 coefficients
# (3, res, res, res, 3) indexed [largest channel][z][y][x][c] (rgb2spec.c: rgb2spec_load, _fetch).
COEFF_MAGIC = b"SPEC"
HALF = 0.5  # the largest component every unbounded value is scaled to


def slice_of_coeff_file(path) -> np.ndarray:
    """The coefficients (3, res, res, 3) of an rgb2spec ``.coeff`` file at z = 1/2, float32.

    Index [largest channel i][y][x][c] with x = rgb[(i + 1) % 3] / z and y = rgb[(i + 2) % 3] / z
    on res nodes from 0 to 1 (rgb2spec_fetch's layout).
    """
    raw = Path(path).read_bytes()
    if raw[:4] != COEFF_MAGIC:
        raise ValueError(f"{path}: not an rgb2spec coefficient file (header {raw[:4]!r}, expected {COEFF_MAGIC!r})")
    res = int(np.frombuffer(raw, "<u4", 1, 4)[0])
    z_nodes = np.frombuffer(raw, "<f4", res, 8).astype(np.float64)
    table = np.frombuffer(raw, "<f4", 3 * res ** 3 * 3, 8 + 4 * res).reshape(3, res, res, res, 3)
    k = int(np.searchsorted(z_nodes, HALF, side="right")) - 1      # z_nodes[k] <= 1/2 < z_nodes[k + 1]
    t = (HALF - z_nodes[k]) / (z_nodes[k + 1] - z_nodes[k])
    return ((1.0 - t) * table[:, k].astype(np.float64) + t * table[:, k + 1]).astype(np.float32)


@lru_cache(maxsize=1)
def half_table() -> np.ndarray:
    """The shipped coefficient slice (3, 64, 64, 3) as float64."""
    return np.load(TABLE_PATH).astype(np.float64)


def coefficients(rgb: np.ndarray) -> np.ndarray:
    """Sigmoid-polynomial coefficients (..., 3) of linear sRGB values (..., 3) >= 0 with max 1/2.

    rgb2spec_fetch at z = 1/2: bilinear in the two smaller channels divided by the largest. A grey
    (r = g = b) is the exact constant (0, 0, (z - 1/2) / sqrt(z (1 - z))), as pbrt-v4 and Mitsuba
    special-case it (the table's grey is off by about 1e-4).
    """
    table = half_table()
    res = table.shape[1]
    rgb = np.asarray(rgb, dtype=np.float64)
    top = np.argmax(rgb, axis=-1)
    z = np.take_along_axis(rgb, top[..., None], -1)[..., 0]
    safe = np.where(z > 0, z, 1.0)
    x = np.take_along_axis(rgb, ((top + 1) % 3)[..., None], -1)[..., 0] / safe * (res - 1)
    y = np.take_along_axis(rgb, ((top + 2) % 3)[..., None], -1)[..., 0] / safe * (res - 1)
    xi = np.minimum(x.astype(np.int64), res - 2)
    yi = np.minimum(y.astype(np.int64), res - 2)
    dx, dy = (x - xi)[..., None], (y - yi)[..., None]
    c00, c10 = table[top, yi, xi], table[top, yi, xi + 1]
    c01, c11 = table[top, yi + 1, xi], table[top, yi + 1, xi + 1]
    fetched = (1.0 - dy) * ((1.0 - dx) * c00 + dx * c10) + dy * ((1.0 - dx) * c01 + dx * c11)
    grey = (rgb[..., 0] == rgb[..., 1]) & (rgb[..., 1] == rgb[..., 2]) & (z > 0) & (z < 1)
    flat = np.zeros_like(fetched)
    flat[..., 2] = np.where(grey, (z - 0.5) / np.sqrt(np.where(grey, z * (1.0 - z), 1.0)), 0.0)
    return np.where(grey[..., None], flat, fetched)


def sigmoid_polynomial(coeffs: np.ndarray, wavelengths_nm: np.ndarray) -> np.ndarray:
    """The model's spectrum (..., n) of coefficients (..., 3) at wavelengths (n,) in nm, in [0, 1]."""
    lam = np.asarray(wavelengths_nm, dtype=np.float64)
    x = (coeffs[..., 0:1] * lam + coeffs[..., 1:2]) * lam + coeffs[..., 2:3]
    return 0.5 + 0.5 * x / np.sqrt(1.0 + x * x)


def unbounded_spectra_rows(channels: np.ndarray, wavelengths_nm: np.ndarray) -> np.ndarray:
    """``unbounded_spectra`` laid out for the file: channels (3, N) -> spectra (n, N) float32.

    The model is evaluated in float32, as Mitsuba and pbrt-v4 evaluate it.
    """
    rgb = np.asarray(channels, dtype=np.float64).T
    scale = 2.0 * rgb.max(axis=-1)
    coeffs = coefficients(rgb / np.where(scale > 0, scale, 1.0)[:, None]).astype(np.float32)
    lam = np.asarray(wavelengths_nm, dtype=np.float32)[:, None]
    x = (coeffs[:, 0] * lam + coeffs[:, 1]) * lam + coeffs[:, 2]
    return (0.5 + 0.5 * x / np.sqrt(1.0 + x * x)) * scale.astype(np.float32)


def unbounded_spectra(rgb, wavelengths_nm) -> np.ndarray:
    """Spectra (..., n) of linear sRGB values (..., 3) >= 0 of any size, at wavelengths (n,) in nm.

    scale * S(rgb / scale) with scale = 2 max(rgb) (module docstring); black stays 0.
    """
    rgb = np.asarray(rgb, dtype=np.float64)
    scale = 2.0 * rgb.max(axis=-1, keepdims=True)
    shape = sigmoid_polynomial(coefficients(rgb / np.where(scale > 0, scale, 1.0)), wavelengths_nm)
    return scale * shape
