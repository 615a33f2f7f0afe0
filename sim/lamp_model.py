"""The simulated lamp: on/off state and an intensity that drifts slowly over nominal time.

Shared by the simulated Modbus drive (coil and photodiode register) and the simulated camera, so
the calibration can normalise drift as on a real rig.
"""
from __future__ import annotations

import numpy as np

from .clock import SimClock

PHOTODIODE_FULL_SCALE = 50_000  # counts at relative intensity 1.0 (fits a 16-bit register)


class LampModel:
    """Relative lamp intensity I(t) = 1 + drift_per_hour * t/3600 + a small slow wobble.

    ``t`` is the clock's nominal time in simulated seconds. ``relative_intensity()`` is 0 while
    the lamp is off. Deterministic for a given seed and nominal time.
    """

    def __init__(self, clock: SimClock, drift_per_hour: float = 0.02, seed: int = 0) -> None:
        self.clock = clock
        self.drift_per_hour = float(drift_per_hour)
        self.is_on = False
        rng = np.random.default_rng(seed)
        self._phase = float(rng.uniform(0, 2 * np.pi))
        self._outage: tuple[float, float, float] | None = None  # (start, end) nominal s, intensity factor

    def interrupt(self, level: float, duration_s: float) -> None:
        """Dim the lamp to ``level`` of its intensity (0: cut) for ``duration_s`` nominal seconds from
        now (a drill: ``lamp_dim``, ``lamp_cut``); then it comes back as it was."""
        t0 = self.clock.nominal_time()
        self._outage = (t0, t0 + float(duration_s), float(level))

    def relative_intensity(self, t: float | None = None) -> float:
        """Intensity relative to nominal at nominal time t (default: the clock's nominal time now); 0 when off."""
        if not self.is_on:
            return 0.0
        t = self.clock.nominal_time() if t is None else t
        wobble = 0.003 * np.sin(2 * np.pi * t / 600.0 + self._phase)
        factor = 1.0
        if self._outage is not None and self._outage[0] <= t < self._outage[1]:
            factor = self._outage[2]
        return float((1.0 + self.drift_per_hour * t / 3600.0 + wobble) * factor)

    def photodiode_counts(self, t: float | None = None) -> int:
        """Monitor photodiode reading in counts (proportional to intensity, 16-bit)."""
        return int(round(min(self.relative_intensity(t) * PHOTODIODE_FULL_SCALE, 65535)))
