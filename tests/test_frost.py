"""FROST core: training, SOMP selection, ridge reconstruction, model and plan files, commands.

Everything runs on small grids with synthetic materials (plus a few real networks), so the
whole file takes a few seconds.
"""
from __future__ import annotations

import json
import re

import numpy as np
import pytest

from goniofrost.app.cli import main
from goniofrost.core.errors import ConfigError
from goniofrost.core.grid import MerlGrid, cosine_weight
from goniofrost.brdf.merl_file import read_merl
from goniofrost.frost.metrics import log_relative_mse
from goniofrost.frost.model import FrostModel, ModelError
from goniofrost.plan.file import plan_document, read_plan, write_plan
from goniofrost.frost.reconstruction import ReconstructionError, reconstruct, reconstruct_log
from goniofrost.frost.samples_file import read_samples_csv
from goniofrost.frost.selection import SelectionError, candidate_mask_max_angle, select_cells
from goniofrost.frost.training import TrainingError, TrainingOptions, fit_model, train

GRID = MerlGrid(10, 10, 20)


def synthetic_tables(grid: MerlGrid, materials: int, seed: int) -> np.ndarray:
    """Positive BRDF-like tables (M, n_valid, 3): a diffuse term plus a random-width lobe."""
    rng = np.random.default_rng(seed)
    th, td, _ = grid.flat_angles(grid.valid_cells)
    kd = rng.uniform(0.02, 0.3, (materials, 1, 3))
    ks = rng.uniform(0.1, 5.0, (materials, 1, 3))
    width = rng.uniform(0.05, 0.5, (materials, 1, 1))
    lobe = np.exp(-(th[None, :, None] / width) ** 2) * (1 + 0.5 * np.sin(td)[None, :, None])
    noise = rng.uniform(0.9, 1.1, (materials, th.size, 3))
    return ((kd + ks * lobe) * noise).astype(np.float32)


@pytest.fixture(scope="module")
def model(synthetic24) -> FrostModel:
    assert synthetic24.grid == GRID
    return synthetic24


def test_duplicated_training_materials_add_no_directions():
    # Each material three times: the same K and atoms, singular values x sqrt(3), the same mean.
    # (noise=False: the noise model's inner folds are not what this checks, and cost 3 s a fit)
    tables = synthetic_tables(GRID, 5, seed=4)
    once = fit_model(tables, [f"m{i}" for i in range(5)], GRID, TrainingOptions(k_max=30, noise=False))
    thrice = fit_model(np.repeat(tables, 3, axis=0), [f"m{i}" for i in np.repeat(range(5), 3)], GRID,
                       TrainingOptions(k_max=30, noise=False))
    assert thrice.n_components == once.n_components == 14  # 15 columns, rank 14 after centring
    np.testing.assert_allclose(thrice.singular_values, np.sqrt(3) * once.singular_values, rtol=1e-5)
    np.testing.assert_allclose(thrice.mean, once.mean, rtol=1e-6, atol=1e-7)
    sign = np.sign(np.sum(np.asarray(once.dictionary) * np.asarray(thrice.dictionary), axis=0))
    np.testing.assert_allclose(np.asarray(thrice.dictionary), np.sqrt(3) * sign * np.asarray(once.dictionary),
                               rtol=1e-3, atol=1e-4 * float(np.abs(once.dictionary).max()))


def textbook_somp(model: FrostModel, m: int, y_form: str, mask=None) -> list[int]:
    """Plain SOMP (paper Algorithm 1) with an lstsq residual, float64, no tricks."""
    d = np.asarray(model.dictionary, np.float64)[:, :m]
    q = (d / np.asarray(model.singular_values[:m]) ** 2).T
    with np.errstate(invalid="ignore"):  # zero atoms become NaN; callers mask them out
        q /= np.linalg.norm(q, axis=0)
    y = np.asarray(model.coefficients[:m], np.float64)
    y = y if y_form == "all" else y[:, :m]
    allowed = np.ones(q.shape[1], bool) if mask is None else mask
    r, picks = y.copy(), []
    for _ in range(m):
        scores = np.abs(r.T @ q).sum(axis=0)
        scores[~allowed] = -1
        scores[picks] = -1
        picks.append(int(np.argmax(scores)))
        a = q[:, picks]
        r = y - a @ np.linalg.lstsq(a, y, rcond=None)[0]
    return picks


# ----- training ----------------------------------------------------------------------------
def test_training_shapes_and_pca_identity(model):
    n, t = GRID.n_valid, 72
    assert model.dictionary.shape == (n, 30) and model.coefficients.shape == (30, t)
    # V^T rows are orthonormal and singular values descend.
    np.testing.assert_allclose(model.coefficients @ model.coefficients.T, np.eye(30), atol=1e-10)
    assert np.all(np.diff(model.singular_values) <= 0)
    # D = X V reproduces the centred mapped data X (all t components kept -> exact).
    tables = synthetic_tables(GRID, 24, seed=1)
    full = fit_model(tables, [f"mat{i}" for i in range(24)], GRID,
                     TrainingOptions(k_max=100, noise=False))  # the PCA alone
    assert full.n_components <= 72
    x = full.to_log(tables).transpose(1, 0, 2).reshape(n, t) - np.asarray(full.mean, np.float64)[:, None]
    np.testing.assert_allclose(np.asarray(full.dictionary, np.float64) @ full.coefficients, x, atol=2e-4)


@pytest.mark.parametrize("bad", [np.inf, -np.inf])
def test_non_finite_training_value_names_material_and_channel(bad):
    tables = synthetic_tables(GRID, 4, seed=2)
    tables[2, 17, 1] = bad
    with pytest.raises(TrainingError, match=r"material 'mat2' channel G .*position 17"):
        fit_model(tables, [f"mat{i}" for i in range(4)], GRID)


def test_nan_in_training_is_a_cell_not_measured():
    # NaN is a cell the material has no data for (rgl:PATH): left out of that row's reference and mean
    tables = synthetic_tables(GRID, 4, seed=2)
    tables[2, 17, :] = np.nan
    model = fit_model(tables, [f"mat{i}" for i in range(4)], GRID, TrainingOptions(noise=False))
    assert np.isfinite(np.asarray(model.dictionary)).all()
    w = cosine_weight(GRID)[17]
    np.testing.assert_allclose(model.reference[17], np.median(w * tables[[0, 1, 3], 17].ravel()), rtol=1e-5)


def test_training_is_deterministic(model):
    again = fit_model(synthetic_tables(GRID, 24, seed=1), [f"mat{i}" for i in range(24)], GRID,
                      TrainingOptions(k_max=30))
    assert again.content_hash == model.content_hash
    np.testing.assert_array_equal(again.dictionary, model.dictionary)


def test_train_from_dataset_uses_cache(merl_npz, tmp_path):
    spec = f"nbrdf:{merl_npz}"
    only = ["chrome", "white-diffuse-bball", "gold-metallic-paint2", "blue-acrylic"]
    first = train([spec], only=only, exclude=["chrome"], grid=GRID, k_max=5)
    assert sorted(first.names) == sorted(only[1:]) and first.n_signals == 9
    again = train([spec], only=only, exclude=["chrome"], grid=GRID, k_max=5)
    assert isinstance(again.dictionary, np.memmap) and again.content_hash == first.content_hash
    with pytest.raises(Exception, match="no such material"):
        train([spec], only=["no-such-material"], grid=GRID)



def test_a_model_opens_its_datasets_again_from_any_working_folder(merl_npz, tmp_path, monkeypatch):
    """plan --usage maps a model's training materials again (``training.remap``): a relative
    ``nbrdf:PATH`` given to train is read from the folder train ran in. The README's ``train
    --dataset nbrdf:../shared/data/...`` planned from any other folder warned "the model's training
    materials cannot be opened again" and wrote a plan that capture --target-error refuses."""
    from goniofrost.frost.training import remap

    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "m.npz").symlink_to(merl_npz)
    for folder in ("lab", "lab/deeper", "elsewhere"):
        (tmp_path / folder).mkdir()
    only = ["white-diffuse-bball", "gold-metallic-paint2", "blue-acrylic"]
    monkeypatch.chdir(tmp_path / "lab")
    model = train(["nbrdf:../data/m.npz"], only=only, grid=GRID, k_max=5)
    assert model.info["datasets"] == ["nbrdf:../data/m.npz"]
    expected = remap(model)
    model.save(tmp_path / "lab" / "model")
    # the same model from the cache, named from another folder: its info is this call's
    monkeypatch.chdir(tmp_path / "lab" / "deeper")
    again = train(["nbrdf:../../data/m.npz"], only=only, grid=GRID, k_max=5)
    assert again.content_hash == model.content_hash
    assert again.info["datasets"] == ["nbrdf:../../data/m.npz"]
    monkeypatch.chdir(tmp_path / "elsewhere")  # where ../data/m.npz is not
    for trained in (FrostModel.load(tmp_path / "lab" / "model"), again):
        mapped, gram = remap(trained)
        np.testing.assert_array_equal(mapped, expected[0])
        np.testing.assert_array_equal(gram, expected[1])


def test_a_model_of_builtin_or_absolute_datasets_is_the_same_file_from_any_folder(merl_npz, tmp_path, monkeypatch):
    """Only a relative dataset path makes train record its working folder: a model of the
    built-in library (the demo's) or of an absolute path is byte for byte the same file wherever
    train ran, also when the cache holds it from a training that did record a folder."""
    only = ["white-diffuse-bball", "gold-metallic-paint2", "blue-acrylic"]
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "m.npz").symlink_to(merl_npz)
    files = {}
    for folder in ("a", "b"):
        (tmp_path / folder).mkdir()
        monkeypatch.chdir(tmp_path / folder)
        relative = train(["nbrdf:../data/m.npz"], only=only, grid=GRID, k_max=5)
        assert relative.info["datasets_from"] == str(tmp_path / folder)
        for name, spec in (("builtin", "builtin"), ("absolute", f"nbrdf:{tmp_path / 'data' / 'm.npz'}")):
            model = train([spec], only=None if spec == "builtin" else only, grid=GRID, k_max=5)
            assert "datasets_from" not in model.info and model.info["datasets"] == [spec]
            model.save(tmp_path / folder / name)
            files.setdefault(name, []).append((tmp_path / folder / name / "model.json").read_bytes())
    for name, (first, second) in files.items():
        assert first == second, name


# ----- model file ----------------------------------------------------------------------------
def test_model_round_trip_memory_mapped(model, tmp_path):
    model.save(tmp_path / "m")
    loaded = FrostModel.load(tmp_path / "m")
    assert isinstance(loaded.dictionary, np.memmap)
    assert loaded.names == model.names and loaded.grid == GRID and loaded.eps == 0.001
    assert loaded.content_hash == model.content_hash == loaded.compute_hash()
    np.testing.assert_array_equal(loaded.dictionary, model.dictionary)
    values = synthetic_tables(GRID, 1, seed=5)[0].astype(np.float64)
    np.testing.assert_allclose(loaded.from_log(loaded.to_log(values)), values, rtol=1e-9)


def _damaged(model, folder, name, index, value):
    """``model`` saved in ``folder`` with element ``index`` of ``name``.npy set to ``value`` (in place)."""
    model.save(folder)
    array = np.load(folder / f"{name}.npy", mmap_mode="r+")
    array[index] = value
    array.flush()
    return folder


@pytest.mark.parametrize("name, index, value, words", [
    ("mean", 17, np.nan, "element [17] is nan"),
    ("dictionary", (5, 2), np.inf, "element [5, 2] is inf"),
    ("weight", 3, -np.inf, "element [3] is -inf"),
])
def test_a_model_with_a_value_that_is_not_finite_is_refused_naming_the_file(model, tmp_path, capsys, name, index,
                                                                            value, words):
    """A NaN in mean.npy was read as a model: plan exited 0 with the good model's hash."""
    folder = _damaged(model, tmp_path / "m", name, index, value)
    out = tmp_path / "plan.json"
    assert main(["plan", "--model", str(folder), "--samples", "5", "--out", str(out)]) == 2 and not out.exists()
    assert capsys.readouterr().err == (f"goniofrost plan: error: {folder / (name + '.npy')}: {words}; expected finite "
                                       "numbers (a damaged model file: train the model again)\n")


def test_a_model_whose_files_do_not_hash_to_its_content_hash_is_refused(model, tmp_path, capsys):
    folder = _damaged(model, tmp_path / "m", "reference", 4, model.reference[4] * 2)
    out = tmp_path / "plan.json"
    assert main(["plan", "--model", str(folder), "--samples", "5", "--out", str(out)]) == 2 and not out.exists()
    found = FrostModel(**{**model.__dict__, "reference": np.load(folder / "reference.npy"), "content_hash": ""})
    assert capsys.readouterr().err == (
        f"goniofrost plan: error: {folder / 'model.json'}: content_hash: expected {found.content_hash[:16]}... (the "
        f"hash of the model's files), found {model.content_hash[:16]}... (a file of the model was changed after "
        "training: train the model again)\n")


def test_the_hash_read_in_chunks_is_the_hash_of_the_whole_arrays(model, monkeypatch):
    from goniofrost.frost import model as model_module

    whole = model.compute_hash()
    monkeypatch.setattr(model_module, "HASH_CHUNK_BYTES", 1000)  # many chunks, a last one short
    assert model.compute_hash() == whole and model.dictionary.nbytes > 10 * 1000


def test_model_load_refuses_non_model(tmp_path):
    with pytest.raises(ModelError, match="not a goniofrost model"):
        FrostModel.load(tmp_path)


# ----- selection -----------------------------------------------------------------------------
@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("y_form", ["all", "firstm"])
def test_fast_somp_equals_textbook(seed, y_form):
    tables = synthetic_tables(GRID, 20, seed=10 + seed)
    rng = np.random.default_rng(seed)
    tables *= rng.uniform(0.5, 2.0, tables.shape).astype(np.float32)  # a random problem
    # SOMP reads the dictionary, singular values and coefficients, none of which the noise model
    # changes: noise=False spares its inner folds (3 s a fit on this grid)
    mdl = fit_model(tables, [f"m{i}" for i in range(20)], GRID, TrainingOptions(k_max=25, noise=False))
    m = int(rng.integers(5, 20))
    mask = rng.random(GRID.n_valid) < 0.7
    assert select_cells(mdl, m, y_form=y_form).positions.tolist() == textbook_somp(mdl, m, y_form)
    assert select_cells(mdl, m, y_form=y_form, candidates=mask).positions.tolist() == \
        textbook_somp(mdl, m, y_form, mask)


@pytest.mark.parametrize("growth", [0.0, None, np.inf])
@pytest.mark.parametrize("y_form", ["all", "firstm"])
def test_fast_somp_with_many_score_blocks(monkeypatch, y_form, growth):
    """Blocks of 64 cells: several per thread (3 threads, uneven shares), the last one
    zero-padded (1670 cells); the Q^T b = C z steps never, as by default, or from the first
    step on."""
    import goniofrost.frost.selection as selection

    if growth is not None:
        monkeypatch.setattr(selection, "CZ_MAX_GROWTH", growth)

    tables = synthetic_tables(GRID, 20, seed=21)
    mdl = fit_model(tables, [f"m{i}" for i in range(20)], GRID, TrainingOptions(k_max=25, noise=False))  # SOMP alone
    mask = np.random.default_rng(5).random(GRID.n_valid) < 0.8
    monkeypatch.setattr(selection, "BLOCK_CELLS", 64)
    assert select_cells(mdl, 15, y_form=y_form, threads=3).positions.tolist() == textbook_somp(mdl, 15, y_form)
    assert select_cells(mdl, 12, y_form=y_form, candidates=mask, threads=3).positions.tolist() == \
        textbook_somp(mdl, 12, y_form, mask)


def test_packed_atoms_are_the_unit_scaled_dictionary_rows(model, monkeypatch):
    """qb[b, :, r] is cell b * W + r's atom S_k^-2 d / ||S_k^-2 d|| (the candidates' rows in
    order), the padding after the last candidate zero; whatever the threads."""
    import goniofrost.frost.selection as selection

    monkeypatch.setattr(selection, "BLOCK_CELLS", 64)
    k, mask = 12, np.random.default_rng(3).random(GRID.n_valid) < 0.6
    rows = np.flatnonzero(mask)
    x = np.asarray(model.dictionary, np.float64)[rows, :k] / np.asarray(model.singular_values[:k], np.float64) ** 2
    expected = x / np.linalg.norm(x, axis=1)[:, None]
    for threads in (1, 3):
        pos, qb, n = selection._atoms(model, k, mask, k, threads)
        assert n == rows.size and pos.tolist() == rows.tolist() and qb.shape == (-(-n // 64), k, 64)
        cells = qb.transpose(0, 2, 1).reshape(-1, k)
        np.testing.assert_allclose(cells[:n], expected, rtol=2e-6, atol=1e-7)
        assert not cells[n:].any()


def test_zero_atoms_are_never_picked(model):
    """Cells whose dictionary row is zero (every training material at its mean there) have a
    zero atom: SOMP passes them over, and allowing only such cells is a clear error."""
    import dataclasses

    d = np.array(model.dictionary)
    zero = np.arange(0, GRID.n_valid, 3)
    d[zero] = 0.0
    mdl = dataclasses.replace(model, dictionary=d, content_hash="")
    sel = select_cells(mdl, 12)
    assert not np.isin(sel.positions, zero).any()
    assert sel.positions.tolist() == textbook_somp(mdl, 12, "firstm", np.isin(np.arange(GRID.n_valid), zero, invert=True))
    only_zero = np.zeros(GRID.n_valid, bool)
    only_zero[zero] = True
    only_zero[1] = True  # one usable cell: one direction, then nothing left
    with pytest.raises(SelectionError, match="span only 1 independent directions"):
        select_cells(mdl, 3, candidates=only_zero)


def test_selection_is_deterministic_and_consistent(model):
    a, b = select_cells(model, 12), select_cells(model, 12)
    np.testing.assert_array_equal(a.positions, b.positions)
    np.testing.assert_array_equal(a.cells, GRID.valid_cells[a.positions])
    assert len(set(a.positions.tolist())) == 12 and np.all(np.diff(a.residuals) < 0)


@pytest.mark.parametrize("y_form", ["all", "firstm"])
def test_max_error_rule(model, y_form):
    sel = select_cells(model, max_error=0.3, y_form=y_form)
    assert sel.residuals[-1] <= 0.3 < sel.residuals[-2]
    # Residuals are ||R||_F / ||Y||_F of the textbook projection onto the chosen columns.
    if y_form == "all":  # (firstm with m given uses the first m columns, not the first k)
        full = select_cells(model, sel.m, k=model.n_components, y_form=y_form)
        np.testing.assert_array_equal(full.positions, sel.positions)
    d = np.asarray(model.dictionary, np.float64)
    q = (d / model.singular_values**2).T
    a = q[:, sel.positions] / np.linalg.norm(q[:, sel.positions], axis=0)
    y = model.coefficients if y_form == "all" else model.coefficients[:, :model.n_components]
    r = y - a @ np.linalg.lstsq(a, y, rcond=None)[0]
    assert np.linalg.norm(r) / np.linalg.norm(y) == pytest.approx(sel.residuals[-1], rel=1e-6)


def test_candidate_mask_max_angle(model):
    mask = candidate_mask_max_angle(GRID, 45.0)
    sel = select_cells(model, 8, candidates=mask)
    assert mask[sel.positions].all()
    w_i, w_o = GRID.cell_directions(sel.cells)
    assert np.all(np.degrees(np.arccos(np.minimum(w_i[:, 2], w_o[:, 2]))) <= 45.0 + 1e-9)


@pytest.mark.parametrize("kwargs, message", [
    ({}, "exactly one of m"),
    ({"m": 5, "max_error": 0.1}, "exactly one of m"),
    ({"m": 0}, "expected an integer in"),
    ({"m": 31}, "expected an integer in"),
    ({"max_error": 1.5}, r"expected a number in \(0, 1\)"),
    ({"m": 5, "y_form": "some"}, "y_form"),
    ({"m": 5, "candidates": np.ones(3, bool)}, "bool mask of shape"),
    ({"m": 5, "k": 3}, r"k \(--atoms\): expected"),
])
def test_bad_selection_options(model, kwargs, message):
    with pytest.raises(SelectionError, match=message):
        select_cells(model, **kwargs)


# ----- reconstruction ------------------------------------------------------------------------
@pytest.mark.parametrize("y_form", ["all", "firstm"])
def test_exact_recovery_in_span(model, y_form):
    m = 10
    coeffs = np.random.default_rng(3).normal(0, 0.05, (m, 3))
    mapped = np.asarray(model.dictionary[:, :m], np.float64) @ coeffs + np.asarray(model.mean, np.float64)[:, None]
    truth = model.from_log(mapped)
    assert truth.min() > 0
    sel = select_cells(model, m, y_form=y_form)
    estimate = reconstruct(model, sel.positions, truth[sel.positions], eta=1e-12)
    np.testing.assert_allclose(estimate, truth, rtol=1e-4)
    assert log_relative_mse(model, truth, estimate) < 1e-10


def test_duplicate_samples_are_averaged(model):
    truth = model.from_log(np.asarray(model.mean, np.float64)[:, None].repeat(3, 1))
    pos = np.array([5, 9, 40, 5])
    values = truth[pos] * np.array([[1.2], [1.0], [1.0], [0.8]])
    a = reconstruct(model, pos, values)
    b = reconstruct(model, pos[:3], np.array([truth[5], truth[9], truth[40]]))
    # Averaged in the BRDF domain (1.2 and 0.8 -> 1.0), atoms = distinct cells (3).
    np.testing.assert_allclose(a, b, rtol=1e-12)
    log_b = reconstruct_log(model, pos[:3], model.to_log(truth[pos[:3]], pos[:3]), 40.0, 3)
    np.testing.assert_allclose(model.from_log(log_b), b, rtol=1e-12)


@pytest.mark.parametrize("values, message", [
    ([[np.nan, 1, 1]], "NaN value nan in channel r"),
    ([[1, np.inf, 1]], "infinite value inf in channel g"),
    ([[1, 1, -0.5]], "negative value -0.5 in channel b"),
])
def test_reconstruct_refuses_bad_values(model, values, message):
    with pytest.raises(ReconstructionError, match=message):
        reconstruct(model, [3], values)


@pytest.mark.parametrize("options, message", [
    ({"eta": -1.0}, "eta (--eta): expected a finite number >= 0, found -1.0"),
    ({"n_atoms": 0}, "n_atoms (--atoms): expected an integer in [1, 30], found 0"),  # K = 30
])
def test_reconstruct_names_the_option_of_a_bad_parameter(model, options, message):
    """reconstruct --eta -5 said 'eta: ...', --atoms 0 'n_atoms: ...': the parameter, not the option."""
    with pytest.raises(ReconstructionError) as err:
        reconstruct(model, [3, 9], [[1.0, 1.0, 1.0], [1.0, 1.0, 1.0]], **options)
    assert str(err.value) == message


def test_reconstruct_refuses_a_diverging_fit(model):
    # 12 neighbouring cells (condition number ~2e3) alternating between 1e-9 and 1e4 1/sr,
    # fitted without a ridge term: the mapped estimate passes exp's range elsewhere.
    values = np.where(np.arange(12)[:, None] % 2 == 0, 1e-9, 1e4) * np.ones((12, 3))
    with np.errstate(all="raise"):  # no overflow warning either
        with pytest.raises(ReconstructionError, match=rf"reconstruction diverged: \d+ of {3 * GRID.n_valid} estimated values overflow.*"
                           r"eta=0: use eta > 0 \(default 40\)"):
            reconstruct(model, np.arange(12), values, eta=0.0)
    assert np.isfinite(reconstruct(model, np.arange(12), values)).all()  # the default ridge term holds it


# ----- SAMPLES.csv and the commands ----------------------------------------------------------
HEADER = "theta_h_deg,theta_d_deg,phi_d_deg,r,g,b,note\n"


def good_rows(model, count=6) -> str:
    cells = GRID.valid_cells[select_cells(model, count).positions]
    th, td, pd = (np.degrees(a) for a in GRID.flat_angles(cells))
    return "".join(f"{a},{b},{c},0.1,0.2,0.3,0.01\n" for a, b, c in zip(th, td, pd))


def test_read_samples_csv(model, tmp_path):
    path = tmp_path / "s.csv"
    path.write_text(HEADER + good_rows(model))
    cells, values, extra = read_samples_csv(path, GRID)
    assert np.all(GRID.valid_position(cells) >= 0) and values.shape == (6, 3)
    assert extra == {"note": ["0.01"] * 6}


@pytest.mark.parametrize("text, message", [
    ("", "empty file"),
    ("theta_h_deg,theta_d_deg,phi_d_deg,r,g\n1,2,3,4,5\n", r"missing column\(s\) \['b'\]"),
    (HEADER + "10,10,10,nan,0.2,0.3,0\n", "line 2: NaN value"),
    (HEADER + "10,10,10,0.1,inf,0.3,0\n", "line 2: infinite value"),
    (HEADER + "10,10,10,0.1,0.2,-1,0\n", "line 2: negative value -1.0 in channel b"),
    (HEADER + "60,80,0,0.1,0.2,0.3,0\n", "line 2: .*not a valid cell"),
    (HEADER + "10,10,x,0.1,0.2,0.3,0\n", "line 2: column phi_d_deg: expected a number"),
    (HEADER, "no samples after the header"),
])
def test_reconstruct_command_bad_csv(model, tmp_path, capsys, text, message):
    model.save(tmp_path / "model")
    (tmp_path / "s.csv").write_text(text)
    out = tmp_path / "out.binary"
    code = main(["reconstruct", "--model", str(tmp_path / "model"), "--samples", str(tmp_path / "s.csv"),
                 "--out", str(out)])
    assert code == 2 and not out.exists()
    assert re.search(message, capsys.readouterr().err)


SESSION_HEADER = "theta_h_deg,theta_d_deg,phi_d_deg,r,g,b,plan_index\n"


@pytest.mark.parametrize("text, message", [
    # a header naming r twice: the second column was ignored
    ("theta_h_deg,theta_d_deg,phi_d_deg,r,g,b,r\n10,10,10,0.1,0.2,0.3,0.4\n",
     "line 1: column 'r' appears twice (columns 4 and 7); expected each column once"),
    # a session's row duplicated: it weighed its cell twice and changed the result
    (SESSION_HEADER + "10,10,10,0.1,0.2,0.3,0\n20,20,20,0.1,0.2,0.3,1\n10,10,10,0.1,0.2,0.3,0\n",
     "line 4: plan_index 0 again (line 2); expected each plan sample once"),
    (SESSION_HEADER + "10,10,10,0.1,0.2,0.3,0\n20,20,20,0.1,0.2,0.3,0\n",
     "line 3: plan_index 0 again (line 2); expected each plan sample once"),
    (HEADER + "10,10,10,0.1,0.2,0.3,x\n10,10,10,0.1,0.2,0.3,x\n",
     "line 3: the same sample as line 2; expected each sample once"),
])
def test_a_repeated_column_or_sample_is_refused_naming_the_line(model, tmp_path, capsys, text, message):
    model.save(tmp_path / "model")
    (tmp_path / "s.csv").write_text(text)
    out = tmp_path / "out.binary"
    code = main(["reconstruct", "--model", str(tmp_path / "model"), "--samples", str(tmp_path / "s.csv"),
                 "--out", str(out)])
    assert code == 2 and not out.exists()
    assert capsys.readouterr().err == f"goniofrost reconstruct: error: {tmp_path / 's.csv'}: {message}\n"


def test_plan_and_reconstruct_commands(model, tmp_path):
    model.save(tmp_path / "model")
    plan = tmp_path / "plan.json"
    assert main(["plan", "--model", str(tmp_path / "model"), "--samples", "7", "--max-angle", "60",
                 "--out", str(plan)]) == 0
    doc = read_plan(plan)
    assert doc["m"] == 7 and doc["model"]["hash"] == model.content_hash
    sample = doc["samples"][0]
    assert max(sample["theta_i_deg"], sample["theta_o_deg"]) <= 60 + 1e-9
    flat = GRID.flat_index(*sample["cell"])
    w_i, w_o = GRID.cell_directions(flat)
    np.testing.assert_allclose(sample["w_i"], w_i)
    np.testing.assert_allclose(sample["w_o"], w_o)
    (tmp_path / "s.csv").write_text(HEADER + good_rows(model))
    out = tmp_path / "out.binary"
    assert main(["reconstruct", "--model", str(tmp_path / "model"), "--samples", str(tmp_path / "s.csv"),
                 "--out", str(out)]) == 0
    brdf = read_merl(out, GRID)
    assert np.isnan(brdf[~GRID.valid_mask]).all() and np.all(brdf[GRID.valid_mask] >= 0)


def test_a_plan_names_its_model_from_its_own_folder_so_a_capture_finds_it_from_any_folder(model, tmp_path,
                                                                                          monkeypatch):
    from pathlib import Path

    from goniofrost.capture.inputs import resolve_model_path

    model.save(tmp_path / "model")
    monkeypatch.chdir(tmp_path)  # plan --model model --out sub/plan.json recorded "model": no model from sub/
    assert main(["plan", "--model", "model", "--samples", "3", "--out", "sub/plan.json"]) == 0
    doc = read_plan(tmp_path / "sub" / "plan.json")
    assert doc["model"]["path"] == "../model"
    monkeypatch.chdir(tmp_path / "sub")
    assert resolve_model_path(doc, Path("plan.json")) == Path("../model")
    doc["model"]["path"] = "gone"
    with pytest.raises(ConfigError) as refused:
        resolve_model_path(doc, tmp_path / "sub" / "plan.json")
    assert str(refused.value) == (f"{tmp_path}/sub/plan.json: model.path: expected a model folder from goniofrost "
                                  f"train ({tmp_path}/sub/gone beside the plan, or gone from the current folder), "
                                  f"found 'gone'")


def test_plan_max_error_command(model, tmp_path):
    model.save(tmp_path / "model")
    plan = tmp_path / "plan.json"
    assert main(["plan", "--model", str(tmp_path / "model"), "--selector", "frost", "--max-error", "0.25",
                 "--out", str(plan)]) == 0
    doc = read_plan(plan)
    assert doc["residuals"][-1] <= 0.25 < doc["residuals"][-2] and len(doc["samples"]) == doc["m"]
    assert doc["selector"] == "frost" and doc["y_form"] == "firstm"


def test_read_plan_refuses_bad_content(model, tmp_path):
    path = tmp_path / "p.json"
    doc = plan_document("m", model, select_cells(model, 3))
    del doc["samples"][1]["w_o"]
    write_plan(path, doc)
    with pytest.raises(ConfigError, match=r"samples\[1\]\.w_o"):
        read_plan(path)
    path.write_text("{not json")
    with pytest.raises(ConfigError, match="valid JSON"):
        read_plan(path)
    path.write_text(json.dumps({"model": {"path": "x", "hash": "y"}, "m": 1, "selection_seconds": 0}))
    with pytest.raises(ConfigError, match="samples"):
        read_plan(path)


@pytest.mark.parametrize("t", [5, 6])
def test_row_median_matches_numpy(t):
    from goniofrost.frost.training import _row_median
    block = np.random.default_rng(t).random((50, t)).astype(np.float32)
    np.testing.assert_array_equal(_row_median(block), np.median(block, axis=1).astype(np.float32))


def test_thread_count_is_a_checked_parameter(model):
    """threads is per call (no module global): any positive count gives the same picks; 0 is refused."""
    picks = select_cells(model, 10, threads=1).positions.tolist()
    assert select_cells(model, 10, threads=2).positions.tolist() == picks
    with pytest.raises(ValueError, match="threads: expected a positive integer, found 0"):
        select_cells(model, 10, threads=0)
