"""The work of one fold: train once, select with every method and m, reconstruct the test set.

``run_fold`` is the unit the executors distribute; it returns plain rows, the same whoever runs it
(time fields aside). ``bayes`` and ``frost-bayesrec`` rows also carry the predicted error and
coverage; ``bayes-target`` rows simulate ``capture --target-error``.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable, Iterator

import numpy as np

from goniofrost.bench.baselines import nielsen_path, random_select, uniform_select
from goniofrost.bench.config import SELECTOR_METHODS, BenchConfig, BenchError, fold_split, method_rng
from goniofrost.bench.data import open_tables
from goniofrost.frost.metrics import batch_log_errors

# Methods whose cells are reconstructed by the Bayesian posterior mean (the others: ridge).
BAYES_RECON = tuple(method for method, (_, _, posterior) in SELECTOR_METHODS.items() if posterior)


@dataclass
class Design:
    """One selection to evaluate: ``positions`` (m,) into the valid cells and its wall time."""

    method: str
    m: int
    trial: int
    positions: np.ndarray
    select_s: float


def run_fold(config: BenchConfig, path: str, names: list[str], fold: int,
             progress: Callable[[int], None] | None = None) -> list[dict]:
    """Evaluate every method, m and trial on one fold; returns result rows (see results.ROW_FIELDS).

    With "bayes" among the methods, the rows also hold the fold's target-error simulations.

    path: the cached tables (``data.tables_path``); names: their material names.
    progress: called with 1 after each evaluated design (for a progress bar).
    """
    from goniofrost.frost.training import TrainingOptions, fit_model

    tables = open_tables(path)
    train, test = fold_split(len(names), config, fold)
    model = fit_model(np.asarray(tables[train]), [names[i] for i in train], config.grid,
                      TrainingOptions(k_max=max(config.m_values)))
    truth_log = model.to_log(np.asarray(tables[test]))  # NaN where not measured: left out of every error
    truth = sampled_truth(model, np.asarray(tables[test]))
    test_names = [names[i] for i in test]
    rows, cache = [], {}
    for design in iter_designs(model, config, fold, cache):
        rows += evaluate_design(model, design, truth, test_names, config.eta, fold, truth_log)
        if progress is not None:
            progress(1)
    if "bayes" in config.methods:
        rows += target_rows(model, config, truth, truth_log, test_names, fold, cache)
    return rows


def sampled_truth(model, truth: np.ndarray) -> np.ndarray:
    """The values a design samples of test materials (n_test, n_valid, 3): ``truth``, with each
    cell a material has no data for (NaN: ``rgl:PATH`` beyond the file's elevations) at the
    model's prior mean there (from_log(mu)); such a sample says only what the training materials
    say. The errors are scored against the NaN truth (``metrics.measured_mean``): never there."""
    missing = np.isnan(truth)
    if not missing.any():
        return truth
    mu = np.asarray(model.mean, dtype=np.float64)
    prior = model.from_log(np.repeat(mu[:, None], 3, axis=1))
    return np.where(missing, prior[None], truth)


def designs_per_fold(config: BenchConfig) -> int:
    """How many designs ``iter_designs`` yields for one fold (for progress totals)."""
    trials = {"nielsen": config.nielsen_trials, "random": config.random_trials}
    return len(config.m_values) * sum(trials.get(m, 1) for m in config.methods)


def iter_designs(model, config: BenchConfig, fold: int, cache: dict | None = None) -> Iterator[Design]:
    """Every (method, m, trial) selection of a fold, in a fixed order.

    cache: a dict shared by the fold's calls, so that a selection two methods use (FROST
    first-m cells for frost-firstm and frost-bayesrec; the Bayesian design) runs once.
    """
    cache = {} if cache is None else cache
    baselines = {"nielsen": _nielsen_designs, "random": _random_designs, "uniform": _uniform_designs}
    for method in config.methods:
        if method in baselines:
            yield from baselines[method](model, config, fold)
        else:
            yield from _selector_designs(model, config, method, cache)


def _timed(fn, *args, **kwargs):
    start = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - start


def _selector_designs(model, config: BenchConfig, method: str, cache: dict) -> Iterator[Design]:
    """A selector's designs (``frost.selectors``): a nested one runs once for every m, the time of
    m being the wall time from the start of that run to the m-th pick (like Nielsen's incremental
    runs); another runs once per m. A selection two methods share (FROST's first-m cells for
    frost-firstm and frost-bayesrec) runs once."""
    from goniofrost.frost.selectors import SELECTORS

    name, options, _ = SELECTOR_METHODS[method]
    if SELECTORS[name].nested:
        selection = nested_design(model, config, cache, name, options)
        for m in config.m_values:
            yield Design(method, m, 0, np.asarray(selection.positions[:m]), float(selection.pick_seconds[m - 1]))
        return
    for m in config.m_values:
        key = (name, tuple(sorted(options.items())), m)
        if key not in cache:
            cache[key] = _timed(SELECTORS[name].select, model, m, **options)
        selection, seconds = cache[key]
        yield Design(method, m, 0, np.asarray(selection.positions, dtype=np.int64), seconds)


def nested_design(model, config: BenchConfig, cache: dict, name: str = "bayes", options=None):
    """The fold's nested design of max(m) cells by selector ``name`` (a Selection with
    pick_seconds), run once per fold (``cache``)."""
    from goniofrost.frost.selectors import SELECTORS

    options = options or {}
    key = name if not options else (name, tuple(sorted(options.items())))
    if key not in cache:
        cache[key] = SELECTORS[name].select(model, max(config.m_values), **options)
    return cache[key]


def bayes_design(model, config: BenchConfig, cache: dict):
    """The fold's nested Bayesian design of max(m) cells (a Selection with pick_seconds)."""
    return nested_design(model, config, cache, "bayes")


def target_rows(model, config: BenchConfig, truth, truth_log, names: list[str], fold: int,
                cache: dict | None = None) -> list[dict]:
    """Rows of kind "bayes-target": per target error and test material, where the simulated
    capture stopped (m = samples), its true error (mse) and predicted error (pred_mse)."""
    from goniofrost.bench.bayes_eval import target_outcomes

    selection = bayes_design(model, config, {} if cache is None else cache)
    rows = []
    for target in config.target_errors:
        out = target_outcomes(model, np.asarray(selection.positions), truth, truth_log, target)
        for i, name in enumerate(names):
            m = int(out["samples"][i])
            rows.append({"method": "bayes-target", "m": m, "fold": int(fold), "trial": 0, "material": name,
                         "mse": float(out["mse"][i]), "select_s": float(selection.pick_seconds[m - 1]),
                         "recon_s": out["seconds"] / len(names), "pred_mse": float(out["pred_mse"][i]),
                         "cover50": None, "cover90": None, "target": float(target)})
    return rows


def _nielsen_designs(model, config: BenchConfig, fold: int) -> Iterator[Design]:
    # One incremental run per trial gives the designs for every m; the time of m is the wall
    # time from the start of that run (all additions and descents up to m points).
    for trial in range(config.nielsen_trials):
        rng = method_rng(config, "nielsen", fold, trial)
        steps = nielsen_path(model.dictionary, config.m_values, config.grid, rng,
                             config.nielsen_subset, config.nielsen_max_iter)
        for step in steps:
            yield Design("nielsen", step.m, trial, step.positions, step.seconds)


def _random_designs(model, config: BenchConfig, fold: int) -> Iterator[Design]:
    for trial in range(config.random_trials):
        rng = method_rng(config, "random", fold, trial)
        for m in config.m_values:
            positions, seconds = _timed(random_select, config.grid, m, rng)
            yield Design("random", m, trial, positions, seconds)


def _uniform_designs(model, config: BenchConfig, fold: int) -> Iterator[Design]:
    for m in config.m_values:
        positions, seconds = _timed(uniform_select, config.grid, m)
        yield Design("uniform", m, 0, positions, seconds)


def evaluate_design(model, design: Design, truth: np.ndarray, names: list[str],
                    eta: float, fold: int, truth_log: np.ndarray | None = None) -> list[dict]:
    """Reconstruct every test material from its values at the design's cells; one row each.

    truth: (n_test, n_valid, 3) BRDF in 1/sr; truth_log: its ``model.to_log`` (computed when
    not given; pass it to reuse it across designs). The error is the log-relative MSE over all
    valid cells and channels (``metrics.log_relative_mse`` of ``reconstruct``'s output; see
    ``batch_log_errors``). ``recon_s`` is the wall time of the ridge solve and the dictionary
    product for all test materials at once, divided by the number of materials.
    """
    truth_log = model.to_log(truth) if truth_log is None else truth_log
    extra = {"pred_mse": None, "cover50": None, "cover90": None, "target": None}
    if design.method in BAYES_RECON:
        from goniofrost.bench.bayes_eval import bayes_errors

        out = bayes_errors(model, design.positions, truth, truth_log)
        errors, seconds = out["mse"], out["seconds"]
    else:
        errors, seconds = _timed_errors(model, design.positions, truth, truth_log, eta)
    rows = []
    for i, name in enumerate(names):
        if not np.isfinite(errors[i]):
            raise BenchError(f"fold {fold}: {design.method} m={design.m} trial {design.trial} "
                             f"gives a non-finite error ({errors[i]}) on {name!r}")
        if design.method in BAYES_RECON:
            extra = {"pred_mse": float(out["pred_mse"][i]), "cover50": float(out["cover50"][i]),
                     "cover90": float(out["cover90"][i]), "target": None}
        rows.append({"method": design.method, "m": int(design.m), "fold": int(fold),
                     "trial": int(design.trial), "material": name, "mse": float(errors[i]),
                     "select_s": float(design.select_s), "recon_s": seconds / len(names)} | extra)
    return rows


def _timed_errors(model, positions, truth, truth_log, eta):
    from goniofrost.frost.reconstruction import reconstruct_log

    n_mat = truth.shape[0]
    # Samples of every material and channel side by side: (m, 3 n_mat) columns, one solve.
    values = truth[:, positions, :].transpose(1, 0, 2).reshape(positions.size, 3 * n_mat)
    start = time.perf_counter()
    estimate = reconstruct_log(model, positions, model.to_log(values, positions), eta=eta)
    seconds = time.perf_counter() - start
    return batch_log_errors(model, estimate, truth_log), seconds
