"""Time evaluating RGL tensor files on the full MERL grid (1,111,432 valid cells), no cache.

    .venv/bin/python benchmarks/rgl_dataset.py DIR_OR_FILE [--repeats 3] [--mitsuba 300] [--out rgl_time.json]
    .venv/bin/python benchmarks/rgl_dataset.py --smallest   # one small export of built-in gold, written here

For every ``.bsdf`` of ``rgl:DIR_OR_FILE``: the wall and CPU time of reading the file and
tabulating it on the full grid (median of the repeats, the file read again each time), its kind
and domain. Timings on a shared machine are noisy: the load average is printed with them. With
``--mitsuba N``: the median and 95th percentile of the relative difference between goniofrost's
evaluation and Mitsuba 3's own ``eval`` at N random direction pairs within 75 deg of the normal
(a spectral file integrated on Mitsuba's film, CIE 1931 x D65).
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import time

import numpy as np

from goniofrost.brdf import rgl_measured
from goniofrost.core.grid import FULL_GRID
from goniofrost.datasets.rgl import RglDataset


def time_file(path, name: str, repeats: int) -> dict:
    """Median wall and CPU seconds of a fresh read + full-grid tabulation of one material."""
    walls, cpus = [], []
    for _ in range(repeats):
        dataset = RglDataset(path)  # nothing kept from the last repeat
        wall, cpu = time.perf_counter(), time.process_time()
        dataset.tabulate([name], FULL_GRID)
        walls.append(time.perf_counter() - wall)
        cpus.append(time.process_time() - cpu)
    return {"material": name, "wall_s": statistics.median(walls), "cpu_s": statistics.median(cpus),
            "domain": RglDataset(path).domain(name)}


def against_mitsuba(path, n: int, seed: int = 1) -> dict:
    """Relative difference (median, 95th percentile) to Mitsuba's eval at n random pairs."""
    from goniofrost.brdf.mitsuba_probe import eval_pairs, eval_pairs_spectral_rgb, load_bsdf
    from goniofrost.brdf.mitsuba_render import SPECTRAL_VARIANT

    rng = np.random.default_rng(seed)

    def directions():
        cos = rng.uniform(np.cos(np.radians(75.0)), 1.0, n)
        phi, sin = rng.uniform(0.0, 2 * np.pi, n), np.sqrt(1.0 - cos ** 2)
        return np.stack([sin * np.cos(phi), sin * np.sin(phi), cos], -1)

    w_i, w_o = directions(), directions()
    measured = rgl_measured.load_measured(path)
    ours = rgl_measured.eval_cosine_weighted(measured, w_i, w_o)
    if measured.kind == "rgb":
        theirs = eval_pairs(load_bsdf(path), w_i, w_o)
    else:
        theirs = eval_pairs_spectral_rgb(load_bsdf(path, SPECTRAL_VARIANT), w_i, w_o, measured.wavelengths)
    rel = np.abs(ours - theirs) / np.maximum(np.abs(theirs), 1e-6 * np.abs(theirs).max())
    return {"pairs": n, "median": float(np.median(rel)), "p95": float(np.percentile(rel, 95))}


def smallest_file() -> str:
    """A small RGB export of built-in gold (12 x 12 x 24 grid, small tables) in ./smallest/."""
    from pathlib import Path

    from goniofrost.brdf import mitsuba_export
    from goniofrost.brdf.merl_file import valid_to_full
    from goniofrost.core.grid import MerlGrid
    from goniofrost.datasets import open_dataset

    grid, folder = MerlGrid(12, 12, 24), Path("smallest")
    folder.mkdir(exist_ok=True)
    values = open_dataset("builtin").tabulate(["gold"], grid)[0].astype(np.float64)
    options = mitsuba_export.ExportOptions(theta_i=6, ndf=16, vndf_theta=16, vndf_phi=8, sample=8)
    mitsuba_export.export_mitsuba(folder / "gold.bsdf", valid_to_full(values, grid), grid, options)
    return str(folder / "gold.bsdf")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("path", nargs="?", help="a .bsdf file or a folder of them")
    parser.add_argument("--smallest", action="store_true", help="time one small export written here, 1 repeat, "
                        "20 pairs against Mitsuba")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--mitsuba", type=int, default=0, metavar="N", help="compare with Mitsuba's eval at N pairs")
    parser.add_argument("--out")
    args = parser.parse_args()
    if args.smallest:
        args.path, args.repeats, args.mitsuba = smallest_file(), 1, 20
    if args.path is None:
        parser.error("give a .bsdf file or folder, or --smallest")
    dataset = RglDataset(args.path)
    rows = [time_file(args.path, name, args.repeats) for name in dataset.names()]
    for row in rows:
        if args.mitsuba:
            row["mitsuba"] = against_mitsuba(dataset.file(row["material"]), args.mitsuba)
        agree = (f"; against Mitsuba: median {row['mitsuba']['median']:.2g}, 95th percentile "
                 f"{row['mitsuba']['p95']:.2g}") if args.mitsuba else ""
        print(f"{row['material']}: {row['wall_s']:.2f} s wall, {row['cpu_s']:.2f} s CPU ({row['domain']}){agree}")
    summary = {"files": len(rows), "median_wall_s": statistics.median(r["wall_s"] for r in rows),
               "median_cpu_s": statistics.median(r["cpu_s"] for r in rows), "load_average": os.getloadavg(),
               "cores": os.cpu_count(), "rows": rows}
    print(f"{len(rows)} files: median {summary['median_wall_s']:.2f} s wall, {summary['median_cpu_s']:.2f} s CPU "
          f"per file; load average {summary['load_average'][0]:.1f} on {summary['cores']} cores")
    if args.out:
        with open(args.out, "w") as handle:
            json.dump(summary, handle, indent=1)


if __name__ == "__main__":
    main()
