"""Where the calibrated bound's misses err, and whether any check on a capture's samples could see it.

Trains one model of a ``target_error.py`` setting (default ``merl-rgl``: trained on the 100 MERL,
tested on the 51 RGL), picks its Bayesian design of 60 cells and, for every test material
measured at the first m cells (m in ``--m``), compares the materials the bound misses (true
error above the 95 % bound) that were bounded below ``--target`` (the ones the rule would stop
on wrongly) with the materials the bound covers:

* the share of their true error (the mean over every valid cell of the squared mapped error)
  in angular regions: how much of it sits where the design samples;
* their prequential score (``posterior.prequential_errors``: each design sample predicted from
  the ones before it) over the design cells in the grazing region (max(theta_i, theta_o) > 80
  degrees) and elsewhere;
* a spot check: k cells drawn uniformly at random among the valid cells (seeded), the mean of
  their squared error (an unbiased estimate of the true error), and how often it exceeds the
  bound (would k extra, randomly placed samples reveal the miss?), over --draws draws.

A diagnostic of the test materials (nothing is chosen on it). 10 s to 2 minutes at 45 x 45 x 90
(the tables tabulated before or not)::

    .venv/bin/python benchmarks/error_where.py --grid 45,45,90 --setting merl-rgl

Smallest setting (tests/test_benchmarks.py)::

    .venv/bin/python benchmarks/error_where.py --grid 10,10,20 --setting builtin --draws 50
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "benchmarks"))

from goniofrost.core.grid import MerlGrid  # noqa: E402


def region_masks(grid: MerlGrid) -> dict:
    """{name: bool (n_valid,)} of the angular regions reported."""
    theta_h, theta_d, _ = (np.degrees(a) for a in grid.flat_angles(grid.valid_cells))
    w_i, w_o = grid.cell_directions(grid.valid_cells)
    grazing = np.degrees(np.arccos(np.clip(np.minimum(w_i[..., 2], w_o[..., 2]), -1, 1))) > 80
    return {"max(theta_i, theta_o) > 80": grazing, "theta_d > 80": theta_d > 80, "theta_h > 70": theta_h > 70}


def median(values: np.ndarray, mask: np.ndarray) -> str:
    """The median of values[mask], "n/a" for an empty group."""
    return f"{np.median(values[mask]):.2f}" if mask.any() else "n/a"


def main(argv=None) -> int:
    import target_error as te
    from goniofrost.bench import bayes_eval
    from goniofrost.frost import posterior
    from goniofrost.frost.bayes_selection import select_bayes
    from goniofrost.frost.training import TrainingOptions, fit_model

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--grid", default="45,45,90")
    parser.add_argument("--setting", default="merl-rgl", choices=te.SETTINGS)
    parser.add_argument("--m", default="15,30")
    parser.add_argument("--target", type=float, default=0.05)
    parser.add_argument("--draws", type=int, default=2000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    grid = MerlGrid(*(int(v) for v in args.grid.split(",")))
    started = time.time()
    _, train, train_names, test, test_names = next(te.folds_of(args.setting, grid, 1))
    model = fit_model(np.asarray(train), train_names, grid, TrainingOptions(k_max=60))
    order = np.asarray(select_bayes(model, 60).positions, dtype=np.int64)
    truth = np.asarray(test, dtype=np.float64)
    truth_log = model.to_log(truth)
    floor = np.log(model.eps) - np.log(np.asarray(model.reference, np.float64) + model.eps)
    regions = region_masks(grid)
    grazing_design = regions["max(theta_i, theta_o) > 80"][order]
    rng = np.random.default_rng(args.seed)
    print(f"setting {args.setting}, grid {args.grid}, {len(test_names)} test materials, target {args.target:g}\n")
    for m in (int(v) for v in args.m.split(",")):
        post, noise, b = bayes_eval._fit(model, order[:m], truth)
        rows = bayes_eval.bound_rows(model, order[:m], truth, truth_log)
        estimate = np.asarray(model.dictionary) @ post.coefficients.astype(np.float32)
        estimate = estimate.astype(np.float64) + np.asarray(model.mean, np.float64)[:, None]
        sq = np.stack([np.mean((np.maximum(estimate[:, 3 * i:3 * i + 3], floor[:, None]) - truth_log[i]) ** 2, axis=1)
                       for i in range(truth.shape[0])])
        one_step = posterior.prequential_errors(model.dictionary[order[:m]], noise[order[:m]],
                                                posterior.prior_variance(model), b)
        missed = (rows["mse"] > rows["upper"]) & (rows["upper"] <= args.target)
        covered = rows["mse"] <= rows["upper"]
        groups = {f"missed, bound <= {args.target:g}": missed, "covered": covered}
        print(f"m = {m}: {int(missed.sum())} missed with a bound <= {args.target:g}, {int(covered.sum())} covered")
        print("| | " + " | ".join(groups) + " |\n|---|---|---|")
        for name, mask in regions.items():
            share = sq[:, mask].sum(axis=1) / sq.sum(axis=1)
            print(f"| error share in {name} ({100 * mask.mean():.1f} % of cells) | "
                  + " | ".join(median(share, g) for g in groups.values()) + " |")
        for name, cells in (("grazing", grazing_design[:m]), ("other", ~grazing_design[:m])):
            cells = cells.copy()
            cells[0] = False  # the prior's prediction of the first sample
            score = np.array([one_step[cells][:, 3 * i:3 * i + 3].mean() for i in range(truth.shape[0])])
            print(f"| prequential score, {name} design cells ({int(cells.sum())}) | "
                  + " | ".join(median(score, g) for g in groups.values()) + " |")
        for k in (5, 10, 20):
            draws = rng.integers(0, sq.shape[1], size=(args.draws, k))
            alarm = (sq[:, draws].mean(axis=2) > rows["upper"][:, None]).mean(axis=1)
            print(f"| spot check of {k} random cells above the bound (probability) | "
                  + " | ".join(f"{np.median(alarm[g]):.2f} ({alarm[g].min():.2f} to {alarm[g].max():.2f})"
                               if g.any() else "n/a" for g in groups.values()) + " |")
        print("| median true error / median estimate | "
              + " | ".join(median(rows["mse"] / rows["median"], g) for g in groups.values()) + " |\n")
    print(f"wall {time.time() - started:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
