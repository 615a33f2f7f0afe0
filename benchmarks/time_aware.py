"""Rig time to a stated-confidence target: the time-aware design against the sample-count design.

For every fold a model is trained on the fold's training materials as ``train --rig`` trains it
(inner designs among the rig's cells), and two nested designs of ``--m-max`` cells are made among
the cells the rig measures, as ``plan --rig`` makes them: ``samples`` (today's: the largest error
reduction per sample) and ``time`` (per second of rig time, ``frost.time_design``, with
``--overhead`` seconds per sample in the score). Every test material is measured along each in
batches until the calibrated bound at 95 % confidence is at most E and the samples are in the
model, or the plan is used up (``bench.bayes_eval.target_outcomes``: exact sample values), and its
rig time on the simulated rig's clock up to that batch is ``bench.rig_clock``'s: motion (each
batch ordered for least motion, the axes' trapezoids) plus exposure brackets (the adaptive rule on
the material's true values). Reported per setting, E and design: median and 90th percentile of
rig time (and of the limit: the exposures alone, zero motion), samples, coverage (of the captures
that stopped on the target, the fraction whose true error is <= E) and median final error.

Settings: ``split`` (MERL + RGL, the benchmark's random 131 / 20 folds) and ``builtin`` (the
analytic library, 64 / 10). Smallest setting (what tests/test_benchmarks.py runs, marked slow)::

    .venv/bin/python benchmarks/time_aware.py --grid 10,10,20 --folds 1 --settings builtin --m-max 20 \\
        --out /tmp/time-small
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from goniofrost.bench import bayes_eval, rig_clock  # noqa: E402
from goniofrost.core.grid import MerlGrid  # noqa: E402

TARGETS = (0.02, 0.05)
DESIGNS = ("samples", "time")
CHUNK = 20


def designs_of(model, mask, rig, m_max: int, variants, retrain=None) -> dict:
    """{design name: (positions (m_max,) int64, selection wall seconds, the model)}: "samples", and
    "time" (one variant (overhead, share)) or "time@X/Y" for each overhead X and share Y; each
    time-aware design on ``retrain(objective)``'s model (trained with time-aware inner designs),
    or on ``model`` when ``retrain`` is None."""
    from goniofrost.frost.bayes_selection import select_bayes
    from goniofrost.frost.time_design import TimeObjective

    out = {}
    named = {"samples": None} | ({"time": variants[0]} if len(variants) == 1 else
                                 {f"time@{x:g}/{y:g}": (x, y) for x, y in variants})
    for name, variant in named.items():
        objective = None if variant is None else TimeObjective(rig, variant[0], share=variant[1])
        own = model if objective is None or retrain is None else retrain(objective)
        t0 = time.perf_counter()
        positions = select_bayes(own, m_max, candidates=mask, time_objective=objective).positions
        out[name] = (np.asarray(positions, np.int64), time.perf_counter() - t0, own)
    return out


def run_fold(train, train_names, test, test_names, grid, rig, mask, m_max, targets, variants,
             calibrate: str = "samples") -> dict:
    """Train as ``train --rig``, make both designs, and simulate every test material at every target;
    calibrate "time": each time-aware design's model trained with its objective's inner designs."""
    from goniofrost.frost.training import TrainingOptions, fit_model

    train = np.asarray(train)
    model = fit_model(train, train_names, grid, TrainingOptions(k_max=60, sentinel_candidates=mask))
    retrain = None if calibrate == "samples" else (
        lambda objective: fit_model(train, train_names, grid,
                                    TrainingOptions(k_max=60, sentinel_candidates=mask, rig_time=objective)))
    designs = designs_of(model, mask, rig, m_max, variants, retrain)
    rows = []
    for lo in range(0, len(test_names), CHUNK):
        truth = np.asarray(test[lo:lo + CHUNK], dtype=np.float64)
        for name, (positions, _, model) in designs.items():
            truth_log = model.to_log(truth)
            clock = rig_clock.design_times(rig, grid, grid.valid_cells[positions], truth[:, positions])
            for target in targets:
                out = bayes_eval.target_outcomes(model, positions, truth, truth_log, target)
                rows += _rows(name, target, out, clock, test_names[lo:lo + CHUNK])
    return {"rows": rows, "selection_s": {name: s for name, (_, s, _) in designs.items()},
            "cells": {name: grid.valid_cells[p].tolist() for name, (p, _, _) in designs.items()}}


def _rows(design: str, target: float, out: dict, clock: dict, names) -> list[dict]:
    """One row per material: its stop and the rig time up to it."""
    rows = []
    for i, name in enumerate(names):
        at = int(np.searchsorted(clock["ends"], out["samples"][i]))
        motion, exposure = float(clock["motion"][at]), float(clock["exposure"][i, at])
        rows.append({"material": name, "design": design, "target": target, "samples": int(out["samples"][i]),
                     "reached": int(out["reached"][i]), "mse": float(out["mse"][i]), "motion_s": motion,
                     "exposure_s": exposure, "time_s": motion + exposure, "ever_out": int(out["ever_out"][i]),
                     "out_of_model": int(out["out_of_model"][i])})
    return rows


def summary(results: dict) -> dict:
    """Per setting, target and design: times, limit, samples, coverage and median final error."""
    out = {}
    for setting, folds in results.items():
        rows = [r for f in folds for r in f["rows"]]
        table = {}
        for target in sorted({r["target"] for r in rows}):
            for design in dict.fromkeys(r["design"] for r in rows):
                group = [r for r in rows if r["target"] == target and r["design"] == design]
                if not group:
                    continue
                hit = [r for r in group if r["reached"]]
                t = np.array([r["time_s"] for r in group])
                limit = np.array([r["exposure_s"] for r in group])
                table[f"{target:g} {design}"] = {
                    "target": target, "design": design, "materials": len(group), "stopped_on_target": len(hit),
                    "time_median_s": float(np.median(t)), "time_p90_s": float(np.percentile(t, 90)),
                    "limit_median_s": float(np.median(limit)), "limit_p90_s": float(np.percentile(limit, 90)),
                    "motion_median_s": float(np.median([r["motion_s"] for r in group])),
                    "samples_median": float(np.median([r["samples"] for r in group])),
                    "coverage": float(np.mean([r["mse"] <= target for r in hit])) if hit else None,
                    "within_all": float(np.mean([r["mse"] <= target for r in group])),
                    "final_error_median": float(np.median([r["mse"] for r in group])),
                    "ever_out": int(sum(r.get("ever_out", 0) for r in group))}
        out[setting] = table
    return out


def markdown(stats: dict) -> str:
    lines = ["| setting | E | design | materials | stopped on E | coverage | rig time median / p90 (s) | "
             "limit: exposures alone, median / p90 (s) | motion median (s) | samples median | median final error | "
             "out of the model at some look |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for setting, table in stats.items():
        for r in table.values():
            cov = "n/a" if r["coverage"] is None else f"{100 * r['coverage']:.1f} %"
            lines.append(f"| {setting} | {r['target']:g} | {r['design']} | {r['materials']} | {r['stopped_on_target']} "
                         f"| {cov} | {r['time_median_s']:.1f} / {r['time_p90_s']:.1f} | {r['limit_median_s']:.2f} / "
                         f"{r['limit_p90_s']:.2f} | {r['motion_median_s']:.1f} | {r['samples_median']:g} | "
                         f"{r['final_error_median']:.4f} | {r.get('ever_out', 0)} |")
    return "\n".join(lines) + "\n"


def _inner(folds):
    """The first fold's training materials split in two: every 7th held out (tuning)."""
    _, train, names, _, _ = next(iter(folds))
    held = np.arange(len(names)) % 7 == 3
    train = np.asarray(train)
    yield 0, train[~held], [n for n, h in zip(names, held) if not h], train[held], [n for n, h in zip(names, held) if h]


def _folds_of():
    """target_error.folds_of (benchmarks/ is not a package, and its planner.py would shadow ours)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("target_error", REPO / "benchmarks" / "target_error.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    # the shared data: $GONIOFROST_SHARED_DATA (as the tests read it), else beside the checkout
    data = Path(os.environ.get("GONIOFROST_SHARED_DATA", module.DATA))
    module.MERL, module.RGL = f"nbrdf:{data / 'nbrdf_merl.npz'}", f"nbrdf:{data / 'nbrdf_rgl.npz'}"
    return module.folds_of


def main(argv=None) -> int:
    folds_of = _folds_of()
    from goniofrost.rig.file import load_checked_rig
    from planner.reach import reachability

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--grid", default="45,45,90", help="NTH,NTD,NPD (default 45,45,90; full: 90,90,180)")
    parser.add_argument("--folds", type=int, default=10, help="folds of each setting (default 10)")
    parser.add_argument("--settings", default="split,builtin", help="comma-separated subset of split,builtin")
    parser.add_argument("--m-max", type=int, default=60, help="the plans' samples (default 60)")
    parser.add_argument("--targets", default=",".join(map(str, TARGETS)))
    parser.add_argument("--overhead", default=None,
                        help="seconds per sample in the time-aware score (default time_design.OVERHEAD_S); several "
                             "(comma-separated): one design each with each share")
    parser.add_argument("--share", default=None,
                        help="the share of each step's largest error reduction a time-aware pick must reach (default "
                             "time_design.SHARE); several (comma-separated): one design each with each overhead")
    parser.add_argument("--variants", default=None,
                        help="instead of every overhead with every share: these pairs OVERHEAD/SHARE (comma-separated)")
    parser.add_argument("--tune", action="store_true",
                        help="choose the overhead on training materials only: the first fold's training materials of "
                             "each setting, every 7th held out (the reported materials are never seen)")
    parser.add_argument("--calibrate", choices=("samples", "time"), default="samples",
                        help="the inner designs the time-aware design's model is calibrated on: samples (the "
                             "sample-count design's model, as train --rig) or time (a model trained with the "
                             "time-aware inner designs of the same overhead and share)")
    parser.add_argument("--rig", type=Path, default=REPO / "config" / "rigs" / "sim.yaml")
    parser.add_argument("--out", type=Path, required=True, help="folder: time_aware.json, time_aware.md")
    args = parser.parse_args(argv)
    from goniofrost.frost.time_design import OVERHEAD_S, SHARE

    overheads = [OVERHEAD_S] if args.overhead is None else [float(v) for v in args.overhead.split(",")]
    shares = [SHARE] if args.share is None else [float(v) for v in args.share.split(",")]
    variants = [(x, y) for x in overheads for y in shares] if args.variants is None else [
        tuple(float(v) for v in pair.split("/")) for pair in args.variants.split(",")]
    grid = MerlGrid(*(int(v) for v in args.grid.split(",")))
    rig = load_checked_rig(args.rig)
    mask = reachability(rig, grid).mask
    targets = tuple(float(v) for v in args.targets.split(","))
    args.out.mkdir(parents=True, exist_ok=True)
    results, started = {}, time.time()
    for setting in args.settings.split(","):
        results[setting] = []
        folds = folds_of(setting, grid, args.folds)
        for fold, train, train_names, test, test_names in (_inner(folds) if args.tune else folds):
            t0 = time.time()
            row = run_fold(train, train_names, test, test_names, grid, rig, mask, args.m_max, targets, variants,
                           args.calibrate)
            results[setting].append(row | {"fold": fold, "seconds": time.time() - t0})
            print(f"{setting} fold {fold}: {time.time() - t0:.0f} s", file=sys.stderr, flush=True)
            stats = summary(results)
            doc = {"command": " ".join(sys.argv), "grid": grid.as_dict(), "folds": args.folds, "m_max": args.m_max,
                   "variants": variants, "tune": args.tune,
                   "calibrate": args.calibrate, "rig": str(args.rig), "wall_s": time.time() - started,
                   "load_average": list(os.getloadavg()), "summary": stats, "results": results}
            (args.out / "time_aware.json").write_text(json.dumps(doc, indent=1))
            (args.out / "time_aware.md").write_text(markdown(stats))
    print(markdown(summary(results)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
