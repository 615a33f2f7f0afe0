"""The rig camera as a pinhole model: where a point of the sample plane falls in the image.

One model serves the planner, the calibration and the simulated camera. OpenCV conventions
(``cv2.projectPoints``): camera x right, y down, z forward; pixel centres at integers; distortion
(k1, k2, p1, p2, k3); lengths in millimetres. A pose is the light and view directions (w_i, w_o)
in the sample frame. The mount: docs/explanations/camera.md.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np


@dataclass(frozen=True)
class CameraModel:
    """Intrinsics (pixels) and mount of the rig camera.

    ``width``, ``height``: image size in pixels; ``fx``, ``fy``: focal lengths in pixels;
    ``cx``, ``cy``: principal point in pixels; ``distortion``: (k1, k2, p1, p2, k3);
    ``distance_mm``: centre of projection to rotation centre; ``rotation_deg``: the camera's
    mounting rotation about its own x, y, z axes (degrees, applied in that order).
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple[float, float, float, float, float]
    distance_mm: float
    rotation_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @classmethod
    def from_section(cls, section: Mapping) -> "CameraModel":
        """From a validated rig ``camera:`` section (its ``intrinsics`` and ``mount`` mappings)."""
        intr, mount = section["intrinsics"], section["mount"]
        fx, fy = intr["focal_px"]
        cx, cy = intr["principal_point_px"]
        width, height = intr["image_size_px"]
        return cls(width=int(width), height=int(height), fx=float(fx), fy=float(fy), cx=float(cx), cy=float(cy),
                   distortion=tuple(float(d) for d in intr["distortion"]),
                   distance_mm=float(mount["distance_mm"]),
                   rotation_deg=tuple(float(r) for r in mount["rotation_deg"]))

    def as_dict(self) -> dict:
        """JSON-friendly description (for cache keys and records)."""
        return {"image_size_px": [self.width, self.height], "focal_px": [self.fx, self.fy],
                "principal_point_px": [self.cx, self.cy], "distortion": list(self.distortion),
                "distance_mm": self.distance_mm, "rotation_deg": list(self.rotation_deg)}

    @property
    def K(self) -> np.ndarray:
        """The 3 x 3 camera matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def dist(self) -> np.ndarray:
        """Distortion coefficients (5,) in OpenCV order."""
        return np.asarray(self.distortion, dtype=np.float64)

    @property
    def mount_rotation(self) -> np.ndarray:
        """R_z(rz) R_y(ry) R_x(rx), (3, 3): ideal camera frame -> actual camera frame."""
        rx, ry, rz = np.radians(self.rotation_deg)
        cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
        r_x = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
        r_y = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
        r_z = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
        return r_z @ r_y @ r_x

    def extrinsics(self, w_i, w_o, arm_side: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """Camera-from-sample rotation R (..., 3, 3) and translation t (..., 3) in mm of poses given
        by unit directions w_i, w_o (..., 3) in the sample frame: p_cam = R p_sample + t."""
        w_i, w_o = np.asarray(w_i, dtype=np.float64), np.asarray(w_o, dtype=np.float64)
        z_c = -_unit(w_o)
        up = arm_side * _unit(np.cross(w_i, w_o))
        up = _unit(up - np.sum(up * z_c, -1, keepdims=True) * z_c)   # exactly perpendicular to the axis
        y_c = -up                                                   # image rows run down the world
        x_c = np.cross(y_c, z_c)
        R0 = np.stack([x_c, y_c, z_c], axis=-2)
        t0 = np.zeros(R0.shape[:-1])
        t0[..., 2] = self.distance_mm
        mount = self.mount_rotation
        return np.einsum("ij,...jk->...ik", mount, R0), np.einsum("ij,...j->...i", mount, t0)

    def project(self, points, R, t) -> np.ndarray:
        """Pixels (..., N, 2) of sample-frame points (N, 3) or (..., N, 3) in mm seen with poses R
        (..., 3, 3), t (..., 3); the same numbers as ``cv2.projectPoints``, vectorised over poses.
        Points behind the camera come out as NaN."""
        p = np.einsum("...ij,...nj->...ni", np.asarray(R), np.asarray(points, dtype=np.float64)) + \
            np.asarray(t)[..., None, :]
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.where(p[..., 2] > 0, p[..., 2], np.nan)
            x, y = p[..., 0] / z, p[..., 1] / z
        k1, k2, p1, p2, k3 = self.distortion
        r2 = x * x + y * y
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        return np.stack([self.fx * xd + self.cx, self.fy * yd + self.cy], -1)

    def project_plane(self, points_mm, w_i, w_o, arm_side: float = 1.0) -> np.ndarray:
        """Pixels (..., N, 2) of points (N, 2) of the sample plane (z = 0, mm) at poses (..., 3)."""
        pts = np.asarray(points_mm, dtype=np.float64)
        pts3 = np.concatenate([pts, np.zeros(pts.shape[:-1] + (1,))], -1)
        R, t = self.extrinsics(w_i, w_o, arm_side)
        return self.project(pts3, R, t)

    def plane_homography(self, w_i, w_o, arm_side: float = 1.0) -> np.ndarray:
        """Homography (3, 3) from sample-plane mm (x, y, 1) to undistorted pixels, one pose (3,)."""
        R, t = self.extrinsics(w_i, w_o, arm_side)
        return self.K @ np.column_stack([R[:, 0], R[:, 1], t])


def _unit(v: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore", divide="ignore"):
        return v / np.linalg.norm(v, axis=-1, keepdims=True)
