"""Check cells (frost.check_cells): chosen on the training materials, measured with the first batch
beside the sentinels, never fitted; their error a feature of the checked (19-feature) calibration."""
from __future__ import annotations

import json

import numpy as np
import pytest

from goniofrost.core.grid import MerlGrid
from goniofrost.frost import check_cells, confidence, prediction, sentinel

GRID = MerlGrid(10, 10, 20)


def test_the_pool_is_a_deterministic_farthest_point_sample_of_the_candidates(monkeypatch):
    pool = check_cells.pool(GRID, count=50)
    assert pool.size == 50 and np.all(np.diff(pool) > 0) and pool.max() < GRID.n_valid
    np.testing.assert_array_equal(pool, check_cells.pool(GRID, count=50))
    allowed = np.zeros(GRID.n_valid, bool)
    allowed[::3] = True
    among = check_cells.pool(GRID, allowed, count=50)
    assert allowed[among].all() and among.size == 50
    assert check_cells.pool(GRID, count=10 ** 6).size == GRID.n_valid  # fewer candidates: all of them
    # more candidates than POOL_SUBSAMPLE: drawn from an even stride of them (no pass over every cell)
    monkeypatch.setattr(check_cells, "POOL_SUBSAMPLE", 100)
    strided = check_cells.pool(GRID, count=10 ** 6)
    np.testing.assert_array_equal(strided, np.linspace(0, GRID.n_valid - 1, 100).round().astype(np.int64))


def test_the_pool_error_averaged_over_cells_is_the_captures_check_error():
    """Training's feature (``pool_errors`` at the chosen cells, their mean, its log) and a capture's
    (``sentinel.check_error`` of the same samples, as ``measured_check_errors`` computes it) agree."""
    rng = np.random.default_rng(4)
    rows, coefficients, b = rng.normal(size=(7, 5)), rng.normal(size=(5, 6)), rng.normal(size=(7, 6))
    errors = check_cells.pool_errors(b, rows, coefficients)  # (7 cells, 2 materials)
    chosen = [1, 4, 6]
    for material in range(2):
        columns = [3 * material, 3 * material + 1, 3 * material + 2]
        expected = sentinel.check_error(rows[chosen], coefficients, b[chosen], columns)
        assert check_cells.feature(errors.T, chosen)[material] == pytest.approx(np.log(expected), rel=1e-6)
    # a known value: one cell, one material, misses 1, 2, 3: (1 + 4 + 9) / 3
    assert check_cells.pool_errors(np.array([[1.0, 2.0, 3.0]]), np.zeros((1, 2)), np.zeros((2, 3)))[0, 0] == \
        pytest.approx(14 / 3)


def test_the_greedy_choice_finds_the_cell_that_carries_the_missing_error():
    """Records whose log actual error is a known feature plus the log error at pool column 5:
    the first chosen column is 5 (ties broken by the lowest index), deterministically."""
    rng = np.random.default_rng(0)
    n, p = 400, 12
    m = np.tile([15, 20, 25, 30], n // 4)
    fold = np.arange(n) % 10
    x = np.column_stack([np.ones(n), rng.normal(size=n)])
    errors = np.exp(rng.normal(size=(n, p)))
    y = x @ [0.5, 1.0] + np.log(errors[:, 5])
    allowed = np.ones(p, bool)
    first = check_cells.choose(x, y, fold, m, errors, allowed, np.ones(n, bool), 1)
    assert first == [5]
    allowed[5] = False
    assert 5 not in check_cells.choose(x, y, fold, m, errors, allowed, np.ones(n, bool), 3)
    assert check_cells.choose(x, y, fold, m, errors, allowed, np.ones(n, bool), 3) == \
        check_cells.choose(x, y, fold, m, errors, allowed, np.ones(n, bool), 3)


def test_the_objective_matches_a_direct_cross_fit_and_a_column_in_the_span_of_the_features_adds_nothing():
    """The per-fold-sums objective against the plain computation (least squares without each fold,
    its records' residual variance per m, averaged); a candidate equal to a feature's column (in the
    span of x) gets the features' own variance, without a warning."""
    import warnings

    rng = np.random.default_rng(1)
    n = 200
    m, fold = np.tile([15, 20], n // 2), np.arange(n) % 5
    x = np.column_stack([np.ones(n), rng.normal(size=n)])
    y = x @ [0.2, 0.7] + rng.normal(size=n)
    z = np.column_stack([rng.normal(size=n), x[:, 1]])   # column 1: exactly a feature
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        objective = check_cells._objective(x, y, fold, z, m, [15, 20])
    for c, columns in ((0, [x, z[:, :1]]), (1, [x])):
        a, residual = np.column_stack(columns), np.empty(n)
        for f in range(5):
            beta, *_ = np.linalg.lstsq(a[fold != f], y[fold != f], rcond=None)
            residual[fold == f] = y[fold == f] - a[fold == f] @ beta
        expected = np.mean([residual[m == v].var() for v in (15, 20)])
        assert objective[c] == pytest.approx(expected, rel=1e-9)


@pytest.fixture(scope="module")
def trained(small_trained):
    return small_trained


def test_a_trained_model_chooses_valid_check_cells_outside_the_sentinels_and_the_inner_designs(trained):
    from test_frost import synthetic_tables
    from goniofrost.frost import calibration, noise
    from goniofrost.frost.training import NOISE_FLOOR, TrainingOptions, _eigen_components, _map_and_gram, fit_model

    model, _ = trained
    checked = prediction.checked_of(model)
    cells = check_cells.cells_of(model)
    assert len(checked["coefficients"]) == prediction.CHECKED_FEATURES == 19
    assert cells.size == check_cells.CHECKS == len(set(cells.tolist()))
    assert np.all((cells >= 0) & (cells < GRID.n_valid))
    assert not set(cells.tolist()) & set(sentinel.calibrated_cells(model).tolist())
    assert set(cells.tolist()) <= set(check_cells.pool(GRID).tolist())
    assert len(checked["bound"]["scores"]) == 40 and "sentinel" not in checked["bound"]
    # outside every inner design: the inner folds' designs (the chosen scale's) sampled none of them
    tables = synthetic_tables(GRID, 40, seed=3)
    names = [f"mat{i}" for i in range(40)]
    mapped, _, _, gram = _map_and_gram(tables, names, np.asarray(model.weight), model.eps, False)
    svals, _ = _eigen_components(gram, 30)
    folds = noise.inner_folds(gram, 40, svals.size)
    learned = np.maximum(noise.smooth_on_grid(noise.representation_variance(mapped, folds), GRID), NOISE_FLOOR)
    scale = model.noise["recon_scale"] * model.noise["design_scale"]
    from goniofrost.frost.bayes_selection import greedy_designs
    for fold in folds:
        d_f = calibration._fold_dictionary(mapped, fold.projector)
        [design] = greedy_designs(d_f, fold.singular_values ** 2, calibration._prior(fold), [scale * learned],
                                  max(calibration.M_VALUES))
        assert not set(cells.tolist()) & set(np.asarray(design.rows).tolist())
    # deterministic: the same training, the same cells and calibration
    again = fit_model(tables, names, GRID, TrainingOptions(k_max=30))
    assert prediction.checked_of(again) == checked


def test_the_checked_calibration_is_used_when_the_check_cells_were_measured_and_the_17_otherwise(trained):
    from test_frost import synthetic_tables
    from goniofrost.frost.reconstruction import _posterior, error_bound

    model, design = trained
    sentinels, checks = sentinel.calibrated_cells(model), check_cells.cells_of(model)
    table = synthetic_tables(GRID, 1, seed=11)[0].astype(np.float64)
    plain = error_bound(model, design, table[design], confidence=0.95)
    with_sentinels = np.concatenate([design, sentinels])
    flags = np.arange(with_sentinels.size) >= design.size
    only_sentinels = error_bound(model, with_sentinels, table[with_sentinels], confidence=0.95, sentinel=flags)
    assert (only_sentinels.median, only_sentinels.upper) == (plain.median, plain.upper)  # the 17 (or 5 / 11)
    everything = np.concatenate([design, sentinels, checks])
    flags = np.arange(everything.size) >= design.size
    bound = error_bound(model, everything, table[everything], confidence=0.95, sentinel=flags)
    # the checked calibration's: its prediction from the sentinels' and the check cells' errors
    *_, post, (_, _, z2, energy, extra, level, spread, clean, coordinates) = _posterior(model, design, table[design],
                                                                                        None)
    errors = [sentinel.measured_check_errors(model, cells, table[cells], post.coefficients)[0]
              for cells in (sentinels, checks)]
    checked = prediction.checked_of(model)
    predicted = prediction.predict(checked, prediction.Features(clean, z2, energy, design.size, level, spread,
                                                                coordinates, errors))
    centre = confidence._at_m(checked["bound"], "center", design.size)
    assert bound.median == pytest.approx(float(predicted * np.exp(centre)) + extra, rel=1e-12)
    assert bound.median != plain.median and bound.out_of_model == only_sentinels.out_of_model
    # the bound: the larger of the checked calibration's and the unchecked one's (the sentinels' run)
    q = confidence.conformal_quantile(checked["bound"]["scores"], 0.95)
    scale = confidence._at_m(checked["bound"], "scale", design.size)
    checked_upper = float(predicted * np.exp(centre + q * scale)) + extra
    assert bound.upper == pytest.approx(max(checked_upper, only_sentinels.upper), rel=1e-12)
    # check cells without the sentinels, or only some of them: the unchecked calibration
    partial = np.concatenate([design, sentinels, checks[:2]])
    flags = np.arange(partial.size) >= design.size
    assert error_bound(model, partial, table[partial], confidence=0.95, sentinel=flags).median == plain.median


def test_with_the_check_cells_the_bound_is_the_larger_of_the_two_calibrations_and_the_median_the_checked():
    """Known values: unchecked bound centre 0, scale 1; checked centre log 2, scale 0.5; scores give
    the same quantile q to both; a point prediction of 1 (unchecked) and 1 (checked)."""
    scores = list(np.linspace(0.0, 2.0, 100))  # 100 held-out scores: the 0.95 quantile is their 96th
    q = confidence.conformal_quantile(scores, 0.95)
    plain = {"m": [10, 60], "center": [0.0, 0.0], "scale": [1.0, 1.0], "scores": scores,
             "log_z2_max": [9.0, 9.0], "log_energy_max": [9.0, 9.0]}
    checked = {**plain, "center": [np.log(2.0)] * 2, "scale": [0.5, 0.5]}
    calibration = {"bound": plain, "checked": {"bound": checked}}
    out = confidence.error_bounds(calibration, 1.0, 1.0, 1.0, 20, 0.95, confidence.Evidence(checked_predicted=1.0))
    assert float(out["median"]) == pytest.approx(2.0)  # the checked median
    # unchecked upper exp(q), checked 2 exp(q / 2): the larger
    assert float(out["upper"]) == pytest.approx(max(np.exp(q), 2 * np.exp(q / 2)))
    low = confidence.error_bounds(calibration, 1.0, 1.0, 1.0, 20, 0.95, confidence.Evidence(checked_predicted=0.01))
    assert float(low["upper"]) == pytest.approx(np.exp(q))  # the checked bound lower: the unchecked one
    assert float(low["median"]) == pytest.approx(0.02)
    alone = confidence.error_bounds(calibration, 1.0, 1.0, 1.0, 20, 0.95)  # no checks measured
    assert (float(alone["median"]), float(alone["upper"])) == pytest.approx((1.0, np.exp(q)))


def test_the_simulated_capture_counts_the_check_cells_and_uses_the_checked_bound(trained):
    from test_frost import synthetic_tables
    from goniofrost.bench import bayes_eval

    model, _ = trained
    from goniofrost.frost.bayes_selection import select_bayes
    order = np.asarray(select_bayes(model, 20).positions, dtype=np.int64)
    truth = synthetic_tables(GRID, 2, seed=11).astype(np.float64)
    checked = bayes_eval.target_outcomes(model, order, truth, model.to_log(truth), 1e9,
                                         checks=bayes_eval.MeasuredChecks())
    np.testing.assert_array_equal(checked["samples"], [21, 21])  # 15 + 3 sentinels + 3 check cells
    rows = bayes_eval.bound_rows(model, order[:15], truth, model.to_log(truth))
    np.testing.assert_array_equal(checked["pred_mse"], rows["median"])
    assert not np.array_equal(rows["median"], rows["median_unchecked"])
    bare = bayes_eval.target_outcomes(model, order, truth, model.to_log(truth), 1e9,
                                      checks=bayes_eval.MeasuredChecks(check_cells=np.zeros(0, np.int64)))
    np.testing.assert_array_equal(bare["samples"], [18, 18])
    np.testing.assert_array_equal(bare["pred_mse"], rows["median_unchecked"])


def test_a_plan_measures_the_check_cells_with_the_sentinels_and_without_them_none(trained, tmp_path):
    from goniofrost.plan.file import sentinel_flags, with_sentinels

    model, design = trained
    doc = {"m": 15, "batch_ends": [15], "samples": [{}] * 15, "selector": "bayes"}
    planned, said = with_sentinels(doc, model, design)
    assert (planned["m"], planned["sentinels"], planned["checks"], planned["batch_ends"]) == (21, 3, 3, [21])
    assert said.endswith("; check cells: 3 samples with the first batch (never fitted: their error sharpens the bound)")
    assert sentinel_flags(planned["samples"]) == [False] * 15 + [True] * 6
    assert [bool(s.get("check")) for s in planned["samples"]] == [False] * 18 + [True] * 3
    # a candidate mask (a rig) that cannot reach one of them: the sentinels alone
    allowed = np.ones(GRID.n_valid, bool)
    allowed[check_cells.cells_of(model)[0]] = False
    planned, said = with_sentinels(doc, model, design, allowed)
    assert (planned["m"], "checks" in planned) == (18, False) and "check cells: none" in said


def test_plan_no_sentinels_has_no_check_cells(tmp_path, capsys):
    from goniofrost.app.cli import main
    from goniofrost.core.cache import cache_path
    from test_session import session_model

    model = session_model()
    folder, plan = str(cache_path("models", model.info["cache_key"], "")), tmp_path / "plan.json"
    assert main(["plan", "--model", folder, "--samples", "17", "--no-sentinels", "--out", str(plan)]) == 0
    doc = json.loads(plan.read_text())
    assert doc["m"] == 17 and "checks" not in doc and not any(s.get("check") for s in doc["samples"])
    assert main(["plan", "--model", folder, "--samples", "17", "--sentinels", "--out", str(plan)]) == 0
    doc = json.loads(plan.read_text())
    assert (doc["m"], doc["sentinels"], doc["checks"]) == (23, 3, 3)
    assert f"{plan}: m = 17 samples + 3 sentinels + 3 check cells" in capsys.readouterr().out
