"""The compiled (numba) pixel-count bound of ``planner.view.roi_pixels`` at many poses.

Apart from ``view`` so that reading a rig file does not import numba.
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange


@njit(parallel=True, cache=True)
def roi_counts(w_i, w_o, roi, params, dist, mount, out):
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
