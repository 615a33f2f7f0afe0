"""Camera kinds benchmark: one plan captured on the simulated rig with its simulated camera
(config/rigs/sim.yaml) and with pylon's emulated camera serving the same scene through the vendor
SDK (config/rigs/sim-pylon.yaml) -> median and largest relative error per channel of the
calibrated samples against the ground truth at the directions measured, and the wall time.

Usage (from the repository root; needs the pylon extra, and a model and a plan)::

    .venv/bin/goniofrost plan --model MODEL --samples 20 --rig config/rigs/sim-pylon.yaml --out PLAN.json
    .venv/bin/python benchmarks/camera_kinds.py --plan PLAN.json --out DIR
        [--material nbrdf:../shared/data/nbrdf_merl.npz:gold-metallic-paint2]
        [--rig config/rigs/sim.yaml --rig config/rigs/sim-pylon.yaml]

Times are wall seconds of ``goniofrost capture`` on this machine (the machine is shared: the load
average is printed with them). tests/test_pylon_session.py runs ``sample_errors`` on its small
session.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np
from goniofrost.rig.hardware import SimOptions

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
os.environ.setdefault("PYLON_CAMEMU", "1")  # sim-pylon.yaml's camera is pylon's emulation


def sample_errors(session: Path, rig: Path, plan: Path, material: str) -> dict:
    """Relative errors (3,) per channel of a finished session's samples against the material's BRDF
    at the directions each was measured at: median and max, and the sample count."""
    from goniofrost.capture.inputs import load_inputs
    from goniofrost.capture.journal import Journal
    from goniofrost.app.ground_truth import truth_at_measured_directions
    from goniofrost.datasets import shown_material

    with Journal.open(session / "session.sqlite") as journal:
        records = journal.samples()
    truth = truth_at_measured_directions(load_inputs(rig, plan, None), records, shown_material(material))
    rel = np.abs(np.array([r.rgb for r in records]) - truth) / truth
    return {"samples": len(records), "median_per_channel": np.median(rel, axis=0).round(5).tolist(),
            "max_per_channel": np.max(rel, axis=0).round(5).tolist()}


def smallest_plan(folder: Path, rig: Path) -> Path:
    """A 3-sample plan of a 4-material built-in model on a 30 x 30 x 60 grid (what a test runs)."""
    from goniofrost.app.demo import plan_on_rig
    from goniofrost.core.cache import cache_path
    from goniofrost.plan.make import PlanRequest
    from goniofrost.rig.file import load_checked_rig
    from goniofrost.core.grid import MerlGrid
    from goniofrost.frost.training import train

    model = train(["builtin"], only=["white-diffuse", "blue-plastic", "gold", "green-felt"], grid=MerlGrid(30, 30, 60),
                  k_max=12, cache=True)
    folder.mkdir(parents=True, exist_ok=True)
    request = PlanRequest(samples=3, rig=load_checked_rig(rig))
    return plan_on_rig(model, cache_path("models", model.info["cache_key"], ""), request, folder / "plan.json")


def main(argv=None) -> int:
    from goniofrost.app.ground_truth import GroundTruth
    from goniofrost.capture.inputs import load_inputs
    from goniofrost.capture.options import SessionOptions
    from goniofrost.capture.runner import capture
    from goniofrost.datasets import shown_material
    from goniofrost.rig.simulated import rig_devices

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plan", type=Path, help="required unless --smallest")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--material", default="nbrdf:../shared/data/nbrdf_merl.npz:gold-metallic-paint2")
    parser.add_argument("--rig", type=Path, action="append")
    parser.add_argument("--smallest", action="store_true",
                        help="a 3-sample plan of a small built-in model, builtin:red-plastic (what a test runs)")
    args = parser.parse_args(argv)
    rigs = args.rig or [REPO / "config/rigs/sim.yaml", REPO / "config/rigs/sim-pylon.yaml"]
    if args.smallest:
        args.plan, args.material = smallest_plan(args.out, rigs[-1]), "builtin:red-plastic"
    elif args.plan is None:
        parser.error("--plan PLAN.json is required (or --smallest)")
    results = []
    for rig in rigs:
        session = args.out / rig.stem
        t0 = time.perf_counter()
        shown = shown_material(args.material)
        outcome = capture(load_inputs(rig, args.plan), session, devices=rig_devices, sim=SimOptions(material=shown),
                          options=SessionOptions(progress=False, compare=GroundTruth(shown)))
        wall = time.perf_counter() - t0
        results.append({"rig": str(rig), "wall_s": round(wall, 1), "load_average": os.getloadavg(),
                        "log_relative_mse": outcome.report["ground_truth"]["log_relative_mse"],
                        **sample_errors(session, rig, args.plan, args.material)})
        print(json.dumps(results[-1]))
    (args.out / "camera_kinds.json").write_text(json.dumps(results, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
