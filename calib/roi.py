"""Find the sample patch in a frame from the holder's ArUco markers (OpenCV 5 ArucoDetector).

The detected marker corners give a homography from the holder plane (mm) to the image; the
patch, shrunk by a margin, is drawn through it as the region of interest. A frame without a
readable marker set raises MarkerError; nothing is ever guessed.
"""
from __future__ import annotations

import numpy as np

from .errors import MarkerError, WrongTargetError
from .holder import DEFAULT_LAYOUT, HolderLayout

MIN_MARKERS = 2            # 8 corners: a well-determined homography
MAX_REPROJECTION_PX = 2.5  # corners that disagree with one plane mean a misread
MIN_ROI_PIXELS_PER_CHANNEL = 24
UPSAMPLE = 2


def _detector():
    import cv2

    params = cv2.aruco.DetectorParameters()
    # AprilTag refinement kept corner errors < 1 px up to 78 deg views in the simulated rig,
    # where SUBPIX and CONTOUR reached 2 px on thin foreshortened markers
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_APRILTAG
    # foreshortened markers at grazing views are thin: accept small, slanted quads
    params.minMarkerPerimeterRate = 0.02
    params.polygonalApproxAccuracyRate = 0.05
    params.minCornerDistanceRate = 0.02
    params.perspectiveRemovePixelPerCell = 8
    params.adaptiveThreshWinSizeMin = 5
    params.adaptiveThreshWinSizeMax = 53
    params.adaptiveThreshWinSizeStep = 8
    return cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50), params)


def gray_views(linear: np.ndarray) -> list[np.ndarray]:
    """8-bit renderings (H, W) of a linear Bayer frame to try detection on.

    A 2x2 box filter mixes one R, two G and one B at every pixel (no mosaic pattern; shifts the
    image by half a pixel, compensated in ``find_patch``). Several brightness mappings are
    tried because a bright glossy patch or a dark background can dominate one of them.
    """
    import cv2

    g = cv2.blur(np.maximum(linear, 0).astype(np.float32), (2, 2))
    views = []
    for q in (99.5, 90.0, 60.0):
        top = float(np.percentile(g, q))
        if top > 0:
            views.append(np.clip(g * (230.0 / top), 0, 255).astype(np.uint8))
    logg = np.log(g + 2e-3)
    views.append(np.clip((logg - logg.min()) / max(np.ptp(logg), 1e-9) * 255, 0, 255).astype(np.uint8))
    return views


def _candidates(linear: np.ndarray):
    """(scale, 8-bit image) pairs to run the detector on: the frame's own pixels first, then
    2x upsampled views, which read the thin, foreshortened markers of grazing views (on the
    320x240 simulated camera: 76 deg at every azimuth natively, 82 deg upsampled)."""
    import cv2

    views = gray_views(linear)
    for g in views:
        yield 1, g
    for g in views:
        yield UPSAMPLE, cv2.resize(g, None, fx=UPSAMPLE, fy=UPSAMPLE, interpolation=cv2.INTER_CUBIC)


def find_patch(linear: np.ndarray, expected_ids, margin: float, what: str,
               layout: HolderLayout = DEFAULT_LAYOUT) -> np.ndarray:
    """Boolean mask (H, W) of the sample patch, shrunk by ``margin`` (fraction of its side).

    ``expected_ids``: the marker ids of the mounted target; ``what`` names the frame or sample
    in errors. Raises MarkerError when fewer than MIN_MARKERS expected markers are read, when
    ids of another target are seen, or when the corners do not fit one plane.
    """

    det = _detector()
    found: dict[int, np.ndarray] = {}
    others: set[int] = set()
    for scale, gray in _candidates(linear):
        corners, ids, _ = det.detectMarkers(gray)
        ids = [] if ids is None else ids.ravel().tolist()
        # back to frame pixels; the 2x2 blur moved features by +half a pixel: undo it
        got = {i: (c.reshape(4, 2) + 0.5) / scale - 1.0 for i, c in zip(ids, corners) if i in expected_ids}
        others |= set(ids) - set(expected_ids)
        if len(got) > len(found):
            found = got
        if len(found) == len(expected_ids):
            break
    if len(found) < MIN_MARKERS:
        error = WrongTargetError if len(others) >= MIN_MARKERS else MarkerError
        extra = f"; saw markers {sorted(others)} of another target" if others else ""
        raise error(f"{what}: expected holder markers {list(expected_ids)}, read "
                    f"{sorted(found)} (need at least {MIN_MARKERS}){extra}")
    return _patch_mask(found, expected_ids, linear.shape, margin, what, layout)


def _patch_mask(found: dict, expected_ids, shape, margin: float, what: str, layout: HolderLayout) -> np.ndarray:
    """Map the patch through the plane->image homography fitted to the detected corners."""
    import cv2

    ref = layout.marker_corners(expected_ids)
    obj = np.concatenate([ref[i] for i in sorted(found)]).astype(np.float32)
    img = np.concatenate([found[i] for i in sorted(found)]).astype(np.float32)
    hmg, _ = cv2.findHomography(obj, img, 0)
    if hmg is None:
        raise MarkerError(f"{what}: marker corners do not define a plane")
    proj = cv2.perspectiveTransform(obj[None], hmg)[0]
    err = float(np.max(np.linalg.norm(proj - img, axis=1)))
    if err > MAX_REPROJECTION_PX:
        raise MarkerError(f"{what}: marker corners disagree with one plane by {err:.1f} px "
                          f"(limit {MAX_REPROJECTION_PX} px): unreadable marker set")
    patch = cv2.perspectiveTransform(layout.patch_polygon(margin)[None].astype(np.float32), hmg)[0]
    mask = np.zeros(shape, dtype=np.uint8)
    cv2.fillConvexPoly(mask, np.rint(patch * 16).astype(np.int32), 1, shift=4)
    # one pixel off every edge: a partly covered edge pixel would mix patch and card
    mask = cv2.erode(mask, np.ones((3, 3), np.uint8))
    if mask.sum() < 4 * MIN_ROI_PIXELS_PER_CHANNEL:
        raise MarkerError(f"{what}: the sample patch covers only {int(mask.sum())} pixels "
                          f"(need {4 * MIN_ROI_PIXELS_PER_CHANNEL}): view too grazing or target too small")
    return mask.astype(bool)

