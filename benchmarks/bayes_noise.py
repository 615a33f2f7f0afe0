"""Noise models of the Bayesian pipeline compared on training materials only (and on a test set).

For one benchmark fold (the same splits as ``goniofrost bench``), trains on its training
materials and runs training's inner cross-validation (``frost/calibration.py``: simulated
Bayesian designs and reconstructions of held-out training materials) with each noise model:

* scalar 10/t   the ridge-equivalent noise of a format-1 model (posterior.SCALAR_ETA);
* scalar mean   one number: the mean of the learned per-cell variance;
* cells raw     the per-cell mean squared held-out residual, unsmoothed;
* cells binned  its means in 5-degree bins of (min, max)(theta_i, theta_o);
* cells smooth  the default: Gaussian-smoothed over the grid (noise.smooth_on_grid).

Each noise model gets its own design and reconstruction scales, chosen as training chooses
them (``calibration.choose_scales``). Prints the inner-CV mean error per m for each, and with
``--test`` the mean error of the fold's test materials under each model's chosen setting.

    .venv/bin/python benchmarks/bayes_noise.py [--grid 45,45,90] [--fold 0] [--test]
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

from goniofrost.bench.config import BenchConfig, fold_split  # noqa: E402
from goniofrost.bench.data import open_tables, tables_path  # noqa: E402
from goniofrost.core.grid import MerlGrid, cosine_weight  # noqa: E402
from goniofrost.frost import calibration, noise, posterior, training  # noqa: E402

DATA = REPO.parent / "shared" / "data"
SPECS = (f"nbrdf:{DATA / 'nbrdf_merl.npz'}", f"nbrdf:{DATA / 'nbrdf_rgl.npz'}")
TEST_M = (5, 10, 20, 40, 60)


def binned(values: np.ndarray, grid: MerlGrid, width_deg: float = 5.0) -> np.ndarray:
    """Per-cell values replaced by their mean over 5-degree bins of sorted (theta_i, theta_o)."""
    w_i, w_o = grid.cell_directions(grid.valid_cells)
    a, b = (np.degrees(np.arccos(np.clip(w[:, 2], -1, 1))) for w in (w_i, w_o))
    nb = int(np.ceil(90 / width_deg))
    lo = np.minimum((np.minimum(a, b) / width_deg).astype(int), nb - 1)
    hi = np.minimum((np.maximum(a, b) / width_deg).astype(int), nb - 1)
    key = lo * nb + hi
    sums, counts = np.bincount(key, values, nb * nb), np.bincount(key, None, nb * nb)
    return (sums / np.maximum(counts, 1))[key]


def noise_models(raw: np.ndarray, grid: MerlGrid, t: int) -> dict:
    smooth = np.maximum(noise.smooth_on_grid(raw, grid), training.NOISE_FLOOR)
    n = raw.size
    return {"scalar 10/t": np.full(n, posterior.SCALAR_ETA / t), "scalar mean": np.full(n, smooth.mean()),
            "cells raw": np.maximum(raw, training.NOISE_FLOOR), "cells binned": np.maximum(binned(raw, grid), training.NOISE_FLOOR),
            "cells smooth": smooth}


def test_errors(model_parts, truth, noise_var, design_scale, recon_scale) -> dict:
    """Mean log-relative MSE of the test materials with this noise and scales, per m."""
    from goniofrost.frost.metrics import batch_log_errors
    from goniofrost.frost.bayes_selection import greedy_design
    from goniofrost.frost.model import FrostModel

    model = FrostModel(**model_parts)
    prior = posterior.prior_variance(model)
    s2 = model.singular_values ** 2
    rows = greedy_design(model.dictionary, s2, prior, design_scale * noise_var, max(TEST_M)).rows
    recon = recon_scale * noise_var
    mu = np.asarray(model.mean, np.float64)
    truth_log = model.to_log(truth)
    out = {}
    for m in TEST_M:
        pos = rows[:m]
        values = truth[:, pos, :].transpose(1, 0, 2).reshape(m, -1)
        b = model.to_log(values, pos) - mu[pos][:, None]
        post = posterior.fit(model.dictionary[pos], recon[pos], prior, b, s2, recon.sum(), recon.size)
        est = np.asarray(model.dictionary) @ post.coefficients.astype(np.float32) + model.mean[:, None]
        out[m] = float(batch_log_errors(model, est.astype(np.float64), truth_log).mean())
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grid", default="45,45,90", help="grid resolution (default 45,45,90)")
    parser.add_argument("--fold", type=int, default=0, help="benchmark fold (default 0)")
    parser.add_argument("--test", action="store_true", help="also reconstruct the fold's test materials")
    parser.add_argument("--json", type=Path, help="write the numbers here")
    args = parser.parse_args()
    grid = MerlGrid(*(int(v) for v in args.grid.split(",")))
    names, path = tables_path(SPECS, grid, progress=True)
    tables = open_tables(path)
    train, test = fold_split(len(names), BenchConfig(SPECS, grid=grid), args.fold)
    start = time.perf_counter()
    weight = cosine_weight(grid).astype(np.float32)
    mapped, reference, mean, gram = training._map_and_gram(np.asarray(tables[train]), [names[i] for i in train],
                                                           weight, training.EPS, False)
    svals, vt = training._eigen_components(gram, training.K_MAX)
    folds = noise.inner_folds(gram, len(train), svals.size)
    raw = noise.representation_variance(mapped, folds)
    parts = dict(grid=grid, names=[names[i] for i in train], eps=training.EPS, dictionary=training._project(mapped, vt),
                 singular_values=svals, coefficients=vt, mean=mean, reference=reference, weight=weight)
    print(f"trained on {len(train)} materials, {grid.shape} grid, {time.perf_counter() - start:.1f} s")
    report = {}
    for name, noise_var in noise_models(raw, grid, gram.shape[0]).items():
        t0 = time.perf_counter()
        results = calibration.simulate(mapped, folds, noise_var, design_scales=calibration.DESIGN_SCALES,
                                       recon_scales=calibration.RECON_SCALES)
        chosen = calibration.choose_scales(results)
        inner = calibration.mean_errors(results[chosen])
        report[name] = {"scales": chosen, "inner_cv": inner}
        line = " ".join(f"m{m} {inner[m]:.4f}" for m in sorted(inner))
        print(f"{name:13s} scales {chosen}: inner CV {line} ({time.perf_counter() - t0:.0f} s)", flush=True)
        if args.test:
            truth = np.asarray(tables[test], np.float64)
            report[name]["test"] = test_errors(parts, truth, noise_var, *chosen)
            print(f"{'':13s} test: " + " ".join(f"m{m} {v:.4f}" for m, v in report[name]["test"].items()), flush=True)
    if args.json:
        args.json.write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
