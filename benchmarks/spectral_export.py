"""The spectral RGL export (pbrt-v4, Mitsuba 3's spectral variants): time, size, round trip, Mitsuba's eval.

    .venv/bin/python benchmarks/spectral_export.py [--repeats 3] [--pairs 3000] [--smallest]

Per built-in material (terracotta, red-plastic, gold), on the full MERL grid with the default
options (``--smallest``: red-plastic alone on a 30 x 30 x 60 grid with small resolutions, one
repeat and 50 pairs, what the test runs):

* time: ``formats.export_file`` (what ``goniofrost export FILE.binary --format pbrt`` runs:
  read and check the .binary, build the fields, upsample, write) and, beside it, the RGB export,
  median of --repeats; the file sizes;
* round trip: every node's spectrum converted back to linear sRGB as Mitsuba's film does (CIE
  1931 under D65, linear between the wavelength nodes) against the node's rgb, relative to the
  node's largest channel (max and median over the nodes);
* eval: Mitsuba 3 ``scalar_spectral``'s eval of the spectral file converted to RGB against
  ``scalar_rgb``'s eval of the RGB file at --pairs random direction pairs with theta_i, theta_o
  <= 75 deg (median, 95th percentile and max of the relative difference per channel).
"""
from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from goniofrost.brdf import mitsuba_export as me
from goniofrost.brdf import formats
from goniofrost.brdf import rgl_spectral as rs
from goniofrost.brdf.merl_file import valid_to_full, write_merl
from goniofrost.brdf.mitsuba_probe import eval_pairs, eval_pairs_spectral_rgb, load_bsdf, spectral_to_rgb_weights
from goniofrost.brdf.mitsuba_render import SPECTRAL_VARIANT
from goniofrost.brdf.rgl_tensor import read_tensor_file
from goniofrost.core.grid import FULL_GRID, MerlGrid
from goniofrost.datasets import open_dataset
from goniofrost.datasets.tabulate import tabulate_cached

MATERIALS = ["terracotta", "red-plastic", "gold"]
SMALLEST = dict(grid=MerlGrid(30, 30, 60), options=me.ExportOptions(theta_i=6, ndf=31, vndf_theta=31, vndf_phi=16,
                                                                       sample=12), materials=["red-plastic"])


def cap_directions(rng, n: int) -> np.ndarray:
    cos = rng.uniform(np.cos(np.radians(75.0)), 1.0, n)
    phi, sin = rng.uniform(0.0, 2 * np.pi, n), np.sqrt(1.0 - cos ** 2)
    return np.stack([sin * np.cos(phi), sin * np.sin(phi), cos], -1)


def timed(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def round_trip(rgb_path: Path, spectral_path: Path) -> tuple[float, float]:
    """(max, median) over the lit nodes of |RGB(spectrum) - rgb| / max(rgb)."""
    rgb_fields, spectral = read_tensor_file(rgb_path), read_tensor_file(spectral_path)
    rgb = rgb_fields["rgb"].transpose(0, 1, 3, 4, 2).reshape(-1, 3).astype(np.float64)
    lam = spectral["wavelengths"]
    spectra = spectral["spectra"].transpose(0, 1, 3, 4, 2).reshape(-1, lam.size).astype(np.float64)
    back = spectra @ spectral_to_rgb_weights(lam)
    lit = rgb.max(axis=-1) > 0
    error = np.abs(back[lit] - rgb[lit]).max(axis=-1) / rgb[lit].max(axis=-1)
    return float(error.max()), float(np.median(error))


def eval_error(rgb_path: Path, spectral_path: Path, pairs: int) -> tuple[float, float, float]:
    rng = np.random.default_rng(7)
    w_i, w_o = cap_directions(rng, pairs), cap_directions(rng, pairs)
    expected = eval_pairs(load_bsdf(rgb_path), w_i, w_o)
    lam = read_tensor_file(spectral_path)["wavelengths"]
    got = eval_pairs_spectral_rgb(load_bsdf(spectral_path, SPECTRAL_VARIANT), w_i, w_o, lam)
    rel = np.abs(got - expected) / np.abs(expected)
    return float(np.median(rel)), float(np.percentile(rel, 95)), float(rel.max())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--pairs", type=int, default=3000)
    parser.add_argument("--smallest", action="store_true", help="the small setting the test runs")
    args = parser.parse_args()
    grid, options, names = FULL_GRID, me.DEFAULT_OPTIONS, MATERIALS
    if args.smallest:
        grid, options, names = SMALLEST["grid"], SMALLEST["options"], SMALLEST["materials"]
        args.repeats, args.pairs = 1, 50
    print(f"load average {os.getloadavg()[0]:.2f}; grid {grid.n_th}x{grid.n_td}x{grid.n_pd}; {options}; "
          f"{rs.DEFAULT_WAVELENGTHS} wavelengths {rs.WAVELENGTH_RANGE_NM[0]:g}-{rs.WAVELENGTH_RANGE_NM[1]:g} nm")
    print(f"{'material':22s} {'spectral s':>10s} {'rgb s':>6s} {'MB':>6s} {'rgb MB':>6s} "
          f"{'round trip max':>14s} {'median':>7s} {'eval median':>11s} {'p95':>6s} {'max':>6s}")
    with tempfile.TemporaryDirectory() as folder:
        binary, rgb_out, spectral_out = (Path(folder) / n for n in ("m.binary", "m.bsdf", "m-spectral.bsdf"))
        for name in names:
            table = tabulate_cached(open_dataset("builtin"), [name], grid, progress=False)[0].astype(np.float64)
            write_merl(binary, valid_to_full(table, grid), grid)
            spectral_s = timed(lambda: formats.export_file(binary, spectral_out, "pbrt", options), args.repeats)
            rgb_s = timed(lambda: formats.export_file(binary, rgb_out, "mitsuba", options), args.repeats)
            worst, median = round_trip(rgb_out, spectral_out)
            e_median, e_p95, e_max = eval_error(rgb_out, spectral_out, args.pairs)
            print(f"builtin:{name:14s} {spectral_s:10.2f} {rgb_s:6.2f} {spectral_out.stat().st_size / 1e6:6.1f} "
                  f"{rgb_out.stat().st_size / 1e6:6.1f} {100 * worst:13.2f}% {100 * median:6.2f}% "
                  f"{100 * e_median:10.2f}% {100 * e_p95:5.2f}% {100 * e_max:5.2f}%", flush=True)
    print("round trip: RGB(spectrum) against rgb per node, relative to its largest channel; eval: per channel")


if __name__ == "__main__":
    main()
