"""Compile every numba kernel once into numba's on-disk cache: ``python -m goniofrost.app.warm``.

``./dev setup`` runs it, so the first plan, selection or reachability map after an install loads
the compiled kernels (cache=True, stored beside the sources in __pycache__) instead of compiling
them inside the command, and ``selection_seconds`` never includes a compilation. The kernels with
explicit signatures compile at import; the others compile on a first call with tiny inputs of
the types the callers pass. It also byte-compiles every module of the project (an editable install
compiles none) and, in a second process beside the kernels, imports the dependencies the
commands use and writes their modules' byte code (uv installs none), so no command after set-up
compiles a module.
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
    from goniofrost.frost import bayes_kernels, check_cells, somp_kernels  # noqa: F401  (signatures: compiled at import)
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
    write_byte_code()   # numba's own modules that its first compilation or cache load imported
    return seconds


# Third-party modules the commands import (most inside functions): imported once at set-up and
# the byte code of every module that brings in written then (uv installs without it; compiling
# every module of every dependency, as `uv pip install --compile-bytecode` does, took 18 s at load 5).
DEPENDENCIES = ("scipy.linalg", "scipy.stats", "scipy.optimize", "scipy.spatial", "scipy.ndimage", "cv2",
                "matplotlib.figure", "matplotlib.backends.backend_agg", "tqdm", "yaml", "tifffile", "rawpy",
                "exifread", "serial", "pymodbus.client", "pymodbus.server", "pymodbus.datastore", "dynamixel_sdk",
                "threadpoolctl", "PIL.BmpImagePlugin", "PIL.GifImagePlugin", "PIL.JpegImagePlugin",
                "PIL.PpmImagePlugin", "PIL.PngImagePlugin")   # PIL's: what matplotlib's savefig loads


def import_dependencies() -> list[str]:
    """Import every module of DEPENDENCIES that is installed; return those that are not."""
    import importlib

    missing = []
    for name in ("numpy", "numba") + DEPENDENCIES:
        try:
            importlib.import_module(name)
        except ImportError:
            missing.append(name)
    return missing


def write_byte_code() -> int:
    """Write the .pyc of every imported module whose source has none or an older one; return how
    many were written. Explicitly, with py_compile, because importing writes none where
    PYTHONDONTWRITEBYTECODE is set (as on these machines), and uv installs none: every command
    would then compile numpy, scipy, matplotlib... again on each start (2 to 4 s)."""
    import importlib.util
    import os
    import py_compile
    import sys

    written = 0
    for module in list(sys.modules.values()):
        source = getattr(module, "__file__", None)
        if not source or not source.endswith(".py") or not os.path.isfile(source):
            continue
        cached = importlib.util.cache_from_source(source)
        if os.path.isfile(cached) and os.stat(cached).st_mtime >= os.stat(source).st_mtime:
            continue
        try:
            py_compile.compile(source, cfile=cached, doraise=True)
            written += 1
        except (py_compile.PyCompileError, OSError):   # a read-only install: its modules compile on import
            pass
    return written


def main(argv=None) -> int:
    """Warm the kernels here while a second process imports the dependencies (no numba in it:
    a second numba process would pay numba's own set-up again, about as long as a kernel)."""
    import subprocess
    import sys

    argv = sys.argv[1:] if argv is None else argv
    if argv == ["--dependencies"]:
        for name in import_dependencies():
            print(f"not installed: {name}")
        print(f"byte code written for {write_byte_code()} modules of the dependencies")
        return 0
    start = time.perf_counter()
    helper = subprocess.Popen([sys.executable, "-m", "goniofrost.app.warm", "--dependencies"])
    seconds = warm_kernels()
    if helper.wait() != 0:
        raise SystemExit(f"warm: importing the dependencies failed (exit code {helper.returncode})")
    seconds["dependencies imported (beside the kernels)"] = time.perf_counter() - start
    for name, s in seconds.items():
        print(f"{name}: {s:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
