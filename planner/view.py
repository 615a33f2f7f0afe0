"""What the camera can measure at a pose: enough patch pixels, the patch in the lamp's beam.

A pose fails with ``PATCH_PIXELS`` (too few pixels per Bayer channel in the region of interest),
``LAMP_BEAM`` (a patch corner outside the beam) or ``LIGHT_GRAZING`` (light beyond
``max_incidence_deg``). The pixel count is a closed-form lower bound: docs/explanations/camera.md.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Pixels of a 3x3 erosion survive when their centre lies sqrt(2) inside the polygon; 0.1 px more
# covers the rasteriser's 1/16-pixel rounding of the polygon's corners.
ERODE_PX = float(np.sqrt(2.0)) + 0.1


@dataclass(frozen=True)
class Measurability:
    """What decides whether the camera can measure a pose.

    ``camera``: ``goniofrost.core.camera_model.CameraModel``; ``roi_mm``: (4, 2) corners of the
    region of interest in the sample plane (mm); ``patch_mm``: (4, 2) corners of the whole
    patch (mm); ``min_pixels``: pixels per colour channel; ``beam_radius_mm``: radius of the
    lamp's collimated beam (None: it covers the whole holder); ``max_incidence_deg``: the light's
    largest angle from the sample's normal (None: no limit).
    """

    camera: object
    roi_mm: tuple
    patch_mm: tuple
    min_pixels: int
    beam_radius_mm: float | None = None
    max_incidence_deg: float | None = None

    def as_dict(self) -> dict:
        """JSON-friendly description (cache keys)."""
        return {"camera": self.camera.as_dict(), "roi_mm": np.asarray(self.roi_mm).tolist(),
                "patch_mm": np.asarray(self.patch_mm).tolist(), "min_pixels": self.min_pixels,
                "beam_radius_mm": self.beam_radius_mm, "max_incidence_deg": self.max_incidence_deg}


def roi_pixels(view: Measurability, w_i, w_o, arm_side: float = 1.0) -> np.ndarray:
    """Lower bound (float (...,)) on the pixels per colour channel the region of interest keeps at
    poses given by unit directions w_i, w_o (..., 3) in the sample frame; 0 where the region
    leaves the image or the camera sees the sample from behind. One compiled pass over the poses
    (the whole MERL grid has 4 candidate poses per cell)."""
    from planner.view_kernels import roi_counts  # numba: not imported by what only reads a rig file

    w_i, w_o = np.broadcast_arrays(np.asarray(w_i, dtype=np.float64), np.asarray(w_o, dtype=np.float64))
    shape = w_i.shape[:-1]
    cam = view.camera
    out = np.empty(int(np.prod(shape)), dtype=np.float64)
    roi_counts(np.ascontiguousarray(w_i.reshape(-1, 3)), np.ascontiguousarray(w_o.reshape(-1, 3)),
                np.ascontiguousarray(view.roi_mm, dtype=np.float64),
                np.array([cam.fx, cam.fy, cam.cx, cam.cy, cam.distance_mm, float(arm_side), ERODE_PX,
                          cam.width, cam.height]),
                np.asarray(cam.distortion, dtype=np.float64), np.ascontiguousarray(cam.mount_rotation), out)
    return out.reshape(shape)


def beam_covers(view: Measurability, w_i) -> np.ndarray:
    """bool (...): every patch corner lies within the beam (a cylinder about w_i, sample frame)."""
    w_i = np.asarray(w_i, dtype=np.float64)
    if view.beam_radius_mm is None:
        return np.ones(w_i.shape[:-1], dtype=bool)
    p = np.column_stack([np.asarray(view.patch_mm, dtype=np.float64), np.zeros(len(view.patch_mm))])   # (4, 3)
    along = np.einsum("kj,...j->...k", p, w_i)                                        # (..., 4)
    off_axis = np.sum(p ** 2, -1) - along ** 2                                         # squared distances
    return np.all(off_axis <= view.beam_radius_mm ** 2 + 1e-9, axis=-1)


def light_reaches(view: Measurability, w_i) -> np.ndarray:
    """bool (...): the light direction w_i (..., 3, unit, sample frame) lies within
    ``max_incidence_deg`` of the sample's normal (everywhere True without a limit)."""
    w_i = np.asarray(w_i, dtype=np.float64)
    if view.max_incidence_deg is None:
        return np.ones(w_i.shape[:-1], dtype=bool)
    return w_i[..., 2] >= np.cos(np.radians(view.max_incidence_deg))
