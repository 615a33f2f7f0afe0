"""Bayesian sample selection: greedy A-optimal design for the posterior-mean reconstruction.

Each step adds the cell c* = argmax_c u_c^T S^2 u_c / (sigma_c^2 + d_c^T u_c), u_c = Sigma d_c,
the largest reduction of trace(S^2 Sigma), in one compiled pass over D (``bayes_kernels``). The
design is deterministic and nested. Why and how: docs/explanations/bayesian-design.md.
"""
from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from goniofrost.frost import bayes_kernels as kernels
from goniofrost.frost.posterior import cell_noise, design_scale, error_trace, prior_variance
from goniofrost.frost.prediction import calibration_of, predict_typical
from goniofrost.frost.selection import Selection, SelectionError
from goniofrost.frost.threads import pass_ranges, resolve_threads
from goniofrost.frost import usage_design
from goniofrost.frost.usage_design import (DesignChoice, SceneDesign, design_weights, is_uniform, scene_matrix,
                                           scene_prior)

# No plan has more samples than this (--samples, and --max-error picks at most this many).
MAX_PICKS = 1000
# A best score at or below this fraction of the first one means no allowed cell still
# reduces the expected error (float rounding of the updated forms is ~1e-7 of them).
EXHAUSTED = 1e-9


@dataclass
class GreedyDesign:
    """A greedy design over candidate rows of D, in pick order.

    rows: int64 (m,) rows of D picked; design_errors: float64 (m,) the design error
    (trace(S^2 Sigma) + sum sigma^2) / n after each pick; pick_seconds: float64 (m,) wall time
    from the start to each pick; covariance: float64 (K, K), Sigma after the last pick.
    """

    rows: np.ndarray
    design_errors: np.ndarray
    pick_seconds: np.ndarray
    covariance: np.ndarray


def greedy_design(dictionary, s2, prior_var, noise, m_max: int, rows=None, stop=None,
                  threads: int | None = None, track=None) -> GreedyDesign:
    """Greedy A-optimal picks among ``rows`` of ``dictionary``.

    dictionary: float32 (n, K) D (memory-mapped is fine); s2: (K,) S^2 = D^T D;
    prior_var: (K,) prior variance of the coefficients; noise: (n,) sigma_c^2 of every row (the
    design errors are under this noise); rows: int64 candidate rows (default all n); m_max: at
    most this many picks; stop: optional ``stop(row) -> bool`` called with each picked row (e.g.
    to track an error target); threads: threads sharing each pass (default: the cores this
    process may use; the picks do not depend on it); track: a ``time_design.RigTrack`` of the
    candidates: each score is then per second of rig time from where the rig stands. Raises
    SelectionError when the candidates stop reducing the error first.
    """
    return _greedy(dictionary, s2, prior_var, [noise], m_max, rows, stop, threads, track)[0]


def greedy_designs(dictionary, s2, prior_var, noises, m_max: int, rows=None,
                   threads: int | None = None) -> list[GreedyDesign]:
    """One greedy design per noise vector of ``noises`` (each (n,)), on the same dictionary,
    S^2, prior and candidates, sharing every pass over D (it is read once per step for all of
    them). Each design is ``greedy_design``'s with that noise, to the bit: its arithmetic is the
    same, in the same order. Their ``pick_seconds`` are the shared passes' times.
    """
    return _greedy(dictionary, s2, prior_var, list(noises), m_max, rows, None, threads)


def _greedy(dictionary, s2, prior_var, noises: list, m_max: int, rows, stop, threads,
            track=None) -> list[GreedyDesign]:
    """The greedy loop of every design in ``noises`` (see greedy_designs); ``stop`` sees the
    first design's picks; ``track`` (one design only): time-aware scores (greedy_design)."""
    start = time.perf_counter()
    threads = resolve_threads(threads)
    forms = _Forms(dictionary, rows, noises, threads, track)
    prior = np.asarray(prior_var, np.float64)
    sigmas = [np.diag(prior) for _ in noises]
    s2 = np.asarray(s2, np.float64)
    designs, n = len(noises), forms.d.shape[0]
    noise_totals = [float(forms.noise[s].sum()) for s in range(designs)]
    picks, errors, seconds = [[] for _ in noises], [[] for _ in noises], []
    u, v = np.empty((designs, prior.size)), np.empty((designs, prior.size))
    inv_delta, usu_delta2 = np.empty(designs), np.empty(designs)
    with ThreadPoolExecutor(max_workers=threads) as pool:
        best, index = forms.first_pass(pool, np.tile(prior, (designs, 1)), s2)
        if track is not None:
            best, index = forms.timed_pass(pool, best)
        first = best.copy()
        while True:
            for s in range(designs):
                if index[s] < 0 or best[s] <= EXHAUSTED * first[s]:
                    raise SelectionError(
                        f"selection: after {len(picks[s])} picks no allowed cell reduces the expected error any "
                        "more; allow more cells or ask for fewer samples")
                row, picked = forms.close(s, int(index[s]))
                sigma = sigmas[s]
                u[s] = sigma @ row
                delta = forms.noise[s][picked] + row @ u[s]
                v[s] = sigma @ (s2 * u[s])
                sigma -= np.outer(u[s], u[s]) / delta
                picks[s].append(picked)
                if track is not None:
                    track.picked(int(index[s]))
                errors[s].append((error_trace(s2, sigma) + noise_totals[s]) / n)
                inv_delta[s], usu_delta2[s] = 1.0 / delta, float(u[s] @ (s2 * u[s])) / delta ** 2
            seconds.append(time.perf_counter() - start)
            if len(picks[0]) >= min(m_max, forms.rows.size) or (stop is not None and stop(picks[0][-1])):
                break
            best, index = forms.update_pass(pool, u, v, inv_delta, usu_delta2)
    return [GreedyDesign(np.array(picks[s], dtype=np.int64), np.array(errors[s]), np.array(seconds), sigmas[s])
            for s in range(designs)]


class _Forms:
    """The quadratic forms q, p of every candidate in every design and the fused passes that
    keep them (shared by ``threads`` threads over contiguous pieces of the candidates; see
    bayes_kernels)."""

    def __init__(self, dictionary, rows, noises: list, threads: int, track=None) -> None:
        self.d = np.ascontiguousarray(dictionary, dtype=np.float32)
        n = self.d.shape[0]
        # Every row a candidate: the kernels take candidate i as row i and read no index array.
        self.rows = np.arange(n, dtype=np.int64) if rows is None else np.ascontiguousarray(rows, dtype=np.int64)
        self.kernel_rows = np.empty(0, dtype=np.int64) if rows is None else self.rows
        self.noise = [np.asarray(noise, dtype=np.float64) for noise in noises]  # S of (n,), the callers'
        # private: a picked cell gets +inf (score 0)
        self.open_noise = _compact(np.array([noise if rows is None else noise[self.rows] for noise in self.noise]))
        self.q, self.p = np.empty(self.open_noise.shape), np.empty(self.open_noise.shape)
        self.parts = pass_ranges(self.rows.size, threads)  # several per thread, taken as threads come free
        self.track = track
        if track is not None and len(noises) != 1:
            raise ValueError("a time-aware design runs alone (one noise vector)")
        if track is not None:  # the cells each pass over D collects for timing (update_collect)
            self.found = np.empty(self.rows.size, np.int32)

    def first_pass(self, pool, prior_var, s2) -> tuple[np.ndarray, np.ndarray]:
        return self._run(pool, kernels.init_forms, self.d, self.kernel_rows, prior_var, self.q, self.p, self.open_noise, s2)

    def timed_pass(self, pool, best_gain: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The best score per second of rig time from the track's pose among the cells whose gain
        is at least the track's share of ``best_gain`` (1,), this step's best (the forms unchanged)."""
        floor = self.track.share * float(best_gain[0])
        return self._run(pool, kernels.timed_scan, self.q[0], self.p[0], self.open_noise[0],
                         *self.track.kernel_args(), floor)

    def update_pass(self, pool, u, v, inv_delta, usu_delta2) -> tuple[np.ndarray, np.ndarray]:
        if self.track is not None and not self.track.full_scan:
            return self.collected_pass(pool, u[0], v[0], float(inv_delta[0]), float(usu_delta2[0]))
        best = self._run(pool, kernels.update_forms, self.d, self.kernel_rows, u, v, inv_delta, usu_delta2,
                         self.q, self.p, self.open_noise)
        return best if self.track is None else self.timed_pass(pool, best[0])

    def collected_pass(self, pool, u, v, inv_delta: float, usu_delta2: float) -> tuple[np.ndarray, np.ndarray]:
        """The time-aware design's step: the pass over D collects the cells whose gain reaches the
        share of its running best (a superset of those reaching the step's best's share), then
        only those are timed: ``timed_pass``'s result, without a second sweep over the forms."""
        share = self.track.share
        best, _ = self._run(pool, kernels.update_collect, self.d, self.kernel_rows, u, v, inv_delta, usu_delta2,
                            self.q[0], self.p[0], self.open_noise[0], share, self.found)
        return self._run(pool, kernels.timed_found, self.found, self.q[0], self.p[0], self.open_noise[0],
                         *self.track.kernel_args(),
                         share * float(best[0]))

    def close(self, s: int, i: int) -> tuple[np.ndarray, int]:
        """Take candidate i out of design s's competition; return its dictionary row (float64)
        and row index."""
        self.open_noise[s, i] = np.inf
        picked = int(self.rows[i])
        return self.d[picked].astype(np.float64), picked

    def _run(self, pool, kernel, *args) -> tuple[np.ndarray, np.ndarray]:
        """Every design's best score and its candidate index (-1: none) over all pieces."""
        designs = self.q.shape[0]
        best = np.empty((len(self.parts), designs))
        best_i = np.empty((len(self.parts), designs), dtype=np.int64)
        futures = [pool.submit(kernel, *args, best[k], best_i[k], lo, hi) for k, (lo, hi) in enumerate(self.parts)]
        for future in futures:
            future.result()
        return _best(best, best_i)


def _compact(noise: np.ndarray) -> np.ndarray:
    """The (S, n_c) float64 noise as float32 when that holds every value exactly (the kernels
    widen it back to the same float64: the same scores, 4 bytes a cell less in every pass),
    else unchanged."""
    narrow = noise.astype(np.float32)
    return narrow if np.array_equal(narrow, noise) else noise


def _best(best: np.ndarray, best_i: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per design, the highest of the pieces' scores (pieces, S); lowest index on ties (the
    pieces cover increasing index ranges, so the first piece holding the maximum)."""
    piece = np.argmax(best, axis=0)  # the first occurrence of the maximum
    designs = np.arange(best.shape[1])
    return best[piece, designs], best_i[piece, designs]


def select_bayes(model, m: int | None = None, *, max_error: float | None = None,
                 candidates: np.ndarray | None = None, threads: int | None = None,
                 scene: SceneDesign | None = None, calibration=None, confidence: float | None = None,
                 time_objective=None) -> Selection:
    """Pick measurement cells by greedy Bayesian A-optimal design; deterministic and nested.

    m: number of samples; or max_error: stop after the first pick whose predicted error of a typical
    material (``prediction.predict_typical``) is <= max_error, or, with ``confidence`` (no
    ``scene``), whose calibrated bound (``typical_bound``) is; the bounds go to ``bounds``.
    candidates: bool (n_valid,) mask of allowed cells (default all valid cells).
    threads: threads sharing each pass (default: the cores this process may use).
    scene: a ``usage_design.SceneDesign`` (its usage u: float (n_valid,) a scene's use of every cell,
    sum 1): the design then minimises the error the scene sees, weights u g^p
    (``usage_design.design_usage``) mixed with the plain design's by its ``hedge`` (1 the scene
    alone, 0 the plain design). ``uniform_is_plain``: a uniform map is taken as the plain design
    without the change of basis (False: the long way, for tests). Its other fields:
    sensitivity_power: p; None: ``usage_design.scene_power(model, usage, m)``. With max_error and p
    None the bands of ``usage_design.BANDS`` run in turn, so the result of n picks is the n-sample
    design and the (n - 1)-sample design does not reach the target.
    prior_spread: t of the weights u g^p exp(t p^2 v / 2); None: ``usage_design.prior_spread(m)``.
    spread_floor: F, a floor on the effective cells 1 / sum w^2 (``usage_design.floor_spread``);
    0 none; None: the band's (``usage_design.spread_floor(m, p)``) when prior_spread is None too.
    mix: the share a of ``usage_design.MIX_DESIGN``'s weights (``mixed_weights``); None: the band's
    share (``BAND_MIX``) when power, spread and floor are the defaults, else 0.
    mix_spread: the spread of a mixed design's own part; None: ``usage_design.mix_spread``.
    calibration: the predicted-error calibration (default the model's), or a function of
    (p, t, F[, a]) (``usage_design.design_key``) returning one (None: the model's).
    time_objective: a ``time_design.TimeObjective``: each pick maximises the expected error
    reduction per second of rig time (whole-BRDF design only). None: per sample.
    Returns a Selection: ``residuals`` the predicted errors after each pick, ``prior_spread`` and
    ``sensitivity_power`` those of the scene's weights (0 / None without a map).
    """
    start = time.perf_counter()
    rows = _candidate_rows(candidates, model.grid.n_valid)
    noise = cell_noise(model)
    design = scene if scene is not None else SceneDesign(usage=None)
    usage, sensitivity_power, prior_spread = design.usage, design.sensitivity_power, design.prior_spread
    aware = usage is not None and not (design.uniform_is_plain and is_uniform(usage))
    if time_objective is not None and usage is not None:
        raise SelectionError("selection: the time-aware design (--objective time) is of the whole BRDF; "
                             "it does not take a scene's use (--usage)")
    # the error no sample removes, as the predicted errors count it (the scene's: weighted by u)
    floor = float(np.dot(usage, noise)) if aware else float(noise.mean())

    # the cells' prior variance, computed once if a scene's weights (or its power choice) need it
    variance = usage_design.cell_variance_of(model)
    setting = _Setting(model, rows, noise, variance, threads, time_objective)

    def calibration_for(choice: DesignChoice):
        chosen = calibration(*choice.key) if callable(calibration) else calibration
        return chosen or calibration_of(model)

    defaults = sensitivity_power is None and prior_spread is None and design.spread_floor is None
    if not aware or sensitivity_power is not None or max_error is None:
        if aware and sensitivity_power is None:
            _check(m, max_error, rows.size, None, floor)  # m itself is checked before its power
        choice = design_options(model, design, m, variance=variance, scene=aware)
        calib = calibration_for(choice)
        limit = _check(m, max_error, rows.size, calib, floor)
        picked, predicted, used_spread, bounds = _design(
            setting, design if aware else None, choice, calib,
            _Stop(limit, max_error, confidence=None if aware else confidence))
    else:  # an error target and the power of the design's own length: a phase per band (docstring)
        # the floor ("however many samples") is the longer design's, checked before it runs
        limit, start_m = _check(None, max_error, rows.size, None, floor), 0
        for i, (last, _, band_spread, _) in enumerate(usage_design.BANDS):
            power = usage_design.scene_power(model, usage, start_m + 1, variance)  # the scene's of the band's
            spread = band_spread if prior_spread is None else prior_spread
            cells_floor = _floor(design.spread_floor, prior_spread, None, True, power,
                                 usage_design.spread_floor(start_m + 1, power))
            share = _mix(design.mix, defaults, start_m + 1, True, power)
            spread = _own_spread(spread, prior_spread, design.mix_spread, share, start_m + 1)
            choice = DesignChoice(power, spread, cells_floor, share)
            calib = calibration_for(choice)
            if i:
                limit = _check(None, max_error, rows.size, calib, floor)
            end = limit if last is None else min(limit, last)
            picked, predicted, used_spread, bounds = _design(
                setting, design, choice, calib, _Stop(end, max_error, min_picks=start_m + 1))
            if predicted[-1] <= max_error or last is None or limit <= last:
                break
            start_m = last
    if max_error is not None and bounds is not None and bounds[-1] > max_error:
        raise SelectionError(f"max_error (--max-error): {max_error:g} not reached with {picked.rows.size} samples (a "
                             f"typical material's bound {bounds[-1]:.4g} at {100 * confidence:g} % confidence); "
                             f"allow more cells or ask for a larger error")
    if max_error is not None and predicted[-1] > max_error:
        raise SelectionError(f"max_error (--max-error): {max_error:g} not reached with {picked.rows.size} samples (predicted "
                             f"{predicted[-1]:.4g}); allow more cells or ask for a larger error")
    return Selection(bounds=None if bounds is None else np.asarray(bounds, np.float64),
                     positions=picked.rows, cells=model.grid.valid_cells[picked.rows],
                     residuals=np.asarray(predicted, dtype=np.float64), seconds=time.perf_counter() - start,
                     y_form="", k=model.n_components, selector="bayes", pick_seconds=picked.pick_seconds,
                     prior_spread=used_spread if aware else (None if usage is None else 0.0),
                     sensitivity_power=choice.power if aware else None,
                     design_key=choice.key if aware else None)


def design_options(model, design: SceneDesign, m, *, variance=None, scene: bool = True) -> DesignChoice:
    """The weights (p, largest t, F, a) of the design of m samples ``select_bayes`` makes for
    ``design``, a SceneDesign (each None field its default, as select_bayes's docstring says),
    without making it: the power (``usage_design.scene_power`` unless given), the prior spread,
    the floor on the effective cells and the share of MIX_DESIGN mixed in. ``scene`` False: no
    scene (p as given, t = 0, F only checked, a = 0). ``variance``: see
    ``usage_design.design_weights``."""
    power, prior_spread = design.sensitivity_power, design.prior_spread
    if scene and power is None:
        power = usage_design.scene_power(model, design.usage, m, variance)
    defaults = design.sensitivity_power is None and prior_spread is None and design.spread_floor is None
    spread = _spread(prior_spread, m, scene)
    cells_floor = _floor(design.spread_floor, prior_spread, m, scene, power)
    share = _mix(design.mix, defaults, m, scene, power)
    return DesignChoice(power, _own_spread(spread, prior_spread, design.mix_spread, share, m), cells_floor, share)


def _spread(spread, m, scene: bool) -> float:
    """The prior spread t of a scene design of m samples: ``spread`` when given, else the default for
    m (``usage_design.prior_spread``; 0 when m is None); 0 without a scene."""
    if not scene:
        return 0.0
    if spread is not None:
        return float(spread)
    return 0.0 if m is None else usage_design.prior_spread(m)


def _floor(floor, spread, m, scene: bool, power: float | None = None, band_floor: float | None = None) -> float:
    """The floor F on the effective cells of a scene design of m samples at ``power`` (select_bayes's
    spread_floor): ``floor`` when given, else the band's for that power (``band_floor``, or that of
    m, ``usage_design.spread_floor``: up to 14 samples p = 1's only) when the spread is the band's
    too (``spread`` None), else 0; 0 without a scene or without m."""
    if floor is not None:
        return usage_design.check_floor(floor)
    if not scene or spread is not None:
        return 0.0
    if band_floor is not None:
        return band_floor
    return 0.0 if m is None else usage_design.spread_floor(m, power)


def _mix(mix, defaults: bool, m, scene: bool, power) -> float:
    """The share a of MIX_DESIGN in a scene design of m samples at ``power`` (select_bayes's mix):
    ``mix`` when given, else the band's when the design is the default one (``defaults``), for a
    power other than the band's own (``usage_design.design_mix``); 0 without a scene or m."""
    if not scene or m is None or (mix is None and not defaults):
        return 0.0
    return usage_design.design_mix(m, power, mix)


def _own_spread(spread: float, prior_spread, mix_spread, share: float, m) -> float:
    """The spread t of a scene design's own part: ``spread`` unless the design is mixed (``share``
    > 0) and prior_spread was not given, then ``mix_spread`` or the band's for m
    (``usage_design.mix_spread``)."""
    if not share or prior_spread is not None:
        return spread
    return usage_design.mix_spread(m) if mix_spread is None else float(mix_spread)


@dataclass(frozen=True)
class _Setting:
    """What every design of one ``select_bayes`` call shares: the model, its candidate ``rows``
    (int64), the cells' ``noise`` sigma_c^2 (n,), their prior ``variance`` (shared by the scene
    weights, ``usage_design.design_weights``), the ``threads`` and the ``time_objective``."""

    model: object
    rows: np.ndarray
    noise: np.ndarray
    variance: object
    threads: int | None
    time_objective: object


@dataclass(frozen=True)
class _Stop:
    """When a design stops: after ``limit`` picks, or with ``max_error`` at the first pick, of at
    least ``min_picks``, whose predicted error (with ``confidence``: the typical material's bound
    at it, ``typical_bound``) is <= max_error."""

    limit: int
    max_error: float | None
    min_picks: int = 1
    confidence: float | None = None


def _design(setting: _Setting, scene: SceneDesign | None, choice: DesignChoice, calibration,
            stop_rule: _Stop) -> tuple[GreedyDesign, np.ndarray, float | None, np.ndarray | None]:
    """One greedy design among ``setting.rows`` stopping by ``stop_rule``, its predicted errors
    (float64 (picks,)) and the prior spread its scene weights used (None without a scene); scene
    None: the plain design, else the scene's usage, hedge and ``uniform_is_plain`` (see
    select_bayes) with ``choice``'s weights; the typical material's bounds at
    ``stop_rule.confidence`` (float64 (picks,), the fourth returned; None without)."""
    model, noise, max_error = setting.model, setting.noise, stop_rule.max_error
    if scene is not None:
        usage = scene.usage
        weights, used_spread = design_weights(model, usage, choice.power, scene.hedge, choice.spread, choice.floor,
                                              setting.variance, choice.mix)
        if scene.uniform_is_plain and is_uniform(weights):  # hedge 0: the plain design, judged by the scene's error
            dictionary, prior_var = model.dictionary, prior_variance(model)
            s2 = np.asarray(model.singular_values, np.float64) ** 2
        else:
            prior = scene_prior(model.dictionary, weights, prior_variance(model))
            dictionary, prior_var, s2 = prior.dictionary, prior.prior_var, prior.weights
        # the predicted error is of u alone: M_u in the design's basis (a second pass over the used
        # rows) unless the design weighs u itself (then Lambda, diagonal)
        error_matrix = s2 if weights is usage or np.array_equal(weights, usage) else scene_matrix(dictionary, usage)
        tracker = _PredictedError(dictionary, error_matrix, prior_var, calibration, noise, usage=usage)
    else:
        dictionary, prior_var = model.dictionary, prior_variance(model)
        s2 = np.asarray(model.singular_values, np.float64) ** 2
        tracker = _PredictedError(dictionary, s2, prior_var, calibration, noise, confidence=stop_rule.confidence)
        used_spread = None
    stop = None
    if max_error is not None:
        def stop(row):
            tracker.add(row)
            said = tracker.bounds if tracker.confidence is not None else tracker.history
            return said[-1] <= max_error and len(tracker.history) >= stop_rule.min_picks
    track = None
    if setting.time_objective is not None:
        from goniofrost.frost.time_design import RigTrack
        track = RigTrack.of_model(model, setting.time_objective, setting.rows, stop_rule.limit)
    design = greedy_design(dictionary, s2, prior_var, noise * design_scale(model), stop_rule.limit,
                           rows=setting.rows, stop=stop, threads=setting.threads, track=track)
    if max_error is None:
        for row in design.rows:
            tracker.add(int(row))
    bounds = None if tracker.confidence is None else np.array(tracker.bounds)
    return design, np.array(tracker.history), used_spread, bounds


def typical_bound(calibration: dict, predicted, m, confidence: float) -> np.ndarray:
    """The calibrated bound at ``confidence`` of a typical material (z2 and energy at their training
    geometric means) whose point prediction is ``predicted`` at m samples: what a capture of it
    would stop on (``confidence.error_bounds``). inf for a calibration without a bound."""
    from goniofrost.frost.confidence import error_bounds

    return error_bounds(calibration, predicted, np.exp(calibration["typical_log_z2"]),
                        np.exp(calibration["typical_log_energy"]), m, confidence)["upper"]


class _PredictedError:
    """The predicted error of a typical material after each pick, under the reconstruction's
    noise (the design may assume a larger one): Sigma by rank-1 downdates, O(K^2) per pick.

    d: (n, K) dictionary; s2: (K,) the error weights of the coefficients (S^2; Lambda of a scene),
    or (K, K) the error's matrix in the dictionary's basis (a scene's M_u when the design weighs more);
    prior_var: (K,); noise: (n,) sigma_c^2; usage: (n,) sum 1, or None for every cell alike (the
    design error is then the mean over the n cells)."""

    def __init__(self, d, s2, prior_var, calibration: dict, noise: np.ndarray, usage=None,
                 confidence: float | None = None) -> None:
        self.d, self.calibration, self.s2 = d, calibration, np.asarray(s2, np.float64)
        self.confidence, self.bounds = confidence, []
        self.noise = noise
        if usage is None:
            self.total, self.n = float(self.noise.sum()), self.noise.size
        else:  # weights summing to 1: the weighted noise, no division
            self.total, self.n = float(np.dot(usage, self.noise)), 1
        self.sigma = np.diag(np.asarray(prior_var, np.float64))
        self.history: list[float] = []

    def add(self, row: int) -> float:
        d = np.asarray(self.d[row], dtype=np.float64)
        u = self.sigma @ d
        self.sigma -= np.outer(u, u) / (self.noise[row] + d @ u)
        design_error = (error_trace(self.s2, self.sigma) + self.total) / self.n
        self.history.append(float(predict_typical(self.calibration, design_error, len(self.history) + 1)))
        if self.confidence is not None:
            self.bounds.append(float(typical_bound(self.calibration, self.history[-1], len(self.history),
                                                   self.confidence)))
        return self.history[-1]


def _candidate_rows(candidates, n: int) -> np.ndarray:
    if candidates is None:
        return np.arange(n, dtype=np.int64)
    mask = np.asarray(candidates)
    if mask.dtype != bool or mask.shape != (n,):
        raise SelectionError(f"candidates: expected a bool mask of shape ({n},), found {mask.dtype} {mask.shape}")
    return np.flatnonzero(mask).astype(np.int64)


def _check(m, max_error, n_candidates: int, calibration: dict, noise_total: float) -> int:
    """Validate the options; return the largest number of picks. noise_total: the design error's
    part no sample removes (the mean sigma_c^2; for a scene sum_c u_c sigma_c^2, what its
    calibration was fitted on); calibration None: max_error's floor is not checked."""
    if (m is None) == (max_error is None):
        raise SelectionError("selection: give exactly one of m (--samples) and max_error (--max-error)")
    if m is not None:
        if not isinstance(m, (int, np.integer)) or not 1 <= m <= MAX_PICKS:
            # each pick reads the whole dictionary: 100000 picks ran for longer than 10 minutes
            raise SelectionError(f"samples m (--samples): expected an integer in [1, {MAX_PICKS}], found {m!r}")
        if m > n_candidates:
            raise SelectionError(f"candidates: {n_candidates} allowed cells, fewer than the {m} samples asked for")
        return int(m)
    if not (isinstance(max_error, (int, float)) and np.isfinite(max_error) and max_error > 0):
        raise SelectionError(f"max_error (--max-error): expected a number > 0, found {max_error!r}")
    if calibration is None:
        return min(n_candidates, MAX_PICKS)
    floor = float(predict_typical(calibration, noise_total, calibration["m_range"][1]))
    if max_error <= floor:
        raise SelectionError(
            f"max_error (--max-error): {max_error:g} is out of reach: the model's own representation error alone "
            f"predicts {floor:.4g} however many samples are taken; ask for more than that")
    return min(n_candidates, MAX_PICKS)
