"""Planner benchmark: reachability of the grid, motion time of planned vs selection order, and the
reconstruction error of rig-restricted FROST against unrestricted FROST on held-out materials.

Usage (from the repository root)::

    .venv/bin/python benchmarks/planner.py [--rig config/rigs/sim.yaml]
        [--dataset nbrdf:../shared/data/nbrdf_merl.npz] [--test-every 5] [--samples 20 60]
        [--repeats 3] [--small] [--out results.json]

Held-out split: every ``--test-every``-th material of the dataset (in its own order) is a test
material, the rest train the model (trained once, then read from the goniofrost cache). Error =
``goniofrost.frost.metrics.log_relative_mse`` of the reconstruction from the exact values at the selected
cells, averaged over the test materials. Timings are medians of ``--repeats`` runs (the machine is
shared, so single timings are noisy).
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from goniofrost.datasets import open_dataset  # noqa: E402
from goniofrost.core.grid import FULL_GRID, MerlGrid  # noqa: E402
from goniofrost.frost.metrics import log_relative_mse  # noqa: E402
from goniofrost.plan.file import plan_document  # noqa: E402
from goniofrost.frost.reconstruction import reconstruct  # noqa: E402
from goniofrost.rig.file import load_checked_rig  # noqa: E402
from goniofrost.frost.selection import select_cells  # noqa: E402
from goniofrost.frost.training import train  # noqa: E402
from planner.kinematics import forward  # noqa: E402
from planner.reach import reachability  # noqa: E402
from planner.schedule import pair_angles, schedule_plan  # noqa: E402


def median_time(func, repeats: int):
    """(median seconds, last result) of ``repeats`` calls."""
    times, result = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        result = func()
        times.append(time.perf_counter() - start)
    return statistics.median(times), result


def test_error(model, tables: np.ndarray, positions: np.ndarray) -> float:
    """Mean log-relative MSE over test materials reconstructed from their values at ``positions``."""
    errors = [log_relative_mse(model, t, reconstruct(model, positions, t[positions].astype(np.float64)))
              for t in tables]
    return float(np.mean(errors))


def reproduction_error_deg(rig, doc) -> float:
    """Largest miss (deg) of theta_i, theta_o, angle(w_i, w_o) of the planned joints."""
    q = np.array([[s["joints"][n] for n in rig.joint_names] for s in doc["samples"]])
    swap = np.array([s["light_camera_swapped"] for s in doc["samples"]])[:, None]
    w_i, w_o = (np.array([s[k] for s in doc["samples"]]) for k in ("w_i", "w_o"))
    want = pair_angles(np.where(swap, w_o, w_i), np.where(swap, w_i, w_o))
    return float(np.abs(pair_angles(*forward(rig, q)) - want).max())


def run_m(args, rig, model, reach, tables, m: int) -> dict:
    free = select_cells(model, m)
    rigged = select_cells(model, m, candidates=reach.mask)
    doc = plan_document("benchmark-model", model, rigged)
    sched_s, planned = median_time(lambda: schedule_plan(doc, rig), args.repeats)
    return {
        "m": m,
        "selection_order_motion_s": planned["selection_order_motion_s"],
        "planned_motion_s": planned["planned_motion_s"],
        "motion_saving": 1.0 - planned["planned_motion_s"] / planned["selection_order_motion_s"],
        "schedule_seconds_median": sched_s,
        "light_camera_swapped": sum(s["light_camera_swapped"] for s in planned["samples"]),
        "mirror_branch": sum(s["branch"] == "mirror" for s in planned["samples"]),
        "reproduction_error_deg": reproduction_error_deg(rig, planned),
        "unrestricted_cells_unreachable": int((~reach.mask[free.positions]).sum()),
        "test_error_unrestricted": test_error(model, tables, free.positions),
        "test_error_rig": test_error(model, tables, rigged.positions),
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rig", default=str(REPO / "config" / "rigs" / "sim.yaml"))
    parser.add_argument("--dataset", default=f"nbrdf:{REPO.parent / 'shared' / 'data' / 'nbrdf_merl.npz'}")
    parser.add_argument("--test-every", type=int, default=5)
    parser.add_argument("--samples", type=int, nargs="+", default=[20, 60])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--small", action="store_true", help="use MerlGrid(30, 30, 60) (quick check)")
    parser.add_argument("--out", help="write the results as JSON here")
    args = parser.parse_args(argv)
    grid = MerlGrid(30, 30, 60) if args.small else FULL_GRID
    rig = load_checked_rig(args.rig)
    grid.valid_cells  # noqa: B018 - build the grid's cell list outside the timing
    reach_s, reach = median_time(lambda: reachability(rig, grid, use_cache=False), args.repeats)
    results = {"rig": rig.name, "grid": grid.as_dict(), "n_valid": grid.n_valid,
               "reachable": int(reach.mask.sum()), "reachable_fraction": reach.fraction,
               "reasons": reach.counts(), "reachability_seconds_median": reach_s}
    print(json.dumps(results, indent=1), flush=True)
    dataset = open_dataset(args.dataset)
    names = dataset.names()
    test_names = names[::args.test_every]
    model = train([args.dataset], exclude=test_names, grid=grid, progress=True)
    tables = dataset.tabulate(test_names, grid)
    results.update(dataset=args.dataset, n_train=len(names) - len(test_names), n_test=len(test_names),
                   runs=[run_m(args, rig, model, reach, tables, m) for m in args.samples])
    print(json.dumps(results["runs"], indent=1))
    if args.out:
        Path(args.out).write_text(json.dumps(results, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
