"""Designs unlike every design the calibration was fitted on (frost.confidence.design_outside):
their predicted error is an extrapolation, flagged wherever it is stated, and a capture never
stops on the target with them; the model's own designs are not flagged."""
from __future__ import annotations

import json
import math
from types import SimpleNamespace

import numpy as np
import pytest

from goniofrost.capture import target
from goniofrost.frost import confidence, stopping
from goniofrost.frost.reconstruction import design_error, error_bound
from goniofrost.frost.selection import candidate_mask_max_angle

from test_frost import synthetic_tables

# A bound as training records it (confidence.fit_bound), with known numbers: the designs' log
# design error lies in [-5, -4] at 10 samples and in [-7, -6] at 20.
BOUND = {"m": [10, 20], "center": [0.0, 0.0], "scale": [1.0, 1.0], "scores": list(np.linspace(0.0, 2.0, 100)),
         "log_z2_max": [9.0, 9.0], "log_energy_max": [9.0, 9.0],
         "log_design_error_min": [-5.0, -7.0], "log_design_error_max": [-4.0, -6.0]}
LINE = "the design is unlike every design the model's calibration was fitted on (log design error "


def test_a_design_beyond_the_calibrations_designs_at_its_m_is_out_of_the_model():
    calibration = {"bound": BOUND}
    # at 20 samples: beyond -6 + log 2 = -5.31 or below -7 - log 2 = -7.69
    logs = np.array([-6.0, -5.4, -5.0, -7.6, -8.0])
    out = confidence.error_bounds(calibration, 1e-4, 1.0, 1.0, 20, 0.95, confidence.Evidence(design_error=np.exp(logs)))
    assert out["out_of_model_design"].tolist() == [False, False, True, False, True]
    assert not out["out_of_model_z2"].any() and not out["out_of_model_energy"].any()
    # between the calibrated m the range is interpolated in log m (sqrt(200): [-6, -5]); below the
    # fewest it is the fewest's
    assert confidence.design_outside(calibration, np.exp([-4.4, -4.2]), math.sqrt(200)).tolist() == [False, True]
    assert confidence.design_outside(calibration, np.exp([-3.4, -3.2]), 5).tolist() == [False, True]
    # not given, or a calibration that records no range (trained before it was): not checked
    assert not confidence.error_bounds(calibration, 1e-4, 1.0, 1.0, 20, 0.95)["out_of_model_design"]
    older = {"bound": {k: v for k, v in BOUND.items() if not k.startswith("log_design_error")}}
    assert confidence.design_range(older, 20) is None
    assert not confidence.design_outside(older, math.exp(0.5), 20)


def test_a_capture_never_stops_on_a_design_out_of_the_model_and_says_which_feature_value_and_range():
    calibration = {"bound": BOUND}
    bound = confidence.error_bound(calibration, 1e-4, 1.0, 1.0, 20, 0.95,
                                   confidence.Evidence(design_error=math.exp(0.5)))
    assert bound.out_of_model == ("design",) and bound.design == (20, 0.5, -7.0, -6.0, 20)
    assert bound.upper < 1.0  # a bound far below the target...
    assert stopping.stop_reason(bound, target=1.0, done=20, total=40) is None  # ...and yet it measures on
    assert stopping.stop_reason(bound, target=1.0, done=40, total=40) == stopping.REASON_PLAN
    assert stopping.why_not_reached(bound, 1.0) == LINE + "0.5 at 20 samples; -7 to -6 in training): an extrapolation"
    fewer = confidence.error_bound(calibration, 1e-4, 1.0, 1.0, 5, 0.95,
                                   confidence.Evidence(design_error=math.exp(0.5)))
    assert stopping.why_not_reached(fewer, 1.0) == (LINE + "0.5 at 5 samples; -5 to -4 in training at 10 samples, "
                                                    "the fewest it saw): an extrapolation")
    # the journal's Assess step holds the detail: a replayed statement says the same
    assessed = target.assessment(lambda records: bound, 0, 20, 40, 1.0, records=[])
    assert (assessed["decision"], assessed["out_of_model"], assessed["design"]) == (
        target.CONTINUE, ("design",), (20, 0.5, -7.0, -6.0, 20))
    assert target.statement(json.loads(json.dumps(assessed))) == stopping.why_not_reached(bound, 1.0)
    # what a report and brdf.json record of it, and the summary's line
    fields = confidence.extrapolation_fields(bound)
    assert fields == {"extrapolation": True, "out_of_model": ["design"], "out_of_model_features": ["log design error"],
                      "design": {"samples": 20, "log_design_error": 0.5, "training": [-7.0, -6.0],
                                 "training_samples": 20}}
    assert confidence.extrapolation_lines(fields) == [
        "EXTRAPOLATION: " + LINE + "0.5 at 20 samples; -7 to -6 in training): its predicted error is not backed by "
        "the calibration"]


@pytest.fixture(scope="module")
def model(small_trained):
    """The model of 40 synthetic materials (seed 3) on a 10 x 10 x 20 grid, trained once per run."""
    return small_trained[0]


def records_of(table, positions):
    """The capture's sample records of ``table`` (n_valid, 3) measured at ``positions`` in order."""
    return [SimpleNamespace(plan_index=i, rgb=tuple(table[p]), sigma=tuple(0.001 * table[p]))
            for i, p in enumerate(positions)]


def test_training_records_its_designs_range_and_the_models_own_design_lies_within_it(model):
    from goniofrost.bench import bayes_eval
    from goniofrost.frost.bayes_selection import select_bayes

    bound = model.noise["calibration"]["bound"]
    assert len(bound["log_design_error_min"]) == len(bound["log_design_error_max"]) == len(bound["m"])
    assert np.all(np.less_equal(bound["log_design_error_min"], bound["log_design_error_max"]))
    order = np.asarray(select_bayes(model, 20).positions, dtype=np.int64)
    truth = synthetic_tables(model.grid, 2, seed=11).astype(np.float64)
    for m in (5, 10, 15, 20):
        assert error_bound(model, order[:m], truth[0][order[:m]]).out_of_model == ()
    # a simulated capture with a target every bound meets stops after its first batch
    outcome = bayes_eval.target_outcomes(model, order, truth, model.to_log(truth), 1e9)
    assert outcome["samples"].tolist() == [15, 15] and outcome["reached"].tolist() == [1, 1]
    assessments = target.history(target.make_assessor(model, order), [15, 20], 1e9, records_of(truth[0], order))
    assert [(a["decision"], a["out_of_model"], a["design"]) for a in assessments] == [("target reached", (), None)]


def test_a_design_of_cells_near_the_normal_is_flagged_and_its_capture_never_stops(model):
    from goniofrost.bench import bayes_eval
    from goniofrost.capture.report import extrapolation_section
    from goniofrost.frost.bayes_selection import select_bayes

    order = np.asarray(select_bayes(model, 20, candidates=candidate_mask_max_angle(model.grid, 10)).positions,
                       dtype=np.int64)
    truth = synthetic_tables(model.grid, 2, seed=11).astype(np.float64)
    bound = model.noise["calibration"]["bound"]
    at = bound["m"].index(20)
    low, high = bound["log_design_error_min"][at], bound["log_design_error_max"][at]
    value = float(np.log(design_error(model, order)))
    assert value > high + math.log(2)
    # the capture: every batch out of the model, whatever the target; it measures the whole plan
    assessments = target.history(target.make_assessor(model, order), [15, 20], 1e9, records_of(truth[0], order))
    assert [(a["decision"], a["out_of_model"]) for a in assessments] == [
        (target.CONTINUE, ("design",)), (stopping.REASON_PLAN, ("design",))]
    assert target.statement(assessments[-1]) == (LINE + f"{value:.3g} at 20 samples; {low:.3g} to {high:.3g} in "
                                                 "training): an extrapolation")
    outcome = bayes_eval.target_outcomes(model, order, truth, model.to_log(truth), 1e9)
    assert outcome["samples"].tolist() == [20, 20] and outcome["reached"].tolist() == [0, 0]
    assert outcome["out_of_model"].tolist() == [1, 1]
    # the report's statement of the whole reconstruction
    section = extrapolation_section(SimpleNamespace(model=model, positions=order), records_of(truth[0], order))
    assert section == {"extrapolation": True, "out_of_model": ["design"], "out_of_model_features": ["log design error"],
                       "design": {"samples": 20, "log_design_error": pytest.approx(value), "training": [low, high],
                                  "training_samples": 20}}


def test_a_plan_of_a_model_without_the_range_says_its_design_is_not_checked(model):
    from goniofrost.plan.file import with_design_check

    noise = json.loads(json.dumps(model.noise))
    for key in ("log_design_error_min", "log_design_error_max"):
        del noise["calibration"]["bound"][key]
    doc = {"m": 15, "batch_ends": [15], "samples": [{}] * 15, "selector": "bayes"}
    assert with_design_check(doc, SimpleNamespace(noise=noise), np.arange(15)) == (
        doc, "design check: none (the model records no range of its calibration's designs: train it again with "
             "this version to have designs unlike them flagged)")


def test_plan_and_reconstruct_say_why_their_prediction_is_an_extrapolation(tmp_path, capsys):
    """A plan within 10 degrees of the normal (the session tests' model, 30 x 30 x 60 grid): PLAN.json and
    the plan's summary flag it, and so do reconstruct's OUT.json and output; the model's own plan is
    not flagged."""
    from goniofrost.app.cli import main
    from goniofrost.core.cache import cache_path
    from goniofrost.datasets import parse_material_spec
    from test_session import session_model

    model = session_model()
    folder, plan = str(cache_path("models", model.info["cache_key"], "")), tmp_path / "plan.json"
    assert main(["plan", "--model", folder, "--samples", "15", "--out", str(plan)]) == 0
    assert json.loads(plan.read_text())["extrapolation"] is False and "EXTRAPOLATION" not in capsys.readouterr().out
    assert main(["plan", "--model", folder, "--samples", "15", "--max-angle", "10", "--out", str(plan)]) == 0
    doc, out = json.loads(plan.read_text()), capsys.readouterr().out
    cells = np.array([model.grid.flat_index(*s["cell"]) for s in doc["samples"]])
    value = float(np.log(design_error(model, model.grid.valid_position(cells))))
    bound = model.noise["calibration"]["bound"]
    at = bound["m"].index(15)
    low, high = bound["log_design_error_min"][at], bound["log_design_error_max"][at]
    said = f"{value:.3g} at 15 samples; {low:.3g} to {high:.3g} in training)"
    assert (doc["extrapolation"], doc["out_of_model"], doc["out_of_model_batch_ends"]) == (True, ["design"], [15])
    assert doc["design"] == {"samples": 15, "log_design_error": pytest.approx(value), "training": [low, high],
                             "training_samples": 15}
    assert "(log-relative MSE; an extrapolation)" in out
    assert out.splitlines()[-1] == ("EXTRAPOLATION: " + LINE + said + ": the predicted error is not backed by the "
                                    "calibration, and capture --target-error does not stop on the target after 15 "
                                    "samples")
    dataset, name = parse_material_spec("builtin:red-plastic")
    values = dataset.tabulate([name], model.grid, cells)[0].astype(np.float64)
    th, td, pd = (np.degrees(a) for a in model.grid.flat_angles(cells))
    rows = [",".join(repr(float(x)) for x in row) for row in zip(th, td, pd, *values.T)]
    samples = tmp_path / "samples.csv"
    samples.write_text("theta_h_deg,theta_d_deg,phi_d_deg,r,g,b\n" + "\n".join(rows) + "\n")
    assert main(["reconstruct", "--model", folder, "--samples", str(samples), "--out", str(tmp_path / "r.binary")]) == 0
    out, record = capsys.readouterr().out, json.loads((tmp_path / "r.json").read_text())
    assert "(an extrapolation)" in out.splitlines()[1]
    assert out.splitlines()[2] == ("EXTRAPOLATION: " + LINE + said + ": its predicted error is not backed by the "
                                   "calibration")
    assert (record["extrapolation"], record["out_of_model"], record["design"]["samples"]) == (True, ["design"], 15)


def test_a_model_trained_on_a_rigs_cells_calibrates_designs_among_them(model, monkeypatch):
    """fit_model(sentinel_candidates=mask) (train --rig): every inner fold's design picks only the
    rig's cells, so a rig reaching within 40 degrees of the normal, whose design lies beyond the
    whole-grid model's designs, lies within its own model's; without a rig the designs pick among
    every cell (rows=None: the arithmetic of models trained before, bit for bit)."""
    from goniofrost.frost import calibration
    from goniofrost.frost.bayes_selection import select_bayes
    from goniofrost.frost.training import TrainingOptions, fit_model

    calls, pick = [], calibration.greedy_designs

    def recorded(*args, rows=None, **kwargs):
        designs = pick(*args, rows=rows, **kwargs)
        calls.append((rows, [d.rows for d in designs]))
        return designs

    monkeypatch.setattr(calibration, "greedy_designs", recorded)
    allowed = candidate_mask_max_angle(model.grid, 40)
    tables, names = synthetic_tables(model.grid, 40, seed=3), [f"mat{i}" for i in range(40)]
    rig_model = fit_model(tables, names, model.grid, TrainingOptions(k_max=30, sentinel_candidates=allowed))
    assert calls and all(np.array_equal(rows, np.flatnonzero(allowed)) for rows, _ in calls)
    assert all(allowed[picked].all() for _, designs in calls for picked in designs)
    # plan --rig's design of each model: the whole grid's lies beyond its calibration, the rig's within
    whole = np.asarray(select_bayes(model, 20, candidates=allowed).positions, dtype=np.int64)
    assert confidence.design_outside(model.noise["calibration"], design_error(model, whole), 20)
    order = np.asarray(select_bayes(rig_model, 20, candidates=allowed).positions, dtype=np.int64)
    assert not confidence.design_outside(rig_model.noise["calibration"], design_error(rig_model, order), 20)
    calls.clear()
    fit_model(synthetic_tables(model.grid, 20, seed=3), names[:20], model.grid, TrainingOptions(k_max=30))
    assert calls and all(rows is None for rows, _ in calls)
