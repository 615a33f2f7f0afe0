"""The exposure bracket a cell is expected to cost: the rule of ``calib.bracket`` run on expected,
noise-free patch levels instead of frames.

Vectorised over cells. A channel's level in a frame of t seconds is ``rate * t`` (fraction of full
scale); its SNR after total unsaturated exposure T over N pixels is
sqrt(N) E / sqrt(E + frames read^2 + dark T), E = rate * full_well * T electrons. Marker search is
not modelled.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .bracket import START_LEVEL

# The brightest pixel of a uniform patch above its mean (shot noise, pixel response spread and
# vignetting left in the raw frame, a few sigma over hundreds of pixels).
PEAK_FACTOR = 1.06
# Pixels of each Bayer channel (R, G, B) per pixel count of one channel (RGGB: two greens).
BAYER_SHARE = np.array([1.0, 2.0, 1.0])


@dataclass(frozen=True)
class Sensor:
    """What turns a BRDF into electrons: ``signal_e_s`` electrons/s per pixel (green) from a BRDF of
    1/pi at normal incidence, ``channel_gain`` (3,) R, G, B response, ``full_well_e`` electrons at
    full scale, ``read_noise_e`` electrons per frame, ``dark_e_s`` electrons/s."""

    signal_e_s: float
    channel_gain: tuple
    full_well_e: float
    read_noise_e: float
    dark_e_s: float

    @classmethod
    def from_section(cls, section: dict) -> "Sensor":
        """From a rig file's validated ``sim.camera`` mapping."""
        return cls(float(section["signal_e_s"]), tuple(float(g) for g in section["channel_gain"]),
                   float(section["full_well_e"]), float(section["read_noise_e"]), float(section["dark_current_e_s"]))

    def rates(self, brdf, cos_i) -> np.ndarray:
        """Patch levels per second (fraction of full scale), (n, 3), of BRDF values (n, 3) in 1/sr lit
        at cos theta_i (n,)."""
        gain = np.asarray(self.channel_gain, dtype=np.float64)
        return (np.asarray(brdf, np.float64) * np.pi * self.signal_e_s * gain
                * np.maximum(np.asarray(cos_i, np.float64), 0.0)[:, None] / self.full_well_e)


# A rig whose response is not given (no ``sim.camera`` section): the default simulated rig's sensor
# (config/rigs/sim.yaml), a stand-in until the response is fitted from the white reference.
DEFAULT_SENSOR = Sensor(2.0e5, (0.6, 1.0, 0.75), 30000.0, 3.0, 5.0)


def first_rungs(ladder, rates, saturation: float) -> np.ndarray:
    """int64 (n,): the rung a bracket starts at for patch levels per second ``rates`` (n, 3)."""
    t = np.asarray(ladder, np.float64)
    fits = rates.max(axis=1)[:, None] * t[None, :] <= START_LEVEL * saturation
    last = t.size - 1 - np.argmax(fits[:, ::-1], axis=1)
    return np.where(fits.any(axis=1), last, 0)


def expected_frames(ladder, rates, pixels, sensor: Sensor, saturation: float, target_snr: float,
                    first=None) -> np.ndarray:
    """bool (n, L): the ladder rungs the bracket is expected to take for each cell.

    ladder: (L,) exposures in s, shortest first; rates: (n, 3) patch levels per second; pixels:
    (n,) pixels of one colour channel in the region of interest; first: int (n,) the first rung
    (default ``first_rungs``: as if the previous sample had this cell's value).
    """
    t = np.asarray(ladder, np.float64)
    n = rates.shape[0]
    first = first_rungs(t, rates, saturation) if first is None else np.asarray(first, np.int64)
    taken = np.zeros((n, t.size), dtype=bool)
    taken[np.arange(n), first] = True
    bright = rates.max(axis=1)
    lo, hi = first.copy(), first.copy()
    for _ in range(t.size):  # shorter while the shortest frame taken saturates
        down = (bright * t[lo] * PEAK_FACTOR >= saturation) & (lo > 0)
        lo = np.where(down, lo - 1, lo)
        taken[np.arange(n), lo] = True
    measured = bright * t[lo] * PEAK_FACTOR < saturation
    counts = np.asarray(pixels, np.float64)[:, None] * BAYER_SHARE[None, :]
    # each channel's unsaturated exposure and frames so far, (n, 3); kept as rungs are added
    exposure, frames = np.zeros_like(rates), np.zeros_like(rates)
    for k in range(t.size):
        _add(exposure, frames, rates, t[k], taken[:, k], saturation)
    for _ in range(t.size):  # longer while a channel lags and the next rung keeps it unsaturated
        up = measured & (hi + 1 < t.size) & _lagging(t, rates, counts, exposure, frames, sensor, saturation,
                                                      target_snr, hi)
        hi = np.where(up, hi + 1, hi)
        taken[np.arange(n), hi] = True
        _add(exposure, frames, rates, t[hi], up, saturation)
    return taken


def _add(exposure, frames, rates, t, rows, saturation: float) -> None:
    """Count a frame of exposure ``t`` (s, scalar or (n,)) of the cells ``rows`` (bool (n,)) in each
    channel it leaves unsaturated (its median pixel: the merge drops saturated pixels)."""
    t = np.broadcast_to(np.asarray(t, np.float64), rows.shape)[:, None]
    used = rows[:, None] & (rates * t < saturation)
    exposure += np.where(used, t, 0.0)
    frames += used


def _lagging(t, rates, counts, exposure, frames, sensor: Sensor, saturation, target_snr, hi) -> np.ndarray:
    """bool (n,): some channel below ``target_snr`` whose median pixel the next rung keeps unsaturated."""
    electrons = rates * sensor.full_well_e * exposure
    noise = np.sqrt(electrons + frames * sensor.read_noise_e ** 2 + sensor.dark_e_s * exposure)
    with np.errstate(invalid="ignore", divide="ignore"):
        snr = np.where(noise > 0, electrons / noise, 0.0) * np.sqrt(counts)
    following = t[np.minimum(hi + 1, t.size - 1)]
    below = (snr < target_snr) & (rates * following[:, None] < saturation)
    return below.any(axis=1)


def bracket_seconds(ladder, taken: np.ndarray) -> np.ndarray:
    """float64 (n,): the exposure time of the rungs ``taken`` (n, L)."""
    return taken.astype(np.float64) @ np.asarray(ladder, np.float64)
