"""The Bayesian pipeline: noise cross-validation, posterior, predicted error, A-optimal
selection, stopping rule, model format 2 (small grids, synthetic materials; a few seconds)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from goniofrost.core.grid import MerlGrid
from goniofrost.frost import bayes_selection, confidence, noise, posterior, prediction, stopping
from goniofrost.frost.bayes_selection import greedy_design, greedy_designs, select_bayes
from goniofrost.frost.model import FrostModel, ModelError
from goniofrost.frost.reconstruction import error_bound, reconstruct, reconstruct_bayes
from goniofrost.frost.selection import SelectionError
from goniofrost.frost.training import _map_and_gram
from goniofrost.core.grid import cosine_weight

from recorded_blas import rounds_as_recorded
from test_frost import synthetic_tables

GRID = MerlGrid(10, 10, 20)


@pytest.fixture(scope="module")
def tables() -> np.ndarray:
    return synthetic_tables(GRID, 24, seed=1)


@pytest.fixture(scope="module")
def model(synthetic24) -> FrostModel:
    assert synthetic24.grid == GRID  # the session's model of these tables
    return synthetic24


@pytest.fixture(scope="module")
def scalar_model(model) -> FrostModel:
    """The same model without a learned noise model (what a format-1 model loads as)."""
    return FrostModel(**{f: getattr(model, f) for f in ("grid", "names", "eps", "dictionary", "singular_values",
                                                         "coefficients", "mean", "reference", "weight")})


def reference_greedy(d, s2, prior, noise_var, m, rows=None):
    """Textbook greedy A-optimal design in float64: recompute every score from Sigma each step."""
    d = np.asarray(d, dtype=np.float64)
    rows = np.arange(d.shape[0]) if rows is None else rows
    sigma, picks = np.diag(prior), []
    for _ in range(m):
        u = d[rows] @ sigma                                         # (n_c, K) rows of D Sigma
        score = np.einsum("ij,ij->i", u * s2, u) / (noise_var[rows] + np.einsum("ij,ij->i", u, d[rows]))
        score[np.isin(rows, picks)] = -1
        j = int(rows[np.argmax(score)])
        uj = sigma @ d[j]
        sigma = sigma - np.outer(uj, uj) / (noise_var[j] + d[j] @ uj)
        picks.append(j)
    return np.array(picks), sigma


# ----- selection ---------------------------------------------------------------------------
@pytest.mark.parametrize("masked", [False, True])
def test_greedy_design_equals_the_textbook_greedy(model, masked):
    d, s2 = np.asarray(model.dictionary), model.singular_values ** 2
    prior, noise_var = posterior.prior_variance(model), posterior.cell_noise(model)
    rows = np.flatnonzero(np.arange(GRID.n_valid) % 3 != 1) if masked else None
    design = greedy_design(d, s2, prior, noise_var, 25, rows=rows)
    picks, sigma = reference_greedy(d, s2, prior, noise_var, 25, rows)
    assert list(design.rows) == list(picks)
    np.testing.assert_allclose(design.covariance, sigma, rtol=1e-9, atol=1e-12)
    # the design error after the last pick is the mean predictive variance over all cells
    q = np.einsum("ij,jk,ik->i", d.astype(np.float64), sigma, d.astype(np.float64))
    np.testing.assert_allclose(design.design_errors[-1], np.mean(q + noise_var), rtol=1e-5)
    assert np.all(np.diff(design.design_errors) < 0) and np.all(np.diff(design.pick_seconds) >= 0)


BEFORE_FUSION = Path(__file__).parent / "data" / "bayes_designs_before_fusion.npz"


@pytest.mark.parametrize("masked", [False, True])
def test_designs_equal_the_single_design_passes_to_the_bit(model, masked):
    """``data/bayes_designs_before_fusion.npz``: greedy_design's picks, design errors and final
    covariance (40 picks, design scales 1, 2, 4, all cells or every third cell left out, one
    thread) from the implementation before several designs shared a pass. The shared passes
    (three designs at once, on 3 threads of 4 pieces each) and greedy_design (any thread count)
    give the same numbers to the bit, and the picks and numbers of the file: to the bit where BLAS
    rounds as where it was made (``recorded_blas``), else the same picks and numbers within float
    rounding (the model itself is trained with BLAS)."""
    d, s2 = np.asarray(model.dictionary), model.singular_values ** 2
    prior, noise_var = posterior.prior_variance(model), posterior.cell_noise(model)
    rows = np.flatnonzero(np.arange(GRID.n_valid) % 3 != 1) if masked else None
    before, scales = np.load(BEFORE_FUSION), (1.0, 2.0, 4.0)
    same = np.testing.assert_array_equal if rounds_as_recorded() else \
        lambda actual, desired: np.testing.assert_allclose(actual, desired, rtol=1e-6, atol=1e-6 * np.abs(desired).max())
    shared = greedy_designs(d, s2, prior, [a * noise_var for a in scales], 40, rows=rows, threads=3)
    for a, together in zip(scales, shared):
        key = f"{'masked' if masked else 'all'}_x{a:g}"
        single = greedy_design(d, s2, prior, a * noise_var, 40, rows=rows, threads=2)
        for name in ("rows", "design_errors", "covariance"):
            np.testing.assert_array_equal(getattr(together, name), getattr(single, name), err_msg=name)
        np.testing.assert_array_equal(together.rows, before[f"{key}_rows"])
        same(together.design_errors, before[f"{key}_errors"])
        same(together.covariance, before[f"{key}_covariance"])
    assert len({tuple(design.rows) for design in shared}) == 3  # the scales do pick differently


def test_the_passes_hold_the_noise_in_float32_only_where_that_is_exact(model):
    """A model's learned noise times a power-of-two scale is float32 exactly and goes to the
    kernels narrowed (the test above: the same bits as before); a noise that is not keeps
    float64, and its design is still the textbook greedy."""
    exact = np.array([[0.5, 3.0, np.inf]])
    assert bayes_selection._compact(exact).dtype == np.float32
    np.testing.assert_array_equal(bayes_selection._compact(exact), exact)
    inexact = np.array([[0.1, 3.0]])  # 0.1 has no float32 twin
    assert bayes_selection._compact(inexact).dtype == np.float64
    d, s2 = np.asarray(model.dictionary), model.singular_values ** 2
    prior, noise_var = posterior.prior_variance(model), posterior.cell_noise(model) * (1 + 2.0 ** -40)
    assert bayes_selection._Forms(d, None, [noise_var], 1).open_noise.dtype == np.float64
    picks, _ = reference_greedy(d, s2, prior, noise_var, 20)
    np.testing.assert_array_equal(greedy_design(d, s2, prior, noise_var, 20).rows, picks)


def test_bayes_selection_is_deterministic_nested_and_thread_independent(model):
    long = select_bayes(model, 30)
    assert list(select_bayes(model, 30).positions) == list(long.positions)
    for m in (1, 7, 20):
        assert list(select_bayes(model, m).positions) == list(long.positions[:m])
    for threads in (1, 3):
        assert list(select_bayes(model, 30, threads=threads).positions) == list(long.positions)
    assert long.selector == "bayes" and len(set(long.positions)) == 30
    np.testing.assert_array_equal(long.cells, GRID.valid_cells[long.positions])


def test_bayes_selection_respects_the_candidate_mask(model):
    from goniofrost.frost.selection import candidate_mask_max_angle

    mask = candidate_mask_max_angle(GRID, 50.0)
    picks = select_bayes(model, 20, candidates=mask).positions
    assert mask[picks].all()


def test_max_error_stops_at_the_first_pick_below_the_target(model):
    full = select_bayes(model, 40)
    target = float(full.residuals[14])  # the predicted error after 15 picks
    stopped = select_bayes(model, max_error=target)
    first = int(np.argmax(full.residuals <= target)) + 1
    assert stopped.m == first and list(stopped.positions) == list(full.positions[:first])
    assert stopped.residuals[-1] <= target < stopped.residuals[-2]


@pytest.mark.parametrize("kwargs, message", [
    ({}, "give exactly one of m"),
    ({"m": 0}, r"samples m \(--samples\): expected an integer in \[1, 1000\], found 0"),
    ({"m": 100000}, r"samples m \(--samples\): expected an integer in \[1, 1000\], found 100000"),  # not minutes of picks
    ({"m": 5, "max_error": 0.1}, "give exactly one of m"),
    ({"max_error": -1.0}, r"max_error \(--max-error\): expected a number > 0, found -1.0"),
    ({"max_error": 1e-9}, r"max_error \(--max-error\): 1e-09 is out of reach"),
    ({"m": 5, "candidates": np.zeros(3, bool)}, r"candidates: expected a bool mask of shape"),
])
def test_bad_bayes_selection_options(model, kwargs, message):
    with pytest.raises(SelectionError, match=message):
        select_bayes(model, **kwargs)


# ----- posterior and reconstruction ------------------------------------------------------------
def test_scalar_noise_posterior_mean_is_ridge_over_all_atoms(scalar_model, tables):
    truth = tables[3].astype(np.float64)
    pos = select_bayes(scalar_model, 12).positions
    bayes = reconstruct_bayes(scalar_model, pos, truth[pos], with_std=False).brdf
    ridge = reconstruct(scalar_model, pos, truth[pos], eta=posterior.SCALAR_ETA, n_atoms=scalar_model.n_components)
    np.testing.assert_allclose(bayes, ridge, rtol=1e-5, atol=1e-9)


def test_loo_residuals_equal_refits_without_each_sample(model):
    rng = np.random.default_rng(3)
    pos = np.sort(rng.choice(GRID.n_valid, 9, replace=False))
    rows = np.asarray(model.dictionary[pos], np.float64)
    noise_var = rng.uniform(0.01, 0.05, (9, 2))
    b = rng.standard_normal((9, 2))
    prior = posterior.prior_variance(model)
    post = posterior.fit(rows, noise_var, prior, b, model.singular_values ** 2, 1.0, GRID.n_valid)
    for i in range(9):
        keep = np.arange(9) != i
        for c in range(2):
            alone = posterior.fit(rows[keep], noise_var[keep, c], prior, b[keep, c:c + 1],
                                  model.singular_values ** 2, 1.0, GRID.n_valid)
            predicted = rows[i] @ alone.coefficients[:, 0]
            q = rows[i] @ alone.covariances[0] @ rows[i]
            assert post.loo_residuals[i, c] == pytest.approx(b[i, c] - predicted, rel=1e-8)
            assert post.loo_variance[i, c] == pytest.approx(noise_var[i, c] + q, rel=1e-8)


def test_predictive_std_mean_square_is_the_predicted_error(model, tables):
    truth = tables[5].astype(np.float64)
    pos = select_bayes(model, 15).positions
    rec = reconstruct_bayes(model, pos, truth[pos])
    # what OUT.json says and what OUT.std.binary holds: the std is scaled to the predicted error
    assert np.mean(rec.std ** 2) == pytest.approx(rec.predicted_error, rel=1e-6)
    assert rec.std.shape == (GRID.n_valid, 3) and np.all(rec.std > 0) and rec.samples == 15


def test_the_variance_pass_gives_every_cells_d_sigma_d_to_float32_rounding(model):
    """d^T Sigma d at every cell, the well-measured ones too: the Woodbury form (used with fewer
    samples than atoms) subtracted two float32 numbers far larger than their difference: 2e-4 off
    at 82 of these 1670 cells, up to 5.4 times on the full grid (2092 cells clamped to 0)."""
    d = np.asarray(model.dictionary, np.float64)
    for m in (5, 15, 40):  # fewer samples than atoms and more
        cells = select_bayes(model, m).positions
        post = posterior.fit(d[cells], posterior.cell_noise(model)[cells], posterior.prior_variance(model),
                             np.zeros((m, 1)), model.singular_values ** 2, 0.0, GRID.n_valid)
        _, var, _ = posterior.mean_and_variance(model.dictionary, model.mean, post)
        exact = np.einsum("ij,jk,ik->i", d, post.covariances[0], d)
        np.testing.assert_allclose(var[:, 0], exact, rtol=1e-4)


def test_sample_sigmas_widen_the_uncertainty_at_their_cells(model, tables):
    truth = tables[7].astype(np.float64)
    pos = select_bayes(model, 15).positions
    plain = reconstruct_bayes(model, pos, truth[pos])
    noisy = reconstruct_bayes(model, pos, truth[pos], sigmas=0.5 * truth[pos])
    # 50 % sample noise: a larger design error, residuals the noise now explains, wider std
    assert noisy.design_error > plain.design_error and noisy.z2 < plain.z2
    assert np.all(noisy.std[pos] > plain.std[pos])
    # the prediction: calibrated on the noise-free design error, plus what the noise adds to it
    expected = float(prediction.predict(prediction.calibration_of(model), prediction.Features(
        plain.design_error, noisy.z2, noisy.energy, 15, noisy.level, noisy.spread))) + noisy.design_error - plain.design_error
    # level and spread are the samples' own: the sigmas change neither
    assert (noisy.level, noisy.spread) == (plain.level, plain.spread)
    assert noisy.predicted_error == pytest.approx(expected, rel=1e-9)
    with pytest.raises(Exception, match="sample 2 standard deviation: negative value"):
        reconstruct_bayes(model, pos, truth[pos], sigmas=np.where(np.arange(15)[:, None] == 2, -1.0, 0.1) * np.ones((15, 3)))


def test_predicted_error_is_specific_to_the_material(model, scalar_model, tables):
    """Same cells, two materials: the one far from the training set gets the larger prediction
    (learned noise, no calibration: design error x z2, from the leave-one-out residuals at its
    own samples; a calibration fitted on these alike synthetic materials gives z2 no weight)."""
    from goniofrost.frost.metrics import log_relative_mse

    model = FrostModel(**{f: getattr(scalar_model, f) for f in ("grid", "names", "eps", "dictionary", "singular_values",
                                                                "coefficients", "mean", "reference", "weight")},
                       noise_variance=model.noise_variance)
    pos = select_bayes(model, 20).positions
    inside = tables[2].astype(np.float64)
    outside = synthetic_tables(GRID, 1, seed=99)[0].astype(np.float64) * np.linspace(0.2, 5, GRID.n_valid)[:, None]
    a, b = (reconstruct_bayes(model, pos, t[pos]) for t in (inside, outside))
    err_a, err_b = log_relative_mse(model, inside, a.brdf), log_relative_mse(model, outside, b.brdf)
    assert a.design_error == b.design_error
    assert err_b > 10 * err_a and b.predicted_error > 10 * a.predicted_error
    assert b.predicted_error == pytest.approx(b.design_error * b.z2)


def synthetic_records(rng, n: int) -> tuple:
    """(m, design error, z2, energy, level, spread), each (n,), of n made-up held-out records."""
    m = rng.choice([5, 10, 20, 40, 60], n)
    design, z2, energy = rng.uniform(0.01, 0.1, n), np.exp(rng.normal(0, 1, n)), np.exp(rng.normal(0, 0.5, n))
    level, spread = rng.normal(0, 1, n), np.exp(rng.normal(0, 0.5, n))
    return m, design, z2, energy, level, spread


def test_calibration_fit_recovers_a_known_law_in_the_samples_level_and_spread():
    from goniofrost.frost.calibration import CvRecords, fit_calibration

    rng = np.random.default_rng(3)
    n = 600
    m, design, z2, energy, level, spread = synthetic_records(rng, n)
    beta = np.array([0.3, 0.9, 0.5, 0.2, -0.1, 0.4, -0.15, 0.25, 0.05, -0.08, 0.1])
    x = prediction.feature_matrix(prediction.Features(design, z2, energy, m, level, spread), [5, 60])
    assert x.shape == (n, prediction.SAMPLE_FEATURES)
    records = CvRecords(np.arange(n) % 10, np.arange(n), m, np.exp(x @ beta), design, z2, energy, level, spread)
    cal = fit_calibration(records)
    np.testing.assert_allclose(cal["coefficients"], beta, atol=1e-9)
    assert cal["typical_level"] == pytest.approx(level.mean())
    assert cal["typical_log_spread"] == pytest.approx(np.log(spread).mean())
    np.testing.assert_allclose(prediction.predict(cal, prediction.Features(design, z2, energy, m, level, spread)),
                               np.exp(x @ beta), rtol=1e-9)
    # beyond the features' range of the records the quadratic terms do not extrapolate: clamped
    lo, hi = cal["feature_range"]
    assert lo[2] == pytest.approx(level.min()) and hi[2] == pytest.approx(level.max())
    at_edge = prediction.predict(cal, prediction.Features(0.05, 1.0, 1.0, 20, hi[2], 1.0))
    assert prediction.predict(cal, prediction.Features(0.05, 1.0, 1.0, 20, hi[2] + 50.0, 1.0)) == pytest.approx(
        at_edge, rel=1e-12)
    assert prediction.predict(cal, prediction.Features(0.05, 1.0, 1.0, 20, hi[2] - 0.5, 1.0)) != pytest.approx(
        at_edge, rel=1e-3)
    with pytest.raises(ValueError, match=r"^predict: this calibration needs the samples' level and spread$"):
        prediction.predict(cal, prediction.Features(design, z2, energy, m))
    # a calibration of the five basic features (a model trained before level and spread) ignores them
    basic = {"coefficients": beta[:5].tolist(), "m_range": [5, 60]}
    np.testing.assert_allclose(prediction.predict(basic, prediction.Features(design, z2, energy, m, level, spread)),
                               np.exp(x[:, :5] @ beta[:5]), rtol=1e-12)
    # level and spread of one material: over its sampled cells and its channels only
    b = np.array([[1.0, 2.0, 3.0, 100.0], [3.0, 4.0, 5.0, -100.0]])
    assert prediction.sample_level(b, [0, 1, 2]) == (3.0, pytest.approx(np.var([1, 2, 3, 3, 4, 5])))


def test_calibration_fit_recovers_a_known_law_in_the_coordinates():
    from goniofrost.frost.calibration import CvRecords, fit_calibration, model_atoms

    rng = np.random.default_rng(5)
    n = 600
    m, design, z2, energy, level, spread = synthetic_records(rng, n)
    coords = rng.normal(0, 1, (n, prediction.COORDINATES))
    beta = np.array([0.3, 0.9, 0.5, 0.2, -0.1, 0.4, -0.15, 0.25, 0.05, -0.08, 0.1, 0.3, -0.2, 0.1, 0.0, 0.15, -0.05])
    x = prediction.feature_matrix(prediction.Features(design, z2, energy, m, level, spread, coordinates=coords),
                                  [5, 60])
    assert x.shape == (n, len(prediction.FEATURES)) == (n, 17)
    records = CvRecords(np.arange(n) % 10, np.arange(n), m, np.exp(x @ beta), design, z2, energy, level, spread,
                        coordinates=coords)
    cal = fit_calibration(records)  # the law holds exactly: the 17 are chosen and recovered
    np.testing.assert_allclose(cal["coefficients"], beta, atol=1e-9)
    np.testing.assert_allclose(cal["typical_coordinates"], coords.mean(axis=0))
    np.testing.assert_allclose(prediction.predict(cal, prediction.Features(design, z2, energy, m, level, spread, coords)),
                               np.exp(x @ beta),
                               rtol=1e-9)
    lo, hi = cal["feature_range"]  # clamped to the records' range like the others
    assert lo[4] == pytest.approx(coords[:, 0].min()) and hi[4] == pytest.approx(coords[:, 0].max())
    far = np.array([hi[4] + 10.0, 0, 0, 0, 0, 0])
    edge = np.array([hi[4], 0, 0, 0, 0, 0])
    assert prediction.predict(cal, prediction.Features(0.05, 1.0, 1.0, 20, 0.0, 1.0, far)) == pytest.approx(
        prediction.predict(cal, prediction.Features(0.05, 1.0, 1.0, 20, 0.0, 1.0, edge)), rel=1e-12)
    with pytest.raises(ValueError, match=r"^predict: this calibration needs the material's coordinates$"):
        prediction.predict(cal, prediction.Features(design, z2, energy, m, level, spread))
    # an 11-feature calibration ignores them
    eleven = {"coefficients": beta[:11].tolist(), "m_range": [5, 60]}
    np.testing.assert_allclose(prediction.predict(eleven, prediction.Features(design, z2, energy, m, level, spread,
                                                                              coords)),
                               np.exp(x[:, :11] @ beta[:11]), rtol=1e-12)
    # the coordinates: the first 6 coefficients times sqrt(t), averaged over the channels, zeros beyond K
    coefficients = np.arange(12.0).reshape(4, 3)
    np.testing.assert_allclose(prediction.material_coordinates(coefficients, [0, 1, 2], 4),
                               [2.0, 8.0, 14.0, 20.0, 0.0, 0.0])
    # model_atoms maps a training column's weights (e_j) to its own coefficients on the atoms (V's row j)
    mapped = rng.normal(0, 1, (200, 12))
    mapped -= mapped.mean(axis=1, keepdims=True)
    gram = mapped.T @ mapped
    evals, evecs = np.linalg.eigh(gram)
    order = np.argsort(evals)[::-1][:8]
    svals, vt = np.sqrt(evals[order]), evecs[:, order].T
    atoms = model_atoms(gram, vt, svals)
    assert atoms.shape == (prediction.COORDINATES, 12)
    np.testing.assert_allclose(atoms @ np.eye(12)[3], vt[:6, 3], atol=1e-10)
    # and any column in the atoms' span to its coefficients: D c with D = X V
    c = rng.normal(0, 1, 8)
    y = vt.T @ c  # X y = X V c = D c
    np.testing.assert_allclose(atoms @ y, c[:6], atol=1e-10)


def test_calibration_fit_recovers_a_known_law():
    from goniofrost.frost.calibration import CvRecords, fit_calibration

    rng = np.random.default_rng(0)
    n = 400
    m = rng.choice([5, 10, 20, 40, 60], n)
    design, z2, energy = rng.uniform(0.01, 0.1, n), np.exp(rng.normal(0, 1, n)), np.exp(rng.normal(0, 0.5, n))
    actual = np.exp(0.3) * design ** 0.9 * z2 ** 0.5 * energy ** 0.2 * m ** -0.1
    records = CvRecords(np.zeros(n, int), np.arange(n), m, actual, design, z2, energy)
    cal = fit_calibration(records)
    np.testing.assert_allclose(cal["coefficients"], [0.3, 0.9, 0.5, 0.2, -0.1], atol=1e-9)
    assert cal["fit"]["per_m"]["20"]["spearman"] == pytest.approx(1.0)
    assert cal["fit"]["per_m"]["20"]["within_factor_2"] == 1.0 and cal["m_range"] == [5, 60]


def few_materials_records(seed: int):
    """CvRecords like a 6-material model's (6 folds of one held-out material each, the m of
    training): per fold a design error falling by 0.03 in log from m = 5 to 60 around a level of
    its own (the representation error dominates), each material's log error its own large offset
    plus a little noise, whatever m: least squares gives the design error and log m whatever
    coefficients the chance between the folds gives."""
    from goniofrost.frost.calibration import M_VALUES, CvRecords

    rng = np.random.default_rng(seed)
    m = np.tile(np.asarray(M_VALUES), 6)
    fold = np.repeat(np.arange(6), len(M_VALUES))
    log_design = 3.55 + 0.004 * rng.normal(size=6)[fold] - 0.012 * np.log(m)
    log_actual = 3.0 * rng.normal(size=6)[fold] + 0.001 * rng.normal(size=m.size)
    z2, energy = np.exp(0.3 * rng.normal(size=m.size)), np.exp(0.3 * rng.normal(size=m.size))
    return CvRecords(fold, fold, m, np.exp(log_actual), np.exp(log_design), z2, energy)


@pytest.mark.parametrize("seed, free_signs, fixed", [
    (0, (-238.2, -2.949), [1]),      # the design error's the wrong way: held at 0
    (2, (131.8, 1.490), [4]),        # log m's the wrong way: held at 0
    (4, (-306.5, -3.650), [1, 4]),   # the design error's, and without it log m's: both at 0
])
def test_a_calibration_on_few_materials_never_predicts_more_error_for_more_samples(seed, free_signs, fixed):
    """Where least squares gives the design error a negative or log m a positive coefficient
    (a 6-material model's records), the calibration is the sign-constrained least squares (the
    least squares of the other features, to the bit), a typical material's prediction along a
    design does not rise with m, and the bound is calibrated on the residuals of the same
    constrained fits, each inner fold's without it."""
    from scipy.optimize import lsq_linear

    from goniofrost.frost import confidence
    from goniofrost.frost.calibration import fit_calibration

    records = few_materials_records(seed)
    x, y = records.features([5, 60], prediction.BASIC_FEATURES), np.log(records.actual)
    free, *_ = np.linalg.lstsq(x, y, rcond=None)
    assert free[[1, 4]] == pytest.approx(free_signs, rel=1e-3)  # least squares alone: a wrong sign
    cal = fit_calibration(records)
    beta = np.asarray(cal["coefficients"])
    assert beta.size == prediction.BASIC_FEATURES and beta[1] >= 0 and beta[4] <= 0
    keep = [j for j in range(prediction.BASIC_FEATURES) if j not in fixed]
    assert beta[fixed].tolist() == [0.0] * len(fixed)
    assert np.array_equal(beta[keep], np.linalg.lstsq(x[:, keep], y, rcond=None)[0])
    bounds = ([-np.inf, 0.0, -np.inf, -np.inf, -np.inf], [np.inf, np.inf, np.inf, np.inf, 0.0])
    np.testing.assert_allclose(beta, lsq_linear(x, y, bounds, method="bvls", tol=1e-14).x, rtol=1e-9, atol=1e-9)
    design = np.exp(3.55 - 0.012 * np.log(np.arange(1, 61)))  # a design: its error falls with m
    assert np.all(np.diff(prediction.predict_typical(cal, design, np.arange(1, 61))) <= 0)
    # the bound's residuals: each fold predicted by the constrained fit without it
    residuals = np.empty_like(y)
    for f in range(6):
        held = records.fold == f
        beta_f = prediction.fit_coefficients(x[~held], y[~held])
        assert beta_f[1] >= 0 and beta_f[4] <= 0
        residuals[held] = y[held] - x[held] @ beta_f
    np.testing.assert_array_equal(confidence.cross_fitted_residuals(records, [5, 60], 5), residuals)
    assert cal["bound"]["center"] == [np.median(residuals[records.m == v]) for v in cal["bound"]["m"]]


def test_a_model_of_four_materials_predicts_no_more_error_for_more_samples():
    """The smallest training set with a calibration (4 built-in materials, test_rig_console's
    model): least squares gave the design error -18.8, and the plan's predicted error of a typical
    material rose from 0 at m = 1 to 0.134 at m = 12; held at 0 it falls (a little) all along."""
    from conftest import train_once

    model = train_once("four-materials", ["builtin"], only=["white-diffuse", "blue-plastic", "gold", "green-felt"],
                       grid=MerlGrid(30, 30, 60), k_max=12)
    beta = prediction.calibration_of(model)["coefficients"]
    assert beta[1] >= 0 and beta[4] <= 0
    predicted = select_bayes(model, 60).residuals
    assert np.all(np.diff(predicted) <= 0) and predicted[-1] < predicted[0]


def test_a_calibration_whose_least_squares_has_the_right_signs_keeps_it_to_the_bit():
    """On many materials least squares gives the design error a positive and log m a negative
    coefficient, in the whole fit and without every inner fold: the calibration and its
    cross-fitted residuals are np.linalg.lstsq's, unchanged."""
    from goniofrost.frost import confidence
    from goniofrost.frost.calibration import CvRecords, fit_calibration

    rng = np.random.default_rng(2)
    ms = np.array([5, 10, 15, 20, 30, 40, 60])
    m, material = np.tile(ms, 100), np.repeat(np.arange(100), ms.size)
    design = np.exp(rng.normal(-4, 0.3, m.size)) * 20 / m
    z2, energy = np.exp(rng.normal(0, 0.5, m.size)), np.exp(rng.normal(0, 0.5, m.size))
    x = prediction.feature_matrix(prediction.Features(design, z2, energy, m), [5, 60])
    y = x @ [0.3, 1.0, 0.5, 0.2, -0.3] + 0.3 * rng.normal(size=100)[material] + 0.2 * rng.normal(size=m.size)
    records = CvRecords(material % 10, material, m, np.exp(y), design, z2, energy)
    free, *_ = np.linalg.lstsq(x, y, rcond=None)
    plain = confidence.cross_fit(x, y, records.fold, signed=())
    for f in range(10):
        beta_f, *_ = np.linalg.lstsq(x[records.fold != f], y[records.fold != f], rcond=None)
        assert beta_f[1] > 0 and beta_f[4] < 0
    assert fit_calibration(records)["coefficients"] == [float(b) for b in free]
    np.testing.assert_array_equal(confidence.cross_fitted_residuals(records, [5, 60], 5), plain)


@pytest.mark.parametrize("materials, candidates", [(6, ["5"]), (12, ["5", "11"]), (18, ["5", "11", "17"])])
def test_a_feature_set_is_a_candidate_only_with_more_held_out_materials_than_coefficients(materials, candidates):
    """The calibration chooses among the feature sets (5, 11, 17 coefficients) only those with
    fewer coefficients than held-out materials: more are fitted on the looks within each material,
    not on the differences between materials (6 built-in materials chose all 17 by chance)."""
    from goniofrost.frost.calibration import CvRecords, fit_calibration

    rng = np.random.default_rng(materials)
    ms = np.array([15, 20, 30, 40, 60])
    m, material = np.tile(ms, materials), np.repeat(np.arange(materials), ms.size)
    design = np.exp(rng.normal(-4, 0.3, m.size)) * 20 / m
    z2, energy = np.exp(rng.normal(0, 0.5, m.size)), np.exp(rng.normal(0, 0.5, m.size))
    level, spread = rng.normal(0, 1, m.size), np.exp(rng.normal(0, 0.5, m.size))
    coordinates = rng.normal(0, 1, (m.size, prediction.COORDINATES))
    actual = design * z2 * np.exp(0.3 * rng.normal(size=materials)[material])
    records = CvRecords(material % 6, material, m, actual, design, z2, energy, level, spread,
                        coordinates=coordinates)
    cal = fit_calibration(records)
    assert sorted(cal["fit"]["cross_fitted_within_factor_2"], key=int) == candidates
    assert len(cal["coefficients"]) <= int(candidates[-1])


# ----- noise cross-validation -------------------------------------------------------------------
def test_inner_folds_from_the_gram_equal_explicit_pca(tables):
    names = [f"mat{i}" for i in range(24)]
    mapped, _, _, gram = _map_and_gram(tables, names, cosine_weight(GRID).astype(np.float32), 0.001, False)
    folds = noise.inner_folds(gram, 24, k=10, folds=4)
    assert sorted(np.concatenate([f.held for f in folds])) == list(range(72))
    x = mapped.astype(np.float64)
    fold = folds[1]
    xa = x[:, fold.train] - x[:, fold.train].mean(axis=1, keepdims=True)
    u, s, _ = np.linalg.svd(xa, full_matrices=False)
    np.testing.assert_allclose(fold.singular_values, s[:10], rtol=1e-6)
    held = x[:, fold.held] - x[:, fold.train].mean(axis=1, keepdims=True)
    residual = held - u[:, :10] @ (u[:, :10].T @ held)
    np.testing.assert_allclose(x @ fold.residual_map, residual, atol=1e-4 * np.abs(held).max())
    np.testing.assert_allclose(fold.residual_norms, np.sum(residual ** 2, axis=0), rtol=1e-4)
    d_f = x @ fold.projector
    np.testing.assert_allclose(d_f @ fold.true_coefficients, held - residual, atol=1e-4 * np.abs(held).max())
    every = np.zeros_like(x)
    for f in folds:
        every[:, f.held] = x @ f.residual_map
    np.testing.assert_allclose(noise.representation_variance(mapped, folds), np.mean(every ** 2, axis=1), rtol=1e-4)


def test_smoothing_keeps_a_constant_and_ignores_invalid_cells():
    values = np.full(GRID.n_valid, 0.25)
    np.testing.assert_allclose(noise.smooth_on_grid(values, GRID), 0.25, rtol=1e-12)
    spike = np.zeros(GRID.n_valid)
    spike[100] = 1.0
    smooth = noise.smooth_on_grid(spike, GRID)
    assert smooth[100] < 1.0 and smooth.sum() > 0 and np.all(smooth >= 0)


def test_calibration_records_equal_explicit_reconstructions(tables):
    """The Gram identity of the simulated captures: the true error of a held-out material,
    computed from the fold's coefficients, equals the error of its explicit reconstruction."""
    from goniofrost.frost.calibration import simulate

    names = [f"mat{i}" for i in range(24)]
    mapped, _, _, gram = _map_and_gram(tables, names, cosine_weight(GRID).astype(np.float32), 0.001, False)
    folds = noise.inner_folds(gram, 24, k=12, folds=3)
    noise_var = np.full(GRID.n_valid, 0.01)
    records = simulate(mapped, folds[:1], noise_var, m_values=(6, 12))[(1.0, 1.0)]
    x = mapped.astype(np.float64)
    fold = folds[0]
    d_f = x @ fold.projector
    design = greedy_design(d_f.astype(np.float32), fold.singular_values ** 2,
                           np.full(fold.singular_values.size, 1 / fold.n_train_columns), noise_var, 12)
    held = x @ fold.centring
    for m in (6, 12):
        cells = design.rows[:m]
        post = posterior.fit(d_f[cells], noise_var[cells], np.full(fold.singular_values.size, 1 / fold.n_train_columns),
                             held[cells], fold.singular_values ** 2, noise_var.sum(), GRID.n_valid)
        err = np.mean((d_f @ post.coefficients - held) ** 2, axis=0)
        expected = err.reshape(-1, 3).mean(axis=1)
        np.testing.assert_allclose(records.actual[records.m == m], expected, rtol=2e-3)
    assert set(records.material) == {i for i in range(24) if i % 3 == 0}


def test_trained_model_carries_the_noise_model(model):
    assert model.noise_variance.shape == (GRID.n_valid,) and model.noise_variance.dtype == np.float32
    assert np.all(model.noise_variance > 0)
    cal = model.noise["calibration"]
    assert cal["m_range"] == [5, 60]
    # the feature set is the one whose cross-fitted median estimates were within x2 more often
    # (the five basic ones on a tie): on these few synthetic materials, the five
    scores = cal["fit"]["cross_fitted_within_factor_2"]
    assert set(scores) == {str(prediction.BASIC_FEATURES), str(prediction.SAMPLE_FEATURES), str(len(prediction.FEATURES))}
    chosen = max(sorted(scores, key=int), key=lambda n: scores[n])
    assert len(cal["coefficients"]) == int(chosen) == prediction.BASIC_FEATURES
    assert model.noise["kind"] == "cells" and model.noise["folds"] == 10
    # every training material held out once at every m, in the chosen setting's records
    assert cal["fit"]["records"] == 24 * 9 and sorted(map(int, model.noise["cv_mean_errors"])) == [5, 10, 15, 20, 25, 30, 40, 50, 60]
    assert len(model.noise["choice_mean_errors"]) == 9 and model.noise["choice_folds"] == 4


# ----- model files --------------------------------------------------------------------------------
def test_model_format_2_round_trip_and_format_1_fallback(model, tmp_path):
    path = model.save(tmp_path / "m2")
    loaded = FrostModel.load(path)
    np.testing.assert_array_equal(loaded.noise_variance, model.noise_variance)
    assert loaded.noise == json.loads(json.dumps(model.noise)) and loaded.content_hash == model.content_hash
    meta = json.loads((path / "model.json").read_text())
    assert meta["version"] == 2
    # a format-1 model: no noise file, version 1 -> the documented scalar sigma^2 = 10 / t
    (path / "noise_variance.npy").unlink()
    meta.update(version=1, noise={})
    (path / "model.json").write_text(json.dumps(meta))
    old = FrostModel.load(path)
    assert old.noise_variance is None and prediction.calibration_of(old) is prediction.UNCALIBRATED
    np.testing.assert_allclose(posterior.cell_noise(old), posterior.SCALAR_ETA / old.n_signals)
    meta["version"] = 3
    (path / "model.json").write_text(json.dumps(meta))
    with pytest.raises(ModelError, match=r"version: expected one of \[1, 2\], found 3"):
        FrostModel.load(path)


def test_noise_changes_the_content_hash(model, scalar_model):
    assert model.content_hash != scalar_model.content_hash


# ----- stopping rule --------------------------------------------------------------------------------
def test_batches_follow_the_design_order():
    assert stopping.batch_ends(60) == [15, 20, 25, 30, 35, 40, 45, 50, 55, 60]
    assert stopping.batch_ends(22) == [15, 20, 22] and stopping.batch_ends(7) == [7]
    assert stopping.batch_ends(22, first=10) == [10, 15, 20, 22]
    with pytest.raises(ValueError):
        stopping.batch_ends(0)


def test_the_stopping_rule_and_its_replay_from_journaled_samples():
    from goniofrost.capture.journal import SampleRecord
    from goniofrost.capture.target import batch_of, finished, history

    from goniofrost.frost.confidence import ErrorBound

    def bound(upper, median=0.001, out=()):
        return ErrorBound(median, upper, 0.95, out)

    assert stopping.stop_reason(bound(0.05), 0.05, 15, 40) == stopping.REASON_TARGET
    assert stopping.stop_reason(bound(0.06), 0.05, 40, 40) == stopping.REASON_PLAN
    assert stopping.stop_reason(bound(0.06), 0.05, 15, 40) is None
    # never on the median estimate alone, never out of the model (measuring on while the plan allows)
    assert stopping.stop_reason(bound(0.06, median=0.01), 0.05, 15, 40) is None
    assert stopping.stop_reason(bound(0.01, out=("z2",)), 0.05, 15, 40) is None
    assert stopping.stop_reason(bound(0.01, out=("z2",)), 0.05, 40, 40) == stopping.REASON_PLAN
    assert stopping.statement(bound(0.04, 0.012), 0.05) == ("error <= 0.04 with 95 % confidence (median estimate 0.012), "
                                                           "within the target 0.05")
    assert stopping.statement(bound(0.07, 0.012), 0.05) == ("error <= 0.07 with 95 % confidence, above the target 0.05 "
                                                            "(median estimate 0.012)")
    assert stopping.statement(bound(0.01, out=("z2",)), 0.05) == (
        "the samples are unlike every training material (leave-one-out residuals beyond the training range): "
        "an extrapolation")
    predicted = {2: 0.2, 4: 0.04, 5: 0.01}
    records = [SampleRecord(i, 0, 0.0, 0.0, 0.0, (1.0,) * 3, (0.1,) * 3, 10.0) for i in range(5)]
    assess = lambda recs: bound(predicted[len(recs)])  # noqa: E731
    steps = history(assess, (2, 4, 5), 0.05, records)
    assert [(b["samples"], b["decision"]) for b in steps] == [(2, "continue"), (4, "target reached")]
    assert finished(assess, (2, 4, 5), 0.05, records) and not finished(assess, (2, 4, 5), 0.05, records[:3])
    assert history(assess, (2, 4, 5), 0.05, records[:3]) == steps[:1]  # batch 2 not complete yet
    assert [batch_of((2, 4, 5), i) for i in range(5)] == [1, 1, 2, 2, 3]


def test_choose_scales_takes_the_lowest_errors_relative_to_the_best_at_each_m():
    from goniofrost.frost.calibration import CvRecords, choose_scales

    def records(errors_by_m):
        m = np.repeat(list(errors_by_m), 2)
        actual = np.repeat(list(errors_by_m.values()), 2)
        ones = np.ones(m.size)
        return CvRecords(np.zeros(m.size, int), np.arange(m.size), m, actual, ones, ones, ones)

    results = {(1.0, 1.0): records({10: 0.10, 20: 0.050, 40: 0.040, 60: 0.040}),
               (2.0, 1.0): records({10: 0.11, 20: 0.050, 40: 0.030, 60: 0.025}),   # best overall
               (4.0, 1.0): records({10: 0.20, 20: 0.060, 40: 0.030, 60: 0.025})}
    assert choose_scales(results) == (2.0, 1.0)
    assert choose_scales(results, choice_m=(10,)) == (1.0, 1.0)


# ----- commands -------------------------------------------------------------------------------------
def samples_csv(model, truth, positions, sigma: bool = False) -> str:
    th, td, pd = (np.degrees(a) for a in GRID.flat_angles(GRID.valid_cells[positions]))
    head = "theta_h_deg,theta_d_deg,phi_d_deg,r,g,b" + (",sigma_r,sigma_g,sigma_b" if sigma else "")
    rows = []
    for i, p in enumerate(positions):
        values = list(truth[p]) + (list(0.05 * truth[p]) if sigma else [])
        rows.append(",".join(repr(float(v)) for v in [th[i], td[i], pd[i]] + values))
    return head + "\n" + "\n".join(rows) + "\n"


def test_plan_bayes_and_reconstruct_with_uncertainty_commands(model, tables, tmp_path):
    from goniofrost.app.cli import main
    from goniofrost.brdf.merl_file import read_merl
    from goniofrost.plan.file import read_plan

    model.save(tmp_path / "model")
    plan = tmp_path / "plan.json"
    assert main(["plan", "--model", str(tmp_path / "model"), "--samples", "12", "--no-sentinels",
                 "--out", str(plan)]) == 0
    doc = read_plan(plan)
    assert doc["selector"] == "bayes" and len(doc["predicted_errors"]) == 12 and "residuals" not in doc
    assert "sentinels" not in doc
    cells = [GRID.flat_index(*s["cell"]) for s in doc["samples"]]
    positions = GRID.valid_position(np.array(cells))
    assert list(positions) == list(select_bayes(model, 12).positions)
    # by default the plan adds the model's sentinels after the design's first batch (here all 12)
    assert main(["plan", "--model", str(tmp_path / "model"), "--samples", "12", "--out", str(plan)]) == 0
    with_sentinels = read_plan(plan)
    # and its 3 check cells (frost.check_cells) with them
    assert (with_sentinels["m"], with_sentinels["sentinels"], with_sentinels["checks"], with_sentinels["batch_ends"]) \
        == (18, 3, 3, [18])
    assert with_sentinels["samples"][:12] == doc["samples"]
    assert all(s["sentinel"] for s in with_sentinels["samples"][12:])
    truth = tables[4].astype(np.float64)
    (tmp_path / "s.csv").write_text(samples_csv(model, truth, positions, sigma=True))
    out = tmp_path / "rec.binary"
    assert main(["reconstruct", "--model", str(tmp_path / "model"), "--samples", str(tmp_path / "s.csv"),
                 "--out", str(out)]) == 0
    expected = reconstruct_bayes(model, positions, truth[positions], sigmas=0.05 * truth[positions])
    std = read_merl(tmp_path / "rec.std.binary", GRID)
    np.testing.assert_allclose(std[GRID.valid_cells], expected.std, rtol=1e-12)
    assert np.isnan(std[~GRID.valid_mask]).all()
    np.testing.assert_allclose(read_merl(out, GRID)[GRID.valid_cells], expected.brdf, rtol=1e-12)
    record = json.loads((tmp_path / "rec.json").read_text())
    # the one error figure (the point prediction before centring is report.json's alone)
    bound = error_bound(model, positions, truth[positions], 0.05 * truth[positions])
    assert record["error_figure"] == confidence.figure_of(bound) and "predicted_log_relative_mse" not in record
    assert record["median_estimate"] == bound.median and record["confidence"] == 0.95
    assert record["std"] == "rec.std.binary" and record["cells"] == 12
    # the paper's ridge stays available, and writes only the BRDF
    ridge = tmp_path / "ridge.binary"
    assert main(["reconstruct", "--model", str(tmp_path / "model"), "--samples", str(tmp_path / "s.csv"),
                 "--estimator", "ridge", "--eta", "40", "--out", str(ridge)]) == 0
    assert ridge.is_file() and not (tmp_path / "ridge.std.binary").exists()


@pytest.mark.parametrize("args, message", [
    (["--atoms", "5"], "--eta and --atoms apply to --estimator ridge only"),
])
def test_reconstruct_command_refuses_ridge_options_with_bayes(model, tables, tmp_path, capsys, args, message):
    from goniofrost.app.cli import main

    model.save(tmp_path / "model")
    pos = np.arange(0, 600, 50)
    (tmp_path / "s.csv").write_text(samples_csv(model, tables[0], pos))
    assert main(["reconstruct", "--model", str(tmp_path / "model"), "--samples", str(tmp_path / "s.csv"),
                 "--out", str(tmp_path / "o.binary")] + args) == 2
    assert message in capsys.readouterr().err and not (tmp_path / "o.binary").exists()


def test_sigma_columns_are_all_or_none_and_numbers(model, tables, tmp_path):
    from goniofrost.frost.reconstruction import ReconstructionError
    from goniofrost.frost.samples_file import read_samples_csv, sample_sigmas

    text = samples_csv(model, tables[0], np.arange(0, 300, 50), sigma=True)
    path = tmp_path / "s.csv"
    path.write_text(text.replace(",sigma_b", ",other"))
    with pytest.raises(ReconstructionError, match=r"columns \['sigma_r', 'sigma_g'\] without \['sigma_b'\]"):
        sample_sigmas(path, read_samples_csv(path, GRID)[2])
    lines = text.splitlines()
    lines[2] = ",".join(lines[2].split(",")[:-1] + ["abc"])
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(ReconstructionError, match="data row 2: column sigma_b: expected a number, found 'abc'"):
        sample_sigmas(path, read_samples_csv(path, GRID)[2])


def test_a_negative_sample_sigma_is_refused_as_a_standard_deviation_naming_its_column(model, tables, tmp_path,
                                                                                      capsys):
    from goniofrost.app.cli import main

    model.save(tmp_path / "model")
    lines = samples_csv(model, tables[0], np.arange(0, 300, 50), sigma=True).splitlines()
    fields = lines[2].split(",")
    lines[2] = ",".join(fields[:7] + ["-0.5"] + fields[8:])  # sigma_g of the second sample
    (tmp_path / "s.csv").write_text("\n".join(lines) + "\n")
    assert main(["reconstruct", "--model", str(tmp_path / "model"), "--samples", str(tmp_path / "s.csv"),
                 "--out", str(tmp_path / "o.binary")]) == 2
    # it read "data row 2 sigma: negative value -0.5 in channel g; expected a finite BRDF >= 0 (1/sr)"
    assert capsys.readouterr().err == (f"goniofrost reconstruct: error: {tmp_path / 's.csv'}: data row 2: negative "
                                       f"value -0.5 in column sigma_g; expected a finite standard deviation >= 0 "
                                       f"(1/sr)\n")
    assert not list(tmp_path.glob("o*"))


@pytest.mark.parametrize("in_the_way", ["o.std.binary", "o.json"])
def test_reconstruct_refuses_a_folder_in_place_of_any_of_its_three_files_before_writing_one(
        in_the_way, model, tables, tmp_path, capsys):
    from goniofrost.app.cli import main

    model.save(tmp_path / "model")
    (tmp_path / "s.csv").write_text(samples_csv(model, tables[0], np.arange(0, 300, 50)))
    out = tmp_path / "out"
    (out / in_the_way).mkdir(parents=True)
    assert main(["reconstruct", "--model", str(tmp_path / "model"), "--samples", str(tmp_path / "s.csv"),
                 "--out", str(out / "o.binary")]) == 2
    assert capsys.readouterr().err == (f"goniofrost reconstruct: error: {out / in_the_way}: cannot write: it is a "
                                       f"directory; give a file name\n")
    # o.binary (and o.std.binary) used to be written before the folder was found
    assert sorted(p.name for p in out.iterdir()) == [in_the_way]
