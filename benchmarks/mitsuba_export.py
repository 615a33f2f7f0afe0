"""Export to Mitsuba 3: time of a full-resolution export beside what Mitsuba makes of the file.

    .venv/bin/python benchmarks/mitsuba_export.py [--repeats 3] [--data ../shared/data] [--skip-variants]

Per material (built-in terracotta, red-plastic, gold; measured chrome, nickel and
gold-metallic-paint as Neural-BRDF fits when --data has them), all on the full MERL grid:

* time: ``export_binary_file``, what ``goniofrost export FILE.binary`` runs (read and check the
  35 MB file, build the fields, write the .bsdf), median of --repeats, and the file size;
* eval: Mitsuba's ``measured`` eval against the table's f cos theta_o at 3000 random direction
  pairs with theta_i, theta_o <= 75 deg (median and 95th percentile of the relative difference);
* render: the rendering SNR of Mitsuba's preview spheres against goniofrost's own (3 lights);
* furnace: the worst relative difference between the mean of 20000 sampled weights and the
  table's albedo, and the pdf integral furthest from 1, at theta_i = 0, 30, 60, 75 deg.

Then how far the table's cell values are from the analytic built-in materials themselves (the
step of a cell lookup, against which Mitsuba's interpolation is measured), and (unless
--skip-variants) variants on the metals: the paper's VNDF of D (warp_exponent 1,
uniform_share 0), D with a 10 % uniform share, the default, and the default with 64 x 64 rgb nodes.
"""
from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from goniofrost.brdf.merl_file import valid_to_full, write_merl
from goniofrost.brdf.mitsuba_export import DEFAULT_OPTIONS, export_binary_file, export_mitsuba, lookup, prepared_table
from goniofrost.brdf.mitsuba_probe import eval_pairs, load_bsdf, pdf_integral, sampled_weights, table_albedo
from goniofrost.brdf.mitsuba_render import render_set_mitsuba
from goniofrost.brdf.preview import DEFAULT_LIGHTS, render_set, rendering_snr_db
from goniofrost.core.grid import FULL_GRID
from goniofrost.datasets import open_dataset
from goniofrost.datasets.tabulate import tabulate_cached

REPO = Path(__file__).resolve().parents[1]
BUILTIN = ["terracotta", "red-plastic", "gold"]
MEASURED = ["chrome", "nickel", "gold-metallic-paint"]
INCIDENT_DEG = (0, 30, 60, 75)
VARIANTS = {"paper VNDF of D": dict(warp_exponent=1.0, uniform_share=0.0),
            "D + 10 % uniform": dict(warp_exponent=1.0, uniform_share=0.1),
            "default D^0.75 + 10 %": {},
            "default, rgb 64 x 64": dict(sample=64)}


def materials(data: Path) -> dict[str, np.ndarray]:
    """label -> (FULL_GRID.size, 3) table in 1/sr, NaN on invalid cells."""
    found = {f"builtin:{n}": (open_dataset("builtin"), n) for n in BUILTIN}
    if (data / "nbrdf_merl.npz").is_file():
        archive = open_dataset(f"nbrdf:{data / 'nbrdf_merl.npz'}")
        found.update({f"merl:{n}": (archive, n) for n in MEASURED})
    return {label: valid_to_full(tabulate_cached(ds, [n], FULL_GRID, progress=False)[0].astype(np.float64), FULL_GRID)
            for label, (ds, n) in found.items()}


def cap_directions(rng, n: int) -> np.ndarray:
    cos = rng.uniform(np.cos(np.radians(75.0)), 1.0, n)
    phi, sin = rng.uniform(0.0, 2 * np.pi, n), np.sqrt(1.0 - cos ** 2)
    return np.stack([sin * np.cos(phi), sin * np.sin(phi), cos], -1)


def eval_error(table, path) -> tuple[float, float]:
    rng = np.random.default_rng(7)
    w_i, w_o = cap_directions(rng, 3000), cap_directions(rng, 3000)
    expected = lookup(table, FULL_GRID, w_i, w_o) * w_o[:, 2:3]
    rel = np.abs(eval_pairs(load_bsdf(path), w_i, w_o) - expected) / expected
    return float(np.median(rel)), float(np.percentile(rel, 95))


def cell_error(name: str) -> tuple[float, float]:
    """How far the table's cell value is from the analytic builtin material itself, at the same pairs."""
    from goniofrost.core.grid import dirs_to_half_diff

    rng = np.random.default_rng(7)
    w_i, w_o = cap_directions(rng, 3000), cap_directions(rng, 3000)
    dataset = open_dataset("builtin")
    table = valid_to_full(tabulate_cached(dataset, [name], FULL_GRID, progress=False)[0].astype(np.float64), FULL_GRID)
    exact = np.asarray(dataset.evaluate(name, *dirs_to_half_diff(w_i, w_o)))
    rel = np.abs(lookup(prepared_table(table, FULL_GRID), FULL_GRID, w_i, w_o) - exact) / exact
    return float(np.median(rel)), float(np.percentile(rel, 95))


def furnace(table, path) -> tuple[float, float]:
    """(worst |mean weight / albedo - 1| over channels and angles, pdf integral furthest from 1)."""
    bsdf, rng, worst, pdf_worst = load_bsdf(path), np.random.default_rng(3), 0.0, 1.0
    for degrees in INCIDENT_DEG:
        theta = np.radians(degrees)
        w_i = np.array([np.sin(theta), 0.0, np.cos(theta)])
        mean = sampled_weights(bsdf, w_i, rng.random((20000, 2))).mean(axis=0)
        worst = max(worst, float(np.max(np.abs(mean / table_albedo(table, FULL_GRID, theta) - 1))))
        integral = pdf_integral(bsdf, theta)
        pdf_worst = integral if abs(integral - 1) > abs(pdf_worst - 1) else pdf_worst
    return worst, pdf_worst


def timed_export(binary: Path, out: Path, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        export_binary_file(binary, out)
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--data", type=Path, default=REPO.parent / "shared" / "data")
    parser.add_argument("--skip-variants", action="store_true")
    args = parser.parse_args()
    print(f"load average {os.getloadavg()[0]:.2f}; options {DEFAULT_OPTIONS}")
    tables = materials(args.data)
    print(f"{'material':28s} {'export s':>8s} {'MB':>5s} {'eval median':>11s} {'p95':>6s} {'render SNR':>10s} "
          f"{'furnace':>8s} {'pdf int':>7s}")
    with tempfile.TemporaryDirectory() as folder:
        binary, out = Path(folder) / "m.binary", Path(folder) / "m.bsdf"
        for label, table in tables.items():
            write_merl(binary, table, FULL_GRID)
            seconds = timed_export(binary, out, args.repeats)
            prepared = prepared_table(table, FULL_GRID)
            median, p95 = eval_error(prepared, out)
            snr = rendering_snr_db(render_set(table, FULL_GRID, DEFAULT_LIGHTS, 128),
                                   render_set_mitsuba(out, DEFAULT_LIGHTS, 128))
            worst, pdf_int = furnace(prepared, out)
            print(f"{label:28s} {seconds:8.2f} {out.stat().st_size / 1e6:5.1f} {100 * median:10.2f}% "
                  f"{100 * p95:5.1f}% {snr:8.1f} dB {100 * worst:7.2f}% {pdf_int:7.4f}", flush=True)
        print("\nThe table's cell value against the analytic material it was tabulated from (same pairs):")
        for name in BUILTIN:
            median, p95 = cell_error(name)
            print(f"  builtin:{name:19s} median {100 * median:.2f}%, p95 {100 * p95:.1f}%")
        if not args.skip_variants:
            variants(tables, out)


def variants(tables: dict, out: Path) -> None:
    print("\nVariants (eval median / p95 at random pairs, rendering SNR):")
    for label, table in tables.items():
        if label.endswith(("terracotta", "red-plastic")):
            continue
        prepared, preview = prepared_table(table, FULL_GRID), render_set(table, FULL_GRID, DEFAULT_LIGHTS, 128)
        cells = []
        for name, change in VARIANTS.items():
            export_mitsuba(out, table, FULL_GRID, replace(DEFAULT_OPTIONS, **change))
            median, p95 = eval_error(prepared, out)
            snr = rendering_snr_db(preview, render_set_mitsuba(out, DEFAULT_LIGHTS, 128))
            cells.append(f"{name}: {100 * median:.1f}% / {100 * p95:.1f}% / {snr:.1f} dB")
        print(f"  {label:26s} " + " | ".join(cells), flush=True)


if __name__ == "__main__":
    main()
