"""The Bayesian pipeline in a benchmark fold: reconstructions with uncertainty, and captures that
stop at a target error.

Per material: the true error, the predicted error and the coverage of the nominal 50 % and 90 %
predictive intervals. Materials measured at the same cells share one posterior solve.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from goniofrost.frost import check_cells, confidence, posterior, prediction, sentinel, stopping

Z50, Z90 = 0.6744897501960817, 1.6448536269514722  # two-sided normal quantiles
DEFAULT_CONFIDENCE = 0.95  # of the simulated captures (capture --confidence's default)


def _fit(model, positions, truth):
    """The posterior of every test material (3 columns each) from its values at ``positions``,
    the cells' noise (n,) and the centred mapped samples b (positions, 3 n_mat)."""
    n_mat = truth.shape[0]
    values = truth[:, positions, :].transpose(1, 0, 2).reshape(positions.size, 3 * n_mat)
    mu = np.asarray(model.mean, dtype=np.float64)
    b = model.to_log(values, positions) - mu[positions][:, None]
    noise = posterior.cell_noise(model)
    s2 = np.asarray(model.singular_values, dtype=np.float64) ** 2
    post = posterior.fit(model.dictionary[positions], noise[positions], posterior.prior_variance(model),
                         b, s2, float(noise.sum()), model.grid.n_valid)
    return post, noise, b


def _features(model, post, b, n_mat: int) -> np.ndarray:
    """float64 (n_mat, 5 + COORDINATES): (design error, z2, energy, level, spread, the
    coordinates) of every material."""
    cols = [[3 * i, 3 * i + 1, 3 * i + 2] for i in range(n_mat)]
    return np.array([prediction.material_features(post, c, model.n_signals) + prediction.sample_level(b, c)
                     + tuple(prediction.material_coordinates(post.coefficients, c, model.n_signals)) for c in cols])


def _predict(calibration, feats: np.ndarray, m: int) -> np.ndarray:
    return prediction.predict(calibration, prediction.Features(feats[:, 0], feats[:, 1], feats[:, 2], m, feats[:, 3],
                                                               feats[:, 4], feats[:, 5:]))


def _predicted(model, post, b, n_mat: int, m: int) -> tuple[np.ndarray, np.ndarray]:
    """(predicted error, design error) per material, float64 (n_mat,) each."""
    feats = _features(model, post, b, n_mat)
    return _predict(prediction.calibration_of(model), feats, m), feats[:, 0]


def _bounds(model, feats: np.ndarray, m: int, level: float, check=None, check_cells_error=None) -> dict:
    """``confidence.error_bounds`` of every material from its ``_features`` (exact samples:
    nothing extra); check: float64 (n_mat,) the sentinels' error (``_checks``), None: unchecked;
    check_cells_error: float64 (n_mat,) the error at the model's check cells (``_checks`` there;
    with ``check``: the checked calibration's median and bound, ``check_cells``), None: not measured."""
    calibration = prediction.calibration_of(model)
    predicted = _predict(calibration, feats, m)
    checked = prediction.checked_of(model)
    checked_predicted = None
    if checked and check is not None and check_cells_error is not None:
        checked_predicted = prediction.predict(checked, prediction.Features(
            feats[:, 0], feats[:, 1], feats[:, 2], m, feats[:, 3], feats[:, 4], feats[:, 5:],
            np.column_stack([check, check_cells_error])))
    return confidence.error_bounds(calibration, predicted, feats[:, 1], feats[:, 2], m, level, confidence.Evidence(
        check=check, checked_predicted=checked_predicted, design_error=feats[:, 0]))


def _checks(model, post, truth: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """float64 (n_mat,): every material's ``sentinel.check_error`` at ``cells`` against the
    posterior ``post`` of its design samples (truth: (n_mat, n_valid, 3) BRDF)."""
    values = truth[:, cells, :].transpose(1, 0, 2).reshape(cells.size, 3 * truth.shape[0])
    return sentinel.measured_check_errors(model, cells, values, post.coefficients)

def bayes_errors(model, positions: np.ndarray, truth: np.ndarray, truth_log: np.ndarray) -> dict:
    """Reconstruct every test material with the posterior mean; float64 (n_mat,) arrays under
    "mse", "pred_mse", "cover50", "cover90", and "seconds" (the whole batch, wall time)."""
    from goniofrost.frost.metrics import batch_log_errors

    start = time.perf_counter()
    n_mat = truth.shape[0]
    positions = np.asarray(positions, dtype=np.int64)
    post, noise, b = _fit(model, positions, truth)
    predicted, design = _predicted(model, post, b, n_mat, np.unique(positions).size)
    estimate, variance, _ = posterior.mean_and_variance(model.dictionary, model.mean, post)
    seconds = time.perf_counter() - start
    floor = np.log(model.eps) - np.log(np.asarray(model.reference, np.float64) + model.eps)
    base_var = variance[:, 0] + noise  # one noise group: every column shares Sigma
    cover50, cover90 = np.empty(n_mat), np.empty(n_mat)
    for i in range(n_mat):
        std = np.sqrt(base_var * (predicted[i] / design[i]))[:, None]
        miss = np.abs(np.maximum(estimate[:, 3 * i:3 * i + 3], floor[:, None]) - truth_log[i])
        measured = ~np.isnan(miss)  # cells without data (rgl:PATH) are not scored
        cover50[i] = np.mean((miss <= Z50 * std)[measured])
        cover90[i] = np.mean((miss <= Z90 * std)[measured])
    return {"mse": batch_log_errors(model, estimate, truth_log), "pred_mse": predicted,
            "cover50": cover50, "cover90": cover90, "seconds": seconds}


def with_bound_kind(model, kind: str):
    """A shallow copy of ``model`` whose calibrations' bounds (and the checked one's) are of
    ``kind`` (``confidence.BOUND_KINDS``): the benchmark's way to measure each kind on one training."""
    import copy
    import json

    noise = json.loads(json.dumps(model.noise))
    calibration = noise.get("calibration") or {}
    for part in (calibration.get("bound"), (calibration.get("checked") or {}).get("bound")):
        if part and "normalised" in part:
            part["kind"] = kind
    out = copy.copy(model)
    out.noise = noise
    return out


def bound_rows(model, positions: np.ndarray, truth: np.ndarray, truth_log: np.ndarray,
               level: float = DEFAULT_CONFIDENCE, kinds=()) -> dict:
    """Every test material measured at ``positions``: float64 (n_mat,) arrays "mse" (true
    error of the posterior mean), "median" and "upper" (the calibrated median estimate and bound
    at ``level``: the checked calibration's when the model has check cells, ``check_cells``;
    "median_unchecked" and "upper_unchecked" without them), "out_of_model" (1 if the samples are
    unlike every training material by z2 or energy, or the design unlike every design of the
    calibration: ``confidence.design_outside``), "sentinel" (1 if the model's sentinel cells flag
    them, ``confidence.sentinel_excess``),
    "feature_distance" (``confidence.feature_distance``: > 1 beyond 95 % of the held-out training
    materials) and "prequential" (``confidence.prequential_excess`` of the samples taken in the
    order of ``positions``: > 1 beyond 95 % of them). kinds: bound kinds (``confidence.BOUND_KINDS``)
    whose unchecked bound is added as "upper_<kind>"."""
    from goniofrost.frost.metrics import batch_log_errors

    positions = np.asarray(positions, dtype=np.int64)
    n_mat = truth.shape[0]
    post, noise, samples = _fit(model, positions, truth)
    feats = _features(model, post, samples, n_mat)
    cells, checking = sentinel.calibrated_cells(model), check_cells.cells_of(model)
    check = _checks(model, post, truth, cells) if cells.size else None
    at_checks = _checks(model, post, truth, checking) if checking.size and check is not None else None
    b = _bounds(model, feats, np.unique(positions).size, level, check, at_checks)
    plain = _bounds(model, feats, np.unique(positions).size, level, check) if at_checks is not None else b
    estimate = np.asarray(model.dictionary) @ post.coefficients.astype(np.float32)
    estimate = estimate.astype(np.float64) + np.asarray(model.mean, np.float64)[:, None]
    distance = confidence.feature_distance(prediction.calibration_of(model), feats[:, 1], feats[:, 2], feats[:, 3],
                                           feats[:, 4], np.unique(positions).size)
    one_step = posterior.prequential_errors(model.dictionary[positions], noise[positions],
                                            posterior.prior_variance(model), samples)
    scores = np.array([prediction.prequential_score(one_step, [3 * i, 3 * i + 1, 3 * i + 2]) for i in range(n_mat)])
    by_kind = {f"upper_{kind}": _bounds(with_bound_kind(model, kind), feats, np.unique(positions).size, level,
                                        check)["upper"] for kind in kinds}
    return by_kind | {"mse": batch_log_errors(model, estimate, truth_log), "median": b["median"], "upper": b["upper"],
            "median_unchecked": plain["median"], "upper_unchecked": plain["upper"],
            "out_of_model": (b["out_of_model_z2"] | b["out_of_model_energy"]
                             | b["out_of_model_design"]).astype(np.float64),
            "sentinel": b["out_of_model_sentinel"].astype(np.float64),
            "feature_distance": distance,
            "prequential": confidence.prequential_excess(prediction.calibration_of(model), scores,
                                                         np.unique(positions).size)}


@dataclass(frozen=True)
class MeasuredChecks:
    """The checks a simulated capture measures with its first batch (``target_outcomes``):
    ``sentinel_cells`` int64 (s,), None: the model's calibrated ones (``sentinel.calibrated_cells``;
    other positions as ``plan --rig`` places them when the rig cannot reach those: the check is
    then approximate); ``check_cells`` int64 (k,), None: the model's (``check_cells.cells_of``),
    empty: none (the unchecked calibration)."""

    sentinel_cells: np.ndarray | None = None
    check_cells: np.ndarray | None = None


def target_outcomes(model, order: np.ndarray, truth: np.ndarray, truth_log: np.ndarray,
                    target: float, confidence_level: float = DEFAULT_CONFIDENCE,
                    checks: MeasuredChecks | None = None) -> dict:
    """Simulated ``capture --target-error target --confidence confidence_level``: every test
    material measured in batches along the nested design ``order`` (positions, length m_max)
    until ``stopping.stop_reason`` says so (its bound at most the target and not out of the model).
    checks: measure the sentinel cells (``sentinel.py``) with the first batch and check them at
    every look (out of the model beyond their calibrated range), and the check cells
    (``check_cells``; the checked calibration's median and bound); they count in "samples".
    None: no checks.

    Returns float64/int64 (n_mat,) arrays "samples" (with the sentinels), "mse" (true error at the stop),
    "pred_mse" (median estimate at the stop), "upper" (the bound at the stop), "reached" (1 if
    the rule stopped on the target), "out_of_model" (1 if the last assessment was out of the
    model), "ever_out" (1 if any assessment was), "ever_sentinel" (1 if the sentinels flagged
    any) and "seconds" (the whole simulation, wall time).
    """
    from goniofrost.frost.metrics import batch_log_errors

    start = time.perf_counter()
    n_mat, m_max = truth.shape[0], order.size
    stop_at, reached = np.full(n_mat, -1), np.zeros(n_mat, dtype=np.int64)
    median_at, upper_at = np.zeros(n_mat), np.zeros(n_mat)
    out_at, ever_out = np.zeros(n_mat, dtype=np.int64), np.zeros(n_mat, dtype=np.int64)
    ever_sentinel = np.zeros(n_mat, dtype=np.int64)
    posts = {}
    cells = np.zeros(0, dtype=np.int64)
    if checks is not None:
        cells = sentinel.calibrated_cells(model) if checks.sentinel_cells is None else \
            np.asarray(checks.sentinel_cells, np.int64)
    checking = np.zeros(0, dtype=np.int64)
    if checks is not None and cells.size:
        checking = check_cells.cells_of(model) if checks.check_cells is None else \
            np.asarray(checks.check_cells, np.int64)
    for end in stopping.batch_ends(m_max):
        post, _, samples = _fit(model, order[:end], truth)
        posts[end] = post
        b = _bounds(model, _features(model, post, samples, n_mat), end, confidence_level,
                    _checks(model, post, truth, cells) if cells.size else None,
                    _checks(model, post, truth, checking) if checking.size else None)
        out = b["out_of_model_z2"] | b["out_of_model_energy"] | b["out_of_model_sentinel"] | b["out_of_model_design"]
        for i in np.flatnonzero(stop_at < 0):
            flags = ("sentinel",) if b["out_of_model_sentinel"][i] else ("z2",) if out[i] else ()
            # a flag of the sentinels stays (capture.target.sticky)
            flags += ("sentinel_earlier",) if ever_sentinel[i] and not b["out_of_model_sentinel"][i] else ()
            bound = confidence.ErrorBound(float(b["median"][i]), float(b["upper"][i]), confidence_level, flags)
            ever_out[i] |= int(out[i])
            ever_sentinel[i] |= int(b["out_of_model_sentinel"][i])
            reason = stopping.stop_reason(bound, target, end, m_max)
            if reason is not None:
                stop_at[i], median_at[i], upper_at[i] = end, bound.median, bound.upper
                reached[i], out_at[i] = int(reason == stopping.REASON_TARGET), int(out[i])
    mse = np.empty(n_mat)
    for end in np.unique(stop_at):
        mats = np.flatnonzero(stop_at == end)
        cols = (3 * mats[:, None] + np.arange(3)).reshape(-1)
        coef = posts[end].coefficients[:, cols].astype(np.float32)
        estimate = np.asarray(model.dictionary) @ coef + np.asarray(model.mean, np.float32)[:, None]
        mse[mats] = batch_log_errors(model, estimate.astype(np.float64), truth_log[mats])
    return {"samples": stop_at + cells.size + checking.size, "mse": mse, "pred_mse": median_at, "upper": upper_at, "reached": reached,
            "out_of_model": out_at, "ever_out": ever_out, "ever_sentinel": ever_sentinel,
            "seconds": time.perf_counter() - start}
