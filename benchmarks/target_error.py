"""The calibrated stopping rule: simulated ``capture --target-error E --confidence C`` on test materials.

For every fold of every setting a model is trained on the fold's training materials only (its
noise model, scales, predicted-error calibration and error bound all come from training's inner
cross-validation of those materials), a Bayesian design of ``--m-max`` cells is picked, and
every test material is measured along it in batches (``frost.stopping``) until the bound at
the confidence is at most E and the samples are not out of the model, or the plan is used up
(``bench.bayes_eval.target_outcomes``). Reported per setting and E:

* stopped on the target, and of those the fraction whose true error is <= E (the goal: at
  least the confidence minus 2 points); every target twice when the model has sentinel cells
  (``frost.sentinel``): without them, and with them measured with the first batch (counted as
  samples) and checked at every look (how many captures they flag);
* mean samples against the plan; materials flagged out of the model (at any look, at the end);
* per m: the fraction of materials whose median estimate is within a factor 2 of the true error,
  and whose true error is below the bound (the bound's coverage at a single look); and how many
  of the materials the bound misses, and of the others, have samples less typical than 95 % of
  the held-out training materials (``confidence.feature_distance``: would an out-of-model
  statistic on the samples' features single out the misses?), and whose samples were predicted
  (each from the ones measured before it) worse than 95 % of theirs
  (``confidence.prequential_excess``: would a held-out statistic?), and whose sentinels flag them
  (``confidence.sentinel_excess``: would a check where the design does not look?).

Settings: ``split`` (MERL + RGL, the benchmark's random 131 / 20 folds), ``builtin`` (the 74
analytic materials, random 64 / 10 folds), ``merl-rgl`` (train on the 100 MERL, test on the 51
RGL) and ``rgl-merl`` (the other way round). ``--rig`` designs among a rig's cells,
``--camera-noise`` reads its samples with the camera's noise (``camera_noise``), ``--train-sizes``
trains on subsets of each fold's training materials (the learning curve), and ``--summarise``
joins runs of disjoint folds (``--first-fold``).

Full size (run once, 3 December 2026, BENCHMARKS.md@8b3941b: split 32 min, the three others 39 min,
on a loaded 2-core machine; peak RSS 14.6 GB with the other three settings; one process, settings in turn;
since the test materials are simulated CHUNK at a time, rgl-merl, the largest test set, peaks at 4.8 GB
instead of 13.7 GB, with the same summary)::

    .venv/bin/python benchmarks/target_error.py --grid 90,90,180 --folds 10 --out /tmp/target-full

Smallest setting (what tests/test_confidence.py runs)::

    .venv/bin/python benchmarks/target_error.py --grid 10,10,20 --folds 1 --settings builtin \\
        --m-max 20 --out /tmp/target-small
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

from goniofrost.bench import bayes_eval, camera_noise  # noqa: E402
from goniofrost.frost import confidence, sentinel  # noqa: E402
from goniofrost.bench.config import BenchConfig, fold_split  # noqa: E402
from goniofrost.bench.data import open_tables, tables_path  # noqa: E402
from goniofrost.core.grid import MerlGrid  # noqa: E402
from goniofrost.frost import stopping  # noqa: E402

# The shared data beside the checkout (a worktree one level deeper: /work/wt/NAME beside /work/shared)
DATA = next((p / "shared" / "data" for p in REPO.parents if (p / "shared" / "data").is_dir()),
            REPO.parent / "shared" / "data")
MERL, RGL = f"nbrdf:{DATA / 'nbrdf_merl.npz'}", f"nbrdf:{DATA / 'nbrdf_rgl.npz'}"
SETTINGS = ("split", "builtin", "merl-rgl", "rgl-merl")
TARGETS = (0.01, 0.02, 0.05)
# Test materials simulated at once: their float64 values, log map and reconstructions are
# (materials, cells, 3) arrays each, so all 100 MERL materials of rgl-merl at the full grid held
# 7.5 GB between calls and peaked at 13.7 GB (BENCHMARKS.md@8b3941b, "Issue 28 at the full grid").
CHUNK = 20
# The bound's kinds every non-rig fold measures (docs/decisions/0100-a-sharper-bound.md)
KINDS = confidence.BOUND_KINDS


class BadOption(ValueError):
    """An option the benchmark cannot run with (``main`` prints it on one line, exit code 2)."""


def folds_of(setting: str, grid: MerlGrid, folds: int, first: int = 0, sizes=None):
    """Yield (label, fold, training tables, training names, test tables, test names) of a
    setting: folds first ... first + folds - 1 of split and builtin (each drawn from its number
    alone, ``fold_split``, so runs of disjoint ranges join), the one fold of the others. sizes:
    numbers of training materials (split, builtin): every fold once per size, trained on that
    many of its training materials (``training_subset``) and labelled "SETTING n=SIZE"."""
    if setting in ("split", "builtin"):
        specs, n_test = ((MERL, RGL), 20) if setting == "split" else (("builtin",), 10)
        n_train = TRAINING_MATERIALS[setting]
        names, path = tables_path(list(specs), grid, progress=False)
        tables = open_tables(path)
        config = BenchConfig(tuple(specs), grid=grid, n_train=n_train, n_test=n_test)
        for fold in range(first, first + folds):
            train, test = fold_split(len(names), config, fold)
            for size in sizes or (None,):
                kept = train if size is None else training_subset(train, size, config.seed, fold)
                label = setting if size is None else f"{setting} n={size}"
                yield label, fold, tables[kept], [names[i] for i in kept], tables[test], [names[i] for i in test]
        return
    train_spec, test_spec = (MERL, RGL) if setting == "merl-rgl" else (RGL, MERL)
    train_names, train_path = tables_path([train_spec], grid, progress=False)
    test_names, test_path = tables_path([test_spec], grid, progress=False)
    yield setting, 0, open_tables(train_path), train_names, open_tables(test_path), test_names


TRAINING_MATERIALS = {"split": 131, "builtin": 64}  # a fold's training materials (folds_of)


def check_sizes(settings: list[str], sizes) -> None:
    """BadOption unless every setting has a fold's training materials to draw ``sizes`` from
    (None: no learning curve), before anything runs."""
    for setting in settings if sizes else ():
        if setting not in TRAINING_MATERIALS:
            raise BadOption(f"--train-sizes: expected the settings split or builtin, found {setting}")
        if not all(0 < size <= TRAINING_MATERIALS[setting] for size in sizes):
            raise BadOption(f"--train-sizes: expected 1 to {TRAINING_MATERIALS[setting]} materials for {setting}, "
                            f"found {','.join(map(str, sizes))}")


SUBSET_SEED = 4901  # the learning curve's stream, apart from the folds' (bench.config)


def training_subset(train: np.ndarray, size: int, seed: int, fold: int) -> np.ndarray:
    """The first ``size`` of a fold's training material indices ``train`` (int64, sorted) in an
    order drawn from the seed and the fold alone: sorted int64 (size,), nested (a smaller size's
    materials are among a larger one's) and never a test material."""
    if not 0 < size <= len(train):
        raise BadOption(f"--train-sizes: expected 1 to {len(train)} materials, found {size}")
    order = np.random.default_rng([seed, SUBSET_SEED, fold]).permutation(np.asarray(train, dtype=np.int64))
    return np.sort(order[:size])


STOP_FIELDS = ("samples", "mse", "pred_mse", "upper", "reached", "out_of_model", "ever_out", "ever_sentinel")


def run_fold(train, train_names, test, test_names, grid, m_max, confidence, targets, rig_mask=None,
             noise=None) -> dict:
    """Train, design, and simulate every target; per-m prediction quality. Plain rows.
    rig_mask: bool (n_valid,) a rig's measurable cells: ``run_rig_fold``; noise: (relative sd,
    seed) of the camera's noise on every sample (``camera_noise.noisy``), None: exact samples."""
    from goniofrost.frost.bayes_selection import select_bayes
    from goniofrost.frost.training import TrainingOptions, fit_model

    if rig_mask is not None:
        return run_rig_fold(train, train_names, test, test_names, grid, m_max, confidence, targets, rig_mask, noise)
    model = fit_model(np.asarray(train), train_names, grid, TrainingOptions(k_max=60))
    order = np.asarray(select_bayes(model, m_max).positions, dtype=np.int64)
    variants = [(False, model, False, None, order)]
    variants += [((False, kind), bayes_eval.with_bound_kind(model, kind), False, None, order)
                 for kind in KINDS if kind != bound_kind(model)]
    if sentinel.calibrated_cells(model).size:
        variants.append((True, model, True, None, order))
    stops, per_m = evaluate(variants, model, order, test, test_names, targets, confidence, m_max, noise)
    return {"stops": stops, "per_m": per_m, "calibration_materials": len(model.noise["calibration"]["bound"]["scores"]),
            "bound_choice": model.noise["calibration"]["bound"].get("choice"), "bound_scale": bound_scale(model)}


def bound_scale(model) -> dict:
    """{m: the spread of the log residual at m} of the model's bound, fitted on its training
    materials' inner folds (``confidence.fit_bound``): the held-out spread training expects."""
    bound = model.noise["calibration"]["bound"]
    return {str(m): float(s) for m, s in zip(bound["m"], bound["scale"])}


def bound_kind(model) -> str:
    """The kind of bound (``confidence.BOUND_KINDS``) the model's captures stop on."""
    return model.noise["calibration"]["bound"].get("kind", "split")


def run_rig_fold(train, train_names, test, test_names, grid, m_max, confidence, targets, mask, noise=None) -> dict:
    """As ``run_fold`` on a rig that measures only the cells of ``mask``: the design among them,
    every target simulated three ways ("sentinels" of the rows): "no" (none), "approx" (the
    model's check calibrated at the whole grid's sentinels, measured at the cells ``plan --rig``
    puts in their place) and "rig" (a model trained with ``sentinel_candidates=mask``, as
    ``train --rig``: its inner designs among the rig's cells too, so its own design, as ``plan
    --rig`` makes it, and measured where they were calibrated). Per-m rows from the second."""
    from goniofrost.frost.bayes_selection import select_bayes
    from goniofrost.frost.training import TrainingOptions, fit_model

    model = fit_model(np.asarray(train), train_names, grid, TrainingOptions(k_max=60))
    rig_model = fit_model(np.asarray(train), train_names, grid, TrainingOptions(k_max=60, sentinel_candidates=mask))
    order = np.asarray(select_bayes(model, m_max, candidates=mask).positions, dtype=np.int64)
    # the rig model's noise scales are chosen on designs among the rig's cells: its design may differ
    rig_order = np.asarray(select_bayes(rig_model, m_max, candidates=mask).positions, dtype=np.int64)
    # where plan --rig puts them: outside each design
    placed = sentinel.cells(grid, sentinel.calibrated_cells(model).size, mask & ~np.isin(np.arange(grid.n_valid), order))
    rig_placed = sentinel.cells(grid, sentinel.calibrated_cells(model).size,
                                mask & ~np.isin(np.arange(grid.n_valid), rig_order))
    variants = [("no", model, False, None, order), ("approx", model, True, placed, order),
                ("rig", rig_model, True, rig_placed, rig_order)]
    stops, per_m = evaluate(variants, rig_model, rig_order, test, test_names, targets, confidence, m_max, noise)
    return {"stops": stops, "per_m": per_m,
            "calibration_materials": len(rig_model.noise["calibration"]["bound"]["scores"]),
            "sentinel_cells": {"whole_grid": sentinel.calibrated_cells(model).tolist(),
                               "rig_calibrated": sentinel.calibrated_cells(rig_model).tolist(),
                               "placed": placed.tolist(), "rig_placed": rig_placed.tolist()},
            "same_design": bool(np.array_equal(order, rig_order)), "bound_scale": bound_scale(rig_model)}


def evaluate(variants, per_m_model, per_m_order, test, test_names, targets, confidence, m_max,
             noise=None) -> tuple[list, list]:
    """(stop rows, per-m rows) of the test materials (``test``: (materials, cells, 3) tables, read
    here a chunk of CHUNK at a time), in the order of one call on all of them: every material is
    simulated on its own, so a chunk's rows are the whole set's. The per-m rows use
    ``per_m_model`` (the sentinel calibration it reports on; the map is every variant's).
    noise: (relative sd, seed): the samples measured with the camera's noise, the errors scored
    against the exact values; None: exact samples."""
    stops, per_m = [], []
    for lo in range(0, len(test_names), CHUNK):
        names = test_names[lo:lo + CHUNK]
        truth = np.asarray(test[lo:lo + CHUNK], dtype=np.float64)
        truth_log = per_m_model.to_log(truth)
        measured = truth if noise is None else camera_noise.noisy(truth, names, *noise)
        stops += stop_rows(variants, measured, truth_log, names, targets, confidence)
        per_m += per_m_rows(per_m_model, per_m_order, measured, truth_log, names, m_max, confidence)
    # stable sorts: the chunks are in the materials' order
    labels = [label if isinstance(label, tuple) else (label, bound_kind(model)) for label, model, *_ in variants]
    stops.sort(key=lambda r: (targets.index(r["target"]), labels.index((r["sentinels"], r["bound"]))))
    per_m.sort(key=lambda r: r["m"])
    return stops, per_m


def stop_rows(variants, measured, truth_log, test_names, targets, confidence) -> list[dict]:
    """Every test material's simulated capture at every target, per variant (label, model,
    sentinels measured, their cells or None: the model's calibrated ones, the design's order);
    measured: (n_mat, cells, 3) the values the samples read, truth_log the exact mapped values."""
    rows = []
    for target in targets:
        for label, model, checked, cells, order in variants:
            out = bayes_eval.target_outcomes(model, order, measured, truth_log, target, confidence,
                                             bayes_eval.MeasuredChecks(cells) if checked else None)
            sentinels, kind = label if isinstance(label, tuple) else (label, bound_kind(model))
            rows += [{"material": name, "target": target, "sentinels": sentinels, "bound": kind,
                      **{k: float(out[k][i]) for k in STOP_FIELDS}} for i, name in enumerate(test_names)]
    return rows


def per_m_rows(model, order, measured, truth_log, test_names, m_max, confidence) -> list[dict]:
    """The bound and median estimate of every test material at every batch end of the design
    (measured, truth_log: as ``stop_rows``)."""
    rows = []
    for m in stopping.batch_ends(m_max):
        out = bayes_eval.bound_rows(model, order[:m], measured, truth_log, confidence, KINDS)
        rows += [{"material": name, "m": m, **{k: float(out[k][i]) for k in out}} for i, name in enumerate(test_names)]
    return rows


def summary(results: dict, m_max: int, confidence: float) -> dict:
    """Per setting: per target the stopping figures, per m the prediction figures."""
    out = {}
    for setting, folds in results.items():
        stops = [s for f in folds for s in f["stops"]]
        per_m = [r for f in folds for r in f["per_m"]]
        rows = {}
        for checked, kind, target in sorted({(s.get("sentinels", False), s.get("bound", "split"), s["target"])
                                             for s in stops}, key=lambda t: (str(t[0]), t[1] != "split", t[1], t[2])):
            group = [s for s in stops if s["target"] == target and s.get("sentinels", False) == checked
                     and s.get("bound", "split") == kind]
            hit = [s for s in group if s["reached"]]
            label = checked if isinstance(checked, str) else "sentinels" if checked else ""
            label += "" if kind == "split" else f" {kind}"
            rows[f"{target:g} {label}".strip()] = {"target": target, "sentinels": checked, "bound": kind,
                            "sentinel_flagged": int(sum(s.get("ever_sentinel", 0) for s in group)),
                            "materials": len(group), "stopped_on_target": len(hit),
                            "within_when_stopped": float(np.mean([s["mse"] <= target for s in hit])) if hit else None,
                            "within_all": float(np.mean([s["mse"] <= target for s in group])),
                            "mean_samples": float(np.mean([s["samples"] for s in group])), "plan": m_max,
                            "ever_out": int(sum(s["ever_out"] for s in group)),
                            "out_at_end": int(sum(s["out_of_model"] for s in group))}
        for key, row in rows.items():
            row |= efficiency(folds, row["target"], row["sentinels"], row["bound"])
            row["ideal_over_oracle"] = ideal_over_oracle(folds, row["target"])
        by_m = {}
        for m in sorted({r["m"] for r in per_m}):
            group = [r for r in per_m if r["m"] == m]
            ratio = np.array([r["median"] / r["mse"] for r in group])
            missed = np.array([r["mse"] > r["upper"] for r in group])
            far = np.array([r.get("feature_distance", np.nan) > 1 for r in group])
            poor = np.array([r.get("prequential", np.nan) > 1 for r in group])
            flagged = np.array([r.get("sentinel", 0.0) > 0 for r in group])
            plain = np.array([r.get("median_unchecked", r["median"]) / r["mse"] for r in group])
            plain_missed = np.array([r["mse"] > r.get("upper_unchecked", r["upper"]) for r in group])
            by_m[m] = {"within_factor_2": float(np.mean((ratio <= 2) & (ratio >= 0.5))),
                       "within_factor_2_unchecked": float(np.mean((plain <= 2) & (plain >= 0.5))),
                       "bound_covers_unchecked": float(np.mean(~plain_missed)),
                       "missed_sentinel": int((missed & flagged).sum()), "covered_sentinel": int((~missed & flagged).sum()),
                       "bound_covers": float(np.mean(~missed)),
                       "out_of_model": float(np.mean([r["out_of_model"] for r in group])), "materials": len(group),
                       "missed": int(missed.sum()), "missed_far": int((missed & far).sum()),
                       "covered_far": int((~missed & far).sum()),
                       "missed_prequential": int((missed & poor).sum()), "covered_prequential": int((~missed & poor).sum())}
        out[setting] = {"targets": rows, "by_m": by_m, "confidence": confidence}
    return out


RATIO_M = (20, 40)  # the looks at which the bound's sharpness (bound / actual) is reported


def efficiency(folds: list, target: float, sentinels, kind: str = "split") -> dict:
    """How much the rule saves at ``target``, from a setting's fold rows (each with its "stops"
    and "per_m"): "clearly_could" (materials whose true error with the whole plan is <= target / 2),
    "clearly_could_stopped" (of those, how many stopped on the target), "bound_over_actual"
    ({m: median of bound / true error} over every material at m in RATIO_M), "oracle_materials"
    (materials an oracle stops: some batch's true error is <= target), "oracle_samples" and
    "samples_used" (their mean samples: the oracle's at its first such batch, the rule's) and
    "over_oracle" (the ratio). The bound of the per-m rows is the unchecked one for a run without
    sentinels (their "upper_unchecked"), the checked one with them. The per-m rows are of the design the stop rows of ``sentinels``
    measured (for a rig run: the "rig" variant's)."""
    could = stopped = 0
    upper = "upper" if sentinels in (True, "approx", "rig") else "upper_unchecked"
    kinds = {r.get("bound", "split") for f in folds for r in f["stops"] if r.get("sentinels", False) is False}
    upper = f"upper_{kind}" if len(kinds) > 1 and upper == "upper_unchecked" else upper
    used, oracle, ratios = [], [], {m: [] for m in RATIO_M}
    for fold in folds:
        curve = {}
        for r in fold["per_m"]:
            curve.setdefault(r["material"], []).append((r["m"], r["mse"]))
            if r["m"] in ratios and r["mse"] > 0:  # the bound the stop rows used: with the check cells or not
                ratios[r["m"]].append(r[upper] / r["mse"])
        for s in fold["stops"]:
            if s["target"] != target or s.get("sentinels", False) != sentinels or s.get("bound", "split") != kind:
                continue
            path = sorted(curve[s["material"]])
            if path[-1][1] <= target / 2:
                could, stopped = could + 1, stopped + int(s["reached"])
            first = next((m for m, mse in path if mse <= target), None)
            if first is not None:
                oracle.append(first), used.append(s["samples"])
    return {"clearly_could": could, "clearly_could_stopped": stopped,
            # 4 digits: the per-m floats differ by ~1e-6 of themselves with the chunking (float32 blocking)
            "bound_over_actual": {str(m): float(f"{np.median(v):.4g}") if v else None for m, v in ratios.items()},
            "oracle_materials": len(oracle), "oracle_samples": float(np.mean(oracle)) if oracle else None,
            "samples_used": float(np.mean(used)) if used else None,
            "over_oracle": float(np.sum(used) / np.sum(oracle)) if oracle else None}


IDEAL_RHO = (1.5, 2.0, 2.5, 3.5)


def ideal_over_oracle(folds: list, target: float) -> dict:
    """{rho: samples / oracle's} of an ideal rule whose bound is rho x the true error for every
    material (it stops at the first batch where rho x true error <= target; the whole plan when
    none), over the materials the oracle stops (the per-m rows' true errors): what a bound that
    sharp could save at best."""
    used = {rho: 0 for rho in IDEAL_RHO}
    oracle = 0
    for fold in folds:
        curve = {}
        for r in fold["per_m"]:
            curve.setdefault(r["material"], []).append((r["m"], r["mse"]))
        for path in map(sorted, curve.values()):
            first = next((m for m, mse in path if mse <= target), None)
            if first is None:
                continue
            oracle += first
            for rho in IDEAL_RHO:
                used[rho] += next((m for m, mse in path if rho * mse <= target), path[-1][0])
    return {f"{rho:g}": used[rho] / oracle if oracle else None for rho in IDEAL_RHO}


CURVE_M = 20  # the look at which the learning curve reports the spread and the bound's sharpness


def learning_curve(results: dict, stats: dict) -> list[dict]:
    """One row per setting labelled "SETTING n=SIZE" (``folds_of``'s sizes), by size: its
    "training_materials", "folds", "test_materials", the held-out "spread" at m = CURVE_M (the
    standard deviation over the test materials of log(true error / median estimate), without
    check cells), the "training_spread" the model's bound expects there (``bound_scale``, mean
    over the folds), "bound_over_actual" (median at CURVE_M), and of the captures without
    sentinels on the model's own bound, per E: "over_oracle" (samples used / the oracle's),
    "clearly_could" ([stopped, of the materials whose error at the plan's end is <= E / 2]) and
    "coverage" (of those stopped on the target, the fraction whose true error is <= E)."""
    rows = []
    for label, folds in results.items():
        if " n=" not in label:
            continue
        at = [r for f in folds for r in f["per_m"] if r["m"] == CURVE_M and r["mse"] > 0]
        log_ratio = np.log([r["mse"] / r.get("median_unchecked", r["median"]) for r in at])
        own = {k: r for k, r in stats[label]["targets"].items() if r["sentinels"] is False and r["bound"] == "split"}
        expected = [f["bound_scale"][str(CURVE_M)] for f in folds if str(CURVE_M) in f.get("bound_scale", {})]
        rows.append({"setting": label.split(" n=")[0], "training_materials": int(label.split(" n=")[1]),
                     "folds": len(folds), "test_materials": len(at),
                     "spread": float(np.std(log_ratio)) if at else None,
                     "training_spread": float(np.mean(expected)) if expected else None,
                     "bound_over_actual": next(iter(own.values()))["bound_over_actual"].get(str(CURVE_M))
                     if own else None,
                     "over_oracle": {f"{r['target']:g}": r["over_oracle"] for r in own.values()},
                     "clearly_could": {f"{r['target']:g}": [r.get("clearly_could_stopped"), r.get("clearly_could")]
                                       for r in own.values()},
                     "coverage": {f"{r['target']:g}": r.get("within_when_stopped") for r in own.values()}})
    return sorted(rows, key=lambda r: (r["setting"], r["training_materials"]))


def curve_markdown(rows: list[dict]) -> str:
    """The learning curve's table (``learning_curve``), "" without one."""
    if not rows:
        return ""
    targets = sorted({t for r in rows for t in r["over_oracle"]}, key=float)
    lines = ["", f"| setting | training materials | folds x test materials | held-out spread of log(actual / median) "
             f"at m = {CURVE_M} | training's spread at m = {CURVE_M} | bound / actual, median, m = {CURVE_M} | "
             + " | ".join(f"samples used / oracle's, E = {t}" for t in targets) + " | "
             + " | ".join(f"clearly could: stopped, E = {t}" for t in targets) + " | "
             + " | ".join(f"coverage at the stop, E = {t}" for t in targets) + " |",
             "|---|---|---|---|---|---|" + "---|" * 3 * len(targets)]
    num = lambda v: "n/a" if v is None else f"{v:.2f}"  # noqa: E731
    could = lambda v: "n/a" if not v or v[1] is None else f"{v[0]} of {v[1]}"  # noqa: E731
    share = lambda v: "n/a" if v is None else f"{100 * v:.1f} %"  # noqa: E731
    for r in rows:
        lines.append(f"| {r['setting']} | {r['training_materials']} | "
                     f"{r['folds']} x {r['test_materials'] // r['folds']} | {num(r['spread'])} | "
                     f"{num(r['training_spread'])} | {num(r['bound_over_actual'])} | "
                     + " | ".join(num(r["over_oracle"].get(t)) for t in targets) + " | "
                     + " | ".join(could(r.get("clearly_could", {}).get(t)) for t in targets) + " | "
                     + " | ".join(share(r.get("coverage", {}).get(t)) for t in targets) + " |")
    return "\n".join(lines) + "\n"


def _said(sentinels) -> str:
    """The sentinels column: yes / no, or a rig run's variant (no, approx, rig)."""
    return sentinels if isinstance(sentinels, str) else "yes" if sentinels else "no"


def _efficiency_cells(r: dict) -> str:
    """The three efficiency columns of a target's row (``efficiency``)."""
    if "clearly_could" not in r:
        return "n/a | n/a | n/a"
    could = f"{r['clearly_could_stopped']} of {r['clearly_could']}"
    ratio = "; ".join("n/a" if v is None else f"{v:.2f}" for v in r["bound_over_actual"].values())
    oracle = "n/a" if r["over_oracle"] is None else (f"{r['samples_used']:.1f} / {r['oracle_samples']:.1f} = "
                                                     f"{r['over_oracle']:.2f} ({r['oracle_materials']})")
    return f"{could} | {ratio} | {oracle}"


def markdown(stats: dict) -> str:
    lines = ["| setting | E | sentinels; bound | materials | stopped on the target | of those, true error <= E | all: true error <= E "
             "| mean samples / plan | out of the model (any look / at the end) | flagged by the sentinels "
             "| clearly could (end <= E/2): stopped | bound / actual, median at m = 20; 40 "
             "| samples used / oracle's (materials the oracle stops) |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for setting, s in stats.items():
        for r in s["targets"].values():
            within = "n/a" if r["within_when_stopped"] is None else f"{100 * r['within_when_stopped']:.1f} %"
            kind = "" if r.get("bound", "split") == "split" else f"; {r['bound']}"
            lines.append(f"| {setting} | {r['target']:g} | {_said(r.get('sentinels'))}{kind} | {r['materials']} | {r['stopped_on_target']} | {within} | "
                         f"{100 * r['within_all']:.1f} % | {r['mean_samples']:.1f} / {r['plan']} | "
                         f"{r['ever_out']} / {r['out_at_end']} | {r.get('sentinel_flagged', 0)} | "
                         + _efficiency_cells(r) + " |")
    lines += ["", "| setting | m | median estimate within x2 (checked; unchecked) | true error <= bound (checked; "
              "unchecked) | out of the model "
              "| features beyond 95 % of training: of the bound's misses / of the rest "
              "| prequential score beyond 95 % of training: of the misses / of the rest "
              "| sentinels flag: of the misses / of the rest |", "|---|---|---|---|---|---|---|---|"]
    for setting, s in stats.items():
        for m, r in s["by_m"].items():
            lines.append(f"| {setting} | {m} | {100 * r['within_factor_2']:.1f} %; "
                         f"{100 * r.get('within_factor_2_unchecked', r['within_factor_2']):.1f} % | "
                         f"{100 * r['bound_covers']:.1f} %; {100 * r.get('bound_covers_unchecked', r['bound_covers']):.1f} % | "
                         f"{100 * r['out_of_model']:.1f} % | {r['missed_far']} of {r['missed']} / "
                         f"{r['covered_far']} of {r['materials'] - r['missed']} | "
                         f"{r.get('missed_prequential', 0)} of {r['missed']} / "
                         f"{r.get('covered_prequential', 0)} of {r['materials'] - r['missed']} | "
                         f"{r.get('missed_sentinel', 0)} of {r['missed']} / "
                         f"{r.get('covered_sentinel', 0)} of {r['materials'] - r['missed']} |")
    return "\n".join(lines) + "\n"


def joined(docs: list[dict], kinds) -> dict:
    """One document of the rows of ``docs`` (target_error.json contents, runs of disjoint folds):
    every setting's folds in fold order, the stop rows of the bound's ``kinds`` only; the first
    document's other fields, "joined" the commands, "folds" the most of a setting, "wall_s" their
    sum, "load_average" each one's. BadOption on a fold that two of them ran."""
    results = {}
    for doc in docs:
        for setting, folds in doc["results"].items():
            for fold in folds:
                if any(f["fold"] == fold["fold"] for f in results.get(setting, [])):
                    raise BadOption(f"--summarise: expected each fold once, found {setting} "
                                     f"fold {fold['fold']} twice")
                rows = [r for r in fold["stops"] if r.get("bound", "split") in kinds]
                results.setdefault(setting, []).append(fold | {"stops": rows})
    for folds in results.values():
        folds.sort(key=lambda f: f["fold"])
    return docs[0] | {"results": results, "joined": [d["command"] for d in docs],
                      "folds": max(len(folds) for folds in results.values()),
                      "wall_s": sum(d["wall_s"] for d in docs), "load_average": [d["load_average"] for d in docs]}


def resummarise(sources: list[Path], out: Path, kinds=None) -> int:
    """Write OUT/target_error.json and .md from the rows of ``sources`` (target_error.json files
    of disjoint folds, ``joined``; kinds: the bound's kinds kept, None: all)."""
    docs = [json.loads(source.read_text()) for source in sources]
    doc = joined(docs, kinds or confidence.BOUND_KINDS) if len(docs) > 1 or kinds else docs[0]
    plan = next(iter(next(iter(doc["summary"].values()))["targets"].values()))["plan"]
    level = next(iter(doc["summary"].values()))["confidence"]
    doc["summary"] = summary(doc["results"], plan, level)
    doc["learning_curve"] = learning_curve(doc["results"], doc["summary"])
    out.mkdir(parents=True, exist_ok=True)
    (out / "target_error.json").write_text(json.dumps(doc, indent=1))
    text = markdown(doc["summary"]) + curve_markdown(doc["learning_curve"])
    (out / "target_error.md").write_text(text)
    print(text)
    return 0


def main(argv=None) -> int:
    """The command line; 2 and one line on stderr for a bad option (``BadOption``)."""
    try:
        return run(argv)
    except BadOption as error:
        print(f"target_error.py: {error}", file=sys.stderr)
        return 2


def run(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--grid", default="45,45,90", help="NTH,NTD,NPD (default 45,45,90; full: 90,90,180)")
    parser.add_argument("--folds", type=int, default=10, help="folds of the split and builtin settings (default 10)")
    parser.add_argument("--first-fold", type=int, default=0,
                        help="the first fold's number (split, builtin; default 0): "
                             "--folds 5 --first-fold 5 runs 5 ... 9")
    parser.add_argument("--settings", default=",".join(SETTINGS), help=f"comma-separated subset of {','.join(SETTINGS)}")
    parser.add_argument("--m-max", type=int, default=60, help="the plan's samples (default 60)")
    parser.add_argument("--confidence", type=float, default=0.95)
    parser.add_argument("--targets", default=",".join(map(str, TARGETS)))
    parser.add_argument("--rig", type=Path, default=None,
                        help="a rig file: designs among the cells it can measure, and its sentinels placed for it "
                             "against calibrated among its cells (run_rig_fold)")
    parser.add_argument("--camera-noise", action="store_true",
                        help="with --rig: every sample read with the rig camera's noise, relative sd 1 / target_snr, "
                             "seeded by the rig's sim.seed (goniofrost.bench.camera_noise); errors scored on exact values")
    parser.add_argument("--train-sizes", default=None,
                        help="comma-separated numbers of training materials (split, builtin): the learning curve, "
                             "each fold trained on that many of its training materials, tested on its test materials")
    parser.add_argument("--out", type=Path, required=True, help="folder: target_error.json, target_error.md")
    parser.add_argument("--kinds", default=",".join(confidence.BOUND_KINDS),
                        help="the bound's kinds measured (confidence.BOUND_KINDS; default all)")
    parser.add_argument("--summarise", default=None,
                        help="comma-separated target_error.json files written before (runs of disjoint folds): "
                             "their rows joined, the summary and table again (no simulation; the options but "
                             "--out and --kinds, the bound's kinds kept, are ignored)")
    args = parser.parse_args(argv)
    if args.summarise is not None:
        kinds = None if args.kinds == parser.get_default("kinds") else tuple(args.kinds.split(","))
        return resummarise([Path(v) for v in args.summarise.split(",")], args.out, kinds)
    grid = MerlGrid(*(int(v) for v in args.grid.split(",")))
    rig_mask = noise = None
    if args.camera_noise and args.rig is None:
        raise BadOption("--camera-noise: expected --rig (the camera whose noise is simulated), found none")
    if args.rig is not None:
        from goniofrost.rig.file import load_checked_rig
        from planner.reach import reachability

        rig = load_checked_rig(args.rig)
        rig_mask = reachability(rig, grid).mask
        if args.camera_noise:
            noise = (camera_noise.relative_sd(rig.camera), int(rig.sim.get("seed", 0)))
    sizes = None if args.train_sizes is None else [int(v) for v in args.train_sizes.split(",")]
    check_sizes(args.settings.split(","), sizes)
    targets = tuple(float(v) for v in args.targets.split(","))
    global KINDS
    KINDS = tuple(args.kinds.split(","))
    args.out.mkdir(parents=True, exist_ok=True)
    results, started = {}, time.time()
    for setting in args.settings.split(","):
        for label, fold, train, train_names, test, test_names in folds_of(setting, grid, args.folds, args.first_fold,
                                                                         sizes):
            t0 = time.time()
            row = run_fold(train, train_names, test, test_names, grid, args.m_max, args.confidence, targets, rig_mask,
                           noise)
            results.setdefault(label, []).append(row | {"fold": fold, "seconds": time.time() - t0,
                                                        "training_materials": len(train_names)})
            print(f"{label} fold {fold}: {time.time() - t0:.0f} s", file=sys.stderr, flush=True)
            stats = summary(results, args.m_max, args.confidence)
            doc = {"command": " ".join(sys.argv), "grid": grid.as_dict(), "folds": args.folds,
                   "first_fold": args.first_fold, "wall_s": time.time() - started,
                   "load_average": list(__import__("os").getloadavg()),
                   "camera_noise": None if noise is None else {"relative_sd": noise[0], "seed": noise[1]},
                   "summary": stats, "learning_curve": learning_curve(results, stats), "results": results}
            (args.out / "target_error.json").write_text(json.dumps(doc, indent=1))
            (args.out / "target_error.md").write_text(markdown(stats) + curve_markdown(doc["learning_curve"]))
    stats = summary(results, args.m_max, args.confidence)
    print(markdown(stats) + curve_markdown(learning_curve(results, stats)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
