"""What one image of the holder card says about the rig's alignment: its marker corners, the camera
pose they give (OpenCV solvePnP) and the white tile's brightness. Input of
``planner.alignment.fit_alignment``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .holder import DEFAULT_LAYOUT, HolderLayout
from .roi import MIN_MARKERS, UPSAMPLE, read_markers

# The white tile's brightness is the mean of a fixed disc of pixels around where the rotation
# centre is imaged: the same pixels in every image, so their gains and vignetting are one constant
# factor. Its radius (pixels) is the largest that stays on the tile at every alignment pose, within:
MIN_DISC_PX, MAX_DISC_PX = 4.0, 20.0


@dataclass(frozen=True)
class CardReading:
    """The marker corners read in one image: ``plane_mm`` (N, 2) on the card, ``image_px`` (N, 2)
    in the frame; ``rotation`` (3, 3) and ``translation`` (3,) mm of the camera-from-card pose
    solvePnP finds from them alone, and its RMS reprojection error (px)."""

    plane_mm: np.ndarray
    image_px: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    pnp_rms_px: float


def read_card(linear: np.ndarray, ids, model, guess=None, layout: HolderLayout = DEFAULT_LAYOUT) -> CardReading | None:
    """The markers ``ids`` read in a frame (2x upsampled views: the most precise corners) and the
    camera pose they give; None when fewer than MIN_MARKERS are read.

    ``model``: the ``CameraModel``; ``guess``: (R (3, 3), t (3,)) where the kinematics put the
    camera (solvePnP starts there, which also settles the two-fold ambiguity of a planar target
    seen almost orthographically).
    """
    import cv2

    found, _ = read_markers(linear, ids, scales=(UPSAMPLE,))
    if len(found) < MIN_MARKERS:
        return None
    reference = layout.marker_corners(ids)
    plane = np.concatenate([reference[i] for i in sorted(found)])
    image = np.concatenate([found[i] for i in sorted(found)])
    obj = np.column_stack([plane, np.zeros(len(plane))])
    if guess is None:
        ok, rvec, tvec = cv2.solvePnP(obj, image, model.K, model.dist, flags=cv2.SOLVEPNP_IPPE)
    else:
        rvec0, tvec0 = cv2.Rodrigues(np.asarray(guess[0], dtype=np.float64))[0], np.asarray(guess[1], dtype=np.float64)
        ok, rvec, tvec = cv2.solvePnP(obj, image, model.K, model.dist, rvec0.copy(), tvec0.reshape(3, 1).copy(),
                                      useExtrinsicGuess=True, flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok:
        return None
    projected, _ = cv2.projectPoints(obj, rvec, tvec, model.K, model.dist)
    rms = float(np.sqrt(np.mean(np.sum((projected.reshape(-1, 2) - image) ** 2, axis=1))))
    return CardReading(plane, image, cv2.Rodrigues(rvec)[0], tvec.ravel(), rms)


def centre_px(model) -> np.ndarray:
    """Where the rotation centre is imaged (2,) px: the same at every pose (the camera is aimed at it)."""
    _, t = model.extrinsics(np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 1.0]) / np.sqrt(2.0))
    return model.project(np.zeros((1, 3)), np.eye(3), t)[0]


def disc_radius_px(model, tile_polygons) -> float:
    """The brightness disc's radius: the largest circle about ``centre_px`` inside every tile region
    (polygons (4, 2) px, one per pose; the patch region shrunk by the ROI margin), less 2 px, within
    [MIN_DISC_PX, MAX_DISC_PX]; 0 when even MIN_DISC_PX does not fit."""
    c = centre_px(model)
    room = min(_inside_distance(c, np.asarray(poly, dtype=np.float64)) for poly in tile_polygons) - 2.0
    return 0.0 if room < MIN_DISC_PX else min(room, MAX_DISC_PX)


def tile_disc(model, shape, radius_px: float) -> np.ndarray:
    """Pixels (H, W) bool within ``radius_px`` of where the rotation centre is imaged."""
    c = centre_px(model)
    rows, cols = np.mgrid[0:shape[0], 0:shape[1]]
    return (cols - c[0]) ** 2 + (rows - c[1]) ** 2 <= radius_px ** 2


def _inside_distance(point: np.ndarray, poly: np.ndarray) -> float:
    """Distance from ``point`` to the nearest edge line of the convex quadrilateral ``poly`` (4, 2),
    negative when the point lies outside."""
    edges = np.roll(poly, -1, axis=0) - poly
    cross = edges[:, 0] * (point[1] - poly[:, 1]) - edges[:, 1] * (point[0] - poly[:, 0])
    area2 = np.sum(poly[:, 0] * np.roll(poly[:, 1], -1) - np.roll(poly[:, 0], -1) * poly[:, 1])
    return float(np.min(np.sign(area2) * cross / np.linalg.norm(edges, axis=1)))


def tile_rate(linear: np.ndarray, dark: np.ndarray, disc: np.ndarray, exposure_s: float, lamp_relative: float) -> float:
    """Mean signal per second of the disc's pixels, per unit lamp level (linear units / s)."""
    return float(np.mean(linear[disc] - dark[disc]) / (exposure_s * lamp_relative))
