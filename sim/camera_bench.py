"""A simulated camera on an optical bench: a settable pose instead of a moving rig.

For calibration tests and benchmarks that need the camera, the lamp and a clock but no motors:
``bench.pose = (w_i, w_o)`` stands for the rig's forward kinematics.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from .camera import SimCamera
from .clock import SimClock
from .direct_lamp import DirectLamp
from .lamp_model import LampModel


def direction(theta_deg: float, phi_deg: float = 0.0) -> np.ndarray:
    """Unit vector (3,) at zenith ``theta_deg`` and azimuth ``phi_deg`` in the sample frame."""
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return np.array([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])


class CameraBench:
    """Clock, lamp model, lamp contract (``lamp``) and a connected SimCamera (``camera``)."""

    def __init__(self, material: tuple[str, Callable], params: dict, seed: int = 0, speedup: float = 100.0,
                 drift_per_hour: float = 0.02) -> None:
        self.clock = SimClock(speedup)
        self.model = LampModel(self.clock, drift_per_hour, seed)
        self.lamp = DirectLamp(self.model)
        self.pose = (direction(0.0), direction(30.0, 180.0))
        name, brdf = material    # (SPEC:NAME, BrdfFunction), e.g. goniofrost.datasets.material_brdf(...)
        self.camera = SimCamera(name, brdf, lambda: self.pose, self.model, self.clock, params, seed)
        self.camera.connect()

    def set_angles(self, theta_i: float, theta_o: float, phi_o: float = 180.0) -> tuple:
        """Light at (theta_i, 0), view at (theta_o, phi_o), degrees; returns the pose."""
        self.pose = (direction(theta_i, 0.0), direction(theta_o, phi_o))
        return self.pose
