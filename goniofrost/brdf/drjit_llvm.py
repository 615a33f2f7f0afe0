"""The LLVM library Mitsuba's ``llvm_*`` variants (Dr.Jit's LLVM backend) run on.

Before a ``llvm_*`` variant is set, the newest ``libLLVM`` on the machine is named to Dr.Jit
(``DRJIT_LIBLLVM_PATH``); a machine with none new enough gets a one-line error. Why:
docs/explanations/mitsuba-export.md.
"""
from __future__ import annotations

import os
import re
import sys
from pathlib import Path

ENV = "DRJIT_LIBLLVM_PATH"
MIN_MAJOR = 16  # LLVM 15 aborts (above); 19 works
FOLDERS = ("/usr/lib/x86_64-linux-gnu", "/usr/lib/aarch64-linux-gnu", "/usr/lib", "/usr/lib64")
# libLLVM-19.so, libLLVM-14.0.6.so.1, libLLVM-15.so.1, libLLVM.so.19.1
_NAME = re.compile(r"libLLVM(?:-(\d+)[^/]*\.so(?:\.[\d.]+)?|\.so\.(\d+)(?:\.[\d.]+)?)")


def major_version(name: str) -> int | None:
    """LLVM's major version in a library file name (``libLLVM-19.so`` -> 19), None if it holds none."""
    match = _NAME.fullmatch(name)
    return None if match is None else int(match.group(1) or match.group(2))


def libraries(folders=FOLDERS) -> dict[int, Path]:
    """{major version: a library file} of the LLVM libraries in ``folders`` (the first of each version)."""
    found: dict[int, Path] = {}
    for folder in map(Path, folders):
        for path in sorted(folder.glob("libLLVM*.so*")) if folder.is_dir() else ():
            major = major_version(path.name)
            if major is not None:
                found.setdefault(major, path)
    return found


def name_newest_llvm(variant: str, environ=os.environ, folders=FOLDERS) -> None:
    """Set ``environ[DRJIT_LIBLLVM_PATH]`` to the newest LLVM library (>= MIN_MAJOR) in ``folders``
    unless it is set already (the user's choice is kept). Raise ``RuntimeError`` naming what was
    found and what to install when none is new enough; do nothing elsewhere than Linux."""
    if environ.get(ENV) or not sys.platform.startswith("linux"):
        return
    found = libraries(folders)
    usable = [major for major in found if major >= MIN_MAJOR]
    if usable:
        environ[ENV] = str(found[max(usable)])
        return
    have = ", ".join(str(found[major]) for major in sorted(found)) or f"no libLLVM in {', '.join(folders)}"
    raise RuntimeError(f"Mitsuba's {variant} variant needs LLVM {MIN_MAJOR} or newer (found: {have}); install it "
                       f"(Debian 12: apt-get install libllvm19) or name one with {ENV}=/path/to/libLLVM.so")
