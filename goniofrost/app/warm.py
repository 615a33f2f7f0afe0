"""Compile every numba kernel once into numba's on-disk cache: ``python -m goniofrost.app.warm``.

``./dev setup`` runs it, so the first plan, selection or reachability map after an install loads
the compiled kernels (cache=True, stored beside the sources in __pycache__) instead of compiling
them inside the command, and ``selection_seconds`` never includes a compilation. The kernels with
explicit signatures compile at import; the others compile on a first call with tiny inputs of
the types the callers pass.
"""
from __future__ import annotations

import time


def warm_kernels() -> dict:
    """Import or call every compiled kernel once; return {module: seconds}."""
    import numpy as np

    seconds = {}
    start = time.perf_counter()
    from goniofrost.frost import bayes_kernels, somp_kernels  # noqa: F401  (signatures: compiled at import)
    seconds["frost kernels"] = time.perf_counter() - start

    start = time.perf_counter()
    from goniofrost.core.camera_model import CameraModel
    from planner.view import Measurability, roi_pixels

    camera = CameraModel(width=1280, height=960, fx=1000.0, fy=1000.0, cx=640.0, cy=480.0,
                         distortion=(0.0, 0.0, 0.0, 0.0, 0.0), distance_mm=300.0)
    view = Measurability(camera=camera, roi_mm=((-5, -5), (5, -5), (5, 5), (-5, 5)),
                         patch_mm=((-6, -6), (6, -6), (6, 6), (-6, 6)), min_pixels=10)
    w = np.array([[0.0, 0.0, 1.0]])
    roi_pixels(view, w, w)
    seconds["planner.view"] = time.perf_counter() - start
    return seconds


def main() -> int:
    for name, s in warm_kernels().items():
        print(f"{name}: {s:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
