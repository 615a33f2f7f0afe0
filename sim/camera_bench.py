"""A simulated camera on an optical bench: a settable pose instead of a moving rig.

For calibration tests and benchmarks that need the camera, the lamp and a clock but no motors:
``bench.pose = (w_i, w_o)`` stands for the rig's forward kinematics.
"""
from __future__ import annotations

from typing import Callable, Mapping

import numpy as np

from calib.config import validate_camera_section
from goniofrost.core.camera_model import CameraModel

from .camera import SimCamera
from .clock import SimClock
from .direct_lamp import DirectLamp
from .lamp_model import LampModel


def direction(theta_deg: float, phi_deg: float = 0.0) -> np.ndarray:
    """Unit vector (3,) at zenith ``theta_deg`` and azimuth ``phi_deg`` in the sample frame."""
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return np.array([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])


class CameraBench:
    """Clock, lamp model, lamp contract (``lamp``) and a connected SimCamera (``camera``).

    ``params``: the rig's ``sim.camera`` section (the sensor); ``camera``: its ``camera`` section
    (the camera model: intrinsics and mount). The arm works counter-clockwise of the light.
    """

    def __init__(self, material: tuple[str, Callable], params: dict, camera: Mapping, seed: int = 0,
                 speedup: float = 100.0, drift_per_hour: float = 0.02) -> None:
        self.clock = SimClock(speedup)
        self.model = LampModel(self.clock, drift_per_hour, seed)
        self.lamp = DirectLamp(self.model)
        self.pose = (direction(0.0), direction(30.0, 180.0))
        name, brdf = material    # (SPEC:NAME, BrdfFunction), e.g. goniofrost.datasets.material_brdf(...)
        self.camera_model = CameraModel.from_section(validate_camera_section(dict(camera), "CameraBench camera"))
        self.camera = SimCamera(name, brdf, lambda: self.pose, self.model, self.clock, params, seed,
                                model=self.camera_model)
        self.camera.connect()

    def set_angles(self, theta_i: float, theta_o: float, phi_o: float = 180.0) -> tuple:
        """Light at (theta_i, 0), view at (theta_o, phi_o), degrees, both turned about the sample
        normal as a rig's stage would hold the card (its x axis horizontal); returns the pose."""
        self.pose = rig_like(direction(theta_i, 0.0), direction(theta_o, phi_o))
        return self.pose


def rig_like(w_i: np.ndarray, w_o: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(w_i, w_o) turned about the sample normal so that the world vertical (along w_i x w_o on a
    rig whose arm works counter-clockwise of the light) lies in the sample's y-z plane, as on
    a rig (DESIGN.md: the stage keeps the sample's x axis horizontal). Isotropic BRDFs see the
    same pair."""
    c = np.cross(w_i, w_o)
    phi = np.arctan2(c[0], c[1])
    rot = np.array([[np.cos(phi), -np.sin(phi), 0.0], [np.sin(phi), np.cos(phi), 0.0], [0.0, 0.0, 1.0]])
    return rot @ w_i, rot @ w_o
