"""The one check of an ``--out FILE.png`` option: commands that draw a picture write PNG data, so
a name with another suffix (``look.jpg``) would hold PNG bytes under a name that says otherwise."""
from __future__ import annotations

from goniofrost.core.errors import GoniofrostError


def check_png_name(out, option: str = "--out") -> None:
    """GoniofrostError (one line, exit 2) unless ``out`` ends in .png (any case)."""
    if not str(out).lower().endswith(".png"):
        raise GoniofrostError(f"{option} {out}: expected a file name ending in .png (the picture is written as PNG)")
