"""Compare two benchmark runs per material: RGL materials as fits (Neural-BRDF networks) and as files.

    .venv/bin/python benchmarks/rgl_fits_vs_files.py FITS_OUT FILES_OUT --files-dataset rgl:DIR [--out rgl.json]
    .venv/bin/python benchmarks/rgl_fits_vs_files.py --smallest   # both runs made here, on a tiny grid

FITS_OUT and FILES_OUT are ``goniofrost bench --out`` folders of two runs that differ only in how the
RGL materials are given (``nbrdf:nbrdf_rgl.npz`` against ``rgl:DIR``), same counts, seed and folds,
so every fold tests the same materials. The compared materials are those of ``--files-dataset``,
matched by name without a ``SPEC:`` prefix and an ``_rgb`` / ``_spec`` suffix. For each method and m, over the materials both runs tested:
the median log-relative MSE of each run, and the median and 10-90 % range of the per-material ratio
files / fits. The files' errors are over the cells each file measured (``metrics.measured_mean``).
"""
from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path

import numpy as np


def key(name: str) -> str:
    """A material's name without a SPEC: prefix and an _rgb / _spec suffix."""
    name = name.rsplit(":", 1)[-1]
    for suffix in ("_rgb", "_spec"):
        if name.endswith(suffix):
            return name[:-len(suffix)]
    return name


def errors(folder) -> dict:
    """{(method, m, fold, trial, material key): mse} of a run's results.json."""
    rows = json.loads((Path(folder) / "results.json").read_text())["rows"]
    return {(r["method"], r["m"], r["fold"], r["trial"], key(r["material"])): r["mse"] for r in rows
            if r["method"] != "bayes-target"}


def compare(fits: dict, files: dict, names: set[str]) -> list[dict]:
    """One row per (method, m): medians of both runs and of their per-material ratio."""
    shared = sorted(k for k in fits.keys() & files.keys() if k[4] in names)
    out = []
    for method, m in sorted({(k[0], k[1]) for k in shared}):
        keys = [k for k in shared if k[:2] == (method, m)]
        ratio = np.array([files[k] / fits[k] for k in keys])
        out.append({"method": method, "m": m, "materials": len(keys),
                    "fits_median": statistics.median(fits[k] for k in keys),
                    "files_median": statistics.median(files[k] for k in keys),
                    "ratio_median": float(np.median(ratio)), "ratio_p10": float(np.percentile(ratio, 10)),
                    "ratio_p90": float(np.percentile(ratio, 90))})
    return out


SMALLEST_SPEC = "builtin-random:1:10"
SMALLEST_BENCH = ["--grid", "12,12,24", "--folds", "1", "--train", "8", "--test", "2", "--m", "3,6",
                  "--methods", "frost,uniform", "--jobs", "1", "--no-progress"]


def smallest_runs() -> tuple[str, str, str]:
    """(fits, files, files spec): 10 seeded analytic materials as they are and exported to .bsdf
    files (small tables), each benchmarked on a 12 x 12 x 24 grid, in this folder."""
    import subprocess
    import sys

    from goniofrost.brdf import mitsuba_export
    from goniofrost.brdf.merl_file import valid_to_full
    from goniofrost.core.grid import MerlGrid
    from goniofrost.datasets import open_dataset

    grid, folder = MerlGrid(12, 12, 24), Path("smallest-files")
    folder.mkdir(exist_ok=True)
    dataset = open_dataset(SMALLEST_SPEC)
    options = mitsuba_export.ExportOptions(theta_i=6, ndf=16, vndf_theta=16, vndf_phi=8, sample=8)
    for name in dataset.names():
        values = dataset.tabulate([name], grid)[0].astype(np.float64)
        mitsuba_export.export_mitsuba(folder / f"{name}.bsdf", valid_to_full(values, grid), grid, options)
    for spec, out in ((SMALLEST_SPEC, "smallest-fits"), (f"rgl:{folder}", "smallest-bench-files")):
        subprocess.run([sys.executable, "-m", "goniofrost", "bench", "--dataset", spec, *SMALLEST_BENCH,
                        "--out", out], check=True, stdout=subprocess.DEVNULL)
    return "smallest-fits", "smallest-bench-files", f"rgl:{folder}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("fits", nargs="?", help="the bench --out folder of the fits")
    parser.add_argument("files", nargs="?", help="the bench --out folder of the files")
    parser.add_argument("--files-dataset", metavar="rgl:DIR", help="the RGL files' dataset spec")
    parser.add_argument("--smallest", action="store_true", help="make both runs here on a tiny grid first")
    parser.add_argument("--out")
    args = parser.parse_args()
    if args.smallest:
        args.fits, args.files, args.files_dataset = smallest_runs()
    if not (args.fits and args.files and args.files_dataset):
        parser.error("give FITS_OUT FILES_OUT --files-dataset rgl:DIR, or --smallest")
    from goniofrost.datasets import open_dataset

    rgl = {key(name) for name in open_dataset(args.files_dataset).names()}
    fits, files = errors(args.fits), errors(args.files)
    rows = compare(fits, files, rgl)
    print("| method | m | materials | median MSE, fits | median MSE, files | files / fits: median (10-90 %) |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['method']} | {r['m']} | {r['materials']} | {r['fits_median']:.4g} | {r['files_median']:.4g} | "
              f"{r['ratio_median']:.3f} ({r['ratio_p10']:.3f}-{r['ratio_p90']:.3f}) |")
    if args.out:
        Path(args.out).write_text(json.dumps({"fits": str(args.fits), "files": str(args.files), "rows": rows,
                                              "materials": sorted(rgl)}, indent=1))


if __name__ == "__main__":
    main()
