"""A rig pose as drawings: the rig seen from above and from the side, in 2-D coordinates.

The geometry is ``planner.kinematics``'s (world z up, sample at the origin, fixed horizontal lamp,
camera arm alpha in the horizontal plane, stage yawed by psi about z and tilted by tau about its
x_s axis). Lengths are in units of the sample-to-lamp distance. From above: world (x, y). From the
side, looking along x_s so the tilt shows at its true angle: horizontal = the horizontal direction
h of the sample normal, vertical = world z; lamp and camera lie on the horizon at their distance
along h.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

LAMP_R, CAMERA_R, PLATE_HALF, NORMAL_LEN = 1.0, 0.85, 0.25, 0.45


@lru_cache(maxsize=4)
def rig_from_text(rig_text: str, source: str):
    """The journaled rig file's text as a ``planner.rig.Rig`` (kinematics only; the driver, camera
    and sim sections are not checked again: the capture checked them when it started)."""
    import yaml

    from planner.rig import rig_from_mapping

    return rig_from_mapping(yaml.safe_load(rig_text), source)


def pose_drawing(rig, joints: dict) -> dict:
    """The pose ``joints`` {axis name: deg} drawn from above and from the side (module doc).

    Returns ``{"joints": [[axis, role, deg], ...], "top": VIEW, "side": VIEW}`` where each VIEW maps
    ``lamp``, ``camera``, ``normal`` to [u, v] points and ``plate`` to four [u, v] corners.
    """
    from planner.kinematics import camera_direction, joints_array, stage_rotation

    q = joints_array(rig, joints)
    light = np.asarray(rig.geometry.light_direction, dtype=np.float64)
    camera = camera_direction(rig, q[0])
    m = stage_rotation(rig, q[1], q[2])
    x_s, y_s, normal = m[:, 0], m[:, 1], m[:, 2]
    corners = [PLATE_HALF * (a * x_s + b * y_s) for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    points = {"lamp": LAMP_R * light, "camera": CAMERA_R * camera, "normal": NORMAL_LEN * normal}
    h = np.array([normal[0], normal[1], 0.0])
    h = h / np.linalg.norm(h) if np.linalg.norm(h) > 1e-9 else np.array([1.0, 0.0, 0.0])

    def view(project) -> dict:
        out = {name: project(p) for name, p in points.items()}
        out["plate"] = [project(c) for c in corners]
        return out

    return {
        "joints": [[axis.name, axis.role.value, round(float(v), 3)] for axis, v in zip(rig.ordered_axes, q)],
        "top": view(lambda p: [round(float(p[0]), 4), round(float(p[1]), 4)]),
        "side": view(lambda p: [round(float(p @ h), 4), round(float(p[2]), 4)]),
    }
