"""FROST accuracy: reconstruct held-out materials from their own values at the selected cells.

Trains on MERL + RGL (Neural-BRDF fits) minus a 20-material test set drawn with
``numpy.random.default_rng(SEED).choice`` (SEED = 0 by default; the list is printed), then for
each m reports the mean log-relative MSE (metrics.log_relative_mse: mapped domain, over valid
cells and channels, averaged over the test materials) for FROST with both forms of Y and for
random valid cells (median over 5 draws, seeds 0..4).

    .venv/bin/python benchmarks/frost_accuracy.py [--grid full|small] [--seed 0] [--m 10 20 40 60]
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from goniofrost.datasets import open_dataset  # noqa: E402
from goniofrost.core.grid import FULL_GRID, MerlGrid  # noqa: E402
from goniofrost.frost.metrics import log_relative_mse  # noqa: E402
from goniofrost.frost.model import FrostModel  # noqa: E402
from goniofrost.frost.reconstruction import reconstruct  # noqa: E402
from goniofrost.frost.selection import select_cells  # noqa: E402
from goniofrost.frost.training import train  # noqa: E402

DATA = REPO.parent / "shared" / "data"
SPECS = [f"nbrdf:{DATA / 'nbrdf_merl.npz'}", f"nbrdf:{DATA / 'nbrdf_rgl.npz'}"]
TEST_SIZE = 20
RANDOM_DRAWS = 5


def test_split(seed: int = 0, size: int = TEST_SIZE) -> list[str]:
    """The held-out material names: ``size`` of MERL + RGL (in archive order), sorted."""
    names = [n for spec in SPECS for n in open_dataset(spec).names()]
    rng = np.random.default_rng(seed)
    return sorted(names[i] for i in rng.choice(len(names), size, replace=False))


def test_tables(names: list[str], grid: MerlGrid) -> np.ndarray:
    """float64 (len(names), n_valid, 3) ground truth of the test materials."""
    out = []
    for spec in SPECS:
        ds = open_dataset(spec)
        mine = [n for n in names if n in set(ds.names())]
        if mine:
            out.extend(zip(mine, ds.tabulate(mine, grid)))
    order = {n: i for i, n in enumerate(names)}
    return np.stack([t for _, t in sorted(out, key=lambda p: order[p[0]])]).astype(np.float64)


def mean_error(model, truth: np.ndarray, positions: np.ndarray) -> float:
    """Mean over test materials of the log-relative MSE reconstructing from ``positions``."""
    return float(np.mean([log_relative_mse(model, t, reconstruct(model, positions, t[positions]))
                          for t in truth]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grid", choices=("full", "small"), default="full")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--m", type=int, nargs="+", default=[10, 20, 40, 60])
    parser.add_argument("--json", type=Path, help="also write the table as JSON here")
    parser.add_argument("--model", type=Path, help="use this trained model (must exclude the test set)")
    args = parser.parse_args()
    grid = FULL_GRID if args.grid == "full" else MerlGrid(30, 30, 60)
    held_out = test_split(args.seed)
    print(f"test set (seed {args.seed}): {', '.join(held_out)}")
    start = time.perf_counter()
    if args.model:
        model = FrostModel.load(args.model)
        grid = model.grid
        overlap = set(model.names) & set(held_out)
        if overlap or len(model.names) != 151 - TEST_SIZE:
            raise SystemExit(f"{args.model}: trained on {len(model.names)} materials incl. test ones {sorted(overlap)}")
    else:
        model = train(SPECS, exclude=held_out, grid=grid, progress=True)
    print(f"model: {len(model.names)} materials, K = {model.n_components}, {time.perf_counter() - start:.1f} s")
    truth = test_tables(held_out, grid)
    rows = []
    print(f"mean log-relative MSE over the {len(held_out)} held-out materials (ridge reconstruction, lower is better):")
    print("| m | FROST (Y = all) | FROST (Y = first m) | random (median of 5) |")
    print("|---|---|---|---|")
    for m in args.m:
        frost = {f: mean_error(model, truth, select_cells(model, m, y_form=f).positions) for f in ("all", "firstm")}
        draws = [mean_error(model, truth, np.random.default_rng(s).choice(grid.n_valid, m, replace=False))
                 for s in range(RANDOM_DRAWS)]
        rows.append({"m": m, "frost_all": frost["all"], "frost_firstm": frost["firstm"],
                     "random_median": float(np.median(draws)), "random_draws": draws})
        print(f"| {m} | {frost['all']:.4f} | {frost['firstm']:.4f} | {np.median(draws):.4f} |", flush=True)
    if args.json:
        args.json.write_text(json.dumps({"seed": args.seed, "test_set": held_out, "grid": grid.as_dict(),
                                         "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
