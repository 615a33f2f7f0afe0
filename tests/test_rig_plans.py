"""A rig's plan is a plan its capture accepts: the planner judges what the camera can measure at
the joints it commands (on the axes' command lattices), the capture's input check at the same
joints (issue 51, B1: a 40-sample plan's light at 88.977 deg from the inverse kinematics was at
89.004 deg from its commanded joints, past the lamp's 89, and capture refused the plan)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from goniofrost.app.cli import main
from goniofrost.capture.inputs import load_inputs
from goniofrost.rig.file import command_steps, load_checked_rig
from goniofrost.core.cache import cache_path
from planner.candidates import candidate_poses, measurable_reason
from planner.kinematics import Reason
from planner.steps import on_lattice

from test_session import GRID, session_model

RIG_FILE = Path(__file__).resolve().parents[1] / "config" / "rigs" / "sim.yaml"


@pytest.fixture(scope="module")
def model_folder():
    return cache_path("models", session_model().info["cache_key"], "")


@pytest.mark.parametrize("m", [30, 40, 60, 100, 150, 200])
def test_capture_accepts_every_plan_made_for_its_rig(model_folder, m, tmp_path, capsys):
    plan = tmp_path / "plan.json"
    assert main(["plan", "--model", str(model_folder), "--samples", str(m), "--rig", str(RIG_FILE),
                 "--out", str(plan)]) == 0, capsys.readouterr().err
    inputs = load_inputs(RIG_FILE, plan)   # raises the capture's one-line refusal
    assert len(inputs.samples) >= m


def test_every_cell_the_rig_offers_is_scheduled_onto_joints_the_capture_accepts():
    """The cells of GRID with a pose measurable at its inverse-kinematics joints but not at its
    joints on the command lattices: each is scheduled onto joints the capture's check accepts, or
    refused by the scheduler and left out of the reach map plan selects from (two of the six were
    scheduled with the light past the lamp's 89 deg: LIGHT_GRAZING, the capture's refusal)."""
    from goniofrost.plan.file import sample_entries
    from planner.kinematics import joints_array
    from planner.reach import reachability
    from planner.schedule import UnreachableSampleError, schedule_plan

    rig = load_checked_rig(RIG_FILE)
    steps = command_steps(rig)
    w_i, w_o = GRID.cell_directions(GRID.valid_cells)
    joints, usable, _ = candidate_poses(rig, w_i, w_o)
    rounded = np.full(usable.shape, Reason.OK, dtype=np.uint8)
    rounded[usable] = measurable_reason(rig, on_lattice(joints[usable], steps))
    cells = GRID.valid_cells[(usable & (rounded != Reason.OK)).any(axis=1)]
    assert cells.size == 6
    refused = []
    for cell in cells:
        doc = {"grid": GRID.as_dict(), "samples": sample_entries(GRID, np.array([cell]))}
        try:
            [sample] = schedule_plan(doc, rig, steps=steps)["samples"]
        except UnreachableSampleError:
            refused.append(cell)
            continue
        commanded = joints_array(rig, sample["joints"])
        assert Reason(int(measurable_reason(rig, commanded))) == Reason.OK, (cell, sample["joints"])
    offered = reachability(rig, GRID, steps=steps).mask
    assert refused and not offered[GRID.valid_position(np.array(refused))].any()
    assert offered[GRID.valid_position(np.setdiff1d(cells, refused))].all()
