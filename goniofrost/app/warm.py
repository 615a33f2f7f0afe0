"""Compile every numba kernel once into numba's on-disk cache: ``python -m goniofrost.app.warm``.

``./dev setup`` runs it, so the first plan, selection or reachability map after an install loads
the compiled kernels (cache=True, stored beside the sources in __pycache__) instead of compiling
them inside the command, and ``selection_seconds`` never includes a compilation. The kernels with
explicit signatures compile at import; the others compile on a first call with tiny inputs of
the types the callers pass. It also byte-compiles every module of the project (an editable install
compiles none) and imports the dependencies the commands use (uv installs them without byte
code), so the first command after set-up compiles no module either. The kernels of the three
parts compile in processes side by side (numba compiles on one thread).
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


# Third-party modules the commands import (many inside functions): imported once at set-up so
# their byte code is written then (uv installs without compiling it, and compiling every module
# of every dependency, as `--compile-bytecode` does, takes 15-20 s of which the commands use a fifth).
DEPENDENCIES = ("numpy", "scipy.linalg", "scipy.stats", "scipy.optimize", "scipy.spatial", "scipy.ndimage",
                "cv2", "matplotlib", "matplotlib.figure", "matplotlib.backends.backend_agg", "matplotlib.pyplot",
                "tqdm", "threadpoolctl", "yaml", "tifffile", "rawpy", "exifread", "serial", "pymodbus.client",
                "pymodbus.server", "pymodbus.datastore", "dynamixel_sdk", "numba")

# What each part warms, run as separate processes side by side (each numba compilation is
# single-threaded): {part: seconds} from warm_part.
PARTS = ("frost.bayes_kernels", "frost.somp_kernels", "planner.view and the dependencies")


def warm_part(part: str) -> dict:
    """Warm one of PARTS in this process; return {what: seconds}."""
    import importlib

    start = time.perf_counter()
    if part == "frost.bayes_kernels":   # explicit signatures: compiled (or loaded) at import
        from goniofrost.frost import bayes_kernels  # noqa: F401
    elif part == "frost.somp_kernels":
        from goniofrost.frost import somp_kernels  # noqa: F401
    elif part == "planner.view and the dependencies":
        import matplotlib
        matplotlib.use("Agg")   # pyplot without a display
        for name in DEPENDENCIES:
            try:
                importlib.import_module(name)
            except ImportError:   # an optional one a demo-only install lacks is compiled on its first import
                pass
        _warm_view()
    else:
        raise ValueError(f"warm: unknown part {part!r} (one of {', '.join(PARTS)})")
    return {part: time.perf_counter() - start}


def _warm_view() -> None:
    """Call planner.view's kernels (compiled on a first call) with tiny inputs of the callers' types."""
    import numpy as np

    from goniofrost.core.camera_model import CameraModel
    from planner.view import Measurability, roi_pixels

    camera = CameraModel(width=1280, height=960, fx=1000.0, fy=1000.0, cx=640.0, cy=480.0,
                         distortion=(0.0, 0.0, 0.0, 0.0, 0.0), distance_mm=300.0)
    view = Measurability(camera=camera, roi_mm=((-5, -5), (5, -5), (5, 5), (-5, 5)),
                         patch_mm=((-6, -6), (6, -6), (6, 6), (-6, 6)), min_pixels=10)
    w = np.array([[0.0, 0.0, 1.0]])
    roi_pixels(view, w, w)


def warm_kernels(parallel: bool = True) -> dict:
    """Byte-compile the project, then warm every part of PARTS (``parallel``: each in its own
    process, all at once); return {what: seconds}. Raises SystemExit when a part fails."""
    import subprocess
    import sys

    seconds = {}
    start = time.perf_counter()
    if not byte_compile():
        raise SystemExit("warm: a module of the project does not compile")
    seconds["byte-compiled modules"] = time.perf_counter() - start
    if not parallel:
        for part in PARTS:
            seconds |= warm_part(part)
        return seconds
    starts = {part: time.perf_counter() for part in PARTS}
    runs = {part: subprocess.Popen([sys.executable, "-m", "goniofrost.app.warm", "--part", part]) for part in PARTS}
    for part, run in runs.items():
        if run.wait() != 0:
            raise SystemExit(f"warm: warming {part} failed (exit code {run.returncode})")
        seconds[part] = time.perf_counter() - starts[part]
    return seconds


def main(argv=None) -> int:
    import sys

    argv = sys.argv[1:] if argv is None else argv
    if len(argv) == 2 and argv[0] == "--part":
        warm_part(argv[1])
        return 0
    for name, s in warm_kernels().items():
        print(f"{name}: {s:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
