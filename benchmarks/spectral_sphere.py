"""A material rendered by Mitsuba 3 from its RGB export (scalar_rgb) and from its spectral export (scalar_spectral).

    .venv/bin/python benchmarks/spectral_sphere.py [--material red-plastic] [--out docs/spectral_sphere.png] [--size 128] [--spp 128]

The built-in material is tabulated on the full grid and exported twice with the default options
(``goniofrost export --format mitsuba`` and ``--format pbrt``); the preview spheres (three lights,
rows) are rendered by Mitsuba's ``measured`` BSDF from each file, the same scene and the same
independent sampler at ``--spp`` (the spectral variant needs many samples per pixel for its
wavelengths; the RGB one gets the same so that both carry the same pixel-position noise).
Columns: RGB | spectral | |difference| x10, one exposure, gamma 2; prints the rendering SNR of
the spectral image against the RGB one and the mean colour of each.
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from goniofrost.brdf import mitsuba_export as me
from goniofrost.brdf import rgl_spectral as rs
from goniofrost.brdf.merl_file import valid_to_full
from goniofrost.brdf.mitsuba_render import SPECTRAL_VARIANT, render_set_mitsuba
from goniofrost.brdf.preview import DEFAULT_LIGHTS, ERROR_GAIN, rendering_snr_db
from goniofrost.core.grid import FULL_GRID
from goniofrost.datasets import open_dataset
from goniofrost.datasets.tabulate import tabulate_cached

REPO = Path(__file__).resolve().parents[1]


def main() -> None:
    import importlib.util

    spec = importlib.util.spec_from_file_location("mitsuba_sphere", REPO / "benchmarks" / "mitsuba_sphere.py")
    sphere = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(sphere)  # its compose and write_png: the same picture layout

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--material", default="red-plastic", help="a built-in material")
    parser.add_argument("--out", default=str(REPO / "docs" / "spectral_sphere.png"))
    parser.add_argument("--size", type=int, default=128)
    parser.add_argument("--spp", type=int, default=128)
    args = parser.parse_args()
    table = valid_to_full(tabulate_cached(open_dataset("builtin"), [args.material], FULL_GRID,
                                          progress=False)[0].astype(np.float64), FULL_GRID)
    with tempfile.TemporaryDirectory() as folder:
        rgb_path, spectral_path = Path(folder) / "rgb.bsdf", Path(folder) / "spectral.bsdf"
        me.export_mitsuba(rgb_path, table, FULL_GRID, source=f"builtin:{args.material}")
        rs.export_spectral(spectral_path, table, FULL_GRID, source=f"builtin:{args.material}")
        start = time.perf_counter()
        rgb = render_set_mitsuba(rgb_path, DEFAULT_LIGHTS, args.size, spp=args.spp)
        middle = time.perf_counter()
        spectral = render_set_mitsuba(spectral_path, DEFAULT_LIGHTS, args.size, SPECTRAL_VARIANT, args.spp)
        end = time.perf_counter()
    snr = rendering_snr_db(rgb, spectral)
    means = [img[img.max(axis=-1) > 0].mean(axis=0) for img in (rgb, spectral)]
    print(f"builtin:{args.material}: rendering SNR of the spectral render against the RGB one {snr:.2f} dB; "
          f"mean lit pixel RGB {np.round(means[0], 4)} vs spectral {np.round(means[1], 4)}; "
          f"render {middle - start:.0f} s (scalar_rgb) and {end - middle:.0f} s (scalar_spectral), {args.spp} spp")
    title = (f"builtin:{args.material}, Mitsuba 3, {args.spp} spp, SNR {snr:.1f} dB\n"
             f"RGB file (scalar_rgb) | spectral file\n(scalar_spectral) | |difference| x{ERROR_GAIN:g}")
    sphere.write_png(Path(args.out), sphere.compose(rgb, spectral), title)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
