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

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
os.environ.setdefault("PYLON_CAMEMU", "1")  # sim-pylon.yaml's camera is pylon's emulation


def sample_errors(session: Path, rig: Path, plan: Path, material: str) -> dict:
    """Relative errors (3,) per channel of a finished session's samples against the material's BRDF
    at the directions each was measured at: median and max, and the sample count."""
    from goniofrost.capture.inputs import load_inputs
    from goniofrost.capture.journal import Journal
    from goniofrost.capture.report import truth_at_measured_directions

    with Journal.open(session / "session.sqlite") as journal:
        records = journal.samples()
    truth = truth_at_measured_directions(load_inputs(rig, plan, None), records, material)
    rel = np.abs(np.array([r.rgb for r in records]) - truth) / truth
    return {"samples": len(records), "median_per_channel": np.median(rel, axis=0).round(5).tolist(),
            "max_per_channel": np.max(rel, axis=0).round(5).tolist()}


def main(argv=None) -> int:
    from goniofrost.capture.runner import capture

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plan", type=Path, required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--material", default="nbrdf:../shared/data/nbrdf_merl.npz:gold-metallic-paint2")
    parser.add_argument("--rig", type=Path, action="append")
    args = parser.parse_args(argv)
    rigs = args.rig or [REPO / "config/rigs/sim.yaml", REPO / "config/rigs/sim-pylon.yaml"]
    results = []
    for rig in rigs:
        session = args.out / rig.stem
        t0 = time.perf_counter()
        outcome = capture(rig, args.plan, session, material=args.material, progress=False)
        wall = time.perf_counter() - t0
        results.append({"rig": str(rig), "wall_s": round(wall, 1), "load_average": os.getloadavg(),
                        "log_relative_mse": outcome.report["ground_truth"]["log_relative_mse"],
                        **sample_errors(session, rig, args.plan, args.material)})
        print(json.dumps(results[-1]))
    (args.out / "camera_kinds.json").write_text(json.dumps(results, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
