"""Scheduling a plan on the simulated rig: poses, capture order and motion times."""
from __future__ import annotations

import copy
import itertools
from pathlib import Path

import numpy as np
import pytest

from goniofrost.core.grid import MerlGrid
from planner.kinematics import forward
from planner.motion import move_time
from planner.order import _best_choice, _pose_matrix, plan_tour
from planner.reach import reachability
from planner.rig import load_rig
from planner.schedule import (UnreachableSampleError, candidate_poses, format_table, pair_angles,
                              schedule_plan)

from conftest import made_once

RIG = load_rig(Path(__file__).resolve().parents[1] / "config" / "rigs" / "sim.yaml")
GRID = MerlGrid(30, 30, 60)


def plan_doc(cells) -> dict:
    """A plan document of the FROST layout (cell, w_i, w_o per sample) in selection order."""
    w_i, w_o = GRID.cell_directions(np.asarray(cells))
    samples = [{"cell": [int(v) for v in GRID.unravel(c)], "w_i": list(map(float, a)), "w_o": list(map(float, b))}
               for c, a, b in zip(cells, w_i, w_o)]
    return {"m": len(samples), "grid": GRID.as_dict(), "samples": samples}


def reachable_cells(m: int, seed: int) -> np.ndarray:
    reach = reachability(RIG, GRID)
    rng = np.random.default_rng(seed)
    return GRID.valid_cells[rng.choice(np.flatnonzero(reach.mask), m, replace=False)]


@pytest.fixture(scope="module", params=[20, 60])
def scheduled(request):
    doc = plan_doc(reachable_cells(request.param, seed=request.param))
    before = copy.deepcopy(doc)
    out = schedule_plan(doc, RIG)
    assert doc == before  # the input document is left unchanged
    return doc, out


def test_order_is_a_permutation_of_the_selection(scheduled):
    doc, out = scheduled
    order = [s["selection_index"] for s in out["samples"]]
    assert sorted(order) == list(range(len(doc["samples"])))
    for s in out["samples"]:
        assert s["cell"] == doc["samples"][s["selection_index"]]["cell"]


def test_planned_joints_stay_in_limits_and_reproduce_their_cells(scheduled):
    doc, out = scheduled
    q = np.array([[s["joints"][n] for n in RIG.joint_names] for s in out["samples"]])
    for j, axis in enumerate(RIG.ordered_axes):
        assert np.all((q[:, j] >= axis.limits_deg[0]) & (q[:, j] <= axis.limits_deg[1])), axis.name
    assert np.all(np.abs(q[:, 2]) <= RIG.geometry.tilt_limit_deg) and np.all(q[:, 0] >= 8.0)
    f_i, f_o = forward(RIG, q)
    swapped = np.array([s["light_camera_swapped"] for s in out["samples"]])
    w_i = np.array([s["w_i"] for s in out["samples"]])
    w_o = np.array([s["w_o"] for s in out["samples"]])
    want = pair_angles(np.where(swapped[:, None], w_o, w_i), np.where(swapped[:, None], w_i, w_o))
    np.testing.assert_allclose(pair_angles(f_i, f_o), want, atol=1e-9)


def test_motion_times_add_up_and_beat_the_selection_order(scheduled):
    _, out = scheduled
    q = [[s["joints"][n] for n in RIG.joint_names] for s in out["samples"]]
    stops = [list(RIG.home)] + q + [list(RIG.home)]
    moves = [float(move_time(RIG, a, b)) for a, b in zip(stops[:-1], stops[1:])]
    np.testing.assert_allclose([s["move_s"] for s in out["samples"]], moves[:-1], rtol=1e-12)
    assert out["return_home_s"] == pytest.approx(moves[-1])
    assert out["planned_motion_s"] == pytest.approx(sum(moves))
    assert out["planned_motion_s"] < out["selection_order_motion_s"]
    assert out["rig"] == {"name": "sim-rig", "file": RIG.source, "kinematic_hash": RIG.kinematic_hash}
    table = format_table(out).splitlines()
    assert len(table) == len(q) + 3 and "selection order" in table[-1]


def test_small_tours_are_optimal_against_brute_force():
    cells = reachable_cells(6, seed=3)
    poses, valid, _ = candidate_poses(RIG, *GRID.cell_directions(cells))
    dist, ids = _pose_matrix(RIG, poses, valid, RIG.home)
    best = min(_best_choice(dist, ids, np.array(p))[1] for p in itertools.permutations(range(6)))
    tour = plan_tour(RIG, poses, valid, RIG.home)
    assert tour.total_s == pytest.approx(best, rel=1e-9)


def test_unreachable_sample_is_refused_with_its_reason():
    reach = reachability(RIG, GRID)
    bad = GRID.valid_cells[np.flatnonzero(reach.reason == 1)[0]]
    doc = plan_doc(np.concatenate([reachable_cells(3, seed=1), [bad]]))
    label = "(%d, %d, %d)" % GRID.unravel(bad)
    with pytest.raises(UnreachableSampleError,
                       match=rf"plan sample 3 \(cell \({label[1:-1]}\)\) cannot be reached on this rig: ARM_SEPARATION"):
        schedule_plan(doc, RIG)


def test_without_reciprocity_the_light_always_plays_w_i():
    out = schedule_plan(plan_doc(reachable_cells(15, seed=7)), RIG, reciprocity=False)
    assert not any(s["light_camera_swapped"] for s in out["samples"])
    assert {s["branch"] for s in out["samples"]} <= {"direct", "mirror"}


@pytest.fixture(scope="module")
def small_model():
    """A FROST model of 12 smooth random materials on the small grid, with its noise model (5-6 s of
    CPU): trained once per test run, its folder shared by the workers (read-only)."""
    from goniofrost.frost.training import TrainingOptions, fit_model

    def train(folder):
        rng = np.random.default_rng(0)
        w_i, w_o = GRID.cell_directions(GRID.valid_cells)
        h = w_i + w_o
        cos_h = h[:, 2] / np.linalg.norm(h, axis=1)
        tables = np.stack([(rng.uniform(0.05, 0.3, 3) + rng.uniform(0, 50) * cos_h[:, None] ** rng.uniform(5, 200))
                           for _ in range(12)]).astype(np.float32)
        fit_model(tables, [f"m{i}" for i in range(12)], GRID, TrainingOptions(k_max=30)).save(folder)

    return made_once("schedule-model", train)


def test_plan_command_with_rig_writes_a_scheduled_plan(small_model, tmp_path, capsys):
    from goniofrost.app.cli import main
    from goniofrost.plan.file import read_plan
    out = tmp_path / "plan.json"
    rig_file = Path(RIG.source)
    assert main(["plan", "--model", str(small_model), "--samples", "12", "--rig", str(rig_file), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    from goniofrost.rig.file import command_steps, load_checked_rig
    rig = load_checked_rig(rig_file)
    # with the camera model: cells measurable at the joints commanded (on the axes' lattices) only
    reach = reachability(rig, GRID, steps=command_steps(rig))
    assert f"{int(reach.mask.sum())} of {GRID.n_valid} valid cells reachable" in printed
    assert f"PATCH_PIXELS {reach.counts()['PATCH_PIXELS']}" in printed and reach.counts()["PATCH_PIXELS"] > 0
    assert "selection order" in printed
    doc = read_plan(out)
    assert doc["rig"]["kinematic_hash"] == RIG.kinematic_hash and len(doc["samples"]) == 12
    assert sorted(s["selection_index"] for s in doc["samples"]) == list(range(12))
    positions = GRID.valid_position([GRID.flat_index(*s["cell"]) for s in doc["samples"]])
    assert np.all(reach.mask[positions])  # only reachable cells were selected
    assert doc["planned_motion_s"] == pytest.approx(sum(s["move_s"] for s in doc["samples"]) + doc["return_home_s"])


def test_plan_command_refuses_a_malformed_rig_and_writes_nothing(small_model, tmp_path, capsys):
    from goniofrost.app.cli import main
    bad = tmp_path / "rig.yaml"
    bad.write_text(Path(RIG.source).read_text().replace("speed_deg_s: 20.0", "speed_deg_s: -20.0"))
    out = tmp_path / "plan.json"
    assert main(["plan", "--model", str(small_model), "--samples", "5", "--rig", str(bad), "--out", str(out)]) == 2
    assert "axes.sample_tilt.speed_deg_s: expected a number in (0, inf], found -20.0" in capsys.readouterr().err
    assert not out.exists()


def test_joints_within_rounding_of_a_limit_are_written_on_it():
    from planner.schedule import clip_to_limits

    lo, hi = RIG.axis("camera_arm").limits_deg
    joints = np.array([[lo - 2e-15, 0.0, 0.0], [hi + 1e-12, 10.0, -5.0], [90.0, 1.0, 2.0]])
    clipped = clip_to_limits(RIG, joints)
    assert clipped[0, 0] == lo and clipped[1, 0] == hi
    np.testing.assert_array_equal(clipped[2], joints[2])


def test_batches_are_ordered_each_on_its_own_and_keep_the_design_order():
    from planner.motion import path_time
    from planner.schedule import schedule_batches

    doc = plan_doc(reachable_cells(22, seed=5))
    out = schedule_batches(doc, RIG, [10, 15, 20, 22])
    assert out["batch_ends"] == [10, 15, 20, 22]
    order = [s["selection_index"] for s in out["samples"]]
    for a, b in ((0, 10), (10, 15), (15, 20), (20, 22)):  # every batch is a permutation of its design block
        assert sorted(order[a:b]) == list(range(a, b))
    q = np.array([[s["joints"][n] for n in RIG.joint_names] for s in out["samples"]])
    moves = path_time(RIG, q, start=RIG.home, end=RIG.home)
    assert out["planned_motion_s"] == pytest.approx(moves.sum()) and out["return_home_s"] == pytest.approx(moves[-1])
    # one batch is exactly schedule_plan
    whole = schedule_batches(doc, RIG, [22])
    assert [s["selection_index"] for s in whole["samples"]] == [s["selection_index"] for s in schedule_plan(doc, RIG)["samples"]]
    with pytest.raises(ValueError, match="batch_ends: expected increasing sample counts ending at 22"):
        schedule_batches(doc, RIG, [10, 30])


def test_plan_command_with_an_alignment_records_it_and_refuses_a_bad_one(small_model, tmp_path, capsys):
    import json
    from goniofrost.app.cli import main
    from goniofrost.plan.file import read_plan
    rig_file, out = str(Path(RIG.source)), tmp_path / "plan.json"
    aligned = tmp_path / "alignment.json"
    aligned.write_text(json.dumps({"offsets_deg": {"camera_arm": 0.6, "sample_yaw": -1.1, "sample_tilt": 0.4}}))
    base = ["plan", "--model", str(small_model), "--samples", "6", "--out", str(out)]
    assert main(base + ["--rig", rig_file, "--alignment", str(aligned)]) == 0
    assert f"rig sim-rig (aligned: {aligned})" in capsys.readouterr().out
    doc = read_plan(out)
    assert doc["alignment"]["offsets_deg"] == {"camera_arm": 0.6, "sample_yaw": -1.1, "sample_tilt": 0.4}
    # the joints are commands: reading + offset reproduces every sample's cell (to the command
    # lattices: each joint within planner.steps.SPAN_DEG + half a step of an aligned IK pose)
    from goniofrost.capture.inputs import check_consistency, plan_cells
    from goniofrost.core.errors import ConfigError
    from goniofrost.rig.file import load_checked_rig
    from goniofrost.frost.model import FrostModel
    rig, grid = load_checked_rig(rig_file, aligned), FrostModel.load(small_model).grid
    check_consistency(doc, out, grid, rig, plan_cells(doc, out, grid))
    with pytest.raises(ConfigError, match=r"samples\[\d\].joints: expected joints within"):
        check_consistency(doc, out, grid, load_checked_rig(rig_file), plan_cells(doc, out, grid))  # not aligned
    out.unlink()
    assert main(base + ["--alignment", str(aligned)]) == 2
    assert "command line: --alignment: expected --rig RIG.yaml as well (an alignment belongs to a rig)" in \
        capsys.readouterr().err
    aligned.write_text(json.dumps({"offsets_deg": {"camera_arm": 0.6}}))
    assert main(base + ["--rig", rig_file, "--alignment", str(aligned)]) == 2
    assert f"{aligned}: offsets_deg.sample_yaw: expected a zero offset in degrees within +-10, found 'nothing'" in \
        capsys.readouterr().err
    assert not out.exists()
