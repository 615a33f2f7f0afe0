"""Camera noise on simulated samples: what the simulated rig's camera adds to a patch mean.

The simulated camera brackets each sample until every channel's patch mean reaches the rig's
``camera.target_snr`` (``calib.bracket``), so a measured sample is off its true value by a
relative error of standard deviation at most 1 / target_snr (0.01 on goniofrost/rigs/sim.yaml).
The benchmark draws that error at its largest, per sample and channel, independently:
value x (1 + z / SNR), z standard normal. Each material's errors are drawn from the seed and
its name alone, so they do not depend on which materials are simulated together.
"""
from __future__ import annotations

import zlib

import numpy as np


def relative_sd(camera: dict) -> float:
    """The relative standard deviation of a sample, 1 / SNR, from a rig's camera section."""
    return 1.0 / float(camera["target_snr"])


def material_noise(name: str, shape: tuple[int, ...], seed: int) -> np.ndarray:
    """float64 ``shape`` standard normal draws of the material ``name`` (its cells, 3 channels)."""
    return np.random.default_rng([int(seed), zlib.crc32(name.encode())]).standard_normal(shape)


def noisy(values: np.ndarray, names: list[str], sd: float, seed: int) -> np.ndarray:
    """values (n_mat, n_cells, 3) BRDF of the materials ``names`` as the camera measures them:
    float64, each value x (1 + sd z) (``material_noise``); NaN (cells without data) stays NaN."""
    values = np.asarray(values, dtype=np.float64)
    out = np.empty_like(values)
    for i, name in enumerate(names):
        out[i] = values[i] * (1.0 + sd * material_noise(name, values.shape[1:], seed))
    return out
