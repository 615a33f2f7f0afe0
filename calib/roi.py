"""Where the sample patch is in a frame: predicted by the camera model, checked by the ArUco markers.

``predict_view`` projects the patch and markers at a pose; ``locate_patch`` reads the markers and
draws the region, raises ``MisalignedError`` when they lie too far from the prediction, and uses the
prediction alone where none is readable. ``find_patch`` works from markers only. Pure functions.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from .errors import MarkerError, MisalignedError, PatchTooSmallError, WrongTargetError
from .holder import CARD_MARKER_IDS, DEFAULT_LAYOUT, HolderLayout

log = logging.getLogger(__name__)

MIN_MARKERS = 2            # 8 corners: a well-determined homography
MAX_REPROJECTION_PX = 2.5  # corners that disagree with one plane mean a misread
MIN_ROI_PIXELS_PER_CHANNEL = 24
UPSAMPLE = 2
# A marker whose predicted image is thinner than this (pixels between opposite edges) is not
# looked for: the detector reads markers down to about 8 px on 2x upsampled views in the
# simulated rig, and a misread marker would do more harm than none.
MIN_MARKER_PX = 10.0
# Markers thinner than this are also searched for in 2x upsampled views (slower, needed when thin).
UPSAMPLE_BELOW_PX = 24.0
# With a prediction the markers are first searched for in a box around their predicted corners,
# this many pixels beyond the misalignment tolerance: wider than half the largest adaptive
# threshold window (53 px in the 2x views) and the corner refinement, so that a marker inside
# it is read as in the whole frame. Its edges fall on multiples of SEARCH_ALIGN_PX pixels, which
# keeps the AprilTag refinement's 4 px tiles (8 in the 2x views) where the whole frame has them:
# corners then agree with the whole frame's to float32 rounding (3e-5 px).
SEARCH_MARGIN_PX = 32.0
SEARCH_ALIGN_PX = 8


@dataclass(frozen=True)
class PredictedView:
    """What the camera model expects in one frame.

    ``patch``: (4, 2) pixels, the region of interest (patch shrunk by the margin); ``markers``:
    marker id -> (4, 2) pixel corners in ArUco order; ``readable``: ids predicted big enough and
    inside the frame to be read; ``shape``: (H, W) of the frame.
    """

    patch: np.ndarray
    markers: dict
    readable: tuple
    shape: tuple

    def thinnest_readable_px(self) -> float:
        """Smallest thickness (pixels) of the readable markers (inf if none)."""
        return min((polygon_thickness(self.markers[i]) for i in self.readable), default=float("inf"))


def predict_view(model, w_i, w_o, expected_ids, margin: float, arm_side: float = 1.0,
                 layout: HolderLayout = DEFAULT_LAYOUT) -> PredictedView:
    """The patch region and marker corners at pose (w_i, w_o) (unit (3,), sample frame) seen by
    ``model`` (a ``CameraModel``); ``margin``: fraction of the patch side left at each edge."""
    import cv2

    R, t = model.extrinsics(w_i, w_o, arm_side)
    rvec, _ = cv2.Rodrigues(R)
    corners = layout.marker_corners(expected_ids)
    ids = list(corners)
    plane = np.concatenate([layout.patch_polygon(margin)] + [corners[i] for i in ids])
    obj = np.column_stack([plane, np.zeros(len(plane))])
    img, _ = cv2.projectPoints(obj, rvec, np.asarray(t, dtype=np.float64), model.K, model.dist)
    img = img.reshape(-1, 2)
    markers = {i: img[4 + 4 * k: 8 + 4 * k] for k, i in enumerate(ids)}
    shape = (model.height, model.width)
    readable = tuple(i for i in ids if polygon_thickness(markers[i]) >= MIN_MARKER_PX and _inside(markers[i], shape, 2.0))
    return PredictedView(img[:4], markers, readable, shape)


def expected_view(settings: dict, pose, expected_ids, arm_side: float = 1.0,
                  layout: HolderLayout = DEFAULT_LAYOUT) -> PredictedView:
    """``predict_view`` with the camera model and ROI margin of a validated ``camera`` section, at
    ``pose`` = (w_i, w_o), each (3,), as the kinematics report it."""
    from goniofrost.core.camera_model import CameraModel

    return predict_view(CameraModel.from_section(settings), pose[0], pose[1], expected_ids, settings["roi_margin"],
                        arm_side, layout)


def locate_patch(linear: np.ndarray, expected_ids, margin: float, what: str, view: PredictedView | None = None,
                 tolerance_px: float = 20.0, channels: np.ndarray | None = None,
                 min_pixels: int = MIN_ROI_PIXELS_PER_CHANNEL, layout: HolderLayout = DEFAULT_LAYOUT,
                 whole_frame: bool = True):
    """The region of interest of a frame: ``(mask (H, W) bool, source, offset_px)``.

    ``source`` is ``"markers"`` (homography of the markers read) or ``"prediction"``;
    ``offset_px`` is the largest distance between a read marker corner and its predicted place
    (None when no marker was used: none read, or a misread set). ``channels`` (H, W) Bayer channel of each pixel: with it,
    every colour channel must keep ``min_pixels`` pixels. Raises WrongTargetError when another
    card's markers are read, MisalignedError when the markers lie more than ``tolerance_px``
    from the prediction, MarkerError when the region is too small (or, without a prediction,
    when fewer than MIN_MARKERS expected markers are read). ``whole_frame`` False: when the box
    around the predicted markers holds too few, do not search the rest of the frame (a frame too dark
    or too bright to read markers, where failing in the box says nothing of where they are: the
    bracket tries another exposure, whose search does; the whole frame costs about 6 x the box).
    """
    if view is None:
        mask = find_patch(linear, expected_ids, margin, what, layout)
        return _checked(mask, channels, min_pixels, what), "markers", None
    wanted = [i for i in expected_ids if i in view.readable]
    scales = (1, UPSAMPLE) if view.thinnest_readable_px() < UPSAMPLE_BELOW_PX else (1,)
    box = search_box(view, wanted, tolerance_px + SEARCH_MARGIN_PX)
    found, others = ({}, set()) if not wanted else read_markers(linear, expected_ids, scales, len(wanted), box,
                                                                whole_frame)
    if len(found) < MIN_MARKERS and len(others) >= MIN_MARKERS:
        raise _missing(found, others, expected_ids, what)
    if len(found) >= MIN_MARKERS:
        try:
            mask = _patch_mask(found, expected_ids, view.shape, margin, what, layout)
        except MarkerError as exc:
            # a misread marker set: the prediction is the better region, and its corners say
            # nothing of where the markers are (at grazing views a corner can be off by 5 px
            # on an aligned rig: no offset, no markers-off flag, no misalignment)
            log.info("%s", exc)
            found = {}
        else:
            offset = _aligned_offset(found, view, tolerance_px, what)
            return _checked(mask, channels, min_pixels, what), "markers", offset
    elif wanted:
        log.info("%s: markers %s predicted readable, %s read: the region comes from the camera model",
                 what, wanted, sorted(found))
    offset = _aligned_offset(found, view, tolerance_px, what)
    return _checked(polygon_mask(view.patch, view.shape), channels, min_pixels, what), "prediction", offset


def _aligned_offset(found: dict, view: PredictedView, tolerance_px: float, what: str) -> float | None:
    """``marker_offset_px``; MisalignedError when it exceeds ``tolerance_px``."""
    offset = marker_offset_px(found, view)
    if offset is not None and offset > tolerance_px:
        raise MisalignedError(
            f"{what}: the holder markers lie {offset:.1f} px from where the camera model puts them "
            f"(tolerance {tolerance_px:g} px): the rig looks misaligned (run goniofrost align, or check "
            f"the camera's intrinsics and mount in the rig file)")
    return offset


def marker_offset_px(found: dict, view: PredictedView) -> float | None:
    """Largest distance (pixels) between a read marker corner and its predicted place (None if
    no marker was read)."""
    if not found:
        return None
    return max(float(np.max(np.linalg.norm(found[i] - view.markers[i], axis=1))) for i in found)


def polygon_mask(polygon: np.ndarray, shape) -> np.ndarray:
    """Pixels (H, W) bool whose 3x3 neighbourhood lies inside the convex ``polygon`` (4, 2) px:
    one pixel off every edge, since a partly covered edge pixel would mix patch and card."""
    import cv2

    mask = np.zeros(shape, dtype=np.uint8)
    cv2.fillConvexPoly(mask, np.rint(np.asarray(polygon) * 16).astype(np.int32), 1, shift=4)
    return cv2.erode(mask, np.ones((3, 3), np.uint8)).astype(bool)


def polygon_thickness(polygon: np.ndarray) -> float:
    """Smallest distance (pixels) between an edge of a convex quadrilateral (4, 2) and the
    vertex farthest from it: how thin the shape is."""
    p = np.asarray(polygon, dtype=np.float64)
    best = np.inf
    for k in range(4):
        a, b = p[k], p[(k + 1) % 4]
        edge = b - a
        length = float(np.hypot(*edge))
        if length == 0:
            return 0.0
        dist = np.abs(edge[0] * (p[:, 1] - a[1]) - edge[1] * (p[:, 0] - a[0])) / length
        best = min(best, float(dist.max()))
    return best


def _inside(points: np.ndarray, shape, border: float) -> bool:
    h, w = shape
    return bool(np.all(np.isfinite(points)) and np.all(points >= border - 0.5)
                and np.all(points[:, 0] <= w - 0.5 - border) and np.all(points[:, 1] <= h - 0.5 - border))


def _checked(mask: np.ndarray, channels, min_pixels: int, what: str) -> np.ndarray:
    if channels is None:
        counts = {"all": int(mask.sum()) // 4}
    else:
        counts = {name: int(np.sum(mask & (channels == c))) for c, name in enumerate("RGB")}
    name, fewest = min(counts.items(), key=lambda kv: kv[1])
    if fewest < min_pixels:
        raise PatchTooSmallError(f"{what}: the sample patch keeps only {fewest} pixels of channel {name} "
                          f"(need {min_pixels}): view too grazing or target too small")
    return mask


def _detector(size_scale: float = 1.0):
    """OpenCV's ArUco detector with our settings; ``size_scale`` multiplies the marker perimeter
    limits (fractions of the image's larger side), for a crop of a larger frame."""
    import cv2

    params = cv2.aruco.DetectorParameters()
    # AprilTag refinement kept corner errors < 1 px up to 78 deg views in the simulated rig,
    # where SUBPIX and CONTOUR reached 2 px on thin foreshortened markers
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_APRILTAG
    # foreshortened markers at grazing views are thin: accept small, slanted quads
    params.minMarkerPerimeterRate = 0.02 * size_scale
    params.maxMarkerPerimeterRate = params.maxMarkerPerimeterRate * size_scale
    params.polygonalApproxAccuracyRate = 0.05
    params.minCornerDistanceRate = 0.02
    params.perspectiveRemovePixelPerCell = 8
    params.adaptiveThreshWinSizeMin = 5
    params.adaptiveThreshWinSizeMax = 53
    params.adaptiveThreshWinSizeStep = 8
    return cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50), params)


def gray_views(linear: np.ndarray) -> "GrayViews":
    """8-bit renderings (H, W) of a linear Bayer frame to try detection on (a sequence, each
    rendered when first asked for: detection mostly stops at the first).

    A 2x2 box filter mixes one R, two G and one B at every pixel (no mosaic pattern; shifts the
    image by half a pixel, compensated in ``read_markers``). Several brightness mappings are
    tried because a bright glossy patch or a dark background can dominate one of them.
    """
    return GrayViews(linear)


class GrayViews:
    """``gray_views`` of one frame: the percentile mappings (99.5, 90, 60 % of the blurred frame
    to 230, those whose percentile is > 0) and a log mapping, in that order; ``crop(k, box)`` is
    view k's part in ``box`` (x0, y0, x1, y1) with the whole frame's mapping, rendered alone (the
    same pixels as cropping the view: the mappings are per pixel; the log view is cropped from the
    whole one, whose range it needs)."""

    PERCENTILES = (99.5, 90.0, 60.0)

    def __init__(self, linear: np.ndarray) -> None:
        import cv2

        self._g = cv2.blur(np.maximum(linear, 0).astype(np.float32), (2, 2))
        self.shape = self._g.shape
        # one partition for the three (the same order statistics as three calls)
        tops = np.percentile(self._g, self.PERCENTILES)
        self._tops = [float(t) for t in tops if float(t) > 0]
        self._views: dict[int, np.ndarray] = {}

    def __len__(self) -> int:
        return len(self._tops) + 1

    def __getitem__(self, k: int) -> np.ndarray:
        if not 0 <= k < len(self):
            raise IndexError(k)
        if k not in self._views:
            self._views[k] = self._render(k, self._g)
        return self._views[k]

    def __iter__(self):
        return (self[k] for k in range(len(self)))

    def crop(self, k: int, box) -> np.ndarray:
        """View k's pixels in ``box`` (x0, y0, x1, y1); None: the whole view."""
        if box is None or k in self._views or k == len(self._tops):   # the log view: whole (a strided log may round apart)
            view = self[k]
            return view if box is None else view[box[1]:box[3], box[0]:box[2]]
        return self._render(k, self._g[box[1]:box[3], box[0]:box[2]])

    def _render(self, k: int, g: np.ndarray) -> np.ndarray:
        if k < len(self._tops):
            return np.clip(g * (230.0 / self._tops[k]), 0, 255).astype(np.uint8)
        logg = np.log(g + 2e-3)
        return np.clip((logg - logg.min()) / max(np.ptp(logg), 1e-9) * 255, 0, 255).astype(np.uint8)


def _candidates(views: GrayViews, scales=(1, UPSAMPLE), box=None):
    """(scale, 8-bit image) pairs to run the detector on, in the order of ``scales``: 1 is the
    frame's ``gray_views``, UPSAMPLE the 2x upsampled views, which read thin, foreshortened markers
    and place corners more precisely (AprilTag refinement: 0.02-0.1 px against 0.1-0.4 px).
    ``box`` (x0, y0, x1, y1): only that part of the frame, its brightness mapped as in the whole
    frame's views (upsampling a crop gives the upsampled frame's pixels, offset by scale x0)."""
    import cv2

    for scale in scales:
        for k in range(len(views)):
            g = views.crop(k, box)
            yield scale, (g if scale == 1 else cv2.resize(g, None, fx=scale, fy=scale, interpolation=cv2.INTER_CUBIC))


def read_markers(linear: np.ndarray, expected_ids, scales=(1, UPSAMPLE), stop_at: int | None = None, box=None,
                 whole_frame: bool = True):
    """Marker corners read in a frame: ``(found, others)``, found = id -> (4, 2) pixel corners of
    the expected ids (OpenCV convention: pixel centres at integers), others = ids of the other
    holder card seen (any other id is a misread of a thin, foreshortened marker and is ignored). Stops once ``stop_at`` (default: all expected) markers are read.

    ``box`` (x0, y0, x1, y1) frame pixels (``search_box``: where the prediction puts the markers)
    is searched first: a thin marker needs the 2x views, and a crop of them costs a fraction of
    the frame's. When it holds fewer than MIN_MARKERS markers the whole frame is searched as
    without a box, so markers far from the prediction (a misaligned rig) are still read (unless
    ``whole_frame`` is False: then what the box holds).
    """
    stop_at = len(expected_ids) if stop_at is None else stop_at
    views = gray_views(linear)
    if box is not None:
        found, others = _read_markers(views, expected_ids, scales, stop_at, box)
        if len(found) >= MIN_MARKERS or not whole_frame:
            return found, others
    return _read_markers(views, expected_ids, scales, stop_at, None)


def _read_markers(views: GrayViews, expected_ids, scales, stop_at: int, box):
    h, w = views.shape
    x0, y0, x1, y1 = (0, 0, w, h) if box is None else box
    # The detector's size limits are fractions of the image's larger side: scaled so that a crop
    # accepts the same candidates (in pixels) as the whole frame.
    det = _detector(max(h, w) / max(x1 - x0, y1 - y0))
    found: dict[int, np.ndarray] = {}
    others: set[int] = set()
    for scale, gray in _candidates(views, scales, box):
        corners, ids, _ = det.detectMarkers(gray)
        ids = [] if ids is None else ids.ravel().tolist()
        # Back to frame pixels: ArUco puts pixel centres at +0.5 (c - 0.5 in OpenCV's convention),
        # resize maps x to (x + 0.5) / scale - 0.5, and the 2x2 blur moved features by +0.5.
        got = {i: c.reshape(4, 2).astype(np.float64) / scale - 1.0 + (x0, y0)
               for i, c in zip(ids, corners) if i in expected_ids}
        others |= (set(ids) & set(CARD_MARKER_IDS)) - set(expected_ids)
        if len(got) > len(found):
            found = got
        if len(found) >= stop_at:
            break
    return found, others


def search_box(view: PredictedView, ids, margin_px: float):
    """(x0, y0, x1, y1) frame pixels around the predicted corners of markers ``ids``, widened by
    ``margin_px``, its edges on multiples of SEARCH_ALIGN_PX, clipped to the frame (None without
    such markers)."""
    align = SEARCH_ALIGN_PX
    corners = [view.markers[i] for i in ids if i in view.markers]
    if not corners:
        return None
    pts = np.concatenate(corners)
    h, w = view.shape
    lo = np.floor((pts.min(axis=0) - margin_px) / align) * align
    hi = np.ceil((pts.max(axis=0) + margin_px + 1) / align) * align
    x0, y0 = (int(v) for v in np.clip(lo, 0, (w, h)))
    x1, y1 = (int(v) for v in np.clip(hi, 0, (w, h)))
    return (x0, y0, x1, y1) if x1 - x0 >= 8 and y1 - y0 >= 8 else None


def find_patch(linear: np.ndarray, expected_ids, margin: float, what: str,
               layout: HolderLayout = DEFAULT_LAYOUT) -> np.ndarray:
    """Boolean mask (H, W) of the sample patch from the markers alone, shrunk by ``margin``.

    ``expected_ids``: the marker ids of the mounted target; ``what`` names the frame or sample
    in errors. Raises MarkerError when fewer than MIN_MARKERS expected markers are read, when
    ids of another target are seen, or when the corners do not fit one plane.
    """
    found, others = read_markers(linear, expected_ids)
    if len(found) < MIN_MARKERS:
        raise _missing(found, others, expected_ids, what)
    mask = _patch_mask(found, expected_ids, linear.shape, margin, what, layout)
    if mask.sum() < 4 * MIN_ROI_PIXELS_PER_CHANNEL:
        raise PatchTooSmallError(f"{what}: the sample patch covers only {int(mask.sum())} pixels "
                          f"(need {4 * MIN_ROI_PIXELS_PER_CHANNEL}): view too grazing or target too small")
    return mask


def _missing(found: dict, others: set, expected_ids, what: str) -> MarkerError:
    error = WrongTargetError if len(others) >= MIN_MARKERS else MarkerError
    extra = f"; saw markers {sorted(others)} of another target" if others else ""
    return error(f"{what}: expected holder markers {list(expected_ids)}, read "
                 f"{sorted(found)} (need at least {MIN_MARKERS}){extra}")


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
    return polygon_mask(patch, shape)
