"""The printed sample holder: where the ArUco markers (DICT_4X4_50) and the sample patch sit.

A square card in the sample plane (z = 0, sample frame, millimetres, centred on the rotation
centre); the white reference card has the white tile and its own marker ids. Read by the simulated
camera and the calibration.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

ARUCO_DICT = "DICT_4X4_50"
SAMPLE_MARKER_IDS = (0, 1, 2, 3)
WHITE_MARKER_IDS = (4, 5, 6, 7)
CARD_MARKER_IDS = SAMPLE_MARKER_IDS + WHITE_MARKER_IDS   # every id a holder card carries


@dataclass(frozen=True)
class HolderLayout:
    """Geometry of the holder card in millimetres (sample frame, z = 0).

    ``half_size``: half the side of the card; ``marker_size``: side of each marker including
    its one-cell black border; ``marker_inset``: gap between the card edge and a marker;
    ``patch_half``: half the side of the sample patch.
    """

    half_size: float = 34.0
    marker_size: float = 21.0
    marker_inset: float = 3.0
    patch_half: float = 8.5

    def marker_corners(self, ids=SAMPLE_MARKER_IDS) -> dict[int, np.ndarray]:
        """Corners (4, 2) in mm of each marker, in ArUco order (top-left, top-right,
        bottom-right, bottom-left as printed; "top" is +y). ids go clockwise from top-left."""
        a = self.half_size - self.marker_inset
        b = a - self.marker_size
        # top-left corner (x, y) of each marker's square, markers clockwise from top-left
        origins = [(-a, a), (b, a), (b, -b), (-a, -b)]
        out = {}
        for mid, (x0, y0) in zip(ids, origins):
            s = self.marker_size
            out[mid] = np.array([[x0, y0], [x0 + s, y0], [x0 + s, y0 - s], [x0, y0 - s]], float)
        return out

    def patch_polygon(self, margin: float = 0.0) -> np.ndarray:
        """Corners (4, 2) in mm of the sample patch shrunk by ``margin`` (fraction of its side)."""
        h = self.patch_half * (1.0 - 2.0 * margin)
        return np.array([[-h, h], [h, h], [h, -h], [-h, -h]], float)


DEFAULT_LAYOUT = HolderLayout()
