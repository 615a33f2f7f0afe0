"""Training's inner cross-validation of the Bayesian pipeline: simulated captures of held-out
training materials, the choice of the noise scales, and the predicted-error calibration.

For every inner fold (``noise.inner_folds``) a greedy design of up to max(m) cells is picked on
the fold's dictionary for every design scale (``bayes_selection.greedy_designs``), and every
held-out material is reconstructed from its own values at the first m cells; its true error
comes from the Gram matrix, with no pass over the cells. ``choose_scales`` picks the scales with
the lowest errors on these records (training materials only), and the calibration is fitted on
that setting's records. Why a design scale: docs/explanations/bayesian-design.md.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from goniofrost.frost import posterior
from goniofrost.frost.bayes_selection import greedy_design, greedy_designs
from goniofrost.frost.check_cells import pool_errors
from goniofrost.frost.confidence import fit_bound
from goniofrost.frost.noise import InnerFold
from goniofrost.frost.prediction import (BASIC_FEATURES, COORDINATES, FEATURES, SAMPLE_FEATURES, Features,
                                         feature_matrix, feature_range_of, fit_coefficients, material_coordinates,
                                         material_features, predict,
                                         prequential_score, sample_level)
from goniofrost.frost.sentinel import check_error

# Sample counts simulated (the range of m the calibration is fitted on).
M_VALUES = (5, 10, 15, 20, 25, 30, 40, 50, 60)
# Candidate factors on the learned noise: in the design, and in the reconstruction.
DESIGN_SCALES = (1.0, 2.0, 4.0)
RECON_SCALES = (0.5, 1.0, 2.0)
# The scales are chosen on the errors at these sample counts (each m weighs the same), over
# the first CHOICE_FOLDS inner folds; the other folds simulate the chosen design scale only
# (a design of 60 picks takes about a second at full size).
CHOICE_M = (10, 20, 40, 60)
CHOICE_FOLDS = 4
CHUNK_ROWS = 1 << 15


@dataclass
class CvRecords:
    """Flat arrays, one entry per (fold, held-out material, m): fold, material (index among the
    training materials), m, actual (true log-relative MSE, no clamping), design_error, z2, energy,
    level and spread (``prediction.sample_level``; None: records without them, fitted on the
    first ``prediction.BASIC_FEATURES`` features), prequential (``prediction.prequential_score``
    of the first m samples in design order; None: records without it, e.g. a scene's), sentinel
    (``sentinel.check_error``: the mean squared error at the sentinel cells, never fitted, of the
    posterior of the first m samples; None: records without sentinels), coordinates (records,
    COORDINATES) (``prediction.material_coordinates`` on the trained model's atoms; None: records
    without them), pool_error (records, P) float32 (``check_cells``: the squared error, channel
    mean, of the same posterior at every cell of the candidate pool; NaN at the cells of the
    record's fold's design; None: records without a pool)."""

    fold: np.ndarray
    material: np.ndarray
    m: np.ndarray
    actual: np.ndarray
    design_error: np.ndarray
    z2: np.ndarray
    energy: np.ndarray
    level: np.ndarray | None = None
    spread: np.ndarray | None = None
    prequential: np.ndarray | None = None
    sentinel: np.ndarray | None = None
    coordinates: np.ndarray | None = None
    pool_error: np.ndarray | None = None

    def features(self, m_range, n_features: int | None = None, feature_range=None) -> np.ndarray:
        """float64 (records, n_features): ``prediction.feature_matrix`` of every record (all of
        them when n_features is None; the first BASIC_FEATURES need no level and spread, the
        first SAMPLE_FEATURES no coordinates)."""
        full = self.level is not None and (n_features is None or n_features > BASIC_FEATURES)
        coordinates = self.coordinates if n_features is None or n_features > SAMPLE_FEATURES else None
        x = feature_matrix(Features(self.design_error, self.z2, self.energy, self.m, self.level if full else None,
                                    self.spread if full else None, coordinates if full else None),
                           m_range, feature_range)
        return x if n_features is None else x[:, :n_features]


@dataclass(frozen=True)
class CvSetting:
    """Where the inner folds' simulated designs pick and what their records hold besides the error.

    candidates: bool (n,) the cells the designs pick among (a rig's measurable cells), None: every
    cell; sentinels: int64 (s,) cell positions (``sentinel.cells``) checked at every m; None or empty:
    records without ``sentinel``; atoms: float64 (COORDINATES, t) ``model_atoms`` of the trained
    model (records with the coordinates), None: records without them; pool: int64 (P,) the
    check cells' candidates (``check_cells.pool``): records with ``pool_error``, None: without;
    track_of: ``track_of(m)``, a fresh ``time_design.RigTrack`` of the candidates for a design of m
    picks: the designs are then time-aware (one pass over D_f per design scale), None: per sample.
    """

    candidates: np.ndarray | None = None
    sentinels: np.ndarray | None = None
    atoms: np.ndarray | None = None
    pool: np.ndarray | None = None
    track_of: object | None = None


def simulate(mapped: np.ndarray, folds: list[InnerFold], noise: np.ndarray, m_values=M_VALUES,
             design_scales=(1.0,), recon_scales=(1.0,), setting: CvSetting = CvSetting(),
             progress: bool = False) -> dict:
    """Simulate Bayesian designs and reconstructions of every inner fold's held-out materials.

    mapped: centred mapped training data X, float32 (n, t); noise: float64 (n,) sigma_c^2;
    setting: the designs' cells and the records' extras (CvSetting).
    Returns {(design scale, reconstruction scale): CvRecords} for every pair of scales.
    """
    rows = None if setting.candidates is None else np.flatnonzero(setting.candidates)
    track_of = setting.track_of
    n = mapped.shape[0] if rows is None else len(rows)
    m_values = [m for m in m_values if m <= n]
    out = {(a, b): {key: [] for key in CvRecords.__dataclass_fields__} for a in design_scales for b in recon_scales}
    for f, fold in enumerate(_progress(folds, progress)):
        d_f = _fold_dictionary(mapped, fold.projector)
        # The designs of every design scale share each pass over D_f (one read per step for all).
        if track_of is None:
            designs = greedy_designs(d_f, fold.singular_values ** 2, _prior(fold), [a * noise for a in design_scales],
                                     max(m_values), rows=rows)
        else:  # a time-aware design runs alone
            designs = [greedy_design(d_f, fold.singular_values ** 2, _prior(fold), a * noise, max(m_values), rows=rows,
                                     track=track_of(max(m_values))) for a in design_scales]
        for a, design in zip(design_scales, designs):
            for b in recon_scales:
                acc = out[(a, b)]
                for values in _reconstruct_held_out(mapped, fold, f, d_f, design.rows, b * noise, m_values, setting):
                    for key, value in zip(acc, values, strict=True):
                        acc[key].append(value)
        del d_f
    unchecked = setting.sentinels is None or not len(setting.sentinels)
    absent = {"sentinel"} if unchecked else set()
    absent |= {"coordinates"} if setting.atoms is None else set()
    absent |= {"pool_error"} if setting.pool is None else set()
    return {key: CvRecords(**{k: None if k in absent else np.asarray(v) for k, v in acc.items()})
            for key, acc in out.items()}


def model_atoms(gram: np.ndarray, vt: np.ndarray, singular_values: np.ndarray, count: int = COORDINATES) -> np.ndarray:
    """float64 (count, t): A with A @ y the coefficients on the trained model's first ``count``
    atoms (D = X V, D^T D = S^2) of the mapped BRDF X @ y (t weights over the training columns,
    X centred): V_k^T X^T X y / S_k^2. What an inner fold's reconstruction (the fold's training
    mean plus D_f s) is on the atoms the model will give a capture's coefficients on."""
    k = min(count, vt.shape[0])
    return (np.asarray(vt[:k], dtype=np.float64) @ gram) / (np.asarray(singular_values[:k], dtype=np.float64) ** 2)[:, None]


def simulate_and_choose(mapped: np.ndarray, folds: list[InnerFold], noise: np.ndarray,
                        design_scales=DESIGN_SCALES, recon_scales=RECON_SCALES, setting: CvSetting = CvSetting(),
                        progress: bool = False):
    """Choose the scales on the first CHOICE_FOLDS folds, then simulate the rest with the chosen
    design scale (``setting``: see ``simulate``). Returns ((design scale, recon scale),
    {pair: CvRecords of the choice folds}, CvRecords of every fold with the chosen pair)."""
    head, tail = folds[:CHOICE_FOLDS], folds[CHOICE_FOLDS:]
    choice = simulate(mapped, head, noise, design_scales=design_scales, recon_scales=recon_scales, setting=setting,
                      progress=progress)
    chosen = choose_scales(choice)
    rest = simulate(mapped, tail, noise, design_scales=(chosen[0],), recon_scales=(chosen[1],), setting=setting,
                    progress=progress)[chosen] if tail else None
    return chosen, choice, concatenate([choice[chosen], rest], offset=len(head))


def concatenate(parts, offset: int = 0) -> CvRecords:
    """The records of several simulations in one (the second part's fold numbers + offset)."""
    parts = [p for p in parts if p is not None]
    fields = CvRecords.__dataclass_fields__
    shifted = [parts[0]] + [CvRecords(**{k: getattr(p, k) + offset if k == "fold" else getattr(p, k) for k in fields})
                            for p in parts[1:]]
    return CvRecords(**{k: None if any(getattr(p, k) is None for p in shifted)
                        else np.concatenate([getattr(p, k) for p in shifted]) for k in fields})


def _prior(fold: InnerFold) -> np.ndarray:
    return np.full(fold.singular_values.size, 1.0 / fold.n_train_columns)


def _reconstruct_held_out(mapped, fold: InnerFold, f: int, d_f, rows, noise, m_values,
                          setting: CvSetting) -> list[tuple]:
    """The records of fold f's held-out materials measured at the first m ``rows``, each a tuple
    of CvRecords' fields in order (with their error at the setting's ``sentinels``, NaN without;
    their coordinates on its ``atoms`` (``model_atoms``), NaN without; their errors at its
    ``pool`` cells, NaN without)."""
    sentinels, atoms, pool = setting.sentinels, setting.atoms, setting.pool
    checked = sentinels is not None and len(sentinels) > 0
    sentinel_b = np.asarray(mapped[sentinels], dtype=np.float64) @ fold.centring if checked else None
    sentinel_rows = np.asarray(d_f[sentinels], dtype=np.float64) if checked else None
    n = mapped.shape[0]
    s2 = fold.singular_values ** 2
    if atoms is not None:  # the reconstruction fold mean + D_f s on the model's atoms: offset + on_fold @ s
        train_mean = np.zeros(atoms.shape[1])
        train_mean[fold.train] = 1.0 / fold.train.size
        on_fold, offset = atoms @ fold.projector, atoms @ train_mean
    # Every sample's prediction from the ones before it, in design order (one sequential pass):
    # the prequential score at m is a held-out measure the fit at m never saw.
    ordered = rows[:max(m_values)]
    if pool is not None:  # the pool's mapped values and dictionary rows; the design's own cells masked
        pool = np.asarray(pool, dtype=np.int64)
        pool_b = np.asarray(mapped[pool], dtype=np.float64) @ fold.centring
        pool_rows = np.asarray(d_f[pool], dtype=np.float64)
        in_design = np.isin(pool, ordered)
    records = []
    one_step = posterior.prequential_errors(d_f[ordered], noise[ordered], _prior(fold),
                                            np.asarray(mapped[ordered], dtype=np.float64) @ fold.centring)
    for m in m_values:
        if m > rows.size:
            break
        cells = rows[:m]
        b = np.asarray(mapped[cells], dtype=np.float64) @ fold.centring
        post = posterior.fit(d_f[cells], noise[cells], _prior(fold), b, s2, float(noise.sum()), n)
        miss = fold.singular_values[:, None] * (fold.true_coefficients - post.coefficients)
        column_error = (fold.residual_norms + np.sum(miss ** 2, axis=0)) / n
        on_atoms = on_fold @ post.coefficients + offset[:, None] if atoms is not None else None
        if pool is not None:  # (P, materials): the squared error, channel mean, as sentinel.check_error's
            pool_error = pool_errors(pool_b, pool_rows, post.coefficients)
            pool_error[in_design] = np.nan
        for j in range(0, fold.held.size, 3):
            columns = np.arange(j, j + 3)
            features = material_features(post, columns, fold.n_train_columns) + sample_level(b, columns)
            check = check_error(sentinel_rows, post.coefficients, sentinel_b, columns) if checked else np.nan
            records.append((f, int(fold.held[j]) // 3, m, float(column_error[j:j + 3].mean())) + features
                           + (prequential_score(one_step[:m], columns), check,
                              material_coordinates(on_atoms, columns, atoms.shape[1]) if atoms is not None else np.nan,
                              pool_error[:, j // 3] if pool is not None else np.nan))
    return records


def mean_errors(records: CvRecords) -> dict:
    """{m: mean true error over the held-out materials}."""
    return {int(m): float(records.actual[records.m == m].mean()) for m in np.unique(records.m)}


def choose_scales(results: dict, choice_m=CHOICE_M) -> tuple:
    """The (design, reconstruction) scale pair whose errors are lowest relative to the best
    pair's at every m of ``choice_m`` (averaged over those m; the lowest pair on ties)."""
    means = {key: mean_errors(rec) for key, rec in results.items()}
    ms = [m for m in choice_m if all(m in v for v in means.values())] or sorted(next(iter(means.values())))
    best = {m: min(v[m] for v in means.values()) for m in ms}
    score = {key: float(np.mean([v[m] / best[m] for m in ms])) for key, v in means.items()}
    return min(sorted(score), key=lambda key: score[key])


def _fold_dictionary(mapped: np.ndarray, projector: np.ndarray) -> np.ndarray:
    """D_f = X @ projector, float32 (n, K_f), chunked (no float64 copy of X)."""
    p32 = projector.astype(np.float32)
    out = np.empty((mapped.shape[0], p32.shape[1]), dtype=np.float32)
    for start in range(0, mapped.shape[0], CHUNK_ROWS):
        np.matmul(mapped[start:start + CHUNK_ROWS], p32, out=out[start:start + CHUNK_ROWS])
    return out


def _progress(items, progress: bool):
    if not progress:
        return items
    from goniofrost.core.progress import progress_bar
    return progress_bar(items, desc="noise cross-validation", unit="fold", leave=False)


def fit_calibration(records: CvRecords, pool=None, sentinels=None) -> dict:
    """Least-squares fit of ``prediction.FEATURES`` to log(actual) over every record, the design
    error's and log m's coefficients held to their sign (``prediction.fit_coefficients``).

    The feature set (the BASIC_FEATURES; the SAMPLE_FEATURES when the records carry the samples'
    level and spread; all of FEATURES when they also carry the coordinates) is the one whose cross-fitted residuals (``confidence.cross_fitted_residuals``:
    each inner fold predicted by a fit without it) put more held-out materials within a factor 2
    of the truth, averaged over the looks m >= FIRST_LOOK (the fewer on a tie): eleven
    coefficients on a few training materials predict worse than five, and which is better is
    measured on the training materials only. Only sets of fewer coefficients than held-out
    materials are candidates (6 materials: the 5 alone).

    Returns the calibration dict stored in the model (coefficients, m_range, the typical log
    z2, log energy, level, log spread and coordinates, the range of the features, the error bound's
    calibration ``confidence.fit_bound``) with ``fit`` statistics: the residual standard
    deviation in log units, the cross-fitted fractions the choice was made on, and per m the
    Spearman correlation of predicted and actual error and the fraction of materials predicted
    within a factor 2 (in-sample for the calibration). With the records' ``pool_error`` at the
    ``pool`` cells (int64 (P,)) and ``sentinels`` (their cells), also "checked":
    ``check_cells.fit_checked`` (for captures that measured the sentinels and the check cells).
    """
    from goniofrost.frost.confidence import choice_score, cross_fitted_residuals

    m_range = [int(records.m.min()), int(records.m.max())]
    feature_range = None if records.level is None else feature_range_of(records.z2, records.energy,
                                                                         records.level, records.spread,
                                                                         records.coordinates)
    sets = [BASIC_FEATURES] + ([SAMPLE_FEATURES] if records.level is not None else [])
    sets += [len(FEATURES)] if records.level is not None and records.coordinates is not None else []
    # A set of more coefficients than held-out materials is fitted on the looks within each
    # material, not on the differences between materials it must predict: on 6 built-in materials
    # every set's cross-fitted score was noise (0 to 29 % within x2) and chance chose all 17.
    materials = np.unique(records.material).size
    sets = [n for n in sets if n < materials] or [BASIC_FEATURES]
    scores = {n: choice_score(records, cross_fitted_residuals(records, m_range, n, feature_range)) for n in sets}
    n_features = max(sets, key=lambda n: (scores[n], -n))
    x = records.features(m_range, n_features, feature_range)
    y = np.log(np.maximum(records.actual, 1e-12))
    beta = fit_coefficients(x, y)
    calibration = {"coefficients": [float(b) for b in beta], "m_range": m_range,
                   "typical_log_z2": float(np.mean(np.log(records.z2))),
                   "typical_log_energy": float(np.mean(np.log(records.energy)))}
    if n_features > BASIC_FEATURES:
        calibration |= {"typical_level": float(np.mean(records.level)),
                        "typical_log_spread": float(np.mean(np.log(records.spread))),
                        "feature_range": feature_range}
    if n_features > SAMPLE_FEATURES:
        calibration["typical_coordinates"] = np.mean(records.coordinates, axis=0).tolist()
    elif n_features > BASIC_FEATURES:  # an 11-feature calibration stores no coordinates' range
        calibration["feature_range"] = [v[:4] for v in feature_range]
    calibration["bound"] = fit_bound(records, m_range, n_features, feature_range)
    calibration["fit"] = {"residual_sd_log": float(np.std(y - x @ beta)), "records": int(y.size),
                          "cross_fitted_within_factor_2": {str(n): scores[n] for n in sets},
                          "per_m": prediction_quality(records, calibration)}
    if pool is not None and sentinels is not None and len(sentinels):
        from goniofrost.frost.check_cells import fit_checked

        checked = fit_checked(records, np.asarray(pool, np.int64), sentinels, calibration)
        if checked is not None:
            calibration["checked"] = checked
    return calibration


def prediction_quality(records: CvRecords, calibration: dict) -> dict:
    """Per m: mean actual error, Spearman(predicted, actual), fraction within a factor 2."""
    from scipy.stats import spearmanr

    predicted = predict(calibration, Features(records.design_error, records.z2, records.energy, records.m,
                                              records.level, records.spread, records.coordinates))
    out = {}
    for m in np.unique(records.m):
        sel = records.m == m
        ratio = predicted[sel] / records.actual[sel]
        rho = float(spearmanr(predicted[sel], records.actual[sel])[0]) if sel.sum() > 2 else None
        rho = rho if rho is not None and np.isfinite(rho) else None  # model.json holds no NaN
        out[str(int(m))] = {"mean_actual": float(records.actual[sel].mean()), "spearman": rho,
                            "within_factor_2": float(np.mean((ratio <= 2) & (ratio >= 0.5)))}
    return out
