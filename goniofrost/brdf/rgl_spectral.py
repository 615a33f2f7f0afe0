"""The spectral RGL tensor file: what pbrt-v4's ``measured`` material and Mitsuba 3's spectral variants read.

The same fields as the RGB export (``goniofrost.brdf.mitsuba_export``: ``ndf``, ``sigma``,
``theta_i``, ``phi_i``, ``vndf``, ``luminance``, ``jacobian``, computed by the same code), with
``rgb`` replaced by

* ``wavelengths`` (n_lambda,) float32, nm: evenly spaced over WAVELENGTH_RANGE_NM;
* ``spectra`` (phi_i, theta_i, n_lambda, n, n) float32: each rgb node lifted to a smooth
  spectrum by Jakob and Hanika's sigmoid-polynomial model with the unbounded-RGB rule of pbrt-v4
  and Mitsuba 3 (``goniofrost.brdf.srgb_spectra``), sampled at ``wavelengths``.

Layout and checks follow pbrt-v4's reader (``src/pbrt/bxdfs.cpp``, ``MeasuredBxDFData::Create``,
mmp/pbrt-v4) and Mitsuba 3's ``src/bsdfs/measured.cpp``: ``spectra`` is 5-D float32 with
shape[0] = len(phi_i), shape[1] = len(theta_i), shape[2] = len(wavelengths), shape[3] =
shape[4] = the luminance's shape[2:4]; both read it as a ``PiecewiseLinear2D<3>`` /
``Marginal2D<3>`` whose third parameter is the wavelength, i.e. linear between the wavelength
nodes and clamped outside them. Mitsuba's RGB variants refuse a file with ``spectra`` and its
spectral variants one without, so RGB and spectral are two files.

Why 32 nodes over 380-780 nm (13 nm apart): the renderer interpolates linearly between the nodes,
and that, not the model, sets the round trip RGB -> spectrum -> RGB (under D65, CIE 1931): over
the surface of the sRGB gamut (the hardest colours) the worst is 0.89 % of the largest channel
(0.882 % on 41 x 41 chromaticities per face, 0.886 % on 101 x 101 or finer, near (1, 0, 0.37); a node of
MERL black-obsidian's export reached 0.887 %), 1.2 % with 32 nodes over Mitsuba's 360-830 nm,
0.94 % with 36 there;
the built-in materials' nodes stay under 0.5 %. Beyond 380-780 nm the CIE weights are below 1e-3
of their peak. The file is n_lambda / 3 times the RGB file's rgb field (100 MB at full
resolution; ``--sample 64`` quarters it).
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
