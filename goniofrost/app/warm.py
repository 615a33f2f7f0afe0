"""Compile every numba kernel once into numba's on-disk cache: ``python -m goniofrost.app.warm``.

``./dev setup`` runs it, so the first plan, selection or reachability map after an install loads
the compiled kernels (cache=True, stored beside the sources in __pycache__) instead of compiling
them inside the command, and ``selection_seconds`` never includes a compilation. The kernels with
explicit signatures compile at import; the others compile on a first call with tiny inputs of
the types the callers pass. It also byte-compiles every module of the project (an editable install
compiles none), so the first command after set-up does not compile them either.
"""
from __future__ import annotations

import time


PACKAGES = ("goniofrost", "planner", "drivers", "calib", "sim")


def byte_compile() -> bool:
    """Write the .pyc of every module of the project's packages; True when all compiled."""
    import compileall
    import importlib.util
    from pathlib import Path

    ok = True
    for name in PACKAGES:
        folder = Path(importlib.util.find_spec(name).origin).parent
        ok &= bool(compileall.compile_dir(str(folder), quiet=1))
    return ok


def warm_kernels() -> dict:
    """Byte-compile the project, import or call every compiled kernel once; return {what: seconds}."""
    seconds = {}
    start = time.perf_counter()
    if not byte_compile():
        raise SystemExit("warm: a module of the project does not compile")
    seconds["byte-compiled modules"] = time.perf_counter() - start

    import numpy as np

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
