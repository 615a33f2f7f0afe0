"""The export formats by name: the one table ``export --format``, ``capture --bsdf-format`` and the
demo read.

A format is a module with a writer ``write(path, brdf, grid, options, source=..., ...)`` of a
(grid.size, 3) BRDF in 1/sr (NaN = missing). To add one: docs/how-to/extend.md.
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass
from pathlib import Path

from goniofrost.brdf.mitsuba_export import DEFAULT_OPTIONS, ExportError, ExportOptions


@dataclass(frozen=True)
class ExportFormat:
    """Where a format's writer lives (``module``, ``function``); ``spectral``: it samples
    wavelengths (``--wavelengths`` applies, handed as ``n_wavelengths``); ``reader``: what loads
    the file (said after ``capture --bsdf``); ``how_to_load``: said after ``export``."""

    module: str
    function: str
    spectral: bool
    reader: str
    how_to_load: str

    def write(self, path, brdf, grid, options: ExportOptions, n_wavelengths: int, source: str) -> dict:
        """Write the file; return its fields."""
        writer = getattr(importlib.import_module(self.module), self.function)
        extra = {"n_wavelengths": n_wavelengths} if self.spectral else {}
        return writer(path, brdf, grid, options, source=source, **extra)


_SPECTRAL = ExportFormat("goniofrost.brdf.rgl_spectral", "export_spectral", True,
                         "spectral, for pbrt-v4 and Mitsuba 3",
                         "load it with pbrt-v4: Material \"measured\", or Mitsuba 3: type 'measured', a spectral variant")
FORMATS = {
    # the RGB RGL tensor file (Dupuy and Jakob 2018) of Mitsuba 3's ``measured`` BSDF, RGB variants
    "mitsuba": ExportFormat("goniofrost.brdf.mitsuba_export", "export_mitsuba", False, "for Mitsuba 3",
                            "load it with Mitsuba 3: type 'measured', an RGB variant"),
    # the spectral one (``spectra``, ``wavelengths``) of pbrt-v4 and Mitsuba 3's spectral variants
    "rgl-spectral": _SPECTRAL,
    "pbrt": _SPECTRAL,
}


def export_format(name: str) -> ExportFormat:
    """The format called ``name``; ExportError naming the known ones otherwise."""
    if name not in FORMATS:
        raise ExportError(f"format: expected one of {', '.join(FORMATS)}, found {name!r}")
    return FORMATS[name]


def export_file(binary, out, format: str = "mitsuba", options: ExportOptions = DEFAULT_OPTIONS,
                n_wavelengths: int | None = None) -> dict:
    """Export a MERL .binary to ``out`` in ``format`` (a key of FORMATS); nothing is written on error."""
    from goniofrost.brdf.merl_file import read_merl_complete
    from goniofrost.brdf.rgl_spectral import DEFAULT_WAVELENGTHS, wavelength_nodes

    chosen = export_format(format)
    n_wavelengths = DEFAULT_WAVELENGTHS if n_wavelengths is None else n_wavelengths
    if chosen.spectral:
        wavelength_nodes(n_wavelengths)  # refuse a bad count before reading the file
    brdf, grid = read_merl_complete(binary)
    return chosen.write(out, brdf, grid, options, n_wavelengths, str(binary))


def export_beside(binary, format: str = "mitsuba", options: ExportOptions = DEFAULT_OPTIONS) -> Path:
    """Export FILE.binary to FILE.bsdf beside it in ``format`` (``capture --bsdf``, the demo); return the path."""
    out = Path(binary).with_suffix(".bsdf")
    export_file(binary, out, format, options)
    return out
