"""A calibrated upper bound on a reconstruction's error, and samples unlike every training material.

``fit_bound`` calibrates, on the held-out training materials of training's inner
cross-validation, a split-conformal bound on the point prediction (``prediction``) that holds at
every look of a capture at once; ``error_bounds`` gives a capture's bound and median estimate at a
confidence, and says when the samples or the design are out of the model (beyond the
calibration's range by OUT_OF_MODEL_FACTOR) or the sentinels flag them. ``figure`` words the one
error statement every output makes. BOUND_KINDS other than BOUND_KIND, ``feature_distance`` and
``prequential_excess`` serve the benchmarks only. Why: docs/explanations/error-bound.md.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from goniofrost.frost.prediction import fit_coefficients
from goniofrost.frost.sentinel import SENTINEL_CONFIDENCE


# Captures stop only at m >= this (stopping.FIRST_BATCH; kept here so frost.stopping can import us).
FIRST_LOOK = 15
# Beyond the largest z2 / energy of every held-out training material by this factor: out of the
# model. A factor rather than the bare maximum: among n exchangeable materials a new one exceeds
# the maximum with probability 1 / (n + 1) per feature and look, which is no sign of anything;
# the held-out training materials' largest z2 at an m varied by less than a factor 2 from one m
# to the next (45 x 45 x 90 grid, fold 0 of MERL + RGL: log z2 max 2.3 to 2.9 from m = 5 to 60).
OUT_OF_MODEL_FACTOR = 2.0
# The bound's kinds (docs/decisions/0100-a-sharper-bound.md): "split" (the residual standardized
# by its m's spread), "normalised" (by the material's own predicted spread), "per-look" (a
# quantile per m: coverage at each fixed look, not at once over them), "per-look-tuned" (per look at
# a smaller miss rate chosen on the training materials). BOUND_KIND is the one used.
BOUND_KINDS = ("split", "normalised", "per-look", "per-look-tuned")
# per-look-tuned: the per-look bound at a miss rate (1 - c) f, f the largest of these that keeps the
# coverage at the stop on nested folds of the training materials (``_tuned_factor``)
ALPHA_FACTORS = (1.0, 0.8, 0.6, 0.5, 0.4, 0.3, 0.2, 0.1)
BOUND_KIND = "split"
SPREAD_QUANTILES = (0.1, 0.5, 0.9)  # of the held-out training materials' bounds ``plan --max-error`` prints
CHOICE_SLACK = 0.02  # the coverage below the confidence a kind may show on the nested folds
FEATURE_NAMES = {"z2": "leave-one-out residuals", "energy": "coefficient energy",
                 "sentinel": "the sentinel samples' error",
                 "sentinel_earlier": "the sentinel samples' error at an earlier batch",
                 "design": "log design error"}


@dataclass(frozen=True)
class ErrorBound:
    """What a set of samples says about this material's error (log-relative MSE).

    median: the median estimate; upper: the bound at ``confidence`` (inf when none can be
    given; ``unavailable`` then says why); out_of_model: the features (keys of FEATURE_NAMES)
    beyond every held-out training material, () when the samples look like the training set.
    design: ``design_detail`` (m, log design error, the lowest and highest of the calibration's
    designs at m, the m they are of) when "design" is among them, else None.
    """

    median: float
    upper: float
    confidence: float
    out_of_model: tuple[str, ...] = ()
    unavailable: str | None = None
    design: tuple[int, float, float, float, int] | None = None


def figure(upper, confidence: float, median, error: str = "error") -> str:
    """The one sentence every output states of a reconstruction's error: "error <= B with C %
    confidence (median estimate X)"; "error: no bound at C % confidence (median estimate X)" when
    ``upper`` is None or infinite; the same words and digits wherever it appears."""
    tail = "" if median is None else f" (median estimate {float(median):.3g})"
    if upper is None or not math.isfinite(float(upper)):
        return f"{error}: no bound at {100 * float(confidence):g} % confidence{tail}"
    return f"{error} <= {float(upper):.3g} with {100 * float(confidence):g} % confidence{tail}"


def figure_of(bound: ErrorBound, error: str = "error") -> str:
    """``figure`` of an ErrorBound."""
    return figure(bound.upper, bound.confidence, bound.median, error)


def cross_fitted_residuals(records, m_range, n_features=None, feature_range=None) -> np.ndarray:
    """float64 (records,): log(actual / predicted), each predicted by the calibration (its first
    n_features features, all when None) refitted without the record's inner fold (CvRecords of
    ``calibration.py``)."""
    x = records.features(m_range, n_features, feature_range)
    return cross_fit(x, np.log(np.maximum(records.actual, 1e-12)), records.fold)


def cross_fit(x: np.ndarray, y: np.ndarray, fold: np.ndarray, signed=None) -> np.ndarray:
    """float64 (records,): y - x beta, each fold's records with the beta fitted without that fold
    (x (records, f), y and fold (records,)) as the calibration is: ``prediction.fit_coefficients``,
    least squares with the coefficients of ``signed`` (None: ``prediction.SIGNED``) held to their
    sign in every fold's fit (so the residuals the bound is calibrated on are those of the
    procedure whose fit is used); () plain least squares."""
    out = np.empty_like(y)
    for f in np.unique(fold):
        held = fold == f
        beta = fit_coefficients(x[~held], y[~held], signed)
        out[held] = y[held] - x[held] @ beta
    return out


def choice_score(records, residuals) -> float:
    """The mean over the looks m >= FIRST_LOOK (every m when there are none) of the fraction of
    records whose residual lies within log 2 of its m's median: how often the median estimate
    is within a factor 2 of the truth."""
    ms = np.unique(records.m)
    looks = ms[ms >= FIRST_LOOK] if np.any(ms >= FIRST_LOOK) else ms
    return float(np.mean([np.mean(np.abs(residuals[records.m == m] - np.median(residuals[records.m == m])) <= math.log(2))
                          for m in looks]))


def fit_bound(records, m_range, n_features=None, feature_range=None, residuals=None) -> dict:
    """The bound's calibration (JSON-ready) from the inner cross-validation's records: per m the
    residuals' median and spread, the largest log z2 / log energy, the smallest and largest log
    design error (the range of the designs the calibration saw), and every held-out
    material's simultaneous score, sorted. residuals: (records,) log(actual / predicted) to
    calibrate on (the checked calibration's nested ones, ``check_cells.fit_checked``), None:
    ``cross_fitted_residuals`` of the first n_features."""
    r = cross_fitted_residuals(records, m_range, n_features, feature_range) if residuals is None else residuals
    ms = np.unique(records.m)
    looks = ms[ms >= FIRST_LOOK] if np.any(ms >= FIRST_LOOK) else ms
    center, scale, scores = _simultaneous(records, r, ms, looks)
    spread_x = _spread_features(records.m, records.z2, records.energy, records.actual / np.exp(r))
    factor = _tuned_factor(records, r, ms, looks)
    return {"method": "split-conformal, simultaneous over the looks m >= %d" % int(looks[0]),
            "m": [int(m) for m in ms], "center": center.tolist(), "scale": scale.tolist(),
            "looks": [int(m) for m in looks], "scores": scores, "kind": BOUND_KIND,
            "normalised": _fit_normalised(records, r, ms, looks, spread_x, center),
            "per_look": {"scores": _per_look_scores(records, r, ms, center, scale),
                         "alpha_factor": factor},
            "choice": _nested_choice(records, r, ms, looks, spread_x, factor),
            "log_predicted_quantiles": [np.quantile(np.log(records.actual[records.m == m] / np.exp(r[records.m == m])),
                                                    SPREAD_QUANTILES).tolist() for m in ms],
            "log_z2_max": [float(np.log(records.z2[records.m == m]).max()) for m in ms],
            "log_energy_max": [float(np.log(records.energy[records.m == m]).max()) for m in ms],
            "log_design_error_min": [float(np.log(records.design_error[records.m == m]).min()) for m in ms],
            "log_design_error_max": [float(np.log(records.design_error[records.m == m]).max()) for m in ms]} \
        | _feature_spread(records, ms) | _prequential_spread(records, ms) | _sentinel_spread(records, r, ms, looks)


def _spread_features(m, z2, energy, predicted) -> np.ndarray:
    """float64 (..., 5): (1, log m, log z2, log energy, log predicted): what the normalised
    bound's spread is a function of (arguments broadcast)."""
    parts = np.broadcast_arrays(*(np.log(np.maximum(np.asarray(v, np.float64), 1e-300))
                                  for v in (m, z2, energy, predicted)))
    return np.stack([np.ones_like(parts[0]), *parts], -1)


def _spread_fit(x: np.ndarray, deviation: np.ndarray) -> np.ndarray:
    """(5,) least-squares coefficients of log |deviation| on the spread features x (records, 5)."""
    y = np.log(np.maximum(np.abs(deviation), 1e-3))
    return np.linalg.lstsq(x, y, rcond=None)[0]


def _fit_normalised(records, r, ms, looks, x, center, fold=None) -> dict:
    """The normalised (locally weighted) bound's calibration: the spread sigma(x) = exp(x gamma)
    of the residual about its m's median, gamma fitted on every record (``_spread_fit``), the
    range of log sigma it was fitted on (sigma is clamped there: no extrapolated spread), and
    every held-out material's simultaneous score max over the looks of (r - c_m) / sigma, sorted;
    each record's sigma for its score from a fit without its inner fold (cross-fitted, as the
    residuals). fold: (records,) the folds to cross-fit over (None: records.fold)."""
    fold = records.fold if fold is None else fold
    deviation = r - center[np.searchsorted(ms, records.m)]
    log_sigma = np.empty_like(r)
    for f in np.unique(fold):
        held = fold == f
        log_sigma[held] = x[held] @ _spread_fit(x[~held], deviation[~held])
    gamma = _spread_fit(x, deviation)
    fitted = x @ gamma
    low, high = float(fitted.min()), float(fitted.max())
    standard = deviation / np.exp(np.clip(log_sigma, low, high))
    return {"gamma": gamma.tolist(), "log_sigma_range": [low, high],
            "scores": _material_max(records, standard, looks)}


def _per_look_scores(records, r, ms, center, scale) -> list:
    """Per m (ms,) the held-out materials' standardized residuals (r - c_m) / s_m, sorted: the
    per-look bound's calibration (coverage at each fixed look, not at once over them)."""
    return [sorted(float(v) for v in (r[records.m == m] - c) / s) for m, c, s in zip(ms, center, scale)]


def _material_max(records, standard, looks) -> list:
    """Every held-out material's largest ``standard`` (records,) over the looks, sorted."""
    keys = records.fold.astype(np.int64) * (int(records.material.max()) + 1) + records.material
    in_look = np.isin(records.m, looks)
    _, material = np.unique(keys[in_look], return_inverse=True)
    scores = np.full(int(material.max()) + 1, -np.inf)
    np.maximum.at(scores, material, standard[in_look])
    return sorted(float(s) for s in scores)


def _log_upper(bound: dict, kind: str, m, x, confidence: float) -> np.ndarray:
    """log(bound / point prediction) of the ``kind`` bound at m (broadcast with x (..., 5), the
    ``_spread_features``), at ``confidence``."""
    c = _at_m(bound, "center", m)
    if kind == "normalised":
        part = bound["normalised"]
        log_sigma = np.clip(x @ np.asarray(part["gamma"]), *part["log_sigma_range"])
        return c + conformal_quantile(part["scores"], confidence) * np.exp(log_sigma)
    if kind in ("per-look", "per-look-tuned"):
        if kind == "per-look-tuned":  # the miss rate shrunk by the factor chosen on the training materials
            confidence = 1 - (1 - confidence) * bound["per_look"].get("alpha_factor", 1.0)
        q = [conformal_quantile(sc, confidence) for sc in bound["per_look"]["scores"]]
        return c + _at_m(bound | {"q_scale": np.asarray(q) * np.asarray(bound["scale"])}, "q_scale", m)
    return c + conformal_quantile(bound["scores"], confidence) * _at_m(bound, "scale", m)


def _nested_choice(records, r, ms, looks, x, factor: float = 1.0, confidence: float = 0.95) -> dict:
    """Every bound kind measured on the training materials only: for each inner fold, the bound
    calibrated on the other folds' records, applied to the fold's held-out materials. Per kind:
    "simultaneous_coverage" (materials whose error is below the bound at every look at once: what
    a rule that stops at any look needs) and "median_bound_over_actual" at the look nearest
    m = 20; "chosen": the kind with the smallest such median among those covering at least
    ``confidence`` - CHOICE_SLACK (``BOUND_KIND`` used; this is the record of the measurement).
    None when some fold's complement lacks an m of ``ms``."""
    folds = np.unique(records.fold)
    if folds.size < 2 or any(not np.isin(ms, records.m[records.fold != f]).all() for f in folds):
        return None  # records (synthetic, a few materials) without every m in every fold's complement
    covered = {k: [] for k in BOUND_KINDS}
    ratio = {k: [] for k in BOUND_KINDS}
    near = looks[np.argmin(np.abs(looks - 20))]
    for f in folds:
        held, rest = records.fold == f, records.fold != f
        sub = _subset(records, rest)
        center, scale, scores = _simultaneous(sub, r[rest], ms, looks)
        bound = {"m": [int(m) for m in ms], "center": center.tolist(), "scale": scale.tolist(), "scores": scores,
                 "normalised": _fit_normalised(sub, r[rest], ms, looks, x[rest], center),
                 "per_look": {"scores": _per_look_scores(sub, r[rest], ms, center, scale), "alpha_factor": factor}}
        for kind in BOUND_KINDS:
            log_upper = _log_upper(bound, kind, records.m[held], x[held], confidence)
            miss = (r[held] > log_upper) & np.isin(records.m[held], looks)
            for material in np.unique(records.material[held]):
                covered[kind].append(not miss[records.material[held] == material].any())
            at = records.m[held] == near
            ratio[kind] += list(np.exp(log_upper[at] - r[held][at]))
    # None for a ratio without a finite bound (too few materials for the confidence): JSON has no inf
    out = {k: {"simultaneous_coverage": float(np.mean(covered[k])),
               "median_bound_over_actual": _finite_or_none(np.median(ratio[k])), "at_m": int(near)}
           for k in BOUND_KINDS}
    fine = [k for k in BOUND_KINDS if out[k]["simultaneous_coverage"] >= confidence - CHOICE_SLACK
            and out[k]["median_bound_over_actual"] is not None]
    out["chosen"] = min(fine, key=lambda k: out[k]["median_bound_over_actual"]) if fine else "split"
    return out


def _finite_or_none(value) -> float | None:
    value = float(value)
    return value if math.isfinite(value) else None


def _tuned_factor(records, r, ms, looks, confidence: float = 0.95) -> float:
    """The largest factor f of ALPHA_FACTORS whose per-look bound at confidence 1 - (1 - c) f keeps
    the coverage at the stop at least c on nested inner folds of the training materials: each
    fold's held-out materials captured along their records' looks against the other folds'
    per-look bound, stopping at the first look whose bound is at most E, for E the 10th, 25th,
    50th and 75th percentiles of the records' true errors at the looks (pooled); covered when the
    true error at the stop is at most E. 1.0 when the records lack an m in some fold's complement."""
    folds = np.unique(records.fold)
    if folds.size < 2 or any(not np.isin(ms, records.m[records.fold != f]).all() for f in folds):
        return 1.0
    in_looks = np.isin(records.m, looks)
    targets = np.quantile(records.actual[in_looks], (0.1, 0.25, 0.5, 0.75))
    for factor in ALPHA_FACTORS:
        stopped = covered = 0
        for f in folds:
            held, rest = records.fold == f, records.fold != f
            sub = _subset(records, rest)
            center, scale, _ = _simultaneous(sub, r[rest], ms, looks)
            bound = {"m": [int(m) for m in ms], "center": center.tolist(), "scale": scale.tolist(),
                     "per_look": {"scores": _per_look_scores(sub, r[rest], ms, center, scale)}}
            log_upper = _log_upper(bound, "per-look", records.m[held], None, 1 - (1 - confidence) * factor)
            n, k = _stops(records, held, r[held], log_upper, looks, targets)
            stopped, covered = stopped + n, covered + k
        if stopped == 0 or covered / stopped >= confidence:
            return float(factor)
    return float(ALPHA_FACTORS[-1])


def _stops(records, held, r, log_upper, looks, targets) -> tuple[int, int]:
    """(captures that stop, of those covered) of the ``held`` records' materials at every target:
    a material stops at its first look (m in ``looks``, in order) whose bound (its prediction
    actual / exp(r) times exp(log_upper)) is at most the target; covered when its true error there is."""
    m, actual, material = records.m[held], records.actual[held], records.material[held]
    bound = actual / np.exp(r) * np.exp(log_upper)
    stopped = covered = 0
    for one in np.unique(material):
        mine = (material == one) & np.isin(m, looks)
        order = np.argsort(m[mine])
        b, a = bound[mine][order], actual[mine][order]
        for target in targets:
            first = np.flatnonzero(b <= target)
            if first.size:
                stopped, covered = stopped + 1, covered + int(a[first[0]] <= target)
    return stopped, covered


def _subset(records, keep: np.ndarray):
    """The records (fold, material, m, z2, energy, actual) where ``keep``: what the bound's fit reads."""
    from types import SimpleNamespace

    return SimpleNamespace(fold=records.fold[keep], material=records.material[keep], m=records.m[keep],
                           z2=records.z2[keep], energy=records.energy[keep], actual=records.actual[keep])


def _simultaneous(records, values, ms, looks):
    """Per m the median (ms,) and standard deviation (ms,) of ``values`` (records,), and every
    held-out material's largest standardized value over ``looks``, sorted (list of floats)."""
    center = np.array([np.median(values[records.m == m]) for m in ms])
    scale = np.array([max(float(np.std(values[records.m == m])), 1e-6) for m in ms])
    at = np.searchsorted(ms, records.m)
    return center, scale, _material_max(records, (values - center[at]) / scale[at], looks)


def _sentinel_spread(records, residuals, ms, looks) -> dict:
    """The sentinel check's calibration (``sentinel.py``): g = log(sentinel error / cross-fitted
    prediction) = log(sentinel / actual) + residual per record, its per-m median and spread and
    every held-out material's simultaneous score over the looks, sorted; {} for records without
    sentinels."""
    if records.sentinel is None:
        return {}
    g = np.log(np.maximum(records.sentinel, 1e-12)) - np.log(np.maximum(records.actual, 1e-12)) + residuals
    center, scale, scores = _simultaneous(records, g, ms, looks)
    return {"sentinel": {"center": center.tolist(), "scale": scale.tolist(), "scores": scores}}


def sentinel_excess(calibration: dict, check, predicted, m, level: float) -> np.ndarray:
    """The sentinels' error ``check`` (``sentinel.check_error``) against the ``predicted`` whole
    error (the calibrated point prediction, ``prediction.predict``), standardized at m
    (interpolated in log m), over the conformal quantile at ``level`` of the held-out training
    materials' simultaneous scores: bool, True beyond it (the error where the check looked is
    not the one predicted: out of the model); all False for a model calibrated without
    sentinels. Arguments broadcast."""
    bound = calibration.get("bound") or {}
    shape = np.broadcast(check, predicted, m).shape
    if "sentinel" not in bound:
        return np.zeros(shape, dtype=bool)
    spread = bound["sentinel"] | {"m": bound["m"]}
    g = np.log(np.maximum(check, 1e-12)) - np.log(np.maximum(predicted, 1e-12))
    standard = (g - _at_m(spread, "center", m)) / _at_m(spread, "scale", m)
    return np.broadcast_to(standard > conformal_quantile(spread["scores"], level), shape).copy()


def _prequential_spread(records, ms) -> dict:
    """Per m the 95th percentile of the held-out materials' log prequential score; {} for
    records without it. What ``prequential_excess`` compares a capture's samples with."""
    if records.prequential is None:
        return {}
    return {"log_prequential_q95": [float(np.quantile(np.log(records.prequential[records.m == m]), 0.95)) for m in ms]}


def prequential_excess(calibration: dict, score, m) -> np.ndarray:
    """A prequential score (``prediction.prequential_score``: how well the samples measured so
    far predicted each next one, never fitted) over the 95th percentile of the held-out training
    materials' at m (interpolated in log m; > 1: worse predicted than 95 % of them; NaN when
    the model has no such record). A diagnostic the benchmark measures; the rule does not use it
    (across databases it fires on the materials the bound covers, not on those it misses:
    BENCHMARKS.md@8b3941b, issue 28)."""
    bound = calibration.get("bound") or {}
    if "log_prequential_q95" not in bound:
        return np.full(np.broadcast(score, m).shape, np.nan)
    return np.asarray(score, dtype=np.float64) / np.exp(_at_m(bound, "log_prequential_q95", m))


def _feature_spread(records, ms) -> dict:
    """Per m the mean, inverse covariance and 95th percentile of the squared Mahalanobis
    distance of the held-out materials' (log z2, log energy, level, log spread); {} for records
    without level and spread. What ``feature_distance`` compares a capture's samples with."""
    if records.level is None:
        return {}
    u = _feature_vectors(records.z2, records.energy, records.level, records.spread)
    means, inverses, q95 = [], [], []
    for m in ms:
        at = u[records.m == m]
        mean, inverse = at.mean(axis=0), np.linalg.pinv(np.cov(at.T))
        d2 = np.einsum("ij,jk,ik->i", at - mean, inverse, at - mean)
        means.append(mean.tolist()), inverses.append(inverse.tolist()), q95.append(float(np.quantile(d2, 0.95)))
    return {"feature_mean": means, "feature_inverse_covariance": inverses, "feature_d2_q95": q95}


def _feature_vectors(z2, energy, level, spread) -> np.ndarray:
    return np.stack(np.broadcast_arrays(np.log(z2), np.log(energy), np.asarray(level, np.float64), np.log(spread)), -1)


def feature_distance(calibration: dict, z2, energy, level, spread, m: int) -> np.ndarray:
    """The squared Mahalanobis distance of samples' (log z2, log energy, level, log spread) from
    the held-out training materials' at the calibrated m nearest ``m``, over their 95th
    percentile (> 1: less typical than 95 % of them; NaN when the model has no such record).
    A diagnostic the benchmark measures (does it single out the materials the bound fails on?);
    the stopping rule does not use it."""
    bound = calibration.get("bound") or {}
    if "feature_mean" not in bound:
        return np.full(np.broadcast(z2, energy).shape, np.nan)
    i = int(np.argmin(np.abs(np.log(np.asarray(bound["m"], np.float64)) - np.log(m))))
    diff = _feature_vectors(z2, energy, level, spread) - np.asarray(bound["feature_mean"][i])
    inverse = np.asarray(bound["feature_inverse_covariance"][i])
    return np.einsum("...j,jk,...k->...", diff, inverse, diff) / bound["feature_d2_q95"][i]


def design_range(calibration: dict, m) -> tuple[np.ndarray, np.ndarray] | None:
    """(lowest, highest) log design error of the calibration's designs at m samples (interpolated
    in log m, clamped at the calibrated ends); None for a calibration that records none (no bound,
    or trained before the range was recorded: its designs are not checked)."""
    bound = calibration.get("bound") or {}
    if "log_design_error_min" not in bound:
        return None
    return _at_m(bound, "log_design_error_min", m), _at_m(bound, "log_design_error_max", m)


def design_outside(calibration: dict, design_error, m) -> np.ndarray:
    """bool (broadcast shape): the log ``design_error`` (exact samples) at m samples more than
    log OUT_OF_MODEL_FACTOR beyond the calibration's designs' range there (``design_range``):
    its prediction is an extrapolation. All False when the calibration records no range."""
    shape = np.broadcast(design_error, m).shape
    span = design_range(calibration, m)
    if span is None:
        return np.zeros(shape, dtype=bool)
    value, margin = np.log(np.asarray(design_error, dtype=np.float64)), math.log(OUT_OF_MODEL_FACTOR)
    return np.broadcast_to((value > span[1] + margin) | (value < span[0] - margin), shape).copy()


def design_detail(calibration: dict, design_error: float, m: int) -> tuple[int, float, float, float, int] | None:
    """(m, log design error, lowest and highest of the calibration's designs at m, the m that
    range is of: m clamped into the calibrated ones) when the design is outside them
    (``design_outside``), else None."""
    if not bool(design_outside(calibration, design_error, m)):
        return None
    low, high = design_range(calibration, m)
    calibrated = calibration["bound"]["m"]
    return int(m), float(np.log(design_error)), float(low), float(high), int(np.clip(m, calibrated[0], calibrated[-1]))


def describe_design(design) -> str:
    """The line that says why a design's prediction is an extrapolation, from its ``design_detail``;
    without one (an Assess step journaled before it was recorded) the feature alone."""
    if not design:
        return "the design is unlike every design the model's calibration was fitted on (log design error beyond " \
               "their range)"
    m, value, low, high, at = design
    where = "" if at == m else f" at {at} samples, the {'fewest' if at > m else 'most'} it saw"
    return (f"the design is unlike every design the model's calibration was fitted on (log design error {value:.3g} "
            f"at {int(m)} samples; {low:.3g} to {high:.3g} in training{where})")


def extrapolation_fields(bound: ErrorBound) -> dict:
    """What a report or record says of an ErrorBound's flags: {"extrapolation": bool,
    "out_of_model": keys of FEATURE_NAMES, "out_of_model_features": their names} and, when the
    design is out of the model, "design": {"samples", "log_design_error", "training": [lowest,
    highest], "training_samples": the m that range is of}."""
    fields = {"extrapolation": bool(bound.out_of_model), "out_of_model": list(bound.out_of_model),
              "out_of_model_features": [FEATURE_NAMES[k] for k in bound.out_of_model]}
    if bound.design is not None:
        m, value, low, high, at = bound.design
        fields["design"] = {"samples": int(m), "log_design_error": value, "training": [low, high],
                            "training_samples": int(at)}
    return fields


def extrapolation_lines(fields: dict) -> list[str]:
    """The EXTRAPOLATION lines of ``extrapolation_fields``: the design's (which feature, its
    value, the training range) and the samples' (their features beyond the training range)."""
    if not fields.get("extrapolation"):
        return []
    lines, flags = [], list(fields["out_of_model"])
    if "design" in flags:
        design = fields.get("design")
        detail = design and (design["samples"], design["log_design_error"], *design["training"],
                             design["training_samples"])
        lines.append(f"EXTRAPOLATION: {describe_design(detail)}: its predicted error is not backed by the calibration")
    features = [FEATURE_NAMES[k] for k in flags if k != "design"]
    if features:
        lines.append("EXTRAPOLATION: the samples are unlike every material the model was trained on ("
                     + " and ".join(features) + " beyond the training range): "
                     "this reconstruction and its predicted error are not backed by the training set")
    return lines


def conformal_quantile(scores, confidence: float) -> float:
    """The ceil((n + 1) c)-th smallest of n sorted scores; inf when that exceeds n."""
    k = math.ceil((len(scores) + 1) * confidence - 1e-9)
    return float(scores[k - 1]) if 1 <= k <= len(scores) else math.inf


def max_confidence(bound_calibration: dict) -> float:
    """The highest confidence n scores support: n / (n + 1)."""
    n = len(bound_calibration["scores"])
    return n / (n + 1)


def scores_needed(confidence: float) -> int:
    """The fewest held-out scores whose ``conformal_quantile`` at ``confidence`` (in (0, 1)) is
    finite: about c / (1 - c), found with the quantile's own arithmetic (0.9999 needs 9999)."""
    n = max(1, math.floor(confidence / (1 - confidence)) - 1)
    while math.ceil((n + 1) * confidence - 1e-9) > n:
        n += 1
    return n


def _at_m(bound_calibration: dict, key: str, m) -> np.ndarray:
    ms = np.log(np.asarray(bound_calibration["m"], dtype=np.float64))
    return np.interp(np.log(np.asarray(m, dtype=np.float64)), ms, np.asarray(bound_calibration[key], dtype=np.float64))


@dataclass(frozen=True)
class Evidence:
    """What a reconstruction's bound takes beyond its point prediction (each a float or an
    array broadcast with the prediction). extra: the increase the samples' own variance causes,
    added to the median and the bound (what the model says it costs, ``reconstruction._posterior``);
    check: the error at the sentinel cells (``sentinel.check_error``), None: not checked (never out
    of the model by it; ``sentinel_excess`` at ``sentinel.SENTINEL_CONFIDENCE`` otherwise);
    checked_predicted: the checked calibration's point prediction (``check_cells``: the sentinels'
    and the check cells' errors among its features), None: not measured; design_error: the
    design error of exact samples (``prediction.material_features``), out of the model
    ("design", ``design_outside``) beyond the calibration's designs at m, None: not checked."""

    extra: object = 0.0
    check: object = None
    checked_predicted: object = None
    design_error: object = None


def error_bounds(calibration: dict, predicted, z2, energy, m, confidence: float,
                 evidence: Evidence = Evidence()) -> dict:
    """Vectorised bounds: {"median", "upper", "out_of_model_z2", "out_of_model_energy",
    "out_of_model_sentinel", "out_of_model_design"} arrays (broadcast shape of the arguments).
    predicted: the calibrated point prediction (exact samples); z2, energy: the samples'; m: their
    number; evidence: what else the reconstruction measured (Evidence). With its
    checked_predicted the median is the checked calibration's and the bound the larger of the two
    calibrations' (each calibrated on its own held-out residuals, the checked one's nested: the
    larger covers whenever either does; the checked bound alone under-covered MERL materials on a
    model trained on RGL, 78 to 89 % at m = 15 to 25); the out-of-model flags stay the unchecked
    ones (the sentinels' against ``predicted``)."""
    extra, check, checked_predicted = evidence.extra, evidence.check, evidence.checked_predicted
    design_error = evidence.design_error
    bound = calibration.get("bound")
    predicted = np.asarray(predicted, dtype=np.float64)
    checked = calibration.get("checked") if checked_predicted is not None else None
    if not bound:
        inf = np.full(np.broadcast(predicted, m).shape, np.inf)
        return {"median": predicted + extra, "upper": inf, "out_of_model_z2": inf == 0, "out_of_model_energy": inf == 0,
                "out_of_model_sentinel": inf == 0, "out_of_model_design": inf == 0}
    median, upper = _median_upper(bound, predicted, m, confidence, extra, z2, energy)
    if checked:
        median, checked_upper = _median_upper(checked["bound"], checked_predicted, m, confidence, extra, z2, energy)
        upper = np.maximum(upper, checked_upper)
    margin = math.log(OUT_OF_MODEL_FACTOR)
    return {"median": median, "upper": upper,
            "out_of_model_z2": np.log(z2) > _at_m(bound, "log_z2_max", m) + margin,
            "out_of_model_energy": np.log(energy) > _at_m(bound, "log_energy_max", m) + margin,
            "out_of_model_sentinel": np.zeros(np.shape(upper), bool) if check is None else
            sentinel_excess(calibration, check, predicted, m, SENTINEL_CONFIDENCE) & np.ones(np.shape(upper), bool),
            "out_of_model_design": np.zeros(np.shape(upper), bool) if design_error is None else
            design_outside(calibration, design_error, m) & np.ones(np.shape(upper), bool)}


def _median_upper(bound: dict, predicted, m, confidence: float, extra, z2=1.0, energy=1.0) -> tuple[np.ndarray, np.ndarray]:
    """(median estimate, upper bound) of one calibration's ``bound`` for its point prediction
    (its "kind", ``BOUND_KINDS``; z2 and energy: the samples', for a normalised bound)."""
    predicted = np.asarray(predicted, dtype=np.float64)
    kind = bound.get("kind", "split") if "normalised" in bound else "split"
    log_upper = _log_upper(bound, kind, m, _spread_features(m, z2, energy, predicted), confidence)
    with np.errstate(over="ignore", invalid="ignore"):
        upper = predicted * np.exp(log_upper) + extra
    return predicted * np.exp(_at_m(bound, "center", m)) + extra, np.where(np.isnan(upper), np.inf, upper)


def error_bound(calibration: dict, predicted: float, z2: float, energy: float, m: int,
                confidence: float, evidence: Evidence = Evidence()) -> ErrorBound:
    """The ErrorBound of one reconstruction (see ``error_bounds``; ``evidence``'s fields floats)."""
    out = error_bounds(calibration, predicted, z2, energy, m, confidence, evidence)
    flags = tuple(k for k in FEATURE_NAMES if bool(out.get(f"out_of_model_{k}", False)))  # one look's
    design = design_detail(calibration, evidence.design_error, m) if "design" in flags else None
    return ErrorBound(float(out["median"]), float(out["upper"]), float(confidence), flags,
                      unavailability(calibration, confidence), design)


def training_spread(calibration: dict, m: int, confidence: float) -> list[float] | None:
    """The held-out training materials' bounds at m samples and ``confidence``: their 10th, 50th and
    90th percentiles (SPREAD_QUANTILES of their cross-fitted point predictions at m, interpolated in
    log m, each bounded as a material of typical z2 and energy); None for a calibration that does
    not record them."""
    bound = calibration.get("bound") or {}
    if "log_predicted_quantiles" not in bound:
        return None
    ms = np.log(np.asarray(bound["m"], np.float64))
    table = np.asarray(bound["log_predicted_quantiles"], np.float64)
    at = [float(np.interp(math.log(m), ms, table[:, k])) for k in range(table.shape[1])]
    out = error_bounds(calibration, np.exp(at), np.exp(calibration["typical_log_z2"]),
                       np.exp(calibration["typical_log_energy"]), m, confidence)["upper"]
    return [float(v) for v in out]


def unavailability(calibration: dict, confidence: float) -> str | None:
    """Why no bound at ``confidence`` can be given from this calibration, or None."""
    bound = calibration.get("bound")
    if not bound:
        return "the model has no calibrated error bound (train it again with this version)"
    if conformal_quantile(bound["scores"], confidence) == math.inf:
        n = len(bound["scores"])
        return (f"the model's {n} held-out training materials support a confidence of at most "
                f"{max_confidence(bound):.3f}; {confidence:g} needs {scores_needed(confidence)}")
    return None
