"""Expected rig time of a scheduled plan: each sample's planned move and expected exposure bracket.

Kept apart from PLAN.json's layout (``plan_file``) so that plan-making can move as a whole.
"""
from __future__ import annotations

import numpy as np

from goniofrost.frost.rig_cost import cell_costs, rig_camera, rig_sensor


def with_expected_times(doc: dict, model, rig, objective: str) -> dict:
    """The scheduled plan ``doc`` with, per sample, ``expected_move_s`` (its planned move, s) and
    ``expected_exposure_s`` (the bracket expected from the model's prior at its cell and pose,
    ``frost.rig_cost``), and at the top ``objective`` ("time" | "samples") and
    ``expected_rig_s`` {"motion", "exposure", "total"} (s; motion with the return home)."""
    samples = doc["samples"]
    rows = model.grid.valid_position(model.grid.flat_index(*np.array([s["cell"] for s in samples]).T))
    fixed = cell_costs(model, rig, rows, rig_camera(rig), rig_sensor(rig)).fixed_s
    out = []
    for i, s in enumerate(samples):
        candidate = 2 * int(s["light_camera_swapped"]) + (s["branch"] == "mirror")
        out.append(s | {"expected_move_s": float(s["move_s"]), "expected_exposure_s": float(fixed[i, candidate])})
    exposure = float(sum(s["expected_exposure_s"] for s in out))
    motion = float(doc["planned_motion_s"])
    return doc | {"samples": out, "objective": objective,
                  "expected_rig_s": {"motion": motion, "exposure": exposure, "total": motion + exposure}}
