"""Training with its mapping on threads gives the model of the sequential training it replaced.

``data/frost_model_before_threads.npz`` holds the model the sequential training (one chunk after
the other, 18 chunks of 97 rows) produced for these synthetic materials before the mapping moved onto threads; the
test fits the same materials with small chunks spread over threads and compares every array and
every number of the noise model and its calibration: equal to the bit (the products stay on
BLAS's threads, whose rounding depends on their count and on the CPU's kernels, so this holds on a
machine that rounds as the one the file was made on, ``recorded_blas``; elsewhere within float
rounding).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from goniofrost.core.grid import MerlGrid
from goniofrost.frost import training
from goniofrost.frost.threads import PIECES_PER_THREAD, imap_chunks, map_chunks, pass_ranges, ranges, resolve_threads, run_ranges
from goniofrost.frost.training import TrainingOptions, fit_model
from recorded_blas import rounds_as_recorded
from test_frost import synthetic_tables

GRID = MerlGrid(10, 10, 20)
BEFORE = Path(__file__).parent / "data" / "frost_model_before_threads.npz"


@pytest.fixture(scope="module")
def tables():
    return synthetic_tables(GRID, 12, seed=7)


def _close_numbers(before, after, path: str = "") -> None:
    """Same structure, same strings and integers, floats equal to 1e-5 relative."""
    if isinstance(before, dict):
        assert before.keys() == after.keys(), path
        for key in before:
            _close_numbers(before[key], after[key], f"{path}/{key}")
    elif isinstance(before, list):
        assert len(before) == len(after), path
        for i, (b, a) in enumerate(zip(before, after)):
            _close_numbers(b, a, f"{path}[{i}]")
    elif isinstance(before, float):
        assert after == pytest.approx(before, rel=1e-5, abs=1e-12), path
    else:
        assert after == before, path


def _known_keys(before, after):
    """``after`` restricted, in every nested mapping, to the keys ``before`` has."""
    if isinstance(before, dict):
        return {key: _known_keys(before[key], after[key]) for key in before}
    return after


def test_model_equals_the_sequential_training_to_the_bit(tables, monkeypatch):
    from goniofrost.frost import calibration, prediction

    monkeypatch.setattr(training, "CHUNK_ROWS", 97)  # 18 chunks over the threads
    seen = []
    fit_calibration = calibration.fit_calibration

    def keeping_the_records(records, *args):
        seen.append(records)
        return fit_calibration(records, *args)

    monkeypatch.setattr(calibration, "fit_calibration", keeping_the_records)
    model = fit_model(tables, [f"g{i}" for i in range(12)], GRID, TrainingOptions(k_max=20))
    before = np.load(BEFORE)
    assert model.singular_values.size == 20
    exact = rounds_as_recorded()
    for name in ("singular_values", "coefficients", "mean", "reference", "dictionary", "noise_variance"):
        after, expected = np.asarray(getattr(model, name)), before[name]
        if exact:
            np.testing.assert_array_equal(after, expected, err_msg=name)
        else:
            np.testing.assert_allclose(after, expected, rtol=1e-5, atol=1e-6 * float(np.abs(expected).max()), err_msg=name)
    noise = json.loads(str(before["noise"]))
    assert (model.noise["design_scale"], model.noise["recon_scale"]) == (noise["design_scale"], noise["recon_scale"])
    # The predicted-error calibration's record grew since the file was made (the confidence of
    # the prediction, the choice of its features): every number the sequential training recorded
    # is compared, at every depth; new ones are not.
    # The file's calibration predates the signs held (prediction.fit_coefficients): its least
    # squares gave log m +0.0202, now held at 0. The training's records, fitted by plain least
    # squares, give the file's calibration.
    assert noise["calibration"]["coefficients"][4] > 0 and model.noise["calibration"]["coefficients"][4] == 0.0
    monkeypatch.setattr(prediction, "SIGNED", ())
    after = _known_keys(noise, model.noise | {"calibration": fit_calibration(seen[0])})
    if exact:
        assert after == noise
    _close_numbers(noise, after)


def test_threaded_gram_is_the_textbook_gram_and_independent_of_threads(tables, monkeypatch):
    """X and X^T X against a direct numpy computation; 1 and 3 threads give identical bits."""
    monkeypatch.setattr(training, "CHUNK_ROWS", 97)
    weight = training.cosine_weight(GRID).astype(np.float32)
    names = [f"g{i}" for i in range(12)]
    runs = [training._map_and_gram(tables, names, weight, training.EPS, False, threads) for threads in (1, 3)]
    for a, b in zip(*runs):
        np.testing.assert_array_equal(a, b)
    mapped, _, _, gram = runs[0]
    w = tables.transpose(1, 0, 2).reshape(GRID.n_valid, -1).astype(np.float64) * weight[:, None]
    x = np.log(w + training.EPS) - np.log(np.median(w, axis=1) + training.EPS)[:, None]
    x -= x.mean(axis=1, keepdims=True)
    np.testing.assert_allclose(mapped, x, rtol=0, atol=2e-5)
    np.testing.assert_allclose(gram, mapped.astype(np.float64).T @ mapped.astype(np.float64), rtol=1e-12, atol=1e-9)


def test_chunks_come_back_in_order_whatever_the_threads():
    for threads in (1, 2, 5):
        assert map_chunks(lambda a, b: (a, b), 10, 3, threads) == [(0, 3), (3, 6), (6, 9), (9, 10)]
        assert list(imap_chunks(lambda a, b: a, 100, 7, threads)) == list(range(0, 100, 7))
    assert ranges(10, 3) == [(0, 3), (3, 6), (6, 10)] and ranges(2, 4) == [(0, 1), (1, 2)]
    # A pass: one piece on one thread, PIECES_PER_THREAD per thread otherwise, results in order.
    assert pass_ranges(100, 1) == [(0, 100)] and pass_ranges(100, 2) == ranges(100, 2 * PIECES_PER_THREAD)
    for threads in (1, 2, 3):
        assert run_ranges(lambda k, lo, hi: (k, lo, hi), 50, threads, "x") == \
            [("x", lo, hi) for lo, hi in pass_ranges(50, threads)]
    with pytest.raises(ValueError, match="threads: expected a positive integer, found -1"):
        resolve_threads(-1)


def test_a_failing_chunk_raises_its_own_error():
    def chunk(a, b):
        if a == 6:
            raise ValueError("chunk 6")
        return a

    with pytest.raises(ValueError, match="chunk 6"):
        list(imap_chunks(chunk, 20, 3, 2))


def test_training_reads_the_cache_files_in_chunks_and_gets_the_same_model(tmp_path, monkeypatch):
    """train() streams the tabulation cache entries (TabulatedFiles) instead of stacking them:
    the same model, bit for bit, as fitting the stacked tables."""
    from goniofrost.datasets import open_dataset
    from goniofrost.datasets.base import DatasetError
    from goniofrost.datasets.tabulate import TabulatedFiles, collect_materials, tabulate_materials
    from goniofrost.frost.training import train

    monkeypatch.setenv("GONIOFROST_CACHE", str(tmp_path))
    monkeypatch.setattr(training, "CHUNK_ROWS", 300)
    grid = MerlGrid(8, 8, 16)
    names = open_dataset("builtin").names()[:6]
    streamed = train(["builtin"], only=names, grid=grid, k_max=10, cache=False)
    materials = collect_materials(["builtin"], names, None)
    stacked = fit_model(tabulate_materials(materials, grid), [m.label for m in materials], grid,
                        TrainingOptions(k_max=10))
    for name in ("dictionary", "singular_values", "coefficients", "mean", "reference", "noise_variance"):
        np.testing.assert_array_equal(np.asarray(getattr(streamed, name)), np.asarray(getattr(stacked, name)), name)
    assert streamed.noise == stacked.noise
    paths = sorted((tmp_path / "tabulated").glob("*.npy"))[:2]
    files = TabulatedFiles(paths)
    assert files.shape == (2, grid.n_valid, 3) and files.rows(5, 9).shape == (4, 2, 3)
    tables = np.stack([np.load(path) for path in paths])  # (2, n, 3)
    np.testing.assert_array_equal(files.rows(5, 9), tables[:, 5:9].transpose(1, 0, 2))
    np.testing.assert_array_equal(files.rows(0, grid.n_valid), tables.transpose(1, 0, 2))
    short = tmp_path / "short.npy"
    short.write_bytes(paths[0].read_bytes()[:-12])  # the header still says n rows
    with pytest.raises(DatasetError, match=rf"short.npy: expected rows 0 to {grid.n_valid}, found the file shorter"):
        TabulatedFiles([short]).rows(0, grid.n_valid)
