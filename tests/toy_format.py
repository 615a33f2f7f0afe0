"""A toy export format for tests/test_extend.py: the one file a new export format needs.

Format ``toy-mean``: an RGL tensor file holding only ``mean`` (3,) float64, the BRDF's mean over
its valid cells per channel (1/sr).
"""
from __future__ import annotations

import numpy as np

from goniofrost.brdf.rgl_tensor import write_tensor_file


def export_mean(path, brdf, grid, options, source: str = "BRDF") -> dict:
    """Write the per-channel mean of ``brdf`` ((grid.size, 3) in 1/sr, NaN = missing); return the fields."""
    fields = {"mean": np.nanmean(brdf, axis=0).astype(np.float64)}
    write_tensor_file(path, fields)
    return fields
