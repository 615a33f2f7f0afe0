"""What the camera can measure at a pose: enough patch pixels, and the patch inside the lamp's beam.

A pose (w_i, w_o) is measurable when
* the region of interest (the holder's patch shrunk by the ROI margin), projected through the
  rig's camera model, lies inside the image and keeps at least ``min_pixels`` pixels of every
  Bayer colour channel after the one-pixel erosion the calibration applies (``PATCH_PIXELS``);
* every corner of the patch lies inside the lamp's beam, a cylinder of ``beam_radius_mm`` about
  the light direction through the rotation centre (``LAMP_BEAM``);
* the light meets the sample at most ``max_incidence_deg`` from its normal (``LIGHT_GRAZING``):
  the patch's irradiance is cos theta_i of the normal's, and a light at 89.97 deg (cos 0.0005,
  the MERL grid's most grazing cells) left a capture's sample below its SNR minimum at the
  longest exposure, which ends the session (and a resume meets the same sample again).
The pixel count is a lower bound computed in closed form (no rasterisation), in one compiled
(numba) pass over any number of poses: the eroded mask holds every pixel whose centre lies ERODE_PX inside the
polygon, and a convex region of area A and perimeter P holds at least A/4 - P/4 - 1 points of a
Bayer channel's lattice (spacing 2). So a cell the planner calls measurable is one the capture
can measure (tests/test_view.py checks the bound against the rasterised masks).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit, prange

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
    w_i, w_o = np.broadcast_arrays(np.asarray(w_i, dtype=np.float64), np.asarray(w_o, dtype=np.float64))
    shape = w_i.shape[:-1]
    cam = view.camera
    out = np.empty(int(np.prod(shape)), dtype=np.float64)
    _roi_counts(np.ascontiguousarray(w_i.reshape(-1, 3)), np.ascontiguousarray(w_o.reshape(-1, 3)),
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


@njit(parallel=True, cache=True)
def _roi_counts(w_i, w_o, roi, params, dist, mount, out):
    """out[p] = max(A/4 - P/4 - 1, 0), A and P the area and perimeter of the projected region of
    interest (4 corners, mm) at pose p moved inwards by ERODE_PX; 0 if a corner leaves the image
    or lies behind the camera. See goniofrost.core.camera_model for the projection."""
    fx, fy, cx, cy, distance, side, d, width, height = params
    k1, k2, p1, p2, k3 = dist
    for p in prange(w_i.shape[0]):
        out[p] = 0.0
        ax, ay, az = w_i[p, 0], w_i[p, 1], w_i[p, 2]
        bx, by, bz = w_o[p, 0], w_o[p, 1], w_o[p, 2]
        if bz <= 0.0:
            continue
        # camera frame rows x_c, y_c, z_c in the sample frame (camera_model.extrinsics)
        n = np.sqrt(bx * bx + by * by + bz * bz)
        zx, zy, zz = -bx / n, -by / n, -bz / n
        ux, uy, uz = side * (ay * bz - az * by), side * (az * bx - ax * bz), side * (ax * by - ay * bx)
        dot = ux * zx + uy * zy + uz * zz
        ux, uy, uz = ux - dot * zx, uy - dot * zy, uz - dot * zz
        n = np.sqrt(ux * ux + uy * uy + uz * uz)
        if n == 0.0:
            continue
        yx, yy, yz = -ux / n, -uy / n, -uz / n
        xx, xy, xz = yy * zz - yz * zy, yz * zx - yx * zz, yx * zy - yy * zx
        # columns 0, 1 of R = mount @ [x_c; y_c; z_c] and t = mount @ (0, 0, distance)
        c0 = np.empty(3)
        c1 = np.empty(3)
        t = np.empty(3)
        for r in range(3):
            c0[r] = mount[r, 0] * xx + mount[r, 1] * yx + mount[r, 2] * zx
            c1[r] = mount[r, 0] * xy + mount[r, 1] * yy + mount[r, 2] * zy
            t[r] = mount[r, 2] * distance
        px = np.empty((4, 2))
        ok = True
        for k in range(4):
            X = c0[0] * roi[k, 0] + c1[0] * roi[k, 1] + t[0]
            Y = c0[1] * roi[k, 0] + c1[1] * roi[k, 1] + t[1]
            Z = c0[2] * roi[k, 0] + c1[2] * roi[k, 1] + t[2]
            if Z <= 0.0:
                ok = False
                break
            xn, yn = X / Z, Y / Z
            r2 = xn * xn + yn * yn
            radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            xd = xn * radial + 2.0 * p1 * xn * yn + p2 * (r2 + 2.0 * xn * xn)
            yd = yn * radial + p1 * (r2 + 2.0 * yn * yn) + 2.0 * p2 * xn * yn
            px[k, 0], px[k, 1] = fx * xd + cx, fy * yd + cy
            if not (0.0 <= px[k, 0] <= width - 1 and 0.0 <= px[k, 1] <= height - 1):
                ok = False
                break
        if ok:
            area, perimeter = _inset(px, d)
            out[p] = max(area / 4.0 - perimeter / 4.0 - 1.0, 0.0)


@njit(cache=True)
def _inset(poly, d):
    """Area and perimeter of a convex quadrilateral (4, 2) moved inwards by d (0, 0 if it vanishes)."""
    area2 = 0.0
    for k in range(4):
        j = (k + 1) % 4
        area2 += poly[k, 0] * poly[j, 1] - poly[j, 0] * poly[k, 1]
    if area2 == 0.0:
        return 0.0, 0.0
    ccw = 1.0 if area2 > 0 else -1.0
    normal = np.empty((4, 2))
    offset = np.empty(4)
    for k in range(4):                      # edge k: p_k -> p_k+1; line: normal . x = offset
        j = (k + 1) % 4
        ex, ey = poly[j, 0] - poly[k, 0], poly[j, 1] - poly[k, 1]
        length = np.sqrt(ex * ex + ey * ey)
        if length == 0.0:
            return 0.0, 0.0
        normal[k, 0], normal[k, 1] = -ccw * ey / length, ccw * ex / length
        offset[k] = normal[k, 0] * poly[k, 0] + normal[k, 1] * poly[k, 1] + d
    inset = np.empty((4, 2))
    for k in range(4):                      # vertex k: lines k-1 and k
        i = (k + 3) % 4
        det = normal[i, 0] * normal[k, 1] - normal[i, 1] * normal[k, 0]
        if det == 0.0:
            return 0.0, 0.0
        inset[k, 0] = (offset[i] * normal[k, 1] - offset[k] * normal[i, 1]) / det
        inset[k, 1] = (normal[i, 0] * offset[k] - normal[k, 0] * offset[i]) / det
    area2 = 0.0
    perimeter = 0.0
    for k in range(4):                      # the inset lives while every edge keeps its direction
        j = (k + 1) % 4
        ex, ey = inset[j, 0] - inset[k, 0], inset[j, 1] - inset[k, 1]
        if ex * (poly[j, 0] - poly[k, 0]) + ey * (poly[j, 1] - poly[k, 1]) <= 0.0:
            return 0.0, 0.0
        perimeter += np.sqrt(ex * ex + ey * ey)
        area2 += inset[k, 0] * inset[j, 1] - inset[j, 0] * inset[k, 1]
    return abs(area2) / 2.0, perimeter
