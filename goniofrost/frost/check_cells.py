"""Check cells: a few cells chosen at training where the model errs, measured with the sentinels and
never fitted.

``pool`` offers candidates outside every inner design, ``choose`` picks CHECKS of them, and
``fit_checked`` fits the checked calibration. Why: docs/explanations/sentinels.md.
"""
from __future__ import annotations

import numpy as np
from numba import njit, types
from threadpoolctl import threadpool_limits

from goniofrost.core.grid import MerlGrid
from goniofrost.frost.confidence import FIRST_LOOK

# Cells chosen (measured with the first batch, beside the sentinels).
CHECKS = 3
# Candidate cells in the pool.
POOL = 4000
# The pool is drawn from at most this many cells (an even stride over the candidates): at the
# full grid the farthest-point sampling never runs over 1.1 M cells.
POOL_SUBSAMPLE = 150_000


def pool(grid: MerlGrid, candidates=None, count: int = POOL) -> np.ndarray:
    """int64 (<= count,) valid-cell positions, sorted: farthest-point sampling of the 6-vectors
    (w_i, w_o) of the candidate cells (bool (n_valid,), default all; at most POOL_SUBSAMPLE of
    them by an even stride), starting at the one farthest from their mean. Deterministic (ties:
    the lowest position)."""
    where = np.flatnonzero(np.ones(grid.n_valid, bool) if candidates is None else np.asarray(candidates, bool))
    if where.size > POOL_SUBSAMPLE:
        where = where[np.linspace(0, where.size - 1, POOL_SUBSAMPLE).round().astype(np.int64)]
    if where.size <= count:
        return where.astype(np.int64)
    w_i, w_o = grid.cell_directions(grid.valid_cells[where])
    x = np.concatenate([w_i, w_o], axis=1).astype(np.float64)
    first = int(np.argmax(((x - x.mean(axis=0)) ** 2).sum(axis=1)))
    picks = np.empty(count, dtype=np.int64)
    _farthest_points(np.ascontiguousarray(x.T), first, picks)
    return np.sort(where[picks]).astype(np.int64)


# Compiled: the loop over the picks reads every (sub)sampled cell once per pick (4 000 x 150 000
# cells); in numpy each pick made three (cells, 6) temporaries (23 s of the demo's training, 0.9 s
# here, the same picks).
@njit(types.void(types.float64[:, ::1], types.int64, types.int64[::1]), nogil=True, cache=True)
def _farthest_points(xt, first, picks):
    """Fill picks (count,) by farthest-point sampling of the cells, xt (6, cells) their (w_i, w_o)
    by coordinate, from cell ``first``: each pick the cell farthest (squared distance, summed in
    coordinate order as numpy's row sum) from every pick before, the lowest cell on ties."""
    x0, x1, x2, x3, x4, x5 = xt[0], xt[1], xt[2], xt[3], xt[4], xt[5]
    distance = np.full(xt.shape[1], np.inf)
    picks[0] = first
    for k in range(1, picks.size):
        j = picks[k - 1]
        c0, c1, c2, c3, c4, c5 = x0[j], x1[j], x2[j], x3[j], x4[j], x5[j]
        for i in range(distance.size):  # vectorisable: one cell at a time, no reduction
            e0, e1, e2, e3, e4, e5 = x0[i] - c0, x1[i] - c1, x2[i] - c2, x3[i] - c3, x4[i] - c4, x5[i] - c5
            distance[i] = min(distance[i], e0 * e0 + e1 * e1 + e2 * e2 + e3 * e3 + e4 * e4 + e5 * e5)
        best, best_i = -1.0, 0
        for i in range(distance.size):
            if distance[i] > best:
                best, best_i = distance[i], i
        picks[k] = best_i


def pool_errors(b: np.ndarray, rows: np.ndarray, coefficients: np.ndarray) -> np.ndarray:
    """float32 (P, materials): the squared error, channel mean, of the posterior ``coefficients``
    (K, 3 materials) at the pool cells (rows (P, K) their dictionary rows, b (P, 3 materials) their
    centred mapped values): per cell what ``sentinel.check_error`` averages over its cells (so the
    mean over chosen cells is the check error of a capture measuring them, before its floor)."""
    miss = np.asarray(b, np.float64) - np.asarray(rows, np.float64) @ np.asarray(coefficients, np.float64)
    return (miss ** 2).reshape(miss.shape[0], -1, 3).mean(axis=2).astype(np.float32)


def allowed(records, pool_cells: np.ndarray, sentinels) -> np.ndarray:
    """bool (P,): the pool cells no inner design sampled (finite in every record) and no sentinel."""
    return np.isfinite(records.pool_error).all(axis=0) & ~np.isin(pool_cells, np.asarray(sentinels, np.int64))


def feature(pool_error: np.ndarray, columns) -> np.ndarray:
    """float64 (records,): log of the mean error at the chosen pool ``columns`` (floored at 1e-12,
    as ``sentinel.check_error``)."""
    return np.log(np.maximum(np.asarray(pool_error, np.float64)[:, list(columns)].mean(axis=1), 1e-12))


def choose(x: np.ndarray, y: np.ndarray, fold: np.ndarray, m: np.ndarray, pool_error: np.ndarray,
           allowed_columns: np.ndarray, rows: np.ndarray, count: int = CHECKS) -> list[int]:
    """Greedy forward selection of ``count`` pool columns: at each step the column whose
    log(mean error over the chosen columns and it), added to the features ``x`` (records, f),
    gives the lowest cross-fitted (over the ``fold``s among ``rows``, bool (records,)) residual
    variance of ``y`` = log(actual) per m, averaged over the looks m >= FIRST_LOOK. Every
    candidate at once (Frisch-Waugh: the candidate column against the residual of the fit on
    ``x``). Deterministic: ties to the lowest column."""
    # the records sorted by fold (stable): each fold's records are a slice, read without a copy
    # (the objective does not depend on the records' order)
    rows = np.flatnonzero(rows)
    rows = rows[np.argsort(fold[rows], kind="stable")]
    x_rows, y_rows, fold_rows, m_rows = x[rows], y[rows], fold[rows], m[rows]
    looks = [v for v in np.unique(m_rows) if v >= FIRST_LOOK] or list(np.unique(m_rows))
    columns = np.flatnonzero(allowed_columns)
    errors = np.asarray(pool_error[rows][:, columns], np.float64)
    chosen: list[int] = []
    total = np.zeros(errors.shape[0])
    for _ in range(min(count, columns.size)):
        z = np.log(np.maximum((total[:, None] + errors) / (len(chosen) + 1), 1e-12))
        objective = _objective(x_rows, y_rows, fold_rows, z, m_rows, looks)
        objective[np.isin(columns, chosen)] = np.inf
        best = int(np.argmin(objective))
        chosen.append(int(columns[best]))
        total += errors[:, best]
    return chosen


def _objective(x, y, fold, z, m, looks) -> np.ndarray:
    """(candidates,) the per-m variance of the cross-fitted residual of y ~ [x, z[:, c]], averaged
    over ``looks``, for every column c of z (x holds the intercept).

    Frisch-Waugh from per-fold sums: a fold's training sums (x^T z, z^T z, y^T z) are the totals
    less its own, so z is read a few times in all rather than copied and projected per fold."""
    z = z - z.mean(axis=0)  # the intercept is among x's columns: no fit changes, no sum cancels
    held_of = [fold == f for f in np.unique(fold)]
    # each fold's records: a slice when they are contiguous (``choose`` sorts them), else a mask
    parts = [_span(h) for h in held_of]
    xtz = np.stack([x[h].T @ z[h] for h in parts])  # (folds, features, candidates)
    zz = np.stack([np.einsum("ic,ic->c", z[h], z[h]) for h in parts])
    yz = np.stack([y[h] @ z[h] for h in parts])
    looked = np.isin(m, looks)  # the residuals are only read at the looks
    residual = np.empty((int(looked.sum()), z.shape[1]))
    at = np.cumsum(looked) - 1
    for i, held in enumerate(held_of):
        a = np.linalg.pinv(x[~held])
        beta_y = a @ y[~held]
        xtz_train = xtz.sum(axis=0) - xtz[i]
        gamma = (a @ a.T) @ xtz_train  # pinv(x^T x) x^T z of the fold's training records
        cross = (yz.sum(axis=0) - yz[i]) - beta_y @ xtz_train
        total = zz.sum(axis=0) - zz[i]
        norm = total - np.einsum("fc,fc->c", gamma, xtz_train)
        # a candidate (nearly) in the span of x adds nothing: its slope is rounding noise over noise
        slope = np.divide(cross, norm, out=np.zeros_like(cross), where=norm > 1e-9 * total)
        rows = held & looked
        residual[at[rows]] = (y[rows] - x[rows] @ beta_y)[:, None] - (z[rows] - x[rows] @ gamma) * slope
    return np.mean([residual[m[looked] == v].var(axis=0) for v in looks], axis=0)


def _span(mask: np.ndarray):
    """slice(first, last + 1) when the True entries of ``mask`` are contiguous, else the mask."""
    where = np.flatnonzero(mask)
    contiguous = where.size and where[-1] - where[0] + 1 == where.size
    return slice(int(where[0]), int(where[-1]) + 1) if contiguous else mask


def fit_checked(records, pool_cells: np.ndarray, sentinels, base: dict, count: int = CHECKS) -> dict | None:
    """The checked calibration (JSON-ready) from the inner cross-validation's records with their
    sentinel and pool errors: the check ``cells`` (valid-cell positions, chosen on every record),
    the 19 coefficients (least squares on every record), their ``feature_range`` (the base's
    ranges and the two new features'), and the ``bound`` (``confidence.fit_bound``) on nested
    residuals: each inner fold's records with cells chosen on the other folds' records,
    predicted by a fit without that fold. None when the records lack the sentinels, the
    coordinates or the pool, or no candidate is left."""
    from goniofrost.frost.confidence import choice_score, cross_fit, fit_bound
    from goniofrost.frost.prediction import feature_range_of

    if records.pool_error is None or records.sentinel is None or records.coordinates is None or records.level is None:
        return None
    ok = allowed(records, pool_cells, sentinels)
    if not ok.any():
        return None
    m_range = [int(records.m.min()), int(records.m.max())]
    range17 = feature_range_of(records.z2, records.energy, records.level, records.spread, records.coordinates)
    x17 = records.features(m_range, None, range17)
    log_sentinel = np.log(np.maximum(records.sentinel, 1e-12))
    x18 = np.column_stack([x17, log_sentinel])
    y = np.log(np.maximum(records.actual, 1e-12))
    # Small products (18 features): a second BLAS thread only contends; at load 3 the 11 choices
    # took 23.5 s with two threads and 3.7 s with one (the demo model's records).
    with threadpool_limits(limits=1, user_api="blas"):
        columns, nested = _choose_nested(x18, y, records, ok, count)
    log_check = feature(records.pool_error, columns)
    x = np.column_stack([x18, log_check])
    # Plain least squares, not the unchecked calibration's signs (``prediction.fit_coefficients``):
    # here m acts through log m and the two check errors too (which fall as samples accumulate),
    # and on many materials least squares gives the design error a slightly negative coefficient
    # beside a strongly negative log m (built-in 64 / 10, 45 x 45 x 90: -0.005 to -0.18 beside
    # -2.1 to -2.8 in 3 of 10 folds' fits, and in nested fits of a 4th): holding it at 0 changed
    # those models' checked bounds (benchmarks/target_error.py) for a trend that already falls.
    beta, *_ = np.linalg.lstsq(x, y, rcond=None)
    lows, highs = range17
    feature_range = [list(lows) + [float(log_sentinel.min()), float(log_check.min())],
                     list(highs) + [float(log_sentinel.max()), float(log_check.max())]]
    bound = fit_bound(records, m_range, None, range17, residuals=nested)
    bound.pop("sentinel", None)  # the sentinels' flag stays the unchecked calibration's
    return {"coefficients": [float(b) for b in beta], "m_range": m_range, "feature_range": feature_range,
            "cells": [int(pool_cells[c]) for c in columns], "bound": bound,
            "fit": {"records": int(y.size), "pool": int(pool_cells.size), "candidates": int(ok.sum()),
                    "nested_within_factor_2": choice_score(records, nested),
                    "cross_fitted_within_factor_2": choice_score(records, cross_fit(x, y, records.fold, signed=())),
                    "unchecked_within_factor_2": base.get("fit", {}).get("cross_fitted_within_factor_2")}}


def _choose_nested(x18, y, records, ok, count):
    """(the check cells chosen on every record (pool columns), float64 (records,) the nested
    residuals: each inner fold's records predicted by a fit without it, with cells chosen
    without it)."""
    columns = choose(x18, y, records.fold, records.m, records.pool_error, ok, np.ones(y.size, dtype=bool), count)
    nested = np.empty_like(y)
    for f in np.unique(records.fold):  # the cells chosen without fold f, its records cross-fitted
        held = records.fold == f
        own = choose(x18, y, records.fold, records.m, records.pool_error, ok, ~held, count)
        x = np.column_stack([x18, feature(records.pool_error, own)])
        beta, *_ = np.linalg.lstsq(x[~held], y[~held], rcond=None)
        nested[held] = y[held] - x[held] @ beta
    return columns, nested


def measured(model, positions, flags) -> tuple[np.ndarray, np.ndarray]:
    """Of a capture's not-fitted samples (``flags``, bool (l,): the plan's sentinels and check
    cells), (bool (l,) the sentinels, bool (l,) the check cells): a flagged sample at one of the
    model's check cells is a check, the others sentinels."""
    flags = np.asarray(flags, dtype=bool)
    checks = flags & np.isin(np.asarray(positions, np.int64), cells_of(model))
    return flags & ~checks, checks


def complete(model, positions, checks) -> bool:
    """Whether the check samples (bool (l,)) cover every check cell of the model."""
    cells = cells_of(model)
    return bool(cells.size) and set(np.asarray(positions, np.int64)[np.asarray(checks, bool)].tolist()) >= set(cells.tolist())


def cells_of(model) -> np.ndarray:
    """int64 (k,): the model's check cells (empty: none, a model trained before them)."""
    from goniofrost.frost.prediction import checked_of

    checked = checked_of(model)
    return np.asarray(checked["cells"] if checked else [], dtype=np.int64)

