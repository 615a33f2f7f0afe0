"""Sentinel samples (frost.sentinel): cells the design leaves empty, checked against the
posterior of the design's samples, calibrated on held-out training materials."""
from __future__ import annotations

import copy
import json
from types import SimpleNamespace

import numpy as np
import pytest

from goniofrost.core.grid import MerlGrid
from goniofrost.frost import confidence, sentinel, stopping
from goniofrost.frost.calibration import CvRecords, fit_calibration
from goniofrost.frost.prediction import Features, predict

from test_confidence import MS, synthetic_records

GRID = MerlGrid(10, 10, 20)


def test_the_sentinels_spread_over_the_region_the_design_leaves_empty():
    cells = sentinel.cells(GRID, 5)
    # farthest-point order: the two grazing forward-scatter extremes, then theta_h > 70, then between
    assert cells.tolist() == [180, 199, 1590, 1469, 988]
    theta_h, theta_d, phi_d = (np.degrees(a) for a in GRID.flat_angles(GRID.valid_cells[cells]))
    np.testing.assert_allclose(theta_d, [81, 81, 0, 81, 81])
    np.testing.assert_allclose(phi_d, [0, 171, 0, 81, 126])
    assert theta_h[2] == pytest.approx(72.9, abs=0.05)
    assert sentinel.region(GRID).sum() == 181 and sentinel.region(GRID)[cells].all()
    assert sentinel.cells(GRID).tolist() == [180, 199, 1590]  # nested: the default 3 are the first 3
    # only candidate cells (what a rig can measure); none when the region holds none of them
    allowed = np.ones(GRID.n_valid, bool)
    allowed[[180, 199]] = False
    assert 180 not in sentinel.cells(GRID, 3, allowed) and sentinel.cells(GRID, 3, allowed).size == 3
    assert sentinel.cells(GRID, 3, ~sentinel.region(GRID)).size == 0


def test_the_check_error_is_the_mean_squared_miss_of_the_materials_columns():
    rows = np.array([[1.0, 0.0], [0.0, 2.0]])
    coefficients = np.array([[1.0, 0.0, 5.0], [0.5, 1.0, 5.0]])
    b = np.array([[2.0, 0.0, 0.0], [1.0, 2.0, 0.0]])  # predicted [[1, 0, 5], [1, 2, 10]]
    assert sentinel.check_error(rows, coefficients, b, [0, 1]) == pytest.approx((1 + 0 + 0 + 0) / 4)
    assert sentinel.check_error(rows, coefficients, b, [2]) == pytest.approx((25 + 100) / 2)
    assert sentinel.check_error(rows, coefficients, rows @ coefficients, [0]) == 1e-12  # floored


def sentinel_records(n_materials, seed, odd=0.0):
    """synthetic_records with a sentinel error: the actual error times a per-material factor
    (lognormal, sd 0.5) times noise shrinking with m; ``odd``: log factor added to every material."""
    records = synthetic_records(n_materials, seed)
    rng = np.random.default_rng(seed + 100)
    factor = rng.normal(0, 0.5, n_materials)[records.material] + rng.normal(0, 1, records.m.size) / np.sqrt(records.m)
    return CvRecords(**{k: getattr(records, k) for k in ("fold", "material", "m", "actual", "design_error", "z2",
                                                         "energy")}, sentinel=records.actual * np.exp(factor + odd))


def test_the_sentinel_check_flags_five_percent_of_typical_materials_and_one_whose_error_hides_elsewhere():
    calibration = fit_calibration(sentinel_records(300, seed=1))
    spread = calibration["bound"]["sentinel"]
    assert len(spread["scores"]) == 300 and len(spread["center"]) == len(MS)
    fresh = sentinel_records(4000, seed=2)
    predicted = predict(calibration, Features(fresh.design_error, fresh.z2, fresh.energy, fresh.m))
    looks = fresh.m >= confidence.FIRST_LOOK
    flagged = confidence.sentinel_excess(calibration, fresh.sentinel, predicted, fresh.m, 0.95)
    any_look = flagged.reshape(4000, len(MS))[:, looks[:len(MS)]].any(axis=1).mean()
    assert 0.035 <= any_look <= 0.075, any_look  # simultaneous over the looks: about 1 - 0.95
    # the sentinels' error 20 x what the training materials show where they looked: flagged
    odd = sentinel_records(200, seed=3, odd=np.log(20.0))
    odd_predicted = predict(calibration, Features(odd.design_error, odd.z2, odd.energy, odd.m))
    assert confidence.sentinel_excess(calibration, odd.sentinel, odd_predicted, odd.m, 0.95)[odd.m == 30].mean() > 0.9
    # in error_bounds: a flag of its own, unchecked samples never flagged, a model without sentinels never
    b = confidence.error_bounds(calibration, predicted, fresh.z2, fresh.energy, fresh.m, 0.95,
                                confidence.Evidence(check=fresh.sentinel))
    np.testing.assert_array_equal(b["out_of_model_sentinel"],
                                  confidence.sentinel_excess(calibration, fresh.sentinel, predicted, fresh.m,
                                                             sentinel.SENTINEL_CONFIDENCE))
    assert not confidence.error_bounds(calibration, predicted, fresh.z2, fresh.energy, fresh.m, 0.95)[
        "out_of_model_sentinel"].any()
    assert not confidence.sentinel_excess(fit_calibration(synthetic_records(50, seed=7)), 1e9, 1.0, 20, 0.95)


def test_a_sentinel_flag_stays_for_the_rest_of_the_capture_and_its_replay():
    from goniofrost.capture.journal import SampleRecord
    from goniofrost.capture.target import finished, history, statement

    # the sentinels flag the first look only; the second's bound is below the target
    looks = {2: confidence.ErrorBound(0.01, 0.2, 0.95, ("sentinel",)), 4: confidence.ErrorBound(0.001, 0.02, 0.95),
             5: confidence.ErrorBound(0.001, 0.01, 0.95)}
    records = [SampleRecord(i, 0, 0.0, 0.0, 0.0, (1.0,) * 3, (0.1,) * 3, 10.0) for i in range(5)]
    steps = history(lambda recs: looks[len(recs)], (2, 4, 5), 0.05, records)
    assert [(b["samples"], b["decision"], b["out_of_model"]) for b in steps] == [
        (2, "continue", ("sentinel",)), (4, "continue", ("sentinel_earlier",)),
        (5, "plan used up", ("sentinel_earlier",))]
    assert statement(steps[1]) == ("the samples are unlike every training material (the sentinel samples' error at "
                                   "an earlier batch beyond the training range): an extrapolation")
    assert finished(lambda recs: looks[len(recs)], (2, 4, 5), 0.05, records)
    # never flagged: the second look stops
    looks[2] = confidence.ErrorBound(0.01, 0.2, 0.95)
    assert [b["decision"] for b in history(lambda recs: looks[len(recs)], (2, 4, 5), 0.05, records)] == [
        "continue", "target reached"]


def test_the_sentinel_excess_reads_the_calibrated_center_scale_and_quantile():
    calibration = {"bound": {"m": [15, 60], "sentinel": {"center": [0.0, 1.0], "scale": [1.0, 2.0],
                                                          "scores": [0.5, 1.0, 2.0]}}}
    # n = 3: at 0.5 the ceil(4 * 0.5) = 2nd smallest score, 1.0; m = 30 is halfway in log m
    check = np.exp(np.array([0.99, 1.01]))
    np.testing.assert_array_equal(confidence.sentinel_excess(calibration, check, 1.0, 15, 0.5), [False, True])
    np.testing.assert_array_equal(confidence.sentinel_excess(calibration, np.exp([2.99, 3.01]), 1.0, 60, 0.5),
                                  [False, True])
    np.testing.assert_array_equal(confidence.sentinel_excess(calibration, np.exp([1.99, 2.01]), 1.0, 30, 0.5),
                                  [False, True])  # center 0.5, scale 1.5


def test_a_capture_flagged_by_its_sentinels_never_stops_on_the_bound():
    flagged = confidence.ErrorBound(0.001, 0.002, 0.95, ("sentinel",))
    assert stopping.stop_reason(flagged, target=0.05, done=15, total=40) is None
    assert stopping.stop_reason(flagged, target=0.05, done=40, total=40) == stopping.REASON_PLAN
    assert stopping.why_not_reached(flagged, 0.05) == ("the samples are unlike every training material "
                                                       "(the sentinel samples' error beyond the training range): "
                                                       "an extrapolation")


def test_a_trained_model_calibrates_its_sentinels(small_trained):
    from test_frost import synthetic_tables
    from goniofrost.frost.training import TrainingOptions, fit_model

    model = small_trained[0]  # 40 synthetic materials (seed 3) on GRID
    spread = model.noise["calibration"]["bound"]["sentinel"]
    assert spread["cells"] == sentinel.cells(GRID).tolist() and len(spread["scores"]) == 40
    assert len(spread["center"]) == len(model.noise["calibration"]["bound"]["m"])
    # calibrated among a rig's cells: the plan with that rig measures exactly those
    allowed = np.ones(GRID.n_valid, bool)
    allowed[[180, 199]] = False
    # 20 materials: the fewest whose held-out scores support the check at 0.95 (19), half the training of 40
    rig_model = fit_model(synthetic_tables(GRID, 20, seed=3), [f"mat{i}" for i in range(20)], GRID,
                          TrainingOptions(k_max=30, sentinel_candidates=allowed))
    cells = rig_model.noise["calibration"]["bound"]["sentinel"]["cells"]
    assert cells == sentinel.cells(GRID, 3, allowed).tolist() and not {180, 199} & set(cells)
    design = np.array([0, 1, 2], dtype=np.int64)
    doc = {"m": 3, "batch_ends": [3], "samples": [{}] * 3, "selector": "bayes"}
    from goniofrost.plan.file import with_sentinels
    assert with_sentinels(doc, rig_model, design, allowed)[1] == \
        "sentinels: 3 samples with the first batch, the model's calibrated cells; check cells: 3 samples with the " \
        "first batch (never fitted: their error sharpens the bound)"
    assert "the check is an approximation" in with_sentinels(doc, model, design, allowed)[1]


def test_a_material_that_differs_only_where_the_design_does_not_look_is_flagged_by_its_sentinels(small_trained):
    """End to end on a trained model: the same material with its BRDF x 20 in the sentinels'
    region (the design's cells left as they were) gives the design's samples, and so the bound
    (to rounding: a BLAS kernel may round a row by its place in the batch); only the sentinels
    see it, and the simulated capture measures on."""
    from test_frost import synthetic_tables
    from goniofrost.bench import bayes_eval
    from goniofrost.frost.bayes_selection import select_bayes
    model = small_trained[0]  # 40 synthetic materials (seed 3) on GRID
    order = np.asarray(select_bayes(model, 20).positions, dtype=np.int64)
    like = synthetic_tables(GRID, 2, seed=11).astype(np.float64)
    hidden = sentinel.region(GRID)
    hidden[order] = False
    odd = like.copy()
    odd[:, hidden] *= 20.0
    truth = np.concatenate([like, odd])
    out = bayes_eval.target_outcomes(model, order, truth, model.to_log(truth), 1e9, checks=bayes_eval.MeasuredChecks())
    plain = bayes_eval.target_outcomes(model, order, truth, model.to_log(truth), 1e9)
    np.testing.assert_allclose(plain["upper"][:2], plain["upper"][2:], rtol=1e-12)  # the same samples, the same bound
    np.testing.assert_array_equal(out["ever_sentinel"], [0, 0, 1, 1])
    # 15 + 3 sentinels + 3 check cells; the flagged ones measure on
    np.testing.assert_array_equal(out["samples"], [21, 21, 26, 26])
    np.testing.assert_array_equal(out["reached"], [1, 1, 0, 0])
    np.testing.assert_array_equal(plain["samples"], [15, 15, 15, 15])  # without the check all four stop


def test_a_plan_with_sentinels_measures_them_with_the_first_batch():
    from goniofrost.plan.file import add_sentinels, sample_entries

    design = np.array([5, 6, 7, 8], dtype=np.int64)
    doc = {"m": 4, "batch_ends": [2, 4], "samples": sample_entries(GRID, GRID.valid_cells[design]), "selector": "bayes"}
    out = add_sentinels(doc, GRID, np.array([180, 199]))
    assert (out["m"], out["sentinels"], out["batch_ends"], out["selector"]) == (6, 2, [4, 6], "bayes")
    cells = [tuple(s["cell"]) for s in out["samples"]]
    expected = [tuple(int(v) for v in c) for c in np.stack(GRID.unravel(GRID.valid_cells[[5, 6, 180, 199, 7, 8]]), 1)]
    assert cells == expected
    assert [s.get("sentinel", False) for s in out["samples"]] == [False, False, True, True, False, False]
    assert doc["m"] == 4 and len(doc["samples"]) == 4  # the design's plan is left as it was


@pytest.fixture(scope="module")
def trained(small_trained):
    return small_trained


def test_a_captures_bound_leaves_its_sentinels_out_and_checks_them(trained):
    from test_frost import synthetic_tables
    from goniofrost.capture.target import make_assessor
    from goniofrost.frost.reconstruction import error_bound

    model, design = trained
    cells = np.asarray(model.noise["calibration"]["bound"]["sentinel"]["cells"])
    positions = np.concatenate([design, cells])
    flags = np.arange(positions.size) >= design.size
    like = synthetic_tables(GRID, 1, seed=11)[0].astype(np.float64)
    odd = like.copy()
    odd[cells] *= 20.0
    alone = error_bound(model, design, like[design], confidence=0.95)
    for table, flagged in ((like, ()), (odd, ("sentinel",))):
        bound = error_bound(model, positions, table[positions], confidence=0.95, sentinel=flags)
        assert (bound.median, bound.upper, bound.out_of_model) == (alone.median, alone.upper, flagged)
    records = [SimpleNamespace(plan_index=i, rgb=tuple(odd[p]), sigma=(0.0, 0.0, 0.0)) for i, p in enumerate(positions)]
    assessed = make_assessor(model, positions, 0.95, sentinel=flags)(records)
    assert assessed.out_of_model == ("sentinel",)
    assert stopping.stop_reason(assessed, target=1e9, done=positions.size, total=40) is None
    # the same samples all fitted (a plan without sentinels): x 20 at 3 of 18 cells shows in the
    # leave-one-out residuals instead; the design's 15 alone show nothing
    assert make_assessor(model, positions, 0.95)(records).out_of_model == ("z2",)
    assert make_assessor(model, design, 0.95)(records[:design.size]).out_of_model == ()


def test_a_capture_of_a_plan_with_sentinels_stops_on_the_designs_bound_and_a_resume_keeps_it(tmp_path, capsys):
    """plan --sentinels on the simulated rig, capture --target-error: the first batch measures the
    sentinels too, the bound is the design samples' alone, and a resume moves nothing."""
    import json

    from goniofrost.app.cli import main
    from goniofrost.capture.journal import Journal
    from goniofrost.core.cache import cache_path
    from goniofrost.frost.reconstruction import error_bound
    from test_session import GRID as SESSION_GRID, capture_args, session_model, write_rig

    model = session_model()
    rig, plan, session = write_rig(tmp_path / "rig.yaml"), tmp_path / "plan.json", tmp_path / "s"
    assert main(["plan", "--model", str(cache_path("models", model.info["cache_key"], "")), "--samples", "17",
                 "--rig", str(rig), "--sentinels", "--out", str(plan)]) == 0
    out = capsys.readouterr().out
    assert "sentinels: 3 samples with the first batch" in out and \
        f"{plan}: m = 17 samples + 3 sentinels + 3 check cells" in out
    doc = json.loads(plan.read_text())
    assert (doc["m"], doc["sentinels"], doc["checks"], doc["batch_ends"]) == (23, 3, 3, [21, 23])
    flags = [bool(s.get("sentinel")) for s in doc["samples"]]
    assert sum(flags[:21]) == 6 and not any(flags[21:])
    # 6 training materials: the bound exists at 0.8, the sentinel check (at 0.95) cannot flag
    assert main(capture_args(rig, plan, session, "--speedup", "50", "--target-error", "10000",
                             "--confidence", "0.8")) == 0
    with Journal.open(session / "session.sqlite") as journal:
        records, events = journal.samples(), journal.events()
    assert len(records) == 21
    [batch] = [e for e in events if e["kind"] == "batch"]
    assert batch["data"]["decision"] == "target reached" and batch["data"]["samples"] == 21
    # the bound: the design's samples' posterior, with the sentinels' and the check cells' errors as
    # the checked calibration's features (frost.check_cells), not the design's samples' alone
    def cells_of(rs):
        return SESSION_GRID.valid_position(np.array([SESSION_GRID.flat_index(*doc["samples"][r.plan_index]["cell"])
                                                     for r in rs]))
    design = [r for r in records if not flags[r.plan_index]]
    alone = error_bound(model, cells_of(design), np.array([r.rgb for r in design]), np.array([r.sigma for r in design]),
                        0.8)
    checked = error_bound(model, cells_of(records), np.array([r.rgb for r in records]),
                          np.array([r.sigma for r in records]), 0.8, sentinel=np.array([flags[r.plan_index] for r in records]))
    assert batch["data"]["bound"] == pytest.approx(checked.upper, rel=1e-12) and checked.upper != alone.upper
    report = json.loads((session / "report.json").read_text())
    assert report["target_error"]["samples_used"] == 21 and not report["target_error"]["extrapolation"]
    # the report's own statement is the last batch's, at the session's confidence
    assert (report["prediction"]["bound"], report["prediction"]["median_estimate"], report["prediction"]["confidence"]) \
        == (batch["data"]["bound"], batch["data"]["predicted_error"], 0.8)
    measurement = json.loads((session / "brdf.json").read_text())["measurement"]
    assert {key: measurement[key] for key in ("bound", "median_estimate", "confidence")} == \
        {key: report["prediction"][key] for key in ("bound", "median_estimate", "confidence")}
    assert (f"reconstruction (log-relative MSE): error <= {checked.upper:.3g} with 80 % confidence (median "
            f"estimate {checked.median:.3g})") in (session / "summary.txt").read_text().splitlines()
    # its results lost (a kill while writing them): the resume writes them and moves nothing (with
    # its results written, a finished session refuses --resume: test_first_week)
    (session / "report.json").unlink()
    assert main(capture_args(rig, plan, session, "--resume", "--target-error", "10000", "--confidence", "0.8")) == 0
    with Journal.open(session / "session.sqlite") as journal:
        assert len(journal.events()) == len(events) and len(journal.samples()) == 21
    assert json.loads((session / "report.json").read_text())["target_error"] == report["target_error"]


def test_a_plan_gets_sentinels_by_default_only_from_a_model_whose_check_can_flag(tmp_path, capsys):
    from goniofrost.app.cli import main
    from goniofrost.core.cache import cache_path
    from test_session import session_model

    model = session_model()
    folder, plan = str(cache_path("models", model.info["cache_key"], "")), tmp_path / "plan.json"
    assert main(["plan", "--model", folder, "--samples", "17", "--out", str(plan)]) == 0
    out = capsys.readouterr().out
    # 6 training materials: a check at 0.95 needs 19, so the default plan is the design alone
    assert ("sentinels: none (the model's 6 held-out training materials are too few for a check at 0.95: it "
            "would never flag)") in out
    doc = json.loads(plan.read_text())
    assert doc["m"] == 17 and "sentinels" not in doc
    # asked for, they are planned, and the plan says the check cannot flag
    assert main(["plan", "--model", folder, "--samples", "17", "--sentinels", "--out", str(plan)]) == 0
    assert "it never flags" in capsys.readouterr().out and json.loads(plan.read_text())["sentinels"] == 3


def test_a_model_without_the_sentinel_calibration_plans_none_unless_asked(trained, tmp_path):
    from goniofrost.plan.file import with_sentinels
    from goniofrost.core.errors import GoniofrostError

    model, design = trained
    bound = dict(model.noise["calibration"]["bound"])
    bound.pop("sentinel")
    old = copy.copy(model)
    old.noise = model.noise | {"calibration": model.noise["calibration"] | {"bound": bound}}
    doc = {"m": 15, "batch_ends": [15], "samples": [], "selector": "bayes"}
    same, said = with_sentinels(doc, old, design)
    assert same is doc and said == ("sentinels: none (the model has no sentinel calibration (train it again "
                                    "with this version))")
    with pytest.raises(GoniofrostError, match=r"^--sentinels: the model has no sentinel calibration"):
        with_sentinels(doc, old, design, asked=True)
    planned, said = with_sentinels(doc, model, design)
    assert planned["sentinels"] == 3 and said.startswith("sentinels: 3 samples with the first batch, ")


def test_training_among_a_rigs_cells_is_cached_apart_and_records_them():
    from goniofrost.frost.training import train
    from test_session import GRID as SESSION_GRID, TRAINING, session_model

    whole = session_model()
    allowed = np.ones(SESSION_GRID.n_valid, bool)
    allowed[sentinel.calibrated_cells(whole)] = False  # a rig that cannot reach the whole grid's sentinels
    rig = train(["builtin"], only=TRAINING, grid=SESSION_GRID, k_max=18, cache=True, sentinel_candidates=allowed)
    assert rig.info["cache_key"] != whole.info["cache_key"] and "sentinel_candidates" not in whole.info
    assert rig.info["sentinel_candidates"]["cells"] == SESSION_GRID.n_valid - 3
    assert sentinel.calibrated_cells(rig).tolist() == sentinel.cells(SESSION_GRID, 3, allowed).tolist()
    assert not set(sentinel.calibrated_cells(rig).tolist()) & set(sentinel.calibrated_cells(whole).tolist())
    # the same inputs again: the cached model
    again = train(["builtin"], only=TRAINING, grid=SESSION_GRID, k_max=18, cache=True, sentinel_candidates=allowed)
    assert again.content_hash == rig.content_hash
