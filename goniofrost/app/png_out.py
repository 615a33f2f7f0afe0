"""The checks of a picture's options: ``--out FILE.png`` (commands that draw a picture write PNG
data, so a name with another suffix, ``look.jpg``, would hold PNG bytes under a name that says
otherwise) and a sphere's ``--size``."""
from __future__ import annotations

from goniofrost.core.atomic_file import check_output_suffix
from goniofrost.core.errors import GoniofrostError


def check_png_name(out, option: str = "--out") -> None:
    """GoniofrostError (one line, exit 2) unless ``out`` ends in .png (any case)."""
    check_output_suffix(out, ".png", "the picture is written as PNG", option)


# A sphere of 100,000 pixels asked for 75 GB and ended in a MemoryError traceback; 2048 px (a few
# hundred MB while drawing) is far beyond any screen's use of these previews.
SIZE_RANGE_PX = (16, 2048)


def check_sphere_size(size: int, option: str = "--size") -> None:
    """GoniofrostError (one line, exit 2) unless the sphere diameter ``size`` is within SIZE_RANGE_PX."""
    low, high = SIZE_RANGE_PX
    if size < low:
        raise GoniofrostError(f"{option}: expected at least {low} pixels, found {size}")
    if size > high:
        raise GoniofrostError(f"{option}: expected at most {high} pixels, found {size}")
