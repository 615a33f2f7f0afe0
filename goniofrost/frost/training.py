"""Training: tabulated materials -> log-relative map -> PCA dictionary (a FrostModel).

Pipeline (DESIGN.md "Training", paper section IV), on T, the (n_valid, t) training columns (3 per
material, column ``3 * material + channel``): weight rows by w = clip(cos theta_i cos theta_o,
0.01, 1); map L = log((w T + eps) / (r + eps)), eps = 0.001, r the row median of w T; centre
X = L - mu; PCA from the Gram matrix G = X^T X (t x t, float64, one chunked pass), D = X V; then
the Bayesian noise model and calibration (``noise``, ``calibration``; ``TrainingOptions(noise=False)``
skips them).
Why the Gram route: benchmarks/frost_speed.py.
"""
from __future__ import annotations

import json
import os
import threading
import warnings
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy.linalg import blas
from threadpoolctl import threadpool_limits

from goniofrost.core.errors import GoniofrostError
from goniofrost.core.grid import FULL_GRID, MerlGrid, cosine_weight
from goniofrost.frost.model import FrostModel
from goniofrost.frost.threads import imap_chunks

EPS = 0.001
K_MAX = 60
CHANNELS = "RGB"
# Rows per chunk: a float64 copy of one chunk of 393 columns is ~50 MB.
CHUNK_ROWS = 1 << 14
# Eigenvalues below this fraction of the largest are treated as zero (rank deficiency).
RANK_TOL = 1e-12
# The noise cross-validation needs materials to hold out and others to train on.
MIN_NOISE_MATERIALS = 4
# sigma_c^2 never below this (mapped domain): a cell every training material reproduces exactly
# must not get an infinite weight.
NOISE_FLOOR = 1e-6


class TrainingError(GoniofrostError, ValueError):
    """Training data or options that cannot be used (names the material and channel)."""


@dataclass(frozen=True)
class TrainingOptions:
    """What ``fit_model`` fits. k_max: keep up to this many components (fewer if t = 3 M is
    smaller or the rank is lower); eps: the map's offset (1/sr); noise: learn the noise model and
    predicted-error calibration by inner cross-validation (needs at least MIN_NOISE_MATERIALS
    materials; otherwise the model has scalar noise); sentinel_candidates: bool (n_valid,) a rig's
    measurable cells: the inner folds' designs pick only among them (the calibration, its bound
    and its design range are then those of designs the rig can make) and the sentinel check is
    calibrated there (``plan --rig`` then places the sentinels exactly there), None: every cell;
    rig_time: a ``time_design.TimeObjective`` on the rig of ``sentinel_candidates``: the inner
    designs are time-aware (the calibration, its bound and design range are then those of
    ``plan --objective time``'s designs), None: per sample."""

    k_max: int = K_MAX
    eps: float = EPS
    noise: bool = True
    sentinel_candidates: np.ndarray | None = None
    rig_time: object | None = None


def fit_model(tables: np.ndarray, names: Sequence[str], grid: MerlGrid = FULL_GRID,
              options: TrainingOptions = TrainingOptions(), info: dict | None = None,
              progress: bool = False, on_stage=None) -> FrostModel:
    """Fit the mapping and PCA dictionary to tabulated materials.

    tables: float32 (M, n_valid, 3) BRDF in 1/sr at ``grid.valid_cells`` (any float dtype), or
        an object with that ``shape`` whose ``rows(start, stop)`` gives (stop - start, M, 3)
        (``datasets.tabulate.TabulatedFiles``: the tables are never all in memory).
    names: M material names (stored in the model; used in error messages).
    options: TrainingOptions (components, eps, noise model, a rig's cells and time).
    on_stage: called with each of TRAIN_STAGES' names this fit enters (a progress bar), or None.
    Returns a FrostModel with K = min(k_max, t, rank) atoms. Raises TrainingError on NaN/inf.
    """
    k_max, eps, candidates = options.k_max, options.eps, options.sentinel_candidates
    on_stage = on_stage or (lambda _name: None)
    tables = tables if hasattr(tables, "rows") else np.asarray(tables)
    names = [str(n) for n in names]
    _check_tables(tables, names, grid, k_max)
    weight = cosine_weight(grid).astype(np.float32)
    missing: dict[int, np.ndarray] = {}
    on_stage("mapping")
    mapped, reference, mean, gram = _map_and_gram(tables, names, weight, eps, progress, missing=missing)
    # Our reference is the last one when the caller passed the tables without keeping them
    # (``train`` does): they are freed before the noise cross-validation needs its memory.
    del tables
    # The products below stay on BLAS's own threads: OpenBLAS's results depend (in the last
    # bits) on its thread count, and the noise scales chosen downstream follow the last bits
    # (a design scale of 4 became 1 at full size when these ran on one BLAS thread each).
    on_stage("components")
    svals, vt = _eigen_components(gram, k_max)
    variance, noise_meta = None, {}
    if options.noise and len(names) >= MIN_NOISE_MATERIALS:
        from goniofrost.frost.calibration import CvSetting, model_atoms  # atoms: the inner folds' coordinates

        on_stage("noise cross-validation")
        track_of = None if options.rig_time is None else _inner_tracks(options.rig_time, grid, candidates, reference,
                                                                       mean, weight, eps)
        setting = CvSetting(candidates=candidates, atoms=model_atoms(gram, vt, svals), track_of=track_of)
        variance, noise_meta = learn_noise(mapped, gram, len(names), grid, svals.size, setting, missing=missing,
                                           progress=progress)
    # D after the cross-validation, which never reads it: D and a fold's D_f (n x K float32
    # each, 267 MB at full size) are then never in memory together (the peak is X + one of them).
    on_stage("dictionary")
    dictionary = _project(mapped, vt)
    return FrostModel(grid=grid, names=names, eps=eps, dictionary=dictionary,
                      singular_values=svals, coefficients=vt, mean=mean,
                      reference=reference, weight=weight, noise_variance=variance,
                      noise=noise_meta, info=info or {})


def _inner_tracks(objective, grid: MerlGrid, candidates, reference, mean, weight, eps: float):
    """``track_of(m)``: a fresh ``time_design.RigTrack`` of the candidates on the objective's rig,
    the expected brackets from the training's prior median (``rig_cost.value_costs``)."""
    from goniofrost.frost.rig_cost import rig_camera, rig_sensor, value_costs
    from goniofrost.frost.time_design import RigTrack

    if candidates is None:
        raise TrainingError("training: time-aware inner designs need the rig's cells (--rig)")
    rows = np.flatnonzero(candidates)
    r, w = np.asarray(reference, np.float64)[rows], np.asarray(weight, np.float64)[rows]
    value = np.maximum((np.exp(np.asarray(mean, np.float64)[rows]) * (r + eps) - eps) / w, 0.0)  # FrostModel.from_log
    rig = objective.rig
    costs = value_costs(grid, value, rig, rows, rig_camera(rig), rig_sensor(rig), objective.settle_s)
    return lambda m: RigTrack(costs, rig, objective.overhead_s, m, objective.share)


def learn_noise(mapped: np.ndarray, gram: np.ndarray, n_materials: int, grid: MerlGrid, k: int,
                setting, missing: dict | None = None, progress: bool = False) -> tuple[np.ndarray, dict]:
    """sigma_c^2 (float32 (n,)) and the ``noise`` metadata of the model (see noise.py and
    calibration.py): inner folds, smoothed representation error, simulated captures, calibration.
    setting: a ``calibration.CvSetting`` of the inner designs' candidates (bool (n,) or None: every
    cell), the ``atoms`` (``calibration.model_atoms``; None: a calibration without coordinates) and
    ``track_of`` (time-aware inner designs; None: per sample); its sentinels (``sentinel.cells``
    among the candidates) and check cells' pool are this function's own.
    ``missing``: {material: bool (n,)} its cells not measured, left out of sigma_c^2 (the simulated
    captures of the calibration still score them, at the row's mean)."""
    from dataclasses import replace

    from goniofrost.frost import calibration, check_cells, noise, sentinel

    folds = noise.inner_folds(gram, n_materials, k)
    learned = noise.smooth_on_grid(noise.representation_variance(mapped, folds, missing), grid)
    learned = np.maximum(learned, NOISE_FLOOR)
    sentinels = sentinel.cells(grid, candidates=setting.candidates)
    # the check cells' candidates: among the sentinels' (a rig's cells), outside the sentinels
    pool = check_cells.pool(grid, setting.candidates) if sentinels.size and setting.atoms is not None else None
    # A rig's designs pick among its cells only (the setting's candidates): designs over the whole
    # grid reach cells the rig cannot, and a rig reaching within 70 deg of the normal lay 0.8 to 2.9
    # (log) beyond their design range from m = 20, its bound 3.6 to 17 x below the actual error at
    # m = 40 (BENCHMARKS.md@8b3941b, "Designs among a rig's cells").
    setting = replace(setting, sentinels=sentinels, pool=pool)
    (design_scale, recon_scale), choice, records = calibration.simulate_and_choose(mapped, folds, learned,
                                                                                     setting=setting,
                                                                                     progress=progress)
    variance = (recon_scale * learned).astype(np.float32)
    meta = {"kind": "cells", "learned_by": f"{len(folds)}-fold cross-validation over the training materials",
            "folds": len(folds), "smoothing_fraction": noise.SMOOTH_FRACTION,
            "recon_scale": recon_scale, "design_scale": design_scale / recon_scale,
            "mean_variance": float(variance.mean(dtype=np.float64)),
            "choice_folds": min(calibration.CHOICE_FOLDS, len(folds)),
            "choice_mean_errors": [{"design_scale": a, "recon_scale": b, "by_m": calibration.mean_errors(rec)}
                                   for (a, b), rec in choice.items()],
            "cv_mean_errors": calibration.mean_errors(records),
            "calibration": calibration.fit_calibration(records, pool, sentinels)}
    if "sentinel" in meta["calibration"]["bound"]:
        meta["calibration"]["bound"]["sentinel"]["cells"] = sentinels.tolist()
    # As model.json will hold it (string keys, lists): the content hash is the same before and
    # after a save and load.
    return variance, json.loads(json.dumps(meta))


def _check_tables(tables: np.ndarray, names: list[str], grid: MerlGrid, k_max: int) -> None:
    if tables.ndim != 3 or tables.shape[1:] != (grid.n_valid, 3):
        raise TrainingError(f"training tables: expected shape (M, {grid.n_valid}, 3), found {tables.shape}")
    if tables.shape[0] != len(names):
        raise TrainingError(f"training tables: {tables.shape[0]} materials but {len(names)} names")
    if tables.shape[0] < 1:
        raise TrainingError("training: no materials to train on (check --only/--exclude)")
    if not isinstance(k_max, (int, np.integer)) or k_max < 1:
        raise TrainingError(f"training: --components must be a positive integer, found {k_max!r}")


def _map_and_gram(tables, names, weight, eps, progress, threads=None, missing: dict | None = None):
    """One chunked pass: check finiteness, map, centre, accumulate X^T X in float64.

    ``missing``: a dict filled with {material: bool (n,)}, the cells of each material with NaN
    (not measured) that it has no data for (None: not collected).

    The mapping of the chunks runs on ``threads`` threads (element-wise numpy, no BLAS); the
    Gram is accumulated in chunk order on BLAS's threads as before, so it is the same to the bit.
    """
    m, n, _ = tables.shape
    t = 3 * m
    mapped = np.empty((n, t), dtype=np.float32)
    reference = np.empty(n, dtype=np.float32)
    mean = np.empty(n, dtype=np.float32)
    lock = threading.Lock()

    def chunk(start: int, stop: int) -> np.ndarray:
        rows = tables.rows(start, stop) if hasattr(tables, "rows") else tables[:, start:stop, :].transpose(1, 0, 2)
        block = np.array(rows.reshape(stop - start, t), dtype=np.float32)  # a private, row-contiguous copy
        _check_finite(block, names, start)
        unmeasured = np.isnan(block).reshape(stop - start, m, 3).any(axis=2)
        for j in np.flatnonzero(unmeasured.any(axis=0)) if missing is not None else ():
            with lock:
                missing.setdefault(int(j), np.zeros(n, dtype=bool))[start:stop] = unmeasured[:, j]
        reference[start:stop], mean[start:stop] = _map_block(block, weight[start:stop], eps)
        mapped[start:stop] = block
        return block.astype(np.float64)

    gram = np.zeros((t, t), dtype=np.float64)
    # Gram accumulated in float64 (the tail eigenvalues are ~1e-5 of the first: float32 sums
    # over thousands of rows would blur them), in chunk order by one dsyrk per chunk (the upper
    # triangle) as the sequential training did, so the Gram is the same to the bit: the noise
    # scales chosen downstream follow its last digits. dsyrk on one BLAS thread: the same bits
    # as on two (it splits the output, not the sums), without OpenBLAS's spinning threads,
    # which made this pass 4x the CPU time on a loaded host. The chunk goes in as its transpose
    # (t x rows, Fortran-ordered: no copy) with trans=0: the same bits as dsyrk(wide, trans=1),
    # which made scipy copy every chunk into Fortran order first (21 % of the Gram's CPU time
    # at t = 453).
    with threadpool_limits(limits=1, user_api="blas"):
        for wide in _progress_chunks(imap_chunks(chunk, n, CHUNK_ROWS, threads), n, progress, "training"):
            gram = blas.dsyrk(1.0, wide.T, trans=0, beta=1.0, c=gram, overwrite_c=1)
    return mapped, reference, mean, np.triu(gram) + np.triu(gram, 1).T


def _map_block(block: np.ndarray, w: np.ndarray, eps: float):
    """Map a (rows, t) float32 BRDF block in place to the centred X; return r and mu (rows,).

    float32 is enough for the element-wise map (the inputs are float32); the median is one
    partition (two for an even t) instead of np.median's sort-and-copy. A block with NaN (cells a
    material has no data for: ``rgl:PATH``) goes through ``_map_block_unmeasured``.
    """
    if np.isnan(block).any():
        return _map_block_unmeasured(block, w, eps)
    block *= w[:, None]
    ref = _row_median(block)
    block += np.float32(eps)
    np.log(block, out=block)
    block -= np.log(ref + np.float32(eps))[:, None]
    mu = block.mean(axis=1, dtype=np.float64)
    block -= mu.astype(np.float32)[:, None]
    return ref, mu


def _map_block_unmeasured(block: np.ndarray, w: np.ndarray, eps: float):
    """``_map_block`` of a block holding NaN (not measured): r and mu of each row are the median
    and mean of its measured entries, and an unmeasured entry is set to the row's mean (0 in X),
    so it adds nothing to the Gram matrix nor to the atoms. A row nobody measured is all 0, r = 0.
    """
    missing = np.isnan(block)
    block *= w[:, None]
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN rows: handled below
        ref = np.nan_to_num(np.nanmedian(block, axis=1)).astype(np.float32)
        block += np.float32(eps)
        np.log(block, out=block)
        block -= np.log(ref + np.float32(eps))[:, None]
        mu = np.nan_to_num(np.nanmean(block, axis=1, dtype=np.float64))
    block -= mu.astype(np.float32)[:, None]
    block[missing] = 0.0
    return ref, mu


def _row_median(block: np.ndarray) -> np.ndarray:
    """Per-row median of a (rows, t) array (the mean of the two middle values for even t)."""
    t = block.shape[1]
    half = t // 2
    if t % 2:
        return np.partition(block, half, axis=1)[:, half]
    part = np.partition(block, [half - 1, half], axis=1)
    return 0.5 * (part[:, half - 1] + part[:, half])


def _check_finite(block: np.ndarray, names: list[str], start: int) -> None:
    """Refuse inf; NaN is a cell the material has no data for (``_map_block_unmeasured``)."""
    bad = np.isinf(block)
    if bad.any():
        row, col = np.argwhere(bad)[0]
        value = block[row, col]
        raise TrainingError(
            f"training data: material {names[col // 3]!r} channel {CHANNELS[col % 3]} has a "
            f"non-finite value ({value}) at valid-cell position {start + row}; expected finite BRDF values")


def _eigen_components(gram: np.ndarray, k_max: int) -> tuple[np.ndarray, np.ndarray]:
    """Singular values S (K,) and V^T (K, t) from the Gram matrix X^T X = V S^2 V^T."""
    evals, evecs = np.linalg.eigh(gram)
    order = np.argsort(evals)[::-1]
    evals, evecs = evals[order], evecs[:, order]
    rank = int(np.sum(evals > RANK_TOL * max(evals[0], 0.0))) if evals[0] > 0 else 0
    k = min(k_max, rank)
    if k < 1:
        raise TrainingError("training data: all training columns map to the same values; nothing to learn")
    vt = evecs[:, :k].T.copy()
    # Fix each eigenvector's sign (largest-magnitude entry positive) so training is deterministic.
    signs = np.sign(vt[np.arange(k), np.argmax(np.abs(vt), axis=1)])
    vt *= signs[:, None]
    return np.sqrt(evals[:k]), vt


def _project(mapped: np.ndarray, vt: np.ndarray) -> np.ndarray:
    """D = X V (n, K) float32, chunked so no float64 copy of X is ever made."""
    n = mapped.shape[0]
    v32 = np.ascontiguousarray(vt.T, dtype=np.float32)
    out = np.empty((n, vt.shape[0]), dtype=np.float32)
    step = 8 * CHUNK_ROWS
    for start in range(0, n, step):
        np.matmul(mapped[start:start + step], v32, out=out[start:start + step])
    return out


def _progress_chunks(parts, n: int, progress: bool, what: str):
    if not progress:
        return parts
    from goniofrost.core.progress import progress_bar
    return progress_bar(parts, total=-(-n // CHUNK_ROWS), desc=what, unit="chunk", leave=False)


# ----- training from dataset specs -------------------------------------------------------
# the stages of a training, as its progress bar names them (only on a terminal: core.progress)
TRAIN_STAGES = ("tabulating", "mapping", "components", "noise cross-validation", "dictionary", "saving")


def train(dataset_specs: Sequence[str], only: Sequence[str] | None = None,
          exclude: Sequence[str] | None = None, grid: MerlGrid = FULL_GRID,
          k_max: int = K_MAX, cache: bool = True, progress: bool = False,
          sentinel_candidates=None) -> FrostModel:
    """Train a FrostModel on the materials of one or more datasets.

    dataset_specs: SPEC strings (``builtin``, ``nbrdf:PATH``, ``merl:DIR``, ``rgl:PATH``), combined in order.
    only: keep only these materials; exclude: drop these (names, labels or SPEC:NAME; see
        ``datasets.tabulate.collect_materials``; a selector matching nothing is an error).
    Tabulated values come from the tabulation cache (``datasets.tabulate``).
    cache: reuse a model trained before on exactly the same inputs (keyed by the materials'
        content ids, grid, k_max, eps and the code version) from the goniofrost cache.
    sentinel_candidates: bool (n_valid,) the cells the inner designs pick among and the sentinel
        check is calibrated at (``fit_model``; ``train --rig``: the rig's measurable cells), None:
        the whole grid.
    progress: a bar over TRAIN_STAGES (and each stage's own where it has one) on a terminal.
    Returns the model (memory-mapped from the cache when cache=True).
    """
    from goniofrost.core.progress import StageBar
    from goniofrost.datasets.tabulate import TabulatedFiles, collect_materials, tabulated_material_files

    materials = collect_materials(list(dataset_specs), only, exclude)
    key, among = _model_key(materials, grid, k_max, sentinel_candidates)
    folder = model_cache_folder(key) if cache else None
    named = _datasets_named(dataset_specs)
    if folder is not None and (folder / "model.json").is_file():
        model = FrostModel.load(folder)
        earlier = {k: v for k, v in (model.info or {}).items() if k not in ("datasets", "datasets_from")}
        model.info = {**named, **earlier}  # the order of a fresh training's info
        return model
    info = {**named, "cache_key": key}
    if sentinel_candidates is not None:
        info["sentinel_candidates"] = {"cells": int(np.count_nonzero(sentinel_candidates)), "sha256": among[0]}
    with StageBar("train", TRAIN_STAGES, asked=progress) as bar:
        # The tables are read from the tabulation cache in row chunks: at full size 151 materials
        # are 2 GB, which would double the peak memory beside the mapped X.
        bar.stage("tabulating")
        tables = TabulatedFiles(tabulated_material_files(materials, grid, progress=progress))
        model = fit_model(tables, [m.label for m in materials], grid,
                          TrainingOptions(k_max, sentinel_candidates=sentinel_candidates), info=info,
                          progress=progress, on_stage=bar.stage)
        if folder is None:
            return model
        bar.stage("saving")
        model.save(folder)
    return FrostModel.load(folder)


def trained_model_folder(dataset_specs: Sequence[str], only=None, exclude=None, grid: MerlGrid = FULL_GRID,
                         k_max: int = K_MAX, sentinel_candidates=None):
    """The cache folder ``train(..., cache=True)`` keeps this model in (it holds model.json once
    trained: a caller can say whether a training lies ahead)."""
    from goniofrost.datasets.tabulate import collect_materials

    materials = collect_materials(list(dataset_specs), only, exclude)
    return model_cache_folder(_model_key(materials, grid, k_max, sentinel_candidates)[0])


def model_cache_folder(key: str):
    """The cache folder of the model with cache key ``key``."""
    from goniofrost.core import cache as disk_cache

    return disk_cache.cache_path("models", key, "")


def _model_key(materials, grid: MerlGrid, k_max: int, sentinel_candidates) -> tuple[str, list]:
    """(the cache key of a model of ``materials``, [the candidates' digest] or [])."""
    from goniofrost.core import cache as disk_cache

    ids = [m.dataset.content_id(m.name) for m in materials]
    # v3: the calibration holds the error bound (confidence.py); a v2 model cached before has none
    # v4: the bound holds the sentinel check's calibration (sentinel.py)
    # v5: the calibration may use the material's coordinates on the first atoms (prediction.py)
    # v6: the calibration holds the check cells and the checked calibration (check_cells.py)
    # v7: not used (a reverted change, 3bed68d, cached models under it)
    # v8: the design error's and log m's coefficients held to their sign (prediction.fit_coefficients;
    # models on few materials change)
    # v9: a feature set of the calibration needs more held-out materials than coefficients (6 to 17 materials
    # change); the bound records each m's range of the designs' log design error (confidence.design_range;
    # a model without it is not checked for designs unlike its calibration's)
    # v10: a rig's model (sentinel_candidates) simulates the inner designs among the rig's cells
    # only; a model without a rig is unchanged and keeps v9
    # v11 (v12 with a rig): the bound records its other kinds (normalised, per look) and their
    # measurement on nested inner folds (confidence.fit_bound), and the kind the captures use
    among = [] if sentinel_candidates is None else [_mask_digest(sentinel_candidates)]
    version = "frost-model-v11" if sentinel_candidates is None else "frost-model-v12"
    return disk_cache.content_key(version, ids, [m.label for m in materials],
                                  grid.as_dict(), int(k_max), EPS, *among), among


def _datasets_named(dataset_specs) -> dict:
    """The model's record of its datasets: the specs as given, and the working folder only when
    one of them holds a relative path (``remap`` reads it from there), so that a model of the
    built-in library or of absolute paths is the same file from any folder. This call's even
    when the model comes from the cache (the info is not part of the model's hash)."""
    from goniofrost.datasets.specs import spec_read_from

    named = {"datasets": list(dataset_specs)}
    if any(spec_read_from(spec, os.sep) != spec for spec in dataset_specs):
        named["datasets_from"] = os.getcwd()
    return named


def _label_read_from(label: str, opened: dict) -> str:
    """A training label as ``collect_materials`` labels it from the opened specs ({spec as given:
    spec opened}): a plain NAME stays; SPEC:NAME (a name two datasets share) follows its spec."""
    for given, spec in opened.items():
        if label.startswith(given + ":"):
            return spec + label[len(given):]
    return label


def _mask_digest(mask) -> str:
    """sha256 hex of a bool (n_valid,) cell mask (its packed bits): part of a model's cache key."""
    import hashlib

    return hashlib.sha256(np.packbits(np.asarray(mask, dtype=bool)).tobytes()).hexdigest()


def remap(model: FrostModel, progress: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The centred mapped training data X (float32 (n, t)) and its Gram matrix (float64 (t, t))
    of a model trained by ``train``, from its datasets (``model.info["datasets"]``) and names,
    mapped again exactly as in training (what a later cross-validation of the model needs).

    TrainingError when the model does not name its datasets, they cannot be opened, or they no
    longer hold its training materials (the mean map differs from the model's).
    """
    from goniofrost.datasets.specs import spec_read_from
    from goniofrost.datasets.tabulate import TabulatedFiles, collect_materials, tabulated_material_files

    specs = (model.info or {}).get("datasets")
    if not specs:
        raise TrainingError("the model does not name the datasets it was trained on (train it with goniofrost train)")
    # relative paths are read from the folder the training named them in (a model trained before
    # that was recorded, or of no relative path: from this one)
    origin = (model.info or {}).get("datasets_from")
    opened = [spec_read_from(spec, origin) if origin else spec for spec in specs]
    names = [_label_read_from(name, dict(zip(specs, opened))) for name in model.names]
    try:
        materials = collect_materials(opened, only=names)
    except GoniofrostError as exc:
        raise TrainingError(f"the model's training materials cannot be opened again: {exc}") from None
    if [m.label for m in materials] != names:
        raise TrainingError(f"the datasets {list(specs)} no longer hold the model's {len(model.names)} training "
                            f"materials in its order")
    tables = TabulatedFiles(tabulated_material_files(materials, model.grid, progress=progress))
    mapped, _, mean, gram = _map_and_gram(tables, list(model.names), np.asarray(model.weight), model.eps, progress)
    if not np.array_equal(mean, np.asarray(model.mean)):
        raise TrainingError(f"the datasets {list(specs)} no longer give the model's training data (its mean map differs)")
    return mapped, gram
