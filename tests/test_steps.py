"""Joint targets on the axes' command lattices (planner.steps) and the steps the drivers command."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from drivers.config import command_step_deg
from goniofrost.core.grid import MerlGrid
from planner.kinematics import inverse
from planner.rig import load_rig
from planner.schedule import schedule_plan
from planner.steps import cell_miss, on_lattice, on_steps

SIM = Path(__file__).resolve().parents[1] / "config" / "rigs" / "sim.yaml"
RIG = load_rig(SIM)
GRID = MerlGrid()
SIM_STEPS = [command_step_deg(RIG.axes[name].driver) for name in RIG.joint_names]
# A sentinel of the shared model's plan on sim.yaml and two cells near the specular peak
CELLS = np.array([[0, 86, 0], [2, 22, 16], [6, 82, 124], [52, 6, 28]])


def ik_joints(cells: np.ndarray) -> np.ndarray:
    ik = inverse(RIG, *GRID.cell_directions(GRID.flat_index(*cells.T)))
    return ik.joints[np.arange(len(cells)), np.argmax(ik.valid, axis=1)]


def test_the_drivers_command_steps():
    assert SIM_STEPS == [0.01, 360 / 4096, 0.0]  # Modbus 100 steps/deg, Dynamixel 4096 counts a turn, SMC100
    assert command_step_deg({"protocol": "dynamixel", "counts_per_deg": 4096 / 360}) == 0.087890625


def test_on_lattice_rounds_as_the_devices_do():
    q = on_lattice(np.array([30.004, 10.05, 5.123456]), SIM_STEPS)
    assert np.allclose(q, [30.0, 10.01953125, 5.123456], rtol=0, atol=1e-12)


def test_joints_on_the_lattices_land_on_their_cells_where_plain_rounding_misses():
    """Rounded onto the lattices, the IK joints of (0, 86, 0) read theta_h's index 1.97: the peak is
    read two cells away. On the lattices' best joints it is below 0.5 (the arm's 0.01 deg steps
    leave the half vector up to 0.0025 deg off the normal), and no cell ends farther than rounding."""
    ik = ik_joints(CELLS)
    plain = on_lattice(ik, SIM_STEPS)
    best = on_steps(RIG, GRID, ik, CELLS, SIM_STEPS)
    assert np.allclose(best, on_lattice(best, SIM_STEPS), rtol=0, atol=1e-9)        # what the devices keep
    assert np.all(np.abs(best - ik) < 0.2)
    miss_plain, miss_best = cell_miss(RIG, GRID, plain, CELLS), cell_miss(RIG, GRID, best, CELLS)
    assert np.all(miss_best <= miss_plain)
    assert 1.9 < np.sqrt(miss_plain[0]) < 2.0 and np.sqrt(miss_best[0]) < 0.5
    assert np.all(np.sqrt(miss_best[1:]) < 0.05)


def test_continuous_axes_keep_the_ik_joints_exactly_on_their_cells():
    ik = ik_joints(CELLS)
    assert np.all(cell_miss(RIG, GRID, ik, CELLS) < 1e-12)
    best = on_steps(RIG, GRID, ik, CELLS, [0.0, 0.0, 0.0])
    assert np.all(cell_miss(RIG, GRID, best, CELLS) < 1e-12)


def test_the_scheduled_plan_records_its_steps_and_puts_its_joints_on_them():
    doc = {"grid": GRID.as_dict(), "samples": [{"cell": [int(c) for c in cell]} for cell in CELLS]}
    plain, stepped = schedule_plan(doc, RIG, restarts=1), schedule_plan(doc, RIG, restarts=1, steps=SIM_STEPS)
    assert "command_steps_deg" not in plain["rig"] and stepped["rig"]["command_steps_deg"] == SIM_STEPS
    assert [s["selection_index"] for s in stepped["samples"]] == [s["selection_index"] for s in plain["samples"]]
    joints = np.array([[s["joints"][n] for n in RIG.joint_names] for s in stepped["samples"]])
    cells = CELLS[[s["selection_index"] for s in stepped["samples"]]]
    assert np.allclose(joints, on_lattice(joints, SIM_STEPS), rtol=0, atol=1e-9)
    assert np.all(cell_miss(RIG, GRID, joints, cells) <= cell_miss(RIG, GRID, on_lattice(
        np.array([[s["joints"][n] for n in RIG.joint_names] for s in plain["samples"]]), SIM_STEPS), cells))


def test_the_benchmark_at_its_smallest_compares_both_with_exact_values(tmp_path, monkeypatch):
    """``benchmarks/command_steps.py --smallest``: 12 samples, 2 built-in materials, a model of 25. The joints on
    the lattices by the index metric never end farther from their cells than the rounded ones, and each error is the
    reconstruction's from the material's values at the directions reached (exact at the cells:
    the ratio 1 is what no positioning error can beat)."""
    import importlib.util
    import json

    monkeypatch.setenv("GONIOFROST_CACHE", str(tmp_path / "cache"))
    path = Path(__file__).resolve().parents[1] / "benchmarks" / "command_steps.py"
    spec = importlib.util.spec_from_file_location("command_steps", path)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    assert bench.main(["--smallest", "--repeats", "1", "--out", str(tmp_path / "steps.json")]) == 0
    result = json.loads((tmp_path / "steps.json").read_text())
    miss = {k: np.array(v) for k, v in result["models"][0]["miss"].items()}
    # the index metric's joints never farther in it than rounding (plan's weigh each axis by the model)
    # (and rounding misses visibly: the comparison is not of two exact answers)
    assert np.all(miss["index"] <= miss["rounded"]) and np.any(miss["index"] < miss["rounded"])
    assert miss["rounded"].max() > 0.1
    assert [r["material"] for r in result["rows"]] == ["gold", "red-plastic"]
    for row in result["rows"]:
        assert all(0 < row[k] < 1 for k in ("rounded", "index", "on_steps", "exact"))
    assert result["summary"]["materials"] == 2 and result["samples"] == 12  # 6 + 3 sentinels + 3 check cells


def test_axis_weights_are_the_prior_expected_squared_change_to_the_neighbours(small_trained):
    """On a small model (the session's 10 x 10 x 20 one: any trained model will do, and training
    the built-in library for this alone took most of this file's time): each axis's weight is the
    mean over the cell's valid neighbours one index away of (mu_c - mu_n)^2 + sum_k (D_ck - D_nk)^2
    prior_k (phi_d wraps round); an invalid cell is refused."""
    import pytest

    from goniofrost.frost.cell_sensitivity import axis_weights
    from goniofrost.frost.posterior import prior_variance

    model, _ = small_trained
    small = model.grid
    prior, mean, d = prior_variance(model), np.asarray(model.mean, float), np.asarray(model.dictionary, float)

    def change(a, b):
        pa, pb = (int(small.valid_position(small.flat_index(*c))) for c in (a, b))
        assert pa >= 0 and pb >= 0, (a, b)  # every neighbour named below is a valid cell
        return (mean[pa] - mean[pb]) ** 2 + np.sum((d[pa] - d[pb]) ** 2 * prior)

    cells = [(0, 6, 0), (4, 2, 19)]
    got = axis_weights(model, cells)
    want = [[change((0, 6, 0), (1, 6, 0)),                                      # theta_h: no index -1
             (change((0, 6, 0), (0, 5, 0)) + change((0, 6, 0), (0, 7, 0))) / 2,
             (change((0, 6, 0), (0, 6, 19)) + change((0, 6, 0), (0, 6, 1))) / 2],     # phi_d wraps
            [(change((4, 2, 19), (3, 2, 19)) + change((4, 2, 19), (5, 2, 19))) / 2,
             (change((4, 2, 19), (4, 1, 19)) + change((4, 2, 19), (4, 3, 19))) / 2,
             (change((4, 2, 19), (4, 2, 18)) + change((4, 2, 19), (4, 2, 0))) / 2]]
    assert np.allclose(got, want, rtol=1e-12, atol=0)
    invalid = next(c for c in [(9, 9, k) for k in range(20)] if small.valid_position(small.flat_index(*c)) < 0)
    with pytest.raises(ValueError, match=rf"axis_weights: cell \[9, 9, {invalid[2]}\] is not a valid cell"):
        axis_weights(model, [invalid])

