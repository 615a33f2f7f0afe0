"""Rig time: the cost model against the simulated rig's clock, and the time-aware design
(deterministic, the cheaper of two equally informative cells, plan --objective).

Small: the session tests' model (6 materials, 30 x 30 x 60 grid) and rig (short ladder, small
sensor), a 10-sample capture on the simulated rig at 50 x real time.
"""
from __future__ import annotations

import json
import sqlite3
from contextlib import closing
from pathlib import Path

import numpy as np
import pytest

from calib.exposure_time import Sensor, bracket_seconds, expected_frames, first_rungs
from goniofrost.app.cli import main
from goniofrost.rig.file import load_checked_rig
from goniofrost.frost.rig_cost import CellCosts, rig_camera, rig_sensor
from planner.kinematics import arm_side, forward
from planner.motion import move_time
from planner.view import roi_pixels

from test_session import capture_args, small_plan, write_rig

REPO = Path(__file__).resolve().parents[1]
M = 10


@pytest.fixture(scope="module")
def captured(tmp_path_factory):
    """(rig file, plan document, journal rows (plan_index, joints, move_s, capture_s, r, g, b))
    of a 10-sample capture of the held-out material on the simulated rig."""
    folder = tmp_path_factory.mktemp("rig-time")
    rig = write_rig(folder / "rig.yaml")
    plan, _ = small_plan(rig, M, folder / "plan.json")
    assert main(capture_args(rig, plan, folder / "s", "--speedup", "50")) == 0
    with closing(sqlite3.connect(folder / "s" / "session.sqlite")) as db:
        rows = db.execute("SELECT plan_index, joints, move_s, capture_s, r, g, b FROM samples "
                          "ORDER BY plan_index").fetchall()
    return rig, json.loads(plan.read_text()), rows


def test_the_cost_model_times_every_move_and_bracket_of_the_simulated_rig_within_10_percent(captured):
    rig_file, plan, rows = captured
    rig = load_checked_rig(rig_file)
    assert len(rows) == M
    reached = np.array([[json.loads(r[1])[n] for n in rig.joint_names] for r in rows])
    # the first move starts at the white reference's pose, not a sample's: from the second on
    predicted_moves = move_time(rig, reached[:-1], reached[1:])
    measured_moves = np.array([r[2] for r in rows[1:]])
    assert np.all(np.abs(predicted_moves - measured_moves) <= 0.1 * measured_moves + 1e-9)

    camera, sensor = rig_camera(rig), rig_sensor(rig)
    w_i, w_o = forward(rig, reached)
    values = np.array([r[4:7] for r in rows])  # each cell's value as measured (SNR >= 100)
    previous = np.vstack([np.full((1, 3), 1 / np.pi), values[:-1]])  # capture starts from the last value
    first = first_rungs(camera["exposures_s"], sensor.rates(previous, w_i[:, 2]), camera["saturation"])
    taken = expected_frames(camera["exposures_s"], sensor.rates(values, w_i[:, 2]),
                            roi_pixels(rig.view, w_i, w_o, arm_side(rig)), sensor, camera["saturation"],
                            camera["target_snr"], first)
    predicted, measured = bracket_seconds(camera["exposures_s"], taken), np.array([r[3] for r in rows])
    # One bracket in ten may differ by a rung: a dark cell's (green 0.015 1/sr) last rung is decided
    # by the frames' own noise, which the expectation cannot foresee (with this seed's noise stream
    # the capture stops a rung earlier than expected at plan sample 5)
    within = np.abs(predicted - measured) <= 0.1 * measured
    assert within.sum() >= M - 1, (predicted, measured)


def test_a_bracket_takes_one_frame_with_enough_pixels_and_climbs_the_ladder_when_it_starts_short():
    sensor = Sensor(2.0e5, (0.6, 1.0, 0.75), 30000.0, 3.0, 5.0)
    ladder = [0.001, 0.004, 0.016, 0.064, 0.256]
    rates = sensor.rates(np.full((1, 3), 0.05), np.array([1.0]))  # green 1.05 of full scale per second
    # the start: 0.256 s, the longest rung under 0.475 of full scale (0.27); red collects 4800
    # electrons, SNR 69 a pixel, 1390 over 400 pixels: one frame
    one = expected_frames(ladder, rates, np.array([400.0]), sensor, 0.95, 100.0)
    assert one.tolist() == [[False, False, False, False, True]]
    # started at the shortest rung with 4 pixels: up to 0.064 s red has 1600 electrons, SNR 79 over
    # 4 pixels: the bracket climbs to the ladder's end
    short = expected_frames(ladder, rates, np.array([4.0]), sensor, 0.95, 100.0, first=np.array([0]))
    assert short.tolist() == [[True] * 5]
    assert bracket_seconds(ladder, short).tolist() == [pytest.approx(0.341)]


def _select(model, rig, mask, objective, threads=None):
    from goniofrost.frost.bayes_selection import select_bayes

    return select_bayes(model, 20, candidates=mask, time_objective=objective, threads=threads)


def test_the_time_aware_design_is_deterministic_and_does_not_depend_on_the_threads(captured):
    from goniofrost.frost.time_design import TimeObjective
    from planner.reach import reachability
    from test_session import session_model

    rig = load_checked_rig(captured[0])
    model = session_model()
    mask = reachability(rig, model.grid).mask
    one, again, two = (_select(model, rig, mask, TimeObjective(rig), t) for t in (1, 1, 2))
    assert one.positions.tolist() == again.positions.tolist() == two.positions.tolist()
    assert np.array_equal(one.residuals, two.residuals)
    # a per-sample overhead far above any rig time, or picks held to the step's largest error
    # reduction, give back the sample-count design
    plain = _select(model, rig, mask, None).positions.tolist()
    assert _select(model, rig, mask, TimeObjective(rig, 1e9)).positions.tolist() == plain
    assert _select(model, rig, mask, TimeObjective(rig, share=1.0)).positions.tolist() == plain
    assert one.positions.tolist() != plain


def test_collecting_the_cells_to_time_in_the_pass_over_d_picks_what_a_full_second_sweep_picks(captured):
    """The pass over D collects the cells whose gain reaches the share of its running best and
    only those are timed: the same cells in the same order as timing every cell whose gain
    reaches the share of the step's best in a second sweep over the forms."""
    from goniofrost.frost.bayes_selection import _candidate_rows, greedy_design
    from goniofrost.frost.posterior import cell_noise, design_scale, prior_variance
    from goniofrost.frost.time_design import OVERHEAD_S, SHARE, RigTrack, cached_costs
    from planner.reach import reachability
    from test_session import session_model

    rig = load_checked_rig(captured[0])
    model = session_model()
    rows = _candidate_rows(reachability(rig, model.grid).mask, model.grid.n_valid)
    costs = cached_costs(model, rig, rows)
    s2 = np.asarray(model.singular_values, np.float64) ** 2
    args = (model.dictionary, s2, prior_variance(model), cell_noise(model) * design_scale(model), 30)
    for share, threads in ((SHARE, 1), (SHARE, 2), (0.2, 2), (0.0, 1)):
        designs = [greedy_design(*args, rows=rows, threads=threads,
                                 track=RigTrack(costs, rig, OVERHEAD_S, 30, share, full_scan=full))
                   for full in (True, False)]
        assert designs[1].rows.tolist() == designs[0].rows.tolist(), (share, threads)
        assert np.array_equal(designs[1].design_errors, designs[0].design_errors)


def test_the_inner_designs_of_a_time_aware_training_are_timed_as_plan_times_the_models(captured):
    """Training's time-aware inner designs cost every cell as ``plan --objective time`` costs it
    on the trained model (the prior median from the training's mapping)."""
    from goniofrost.frost.rig_cost import cell_costs
    from goniofrost.frost.time_design import TimeObjective
    from goniofrost.frost.training import _inner_tracks
    from planner.reach import reachability
    from test_session import session_model

    rig = load_checked_rig(captured[0])
    model = session_model()
    mask = reachability(rig, model.grid).mask
    track = _inner_tracks(TimeObjective(rig), model.grid, mask, model.reference, model.mean, model.weight,
                          model.eps)(20)
    expected = cell_costs(model, rig, np.flatnonzero(mask), rig_camera(rig), rig_sensor(rig))
    assert np.array_equal(track.costs.fixed_s, expected.fixed_s)
    assert np.array_equal(track.costs.poses, expected.poses, equal_nan=True)
    assert track.overhead == TimeObjective(rig).overhead_s and track.share == TimeObjective(rig).share


def test_of_two_equally_informative_cells_the_cheaper_is_picked():
    from goniofrost.frost.bayes_selection import greedy_design
    from goniofrost.frost.time_design import RigTrack

    rig = load_checked_rig(REPO / "config" / "rigs" / "sim.yaml")
    # cells 0 and 1 have the same dictionary row; cell 1's bracket is the shorter; all at home
    d = np.array([[1.0, 0.2], [1.0, 0.2], [0.1, 1.0]], dtype=np.float32)
    home = np.asarray(rig.home, np.float64)
    poses = np.repeat(home[None, None, :], 3, axis=0).astype(np.float32)
    for fixed, expected in (([1.0, 0.25, 1.0], 1), ([0.25, 1.0, 1.0], 0)):
        costs = CellCosts(poses, np.array(fixed, np.float32)[:, None], *(np.zeros(3) + v for v in (30.0, 60.0, 0.01)),
                          home)
        track = RigTrack(costs, rig, 0.0, 2)
        design = greedy_design(d, np.ones(2), np.ones(2), np.full(3, 0.01), 1, track=track)
        assert design.rows.tolist() == [expected]
    # without rig time the lower index wins the tie
    assert greedy_design(d, np.ones(2), np.ones(2), np.full(3, 0.01), 1).rows.tolist() == [0]


def test_plan_objective_time_records_expected_move_and_exposure_per_sample(captured, tmp_path, capsys):
    from goniofrost.core.cache import cache_path
    from test_session import session_model

    rig_file = captured[0]
    model = session_model()
    model_dir = cache_path("models", model.info["cache_key"], "")
    out = tmp_path / "plan.json"
    assert main(["plan", "--model", str(model_dir), "--samples", "15", "--rig", str(rig_file), "--objective", "time",
                 "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["objective"] == "time" and doc["batch_ends"][-1] == doc["m"]
    assert all(s["expected_move_s"] == s["move_s"] and s["expected_exposure_s"] > 0 for s in doc["samples"])
    total = doc["expected_rig_s"]
    assert total["total"] == pytest.approx(doc["planned_motion_s"] + sum(s["expected_exposure_s"]
                                                                         for s in doc["samples"]))
    capsys.readouterr()
    assert main(["plan", "--model", str(model_dir), "--samples", "15", "--objective", "time",
                 "--out", str(tmp_path / "other.json")]) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1].endswith(
        "--objective: expected time only with --selector bayes, --rig and no --usage, found 'time'")
    assert not (tmp_path / "other.json").exists()


def test_the_time_aware_picks_are_those_of_a_plain_numpy_greedy_on_error_reduction_per_second(captured):
    """The compiled passes (rank-1 updates, candidates ruled out without their trapezoids) pick
    what the definition picks: argmax of u^T S^2 u / (sigma^2 + d^T u) / (overhead + seconds)."""
    from goniofrost.frost.bayes_selection import _candidate_rows
    from goniofrost.frost.posterior import cell_noise, design_scale, prior_variance
    from goniofrost.frost.rig_cost import cell_costs
    from goniofrost.frost.time_design import OVERHEAD_S, TimeObjective
    from planner.reach import reachability
    from test_session import session_model

    rig = load_checked_rig(captured[0])
    model = session_model()
    mask = reachability(rig, model.grid).mask
    rows = _candidate_rows(mask, model.grid.n_valid)
    costs = cell_costs(model, rig, rows, rig_camera(rig), rig_sensor(rig))
    d = np.asarray(model.dictionary, np.float64)[rows]
    s2 = np.asarray(model.singular_values, np.float64) ** 2
    noise = (cell_noise(model) * design_scale(model))[rows]
    sigma, here, picks = np.diag(prior_variance(model)), costs.home, []
    for _ in range(10):
        u = d @ sigma  # rows u_c = Sigma d_c
        gain = np.einsum("ck,k,ck->c", u, s2, u) / (noise + np.einsum("ck,ck->c", d, u))
        score = gain / (OVERHEAD_S + costs.seconds_from(here))
        score[picks] = -np.inf
        best = int(np.argmax(score))
        picks.append(best)
        here = costs.fastest_pose(best, here)
        uu = sigma @ d[best]
        sigma = sigma - np.outer(uu, uu) / (noise[best] + d[best] @ uu)
    from goniofrost.frost.bayes_selection import select_bayes
    chosen = select_bayes(model, 10, candidates=mask, time_objective=TimeObjective(rig)).positions
    assert chosen.tolist() == rows[picks].tolist()


def test_a_target_error_capture_of_a_time_aware_plan_stops_on_the_calibrated_rule(captured, tmp_path, capsys):
    from goniofrost.capture.journal import Journal
    from goniofrost.core.cache import cache_path
    from test_session import session_model

    rig_file = captured[0]
    model = session_model()
    plan = tmp_path / "plan.json"
    assert main(["plan", "--model", str(cache_path("models", model.info["cache_key"], "")), "--samples", "20",
                 "--rig", str(rig_file), "--objective", "time", "--out", str(plan)]) == 0
    doc = json.loads(plan.read_text())
    first = doc["batch_ends"][0]
    session = tmp_path / "s"
    # a target every bound meets: the capture stops after the first batch, as with a sample-count plan
    assert main(capture_args(rig_file, plan, session, "--speedup", "50", "--target-error", "10000",
                             "--confidence", "0.8")) == 0
    with Journal.open(session / "session.sqlite") as journal:
        records, events = journal.samples(), journal.events()
    [batch] = [e for e in events if e["kind"] == "batch"]
    assert batch["data"]["decision"] == "target reached" and batch["data"]["samples"] == first == len(records)
    assert [r.plan_index for r in records] == list(range(first))
