"""The spectral RGL tensor file read by pbrt-v4's ``measured`` material and Mitsuba 3's spectral
variants.

The RGB export's fields with ``rgb`` replaced by ``wavelengths`` (n_lambda,) in nm and ``spectra``
(phi_i, theta_i, n_lambda, n, n) float32 (``srgb_spectra``). Why 32 wavelengths over 380-780 nm:
docs/decisions/0009-mitsuba-export-warp.md.
"""
from __future__ import annotations

import numpy as np

from goniofrost.brdf import srgb_spectra
from goniofrost.brdf.mitsuba_export import DEFAULT_OPTIONS, ExportError, ExportOptions, build_fields
from goniofrost.brdf.rgl_tensor import write_tensor_file
from goniofrost.core.grid import MerlGrid

WAVELENGTH_RANGE_NM = (380.0, 780.0)
DEFAULT_WAVELENGTHS = 32


def wavelength_nodes(n: int = DEFAULT_WAVELENGTHS) -> np.ndarray:
    """n wavelengths (nm, float32) evenly spaced over WAVELENGTH_RANGE_NM."""
    if not isinstance(n, (int, np.integer)) or n < 2:
        raise ExportError(f"wavelengths: expected an integer >= 2, found {n!r}")
    return np.linspace(*WAVELENGTH_RANGE_NM, n).astype(np.float32)


def spectra_of_rgb(rgb: np.ndarray, wavelengths: np.ndarray) -> np.ndarray:
    """``spectra`` (p, i, n_lambda, n, n) float32 of an ``rgb`` field (p, i, 3, n, n), slice by slice."""
    p, k, _, n, m = rgb.shape
    out = np.empty((p, k, wavelengths.size, n, m), np.float32)
    for a in range(p):
        for b in range(k):  # one incident slice at a time: the temporaries stay a few MB
            rows = srgb_spectra.unbounded_spectra_rows(rgb[a, b].reshape(3, -1), wavelengths)
            out[a, b] = rows.reshape(wavelengths.size, n, m)
    return out


def spectral_fields(rgb_fields: dict, n_wavelengths: int = DEFAULT_WAVELENGTHS) -> dict:
    """The spectral file's fields from the RGB export's (``build_fields``): ``rgb`` -> ``wavelengths``, ``spectra``."""
    wavelengths = wavelength_nodes(n_wavelengths)
    fields = {}
    for name, value in rgb_fields.items():
        if name == "rgb":
            fields["wavelengths"] = wavelengths
            fields["spectra"] = spectra_of_rgb(value, wavelengths)
        else:
            fields[name] = value
    return fields


def export_spectral(path, brdf, grid: MerlGrid, options: ExportOptions = DEFAULT_OPTIONS,
                    n_wavelengths: int = DEFAULT_WAVELENGTHS, source: str = "BRDF") -> dict:
    """Write a (grid.size, 3) BRDF in 1/sr (NaN = missing) as a spectral RGL tensor file; return the fields."""
    wavelength_nodes(n_wavelengths)  # refuse a bad count before the work
    lo, hi = WAVELENGTH_RANGE_NM
    description = (f"isotropic BRDF from {source}, exported by goniofrost "
                   f"(MERL grid {grid.n_th}x{grid.n_td}x{grid.n_pd}; theta_i {options.theta_i}, "
                   f"ndf {options.ndf}, vndf {options.vndf_phi}x{options.vndf_theta}, "
                   f"spectra {options.sample}x{options.sample} x {n_wavelengths} wavelengths {lo:g}-{hi:g} nm; "
                   f"VNDF warp D^{options.warp_exponent:g} + {options.uniform_share:g} uniform; "
                   f"RGB upsampled by Jakob-Hanika 2019, unbounded: 2 max(rgb) x spectrum(rgb / (2 max)))")
    fields = spectral_fields(build_fields(brdf, grid, options, description, source), n_wavelengths)
    write_tensor_file(path, fields)
    return fields
