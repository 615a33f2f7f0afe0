"""Move times in seconds: each axis follows a trapezoidal velocity profile; axes move together.

A move of d degrees at top speed v (deg/s) and acceleration a (deg/s^2) takes ``2 sqrt(d / a)``
when d < v^2 / a, else ``d / v + v / a``. A step takes as long as its slowest axis; an axis already
within tolerance costs nothing.
"""
from __future__ import annotations

import numpy as np

from .kinematics import joints_array
from .rig import Rig


def axis_params(rig: Rig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(speed deg/s, accel deg/s^2, tolerance deg), each (3,) in joint order."""
    axes = rig.ordered_axes
    return tuple(np.array([getattr(a, key) for a in axes]) for key in
                 ("speed_deg_s", "accel_deg_s2", "tolerance_deg"))


def trapezoid_time(distance, speed, accel, tolerance) -> np.ndarray:
    """Seconds to move |distance| degrees with a trapezoidal profile; 0 within tolerance. Broadcasts."""
    d = np.abs(np.asarray(distance, dtype=np.float64))
    cruise = d >= speed * speed / accel
    with np.errstate(invalid="ignore"):
        t = np.where(cruise, d / speed + speed / accel, 2.0 * np.sqrt(d / accel))
    return np.where(d <= tolerance, 0.0, t)


def move_time(rig: Rig, from_joints, to_joints) -> np.ndarray:
    """Seconds to move from joints (..., 3) deg to joints (..., 3) deg (the slowest axis). Broadcasts."""
    delta = joints_array(rig, to_joints) - joints_array(rig, from_joints)
    return trapezoid_time(delta, *axis_params(rig)).max(axis=-1)


def time_matrix(rig: Rig, a, b=None) -> np.ndarray:
    """Pairwise move times (n_a, n_b) in seconds between poses a (n_a, 3) and b (n_b, 3) (default a)."""
    a = joints_array(rig, a)
    b = a if b is None else joints_array(rig, b)
    return move_time(rig, a[:, None, :], b[None, :, :])


def path_time(rig: Rig, poses, start=None, end=None) -> np.ndarray:
    """Per-move times (n (+1),) visiting poses (n, 3) in order from ``start``; with ``end``, the return too."""
    poses = joints_array(rig, poses)
    stops = [poses]
    if start is not None:
        stops.insert(0, joints_array(rig, start)[None])
    if end is not None:
        stops.append(joints_array(rig, end)[None])
    seq = np.concatenate(stops)
    return move_time(rig, seq[:-1], seq[1:])
