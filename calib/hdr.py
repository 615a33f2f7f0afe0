"""Merge an exposure bracket into one radiometric rate per pixel, and summarise a region.

A *rate* is the dark-subtracted, flat-fielded linear value per second of exposure at nominal lamp
intensity (fraction of full range per second): r_p = sum_k v_kp (x_kp - d_kp) / (F_p l_k) /
sum_k v_kp t_k, with v_kp = 0 for a saturated pixel.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class BracketFrame:
    """One calibrated-ready frame: ``linear`` (H, W) float32, ``saturated`` (H, W) bool,
    exposure in seconds, ``dark`` (H, W) for that exposure, lamp level relative to nominal."""

    linear: np.ndarray
    saturated: np.ndarray
    exposure_s: float
    dark: np.ndarray
    lamp_relative: float


def merge(frames: list[BracketFrame], flat: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rates (n,) of the n pixels in ``mask`` and whether each had an unsaturated frame (n,)."""
    num = np.zeros(int(mask.sum()))
    den = np.zeros_like(num)
    for f in frames:
        ok = ~f.saturated[mask]
        num += np.where(ok, (f.linear[mask] - f.dark[mask]) / (flat[mask] * f.lamp_relative), 0.0)
        den += np.where(ok, f.exposure_s, 0.0)
    covered = den > 0
    rates = np.divide(num, den, out=np.full_like(num, np.nan), where=covered)
    return rates, covered


def channel_stats(rates: np.ndarray, channels: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean rate, its standard error and the pixel count per channel, each (3,).

    The patch is uniform (far-field rig), so the scatter of its pixels measures the noise of one
    pixel, and std / sqrt(n) that of the mean. A channel with < 2 pixels gets NaN.
    """
    mean, se, count = np.full(3, np.nan), np.full(3, np.nan), np.zeros(3, dtype=int)
    for c in range(3):
        v = rates[(channels == c) & np.isfinite(rates)]
        count[c] = v.size
        if v.size >= 2:
            mean[c] = v.mean()
            se[c] = v.std(ddof=1) / np.sqrt(v.size)
    return mean, se, count
