"""Rig time of every candidate cell given where the rig stands: move + settle + exposure bracket.

Each cell costs its fastest candidate pose's move (``planner.motion``), the settle time and its
expected bracket (``calib.exposure_time`` at the model's prior median). Pure: no device, no file.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.exposure_time import DEFAULT_SENSOR, Sensor, bracket_seconds, expected_frames
from planner.candidates import candidate_poses
from planner.kinematics import arm_side
from planner.motion import axis_params, trapezoid_time
from planner.view import roi_pixels

# Pixels per colour channel assumed for a rig without a camera model (the default rig keeps
# >= 24 up to grazing views and a few hundred near the normal).
DEFAULT_PIXELS = 100.0


@dataclass(frozen=True)
class CellCosts:
    """The fixed parts of every candidate cell's rig time.

    poses: float32 (n_c, k, 3) candidate joints in degrees (NaN: unusable); fixed_s: float32
    (n_c, k) settle + expected bracket seconds of each candidate (inf: unusable); speed, accel,
    tolerance: float64 (3,) the axes' profiles in joint order (deg/s, deg/s^2, deg); home: float64
    (3,) the rig's home joints.
    """

    poses: np.ndarray
    fixed_s: np.ndarray
    speed: np.ndarray
    accel: np.ndarray
    tolerance: np.ndarray
    home: np.ndarray

    def seconds_from(self, here) -> np.ndarray:
        """float64 (n_c,): each cell's rig time from joints ``here`` (3,) with its fastest candidate."""
        return self.candidate_seconds(here).min(axis=1)

    def candidate_seconds(self, here) -> np.ndarray:
        """float64 (n_c, k): each candidate's move from ``here`` + settle + bracket (inf: unusable)."""
        delta = self.poses.astype(np.float64) - np.asarray(here, np.float64)
        move = trapezoid_time(delta, self.speed, self.accel, self.tolerance).max(axis=-1)
        return np.where(np.isfinite(self.fixed_s), move + self.fixed_s, np.inf)

    def fastest_pose(self, i: int, here) -> np.ndarray:
        """float64 (3,): the candidate pose of cell ``i`` reached soonest from ``here``."""
        one = CellCosts(self.poses[i:i + 1], self.fixed_s[i:i + 1], self.speed, self.accel, self.tolerance, self.home)
        return self.poses[i, int(np.argmin(one.candidate_seconds(here)[0]))].astype(np.float64)


def rig_sensor(rig) -> Sensor:
    """The sensor response of ``rig``: its ``sim.camera`` section's, else ``DEFAULT_SENSOR``."""
    from sim.camera import validate_sim_camera_section

    section = (rig.sim or {}).get("camera")
    return DEFAULT_SENSOR if section is None else Sensor.from_section(
        validate_sim_camera_section(section, rig.source))


def rig_camera(rig) -> dict:
    """The rig's camera section with its defaults (ladder, saturation, target SNR)."""
    from calib.config import validate_camera_section

    return validate_camera_section(rig.camera, rig.source)


def cell_costs(model, rig, rows, camera: dict, sensor: Sensor = DEFAULT_SENSOR, settle_s: float = 0.0) -> CellCosts:
    """The CellCosts of the model's valid cells ``rows`` (int (n_c,)) on ``rig``.

    camera: the rig's validated camera section (``exposures_s``, ``saturation``, ``target_snr``);
    sensor: its response (``calib.exposure_time.Sensor``); settle_s: seconds after every move.
    """
    rows = np.asarray(rows, dtype=np.int64)
    value = model.from_log(np.asarray(model.mean, np.float64)[rows][:, None], rows)[:, 0]  # prior median, 1/sr
    return value_costs(model.grid, value, rig, rows, camera, sensor, settle_s)


def value_costs(grid, value, rig, rows, camera: dict, sensor: Sensor = DEFAULT_SENSOR,
                settle_s: float = 0.0) -> CellCosts:
    """``cell_costs`` of the valid cells ``rows`` (int (n_c,)) of ``grid`` whose expected values
    are ``value`` (float64 (n_c,), 1/sr): training's inner designs use it before the model exists."""
    rows = np.asarray(rows, dtype=np.int64)
    w_i, w_o = grid.cell_directions(grid.valid_cells[rows])
    poses, usable, _ = candidate_poses(rig, w_i, w_o)
    fixed = np.full(usable.shape, np.inf)
    for c in range(usable.shape[1]):
        light, view = (w_o, w_i) if c >= 2 else (w_i, w_o)  # candidates 2, 3: light and camera swapped
        pixels = (roi_pixels(rig.view, light, view, arm_side(rig)) if rig.view is not None
                  else np.full(rows.size, DEFAULT_PIXELS))
        rates = sensor.rates(np.repeat(value[:, None], 3, axis=1), light[:, 2])
        taken = expected_frames(camera["exposures_s"], rates, np.maximum(pixels, 1.0), sensor,
                                camera["saturation"], camera["target_snr"])
        fixed[:, c] = np.where(usable[:, c], settle_s + bracket_seconds(camera["exposures_s"], taken), np.inf)
    speed, accel, tolerance = axis_params(rig)
    poses = np.where(usable[..., None], poses, np.nan).astype(np.float32)
    return CellCosts(poses, fixed.astype(np.float32), speed, accel, tolerance, np.asarray(rig.home, np.float64))
