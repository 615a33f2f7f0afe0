"""The predicted-error calibration of a scene's error, on the held-out training materials.

For every inner fold: the scene-aware design on the fold's dictionary and the usage-weighted error
of each held-out material at its first m cells, fitted as ``calibration.py`` fits the whole-BRDF
error. The algebra: docs/explanations/scene-aware-design.md.
"""
from __future__ import annotations

import numpy as np

from goniofrost.frost import calibration, posterior
from goniofrost.frost.bayes_selection import greedy_design
from goniofrost.frost.calibration import CvRecords, M_VALUES, fit_calibration
from goniofrost.frost.prediction import material_features, sample_level
from goniofrost.frost.usage_design import HEDGE, design_usage, floor_of_power, is_uniform, scene_prior, spread_of_power

# Rows of X per chunk of the weighted Gram (a float64 copy of 16k x 393 = 50 MB).
CHUNK_ROWS = 1 << 14


def calibrate_scene(model, usage: np.ndarray, sensitivity_power: float, progress: bool = False,
                    hedge: float = HEDGE, prior_spread: float | None = None, spread_floor: float | None = None,
                    mix: float = 0.0) -> dict:
    """The calibration (the model's format, ``calibration.fit_calibration``) of the usage-weighted
    error of ``usage`` (n_valid,) sum 1, measured at the design ``select_bayes`` picks for it (its
    weights ``usage_design.design_usage`` of sensitivity_power and hedge, with the model's g on
    every fold; a plan of m samples uses ``usage_design.sensitivity_power(m)``; ``prior_spread``
    None: the spread of that power's band, ``usage_design.spread_of_power``; ``spread_floor`` None:
    the floor on the effective cells of that band, ``usage_design.floor_of_power``, when the spread
    is the band's too, else 0; ``mix``: the share of ``usage_design.MIX_DESIGN``'s weights mixed in,
    ``usage_design.mixed_weights``, 0 none). TrainingError when the model's training data cannot be
    opened again."""
    from goniofrost.frost import noise, training

    mapped, gram = training.remap(model, progress=progress)
    folds = noise.inner_folds(gram, len(model.names), model.n_components)
    recon = posterior.cell_noise(model)
    usage = np.asarray(usage, np.float64)
    records = simulate_scene(mapped, folds, usage, posterior.design_scale(model) * recon, recon, progress=progress,
                             design_weights=design_usage(model, usage, sensitivity_power, hedge,
                                                         *_band_spread(sensitivity_power, prior_spread, spread_floor),
                                                         mix=mix))
    return fit_calibration(records)


# The cached calibrations' version: bump it when calibrate_scene's result changes for the same inputs.
# v2: the design error's and log m's coefficients held to their sign (prediction.fit_coefficients), and the
# bound records its designs' range of log design error (confidence.design_range)
CACHE_VERSION = "scene-calibration-v2"


def calibrate_scene_cached(model, usage: np.ndarray, sensitivity_power: float, progress: bool = False,
                           prior_spread: float | None = None, spread_floor: float | None = None,
                           mix: float = 0.0) -> dict:
    """``calibrate_scene`` (HEDGE), kept in the goniofrost cache under the model's content hash,
    the usage map's bytes and the design's parameters: the same plan --usage again (a minute on
    the full grid, the training materials mapped again) reads it back, also when the training
    materials are no longer at hand. The entry is the JSON PLAN.json carries."""
    import hashlib
    import json

    from goniofrost.core import cache as disk_cache
    from goniofrost.core.atomic_file import write_text_atomic

    digest = hashlib.sha256(np.ascontiguousarray(usage, dtype=np.float64).tobytes()).hexdigest()
    key = disk_cache.content_key(CACHE_VERSION, model.content_hash, digest, sensitivity_power, HEDGE,
                                 prior_spread, spread_floor, mix)
    path = disk_cache.cache_path("scene-calibrations", key, ".json")
    if path.is_file():
        return json.loads(path.read_text())
    fitted = calibrate_scene(model, usage, sensitivity_power, progress, HEDGE, prior_spread, spread_floor, mix)
    text = json.dumps(fitted, allow_nan=False)
    write_text_atomic(path, text)
    return json.loads(text)  # what a later run reads: the same numbers, the same types


def _band_spread(power: float, spread, floor) -> tuple[float, float]:
    """(t, F) of ``calibrate_scene``'s design: each given one, else its power's band's (the floor
    the band's only when the spread is too; else 0, no floor)."""
    if floor is None:
        floor = floor_of_power(power) if spread is None else 0.0
    return (spread_of_power(power) if spread is None else spread), floor


def weighted_gram(mapped: np.ndarray, usage: np.ndarray) -> np.ndarray:
    """G_u = X^T diag(u) X, float64 (t, t), over the rows with u > 0."""
    rows = np.flatnonzero(usage > 0)
    g = np.zeros((mapped.shape[1],) * 2)
    for lo in range(0, rows.size, CHUNK_ROWS):
        part = rows[lo:lo + CHUNK_ROWS]
        x = np.asarray(mapped[part], dtype=np.float64)
        g += x.T @ (x * usage[part, None])
    return 0.5 * (g + g.T)


def weighted_errors(fold, g_u: np.ndarray, coefficients: np.ndarray) -> np.ndarray:
    """sum_c u_c (x_b - D_f s_b)_c^2 of every held-out column b of ``fold`` (float64 (|B|,)) for
    the coefficients s (K_f, |B|) on D_f = X P, from G_u alone (module doc)."""
    p, r = fold.projector, fold.residual_map
    delta = fold.true_coefficients - coefficients
    return (np.einsum("ij,ij->j", delta, p.T @ g_u @ p @ delta) + 2.0 * np.einsum("ij,ij->j", delta, p.T @ g_u @ r)
            + np.einsum("ij,ij->j", r, g_u @ r))


def simulate_scene(mapped, folds, usage, design_noise, recon_noise, m_values=M_VALUES,
                   progress: bool = False, design_weights=None) -> CvRecords:
    """Records (``calibration.CvRecords``) of every fold's held-out materials measured at the
    first m cells of the fold's scene-aware design; ``actual`` and ``design_error`` are the
    usage-weighted error and its expectation. mapped: X float32 (n, t); usage (n,) sum 1; the
    design's and the reconstruction's sigma_c^2 (n,); design_weights: (n,) sum 1, what the design
    weighs (``usage_design.design_usage``; default the usage itself)."""
    design_weights = usage if design_weights is None else design_weights
    g_u = weighted_gram(mapped, usage)
    total = float(usage @ recon_noise)
    m_values = [m for m in m_values if m <= mapped.shape[0]]
    acc = {key: [] for key in CvRecords.__dataclass_fields__}
    for f, fold in enumerate(calibration._progress(folds, progress)):
        d_f = calibration._fold_dictionary(mapped, fold.projector)
        prior = calibration._prior(fold)
        if is_uniform(design_weights):  # the plain design, as select_bayes picks it for uniform weights
            rows = greedy_design(d_f, fold.singular_values ** 2, prior, design_noise, max(m_values)).rows
        else:
            scene = scene_prior(d_f, design_weights, prior)
            rows = greedy_design(scene.dictionary, scene.weights, scene.prior_var, design_noise, max(m_values)).rows
        m_f = fold.projector.T @ g_u @ fold.projector
        for m in m_values:
            cells = rows[:m]
            b = np.asarray(mapped[cells], dtype=np.float64) @ fold.centring
            post = posterior.fit(d_f[cells], recon_noise[cells], prior, b, m_f, total, 1)
            error = weighted_errors(fold, g_u, post.coefficients)
            for j in range(0, fold.held.size, 3):
                columns = np.arange(j, j + 3)  # the samples' level and spread too, as calibration.py records
                features = material_features(post, columns, fold.n_train_columns) + sample_level(b, columns)
                values = (f, int(fold.held[j]) // 3, m, float(max(error[j:j + 3].mean(), 0.0))) + features
                for key, value in zip(acc, values):
                    acc[key].append(value)
        del d_f
    # No prequential score (a scene's bound has no use for the diagnostic, ``confidence.py``).
    return CvRecords(**{k: np.asarray(v) if v else None for k, v in acc.items()})
