"""Joint targets on the axes' command lattices (``planner.steps``) against the IK joints as the
devices round them: the reconstruction error of samples taken where the rig really points.

A Dynamixel servo goes to whole counts (0.088 deg), a Modbus drive to whole steps: a plan's IK
joints are rounded by the devices, and the direction measured differs from the cell's. On the same
selection and tour the joints are: the IK joints as the devices round them (``rounded``:
``on_lattice``), on the lattices closest to the cells in the grid's index space (``index``:
``on_steps``'s default metric), and what ``plan`` does (``on_steps``: each axis's miss weighed by
the model's expected change there, ``frost.cell_sensitivity``). Per test material, the posterior mean
(``reconstruct_bayes``) from the material's exact values at the directions forward(joints)
reaches, assigned to the plan's cells, is compared with the same from the cells' own values
("exact": what no positioning error can beat): log-relative MSE over the whole grid.

Models and test materials (``--setting``): ``split`` (the default): the 151 materials of
``--data`` (../shared/data: 100 MERL and 51 RGL, sorted by name) in ``--folds`` folds (fold k:
names[k::folds]), each fold's materials tested on a model trained on the others, so every
material is tested once on a model that never saw it; ``builtin``: the built-in library without
red-plastic (the demo's model) tested on all 151 (a model that fits measured materials poorly:
there the samples' exact cell values are no better than nearby ones). Plan: per model, the
Bayesian design of ``--samples`` (default 40) among the cells the rig reaches, with the sentinels,
on ``--rig`` (default config/rigs/sim.yaml). The time of ``on_steps`` is the median of ``--repeats``.

    .venv/bin/python benchmarks/command_steps.py --out /tmp/steps.json
    .venv/bin/python benchmarks/command_steps.py --setting builtin --out /tmp/steps-builtin.json
    .venv/bin/python benchmarks/command_steps.py --smallest --out /tmp/steps-small.json   # a test runs it
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
SHARED = REPO.parent / "shared" / "data"
# --smallest trains on every third built-in material (25 of 74, neither test material; k = 18): a run
# of the code path, not a result. 25 held-out materials are enough for the sentinel check at 0.95
# (19 are needed), so its plan has the sentinels and check cells; the library without red-plastic
# took 31 s of its 35 s.
SMALLEST_EVERY = 3


def parse(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--rig", type=Path, default=REPO / "config" / "rigs" / "sim.yaml")
    p.add_argument("--data", type=Path, default=SHARED)
    p.add_argument("--samples", type=int, default=40)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--setting", choices=("split", "builtin"), default="split")
    p.add_argument("--folds", type=int, default=7)
    p.add_argument("--smallest", action="store_true", help="30 x 30 x 60 grid, a model of every third built-in material, 6 samples, 2 built-in test materials")
    return p.parse_args(argv)


def settings(args, grid):
    """[(model, test material specs)]: one per fold of the split, or the built-in model's."""
    from goniofrost.app.demo import train_without
    from goniofrost.bench.data import material_names
    from goniofrost.frost.training import train

    if args.smallest:
        from goniofrost.datasets import open_dataset

        names = open_dataset("builtin").names()[::SMALLEST_EVERY]
        assert not {"gold", "red-plastic"} & set(names)
        return [(lambda: train(["builtin"], only=names, grid=grid, k_max=18, cache=True),
                 ["builtin:gold", "builtin:red-plastic"])]
    if args.setting == "builtin":
        tests = [f"{spec}:{name}" for spec, name in material_names(_shared(args))]
        return [(lambda: train_without("red-plastic", grid, False)[0], tests)]
    pairs = sorted(material_names(_shared(args)), key=lambda p: p[1])
    names = [n for _, n in pairs]
    out = []
    for k in range(args.folds):
        held = names[k::args.folds]
        out.append((lambda held=held: train(_shared(args), only=[n for n in names if n not in held], grid=grid,
                                            cache=True),
                    [f"{spec}:{name}" for spec, name in pairs if name in held]))
    return out


def _shared(args) -> list[str]:
    return [f"nbrdf:{args.data / name}" for name in ("nbrdf_merl.npz", "nbrdf_rgl.npz")]


def scheduled_joints(rig, model, m: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, list]:
    """(IK joints, cells (n, 3), positions (n,)) of the plan in capture order, and the steps."""
    from goniofrost.plan.file import plan_document, with_sentinels
    from goniofrost.rig.file import command_steps
    from goniofrost.frost.bayes_selection import select_bayes
    from planner.reach import reachability
    from planner.schedule import schedule_batches

    reach = reachability(rig, model.grid).mask
    selection = select_bayes(model, m, candidates=reach)
    doc, _ = with_sentinels(plan_document("model", model, selection), model, selection.positions, reach)
    plain = schedule_batches(doc, rig, doc["batch_ends"])
    joints = np.array([[s["joints"][n] for n in rig.joint_names] for s in plain["samples"]])
    cells = np.array([s["cell"] for s in plain["samples"]])
    positions = model.grid.valid_position(model.grid.flat_index(*cells.T))
    return joints, cells, positions, command_steps(rig)


def errors(model, spec: str, positions, directions: dict) -> dict:
    """{name: log-relative MSE} of the reconstruction from ``spec``'s values at each key's
    (w_i, w_o) (each (n, 3)), and "exact" from its values at the cells."""
    from goniofrost.datasets import material_brdf, parse_material_spec
    from goniofrost.frost.metrics import log_relative_mse
    from goniofrost.frost.reconstruction import reconstruct_bayes

    dataset, name = parse_material_spec(spec)
    truth = dataset.tabulate([name], model.grid)[0].astype(np.float64)
    brdf = material_brdf(spec)[1]
    values = {key: np.asarray(brdf(*w), dtype=np.float64).reshape(-1, 3) for key, w in directions.items()}
    values["exact"] = truth[positions]
    return {key: float(log_relative_mse(model, truth, reconstruct_bayes(model, positions, v, with_std=False).brdf))
            for key, v in values.items()}


def main(argv=None) -> int:
    from goniofrost.rig.file import load_checked_rig
    from goniofrost.core.grid import FULL_GRID, MerlGrid

    args = parse(argv)
    grid = MerlGrid(30, 30, 60) if args.smallest else FULL_GRID
    m = 6 if args.smallest else args.samples
    t0 = time.perf_counter()
    rig = load_checked_rig(args.rig)
    rows, folds = [], []
    for k, (model_of, specs) in enumerate(settings(args, grid)):
        model = model_of()
        fold, fold_rows = one_model(rig, model, m, specs, args.repeats)
        folds.append(fold)
        rows += fold_rows
        print(f"model {k + 1}: {fold['samples']} samples, {len(specs)} test materials; on_steps "
              f"{statistics.median(fold['on_steps_s']) * 1e3:.1f} ms (median of {args.repeats}); index-space miss "
              f"median / max: rounded {np.median(fold['miss']['rounded']):.3f} / {max(fold['miss']['rounded']):.3f}, "
              f"on_steps {np.median(fold['miss']['on_steps']):.3f} / {max(fold['miss']['on_steps']):.3f} "
              f"({time.perf_counter() - t0:.0f} s)", flush=True)
    summary = summarise(rows)
    print(json.dumps(summary, indent=1))
    args.out.write_text(json.dumps({"rig": str(args.rig), "setting": "smallest" if args.smallest else args.setting,
                                    "steps_deg": folds[0]["steps_deg"], "samples": folds[0]["samples"],
                                    "models": folds, "summary": summary, "rows": rows}, indent=1))
    print(f"total {time.perf_counter() - t0:.0f} s")
    return 0


def one_model(rig, model, m: int, specs: list[str], repeats: int) -> tuple[dict, list[dict]]:
    """The plan of ``model`` on ``rig``, its joints both ways, and every test material's errors."""
    from goniofrost.frost.cell_sensitivity import axis_weights
    from planner.kinematics import forward
    from planner.steps import cell_miss, on_lattice, on_steps

    ik, cells, positions, steps = scheduled_joints(rig, model, m)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        stepped = on_steps(rig, model.grid, ik, cells, steps, axis_weights(model, cells))
        times.append(time.perf_counter() - start)
    rounded, index = on_lattice(ik, steps), on_steps(rig, model.grid, ik, cells, steps)
    miss = {key: np.sqrt(cell_miss(rig, model.grid, q, cells)).tolist()
            for key, q in (("rounded", rounded), ("index", index), ("on_steps", stepped))}
    directions = {key: forward(rig, q) for key, q in (("rounded", rounded), ("index", index), ("on_steps", stepped))}
    rows = [{"material": spec.rsplit(":", 1)[-1], "spec": spec, **errors(model, spec, positions, directions)}
            for spec in specs]
    return {"samples": len(ik), "steps_deg": steps, "on_steps_s": times, "miss": miss}, rows


def summarise(rows: list[dict]) -> dict:
    """Medians and means over the materials of each error, of its ratio to exact and of the lattice
    joints' errors to the rounded ones' (how many improved)."""
    out = {"materials": len(rows)}
    for key in ("rounded", "index", "on_steps", "exact"):
        out[f"median_{key}"] = float(np.median([r[key] for r in rows]))
        out[f"mean_{key}"] = float(np.mean([r[key] for r in rows]))
    for key in ("rounded", "index", "on_steps"):
        ratio = np.array([r[key] / r["exact"] for r in rows])
        out[f"{key}_over_exact"] = {"median": float(np.median(ratio)), "p90": float(np.percentile(ratio, 90)),
                                    "max": float(ratio.max())}
    for key in ("index", "on_steps"):
        change = np.array([r[key] / r["rounded"] for r in rows])
        out[f"{key}_over_rounded"] = {"median": float(np.median(change)), "min": float(change.min()),
                                      "max": float(change.max()), "better": int((change < 1).sum()),
                                      "worse_by_over_1pct": int((change > 1.01).sum())}
    return out


if __name__ == "__main__":
    sys.exit(main())
