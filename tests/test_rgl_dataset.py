"""RGL tensor files as a dataset (``rgl:PATH``), checked against the real Mitsuba 3.

Every file is written here by goniofrost's own export from built-in materials (small grids and
resolutions): the evaluation at the export's nodes, against Mitsuba's ``measured`` eval at random
direction pairs (RGB and spectral files), the domain and its mask through the metric, training and
a benchmark fold, the commands that accept the dataset, and the one-line errors of bad files.
"""
from __future__ import annotations

import json
from pathlib import Path

import mitsuba as mi
import numpy as np
import pytest

from goniofrost.app.cli import main
from goniofrost.brdf import cie1931, marginal2d
from goniofrost.brdf import mitsuba_export as me
from goniofrost.brdf import rgl_measured as rm
from goniofrost.brdf import rgl_spectral as rs
from goniofrost.brdf.merl_file import read_merl
from goniofrost.brdf.mitsuba_probe import eval_pairs, eval_pairs_spectral_rgb, load_bsdf
from goniofrost.brdf.mitsuba_render import SPECTRAL_VARIANT
from goniofrost.brdf.rgl_tensor import encode, read_tensor_file, write_tensor_file
from goniofrost.core.grid import MerlGrid
from goniofrost.datasets import open_dataset
from goniofrost.frost.metrics import batch_log_errors, log_relative_mse

from test_spectral_export import builtin_table  # a builtin material on a grid, float64 (grid.size, 3)

SMALL = MerlGrid(30, 30, 60)
TINY = MerlGrid(12, 12, 24)
OPTIONS = me.ExportOptions(theta_i=8, ndf=31, vndf_theta=31, vndf_phi=16, sample=16)
MATERIALS = ("gold", "red-plastic", "terracotta", "blue-car-paint", "green-felt", "chrome",
             "white-paper", "brass", "black-rubber", "purple-velvet")
LIMIT_DEG = 50.0  # the limited file keeps the theta_i slices up to here


@pytest.fixture(autouse=True, scope="module")
def rgb_variant_after():
    """Leave Mitsuba in the RGB variant the other modules set at import."""
    yield
    mi.set_variant("scalar_rgb")


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    """A folder of RGB exports of MATERIALS on the small grid, and gold's spectral export."""
    out = tmp_path_factory.mktemp("rgl")
    for name in MATERIALS:
        fields = me.build_fields(builtin_table(name, SMALL), SMALL, OPTIONS, source=f"builtin:{name}")
        write_tensor_file(out / f"{name}.bsdf", fields)
        if name == "gold":
            write_tensor_file(out / "gold-spectral.bsdf", rs.spectral_fields(fields, 16))
    return out


def limited_fields(fields: dict) -> dict:
    """The fields with only the theta_i slices up to LIMIT_DEG: a file measured to that elevation."""
    keep = fields["theta_i"] <= np.radians(LIMIT_DEG)
    out = dict(fields)
    for name in ("theta_i",):
        out[name] = fields[name][keep]
    for name in ("vndf", "luminance", "rgb"):
        out[name] = np.ascontiguousarray(fields[name][:, keep])
    return out


def cap_directions(rng, n: int, max_deg: float = 75.0) -> np.ndarray:
    cos = rng.uniform(np.cos(np.radians(max_deg)), 1.0, n)
    phi, sin = rng.uniform(0.0, 2 * np.pi, n), np.sqrt(1.0 - cos ** 2)
    return np.stack([sin * np.cos(phi), sin * np.sin(phi), cos], -1)


def relative(ours: np.ndarray, theirs: np.ndarray) -> np.ndarray:
    return np.abs(ours - theirs) / np.maximum(np.abs(theirs), 1e-6 * np.abs(theirs).max())


# ----- the evaluation is Mitsuba's ---------------------------------------------------------------
def test_the_export_round_trips_at_its_nodes(folder):
    # the node s of slice theta_i stands for w_o = reflect(w_i, m(s)): f cos theta_o there is the table's
    table = me.prepared_table(builtin_table("red-plastic", SMALL), SMALL)
    fields = read_tensor_file(folder / "red-plastic.bsdf")
    measured = rm.load_measured(folder / "red-plastic.bsdf")
    warp = marginal2d.build(fields["vndf"][0].astype(np.float64))
    s = np.linspace(0.0, 1.0, OPTIONS.sample)[1:-1]  # inner nodes (the edges are clipped)
    points = np.stack(np.broadcast_arrays(s[None, :], s[:, None]), -1).reshape(1, -1, 2)
    u_m, _ = marginal2d.sample(warp, np.repeat(points, OPTIONS.theta_i, axis=0))
    checked = 0
    for k, theta_i in enumerate(fields["theta_i"].astype(np.float64)[:-1]):  # theta_i < 90 deg
        m = me._normal(u_m[k, :, 0], u_m[k, :, 1])
        w_i = me.elevation_dir(theta_i)
        w_o = 2 * (m @ w_i)[:, None] * m - w_i
        keep = w_o[:, 2] > 0.05
        w_i = np.broadcast_to(w_i, w_o.shape)[keep]
        expected = me.lookup(table, SMALL, w_i, w_o[keep])
        np.testing.assert_allclose(rm.brdf(measured, w_i, w_o[keep]), expected, rtol=2e-4, atol=1e-7)
        checked += int(keep.sum())
    assert checked > 1000


@pytest.mark.parametrize("name", ["gold", "blue-car-paint"])
def test_rgb_file_evaluates_as_mitsubas_eval(folder, name):
    rng = np.random.default_rng(3)
    w_i, w_o = cap_directions(rng, 400), cap_directions(rng, 400)
    ours = rm.eval_cosine_weighted(rm.load_measured(folder / f"{name}.bsdf"), w_i, w_o)
    theirs = eval_pairs(load_bsdf(folder / f"{name}.bsdf"), w_i, w_o)
    rel = relative(ours, theirs)
    assert np.median(rel) <= 0.01 and np.percentile(rel, 95) <= 0.05
    assert np.median(rel) < 1e-5  # in fact float32 rounding apart


def test_spectral_file_integrated_to_rgb_is_mitsubas_spectral_eval_on_its_film(folder):
    path = folder / "gold-spectral.bsdf"
    rng = np.random.default_rng(5)
    w_i, w_o = cap_directions(rng, 120), cap_directions(rng, 120)
    ours = rm.eval_cosine_weighted(rm.load_measured(path), w_i, w_o)
    wavelengths = read_tensor_file(path)["wavelengths"]
    theirs = eval_pairs_spectral_rgb(load_bsdf(path, SPECTRAL_VARIANT), w_i, w_o, wavelengths)
    rel = relative(ours, theirs)
    assert np.median(rel) <= 0.01 and np.percentile(rel, 95) <= 0.05
    # and the spectral file is its RGB source's colour again (the upsampling's round trip)
    rgb = rm.eval_cosine_weighted(rm.load_measured(folder / "gold.bsdf"), w_i, w_o)
    assert np.median(relative(ours, rgb)) <= 0.01


def node_round_trip(folder, name: str, illuminant=None) -> np.ndarray:
    """Relative difference at every node of an export's rgb table and its spectral file's
    spectra integrated to RGB (32 wavelengths): what the evaluation does between them is linear."""
    fields = read_tensor_file(folder / f"{name}.bsdf")
    spectral = rs.spectral_fields(fields, 32)
    weights = cie1931.spectrum_to_srgb_weights(spectral["wavelengths"], illuminant)
    rgb = fields["rgb"].transpose(0, 1, 3, 4, 2).reshape(-1, 3).astype(np.float64)
    back = spectral["spectra"].transpose(0, 1, 3, 4, 2).reshape(-1, 32).astype(np.float64) @ weights
    bright = rgb.max(axis=1) > 1e-3 * rgb.max()
    return (np.abs(back - rgb) / np.maximum(rgb, 1e-3 * rgb.max()))[bright]


def test_d65_is_the_illuminant_spectral_exports_come_back_under(folder):
    # decision 0300: under D65 the export's spectra come back to its RGB; under illuminant E they do not
    for name in ("gold", "red-plastic", "blue-car-paint"):
        assert np.median(node_round_trip(folder, name)) < 0.01
        assert np.median(node_round_trip(folder, name, np.ones(cie1931.table().shape[0]))) > 0.05


def test_the_shipped_colour_table_is_mitsubas():
    mi.set_variant(SPECTRAL_VARIANT)
    table = cie1931.table()
    for row in table[::37]:
        np.testing.assert_allclose(row[1:4], mi.cie1931_xyz(float(row[0])), rtol=1e-6, atol=1e-7)
        np.testing.assert_allclose(row[4], mi.cie_d65(float(row[0])), rtol=1e-6)
    theirs = np.array([np.array(mi.xyz_to_srgb(mi.Color3f(*e))) for e in np.eye(3)]).T
    np.testing.assert_allclose(cie1931.XYZ_TO_SRGB, theirs, rtol=1e-6)
    # a spectrum of 1 is white
    np.testing.assert_allclose(cie1931.spectrum_to_srgb_weights(np.linspace(380, 780, 9)).sum(0), 1.0, atol=1e-3)


# ----- the dataset -------------------------------------------------------------------------------
def test_dataset_tabulates_the_brdf_mitsuba_renders_divided_by_the_cosine(folder):
    dataset = open_dataset(f"rgl:{folder}")
    assert dataset.names() == [p.stem for p in sorted(folder.glob("*.bsdf"))]  # the files, in path order
    assert set(dataset.names()) == {"gold-spectral", *MATERIALS}
    cells = SMALL.valid_cells[::97]
    values = dataset.tabulate(["gold"], SMALL, cells)[0]
    w_i, w_o = SMALL.cell_directions(cells)
    theirs = eval_pairs(load_bsdf(folder / "gold.bsdf"), w_i, w_o) / w_o[:, 2:3]
    assert np.median(relative(values, theirs)) < 1e-5
    assert open_dataset(f"rgl:{folder / 'gold.bsdf'}").names() == ["gold"]


def test_cells_beyond_the_measured_elevations_are_not_measured(folder, tmp_path):
    write_tensor_file(tmp_path / "gold-50.bsdf", limited_fields(read_tensor_file(folder / "gold.bsdf")))
    dataset = open_dataset(f"rgl:{tmp_path}")
    values = dataset.tabulate(None, SMALL)[0]
    w_i, _ = SMALL.cell_directions(SMALL.valid_cells)
    top = rm.load_measured(tmp_path / "gold-50.bsdf").theta_i[-1]
    beyond = np.arccos(w_i[:, 2]) > top + 1e-6
    assert 0 < beyond.sum() < SMALL.n_valid
    assert np.isnan(values[beyond]).all() and np.isfinite(values[~beyond]).all()
    full = open_dataset(f"rgl:{folder}").tabulate(["gold"], SMALL)[0]
    np.testing.assert_array_equal(values[~beyond & (np.arccos(w_i[:, 2]) < np.radians(30))],
                                  full[~beyond & (np.arccos(w_i[:, 2]) < np.radians(30))])
    assert f"theta_i 0.0-{np.degrees(top):.1f} deg" in dataset.domain("gold-50")
    from goniofrost.core.grid import FULL_GRID
    full_w_i, _ = FULL_GRID.cell_directions(FULL_GRID.valid_cells)
    inside = int((np.arccos(np.clip(full_w_i[:, 2], -1, 1)) <= top + 1e-6).sum())
    assert f"{inside} of 1111432 valid cells of the full grid measured" in dataset.domain("gold-50")


def test_the_metric_scores_only_measured_cells(folder, tmp_path):
    from goniofrost.frost.training import TrainingOptions, fit_model

    write_tensor_file(tmp_path / "gold-50.bsdf", limited_fields(read_tensor_file(folder / "gold.bsdf")))
    limited = open_dataset(f"rgl:{tmp_path}").tabulate(None, TINY)[0].astype(np.float64)
    tables = open_dataset(f"rgl:{folder}").tabulate(list(MATERIALS[1:6]), TINY)
    model = fit_model(tables, list(MATERIALS[1:6]), TINY, TrainingOptions(k_max=5, noise=False))
    estimate = np.full(limited.shape, 0.05)
    measured = ~np.isnan(limited[:, 0])
    w = np.asarray(model.weight, np.float64)[measured, None]
    by_hand = np.mean((np.log(w * limited[measured] + model.eps) - np.log(w * 0.05 + model.eps)) ** 2)
    assert log_relative_mse(model, limited, estimate) == pytest.approx(by_hand, rel=1e-12)
    # the batched form the benchmarks use agrees
    est_log = model.to_log(estimate)
    batch = batch_log_errors(model, est_log, model.to_log(limited[None]))
    assert batch[0] == pytest.approx(by_hand, rel=1e-9)


def test_training_leaves_unmeasured_cells_out_of_reference_mean_and_atoms(folder, tmp_path):
    from goniofrost.frost.training import TrainingOptions, fit_model

    write_tensor_file(tmp_path / "gold-50.bsdf", limited_fields(read_tensor_file(folder / "gold.bsdf")))
    limited = open_dataset(f"rgl:{tmp_path}").tabulate(None, TINY)
    others = open_dataset(f"rgl:{folder}").tabulate(list(MATERIALS[1:6]), TINY)
    model = fit_model(np.concatenate([limited, others]), ["gold-50", *MATERIALS[1:6]], TINY,
                      TrainingOptions(k_max=18, noise=False))
    alone = fit_model(others, list(MATERIALS[1:6]), TINY, TrainingOptions(k_max=4, noise=False))
    missing = np.isnan(limited[0, :, 0])
    assert missing.any() and np.isfinite(np.asarray(model.dictionary)).all()
    # where gold-50 has no data, the reference and mean are the other materials' alone
    np.testing.assert_allclose(np.asarray(model.reference)[missing], np.asarray(alone.reference)[missing], rtol=1e-6)
    np.testing.assert_allclose(np.asarray(model.mean)[missing], np.asarray(alone.mean)[missing], rtol=1e-5, atol=1e-6)
    # train(), what the command runs, on the dataset spec: the same model
    from goniofrost.frost.training import train
    (tmp_path / "all").mkdir()
    for name in MATERIALS[1:6]:
        (tmp_path / "all" / f"{name}.bsdf").write_bytes((folder / f"{name}.bsdf").read_bytes())
    (tmp_path / "all" / "gold-50.bsdf").write_bytes((tmp_path / "gold-50.bsdf").read_bytes())
    trained = train([f"rgl:{tmp_path / 'all'}"], grid=TINY, k_max=18, cache=False)
    order = [trained.names.index(n) for n in ["gold-50", *MATERIALS[1:6]]]
    assert sorted(order) == list(range(6))
    np.testing.assert_allclose(np.asarray(trained.reference), np.asarray(model.reference), rtol=1e-6)
    # and gold-50's coefficients come from its measured cells only: its atoms are 0 there
    mapped = np.asarray(model.dictionary, np.float64) @ np.asarray(model.coefficients)[:, :3]  # X = D V^T, all atoms
    assert np.abs(mapped[missing]).max() < 1e-4 * np.abs(mapped[~missing]).max()


def test_the_noise_cross_validation_leaves_unmeasured_cells_out(folder, tmp_path):
    from goniofrost.core.grid import cosine_weight
    from goniofrost.frost import noise
    from goniofrost.frost.training import _map_and_gram

    write_tensor_file(tmp_path / "gold-50.bsdf", limited_fields(read_tensor_file(folder / "gold.bsdf")))
    names = ["gold-50", *MATERIALS[1:8]]
    tables = np.concatenate([open_dataset(f"rgl:{tmp_path}").tabulate(None, TINY),
                             open_dataset(f"rgl:{folder}").tabulate(list(MATERIALS[1:8]), TINY)])
    missing = {}
    mapped, _, _, gram = _map_and_gram(tables, names, cosine_weight(TINY).astype(np.float32), 0.001, False,
                                       missing=missing)
    assert list(missing) == [0] and np.array_equal(missing[0], np.isnan(tables[0, :, 0]))
    folds = noise.inner_folds(gram, len(names), k=6, folds=4)
    every = np.zeros(mapped.shape)
    for f in folds:
        every[:, f.held] = mapped.astype(np.float64) @ f.residual_map
    scored = np.ones(mapped.shape, bool)
    scored[missing[0], 0:3] = False
    expected = np.sum(np.where(scored, every, 0.0) ** 2, axis=1) / scored.sum(axis=1)
    np.testing.assert_allclose(noise.representation_variance(mapped, folds, missing), expected, rtol=1e-4)
    assert not np.allclose(noise.representation_variance(mapped, folds)[missing[0]], expected[missing[0]], rtol=1e-4)


def test_a_benchmark_fold_scores_only_measured_cells(folder, tmp_path):
    from goniofrost.bench.config import BenchConfig, fold_split
    from goniofrost.bench.evaluate import Design, evaluate_design, run_fold, sampled_truth
    from goniofrost.bench.baselines import uniform_select
    from goniofrost.frost.reconstruction import reconstruct_log
    from goniofrost.frost.training import TrainingOptions, fit_model

    write_tensor_file(tmp_path / "gold-50.bsdf", limited_fields(read_tensor_file(folder / "gold.bsdf")))
    others = list(MATERIALS[1:8])
    config = BenchConfig(("rgl:x",), folds=1, n_train=6, n_test=2, m_values=(4, 8), methods=("frost", "bayes"),
                         grid=TINY, target_errors=(0.05,))
    _, test = fold_split(8, config, 0)
    names = others[:test[0]] + ["gold-50"] + others[test[0]:]  # gold-50 is a test material of fold 0
    tables = np.stack([open_dataset(f"rgl:{tmp_path if n == 'gold-50' else folder}").tabulate([n], TINY)[0]
                       for n in names])
    np.save(tmp_path / "tables.npy", tables)
    rows = run_fold(config, str(tmp_path / "tables.npy"), names, 0)
    assert {r["material"] for r in rows if r["method"] == "bayes"} == {names[i] for i in test}
    assert all(np.isfinite(r["mse"]) for r in rows)
    # the error of a design is its reconstruction's error over the measured cells alone
    model = fit_model(tables[[i for i in range(8) if i not in test]], ["a"] * 6, TINY,
                      TrainingOptions(k_max=8, noise=False))
    truth = tables[test].astype(np.float64)
    positions = uniform_select(TINY, 8)
    row = evaluate_design(model, Design("uniform", 8, 0, positions, 0.0), sampled_truth(model, truth),
                          ["gold-50", "x"], 40.0, 0, model.to_log(truth))[0]
    sampled = sampled_truth(model, truth)[0, positions]
    estimate = model.from_log(reconstruct_log(model, positions, model.to_log(sampled, positions), eta=40.0))
    measured = ~np.isnan(truth[0, :, 0])
    assert not measured.all()
    assert row["mse"] == pytest.approx(log_relative_mse(model, truth[0], estimate), rel=1e-9)
    w = np.asarray(model.weight, np.float64)[measured, None]
    by_hand = np.mean((np.log(w * truth[0][measured] + model.eps) - np.log(w * estimate[measured] + model.eps)) ** 2)
    assert row["mse"] == pytest.approx(by_hand, rel=1e-9)


def test_convert_materials_and_bench_accept_the_dataset(folder, tmp_path, capsys):
    spec = f"rgl:{folder}"
    out = tmp_path / "gold.binary"
    assert main(["convert", "--dataset", spec, "--material", "gold", "--out", str(out)]) == 0
    assert "from rgl:" in capsys.readouterr().out
    from goniofrost.core.grid import FULL_GRID
    cells = FULL_GRID.valid_cells[::4001]
    np.testing.assert_allclose(read_merl(out)[cells], open_dataset(spec).tabulate(["gold"], FULL_GRID, cells)[0],
                               rtol=1e-6, atol=1e-9)
    assert main(["materials", "--dataset", spec, "--domain"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("black-rubber\tRGB; theta_i 0.0-90.0 deg (8 elevations)")
    assert any(line.startswith("gold-spectral\tspectral, 16 wavelengths 380-780 nm") for line in lines)
    bench = tmp_path / "bench"
    assert main(["bench", "--dataset", spec, "--grid", "12,12,24", "--jobs", "1", "--no-progress", "--folds", "1",
                 "--train", "8", "--test", "3", "--m", "3,6", "--methods", "frost,uniform", "--out", str(bench)]) == 0
    rows = json.loads((bench / "results.json").read_text())["rows"]
    assert len(rows) == 2 * 2 * 3 and all(np.isfinite(r["mse"]) for r in rows)


# ----- bad files: one line, exit 2, nothing written ----------------------------------------------
def _anisotropic(fields: dict) -> dict:
    out = dict(fields)
    out["phi_i"] = np.array([0.0, 2.0, 4.0], np.float32)
    for name in ("vndf", "luminance", "rgb"):
        out[name] = np.ascontiguousarray(np.repeat(fields[name], 3, axis=0))
    return out


def _nan_table(fields: dict) -> dict:
    out = dict(fields)
    out["rgb"] = fields["rgb"].copy()
    out["rgb"][0, 2, 1, 5, 5] = np.nan
    return out


@pytest.mark.parametrize("damage, message", [
    (lambda raw, f: encode(_anisotropic(f)), "anisotropic file: phi_i has 3 entries, expected at most 2"),
    (lambda raw, f: raw[:len(raw) // 2], "the file has"),
    (lambda raw, f: b"tensor_fxle\x00" + raw[12:], "not a tensor file: header b'tensor_fxle\\x00', expected b'tensor_file\\x00'"),
    (lambda raw, f: encode(_nan_table(f)), "field 'rgb' holds 1 NaN or infinite values; expected finite numbers"),
], ids=["anisotropic", "truncated", "magic", "nan"])
def test_a_bad_file_is_refused_in_one_line_with_exit_2(folder, tmp_path, capsys, damage, message):
    raw = (folder / "gold.bsdf").read_bytes()
    bad = tmp_path / "bad.bsdf"
    bad.write_bytes(damage(raw, read_tensor_file(folder / "gold.bsdf")))
    out = tmp_path / "bad.binary"
    assert main(["convert", "--dataset", f"rgl:{bad}", "--material", "bad", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err and str(bad) in err
    assert not out.exists()


# ----- capture on the simulated rig and compare --------------------------------------------------
def test_capture_on_the_simulated_rig_sees_an_rgl_file_and_compare_reads_it(folder, tmp_path, capsys):
    from test_session import GRID, small_plan, write_rig

    assert GRID == SMALL  # the session tests' model grid: the file's values on its cells are the truth
    write_tensor_file(tmp_path / "red-plastic-50.bsdf", limited_fields(read_tensor_file(folder / "red-plastic.bsdf")))
    rig = write_rig(tmp_path / "rig.yaml")
    plan, _ = small_plan(rig, 5, tmp_path / "plan.json")
    session = tmp_path / "s"
    material = f"rgl:{tmp_path / 'red-plastic-50.bsdf'}:red-plastic-50"
    assert main(["capture", "--rig", str(rig), "--plan", str(plan), "--session", str(session),
                 "--material", material, "--no-progress", "--speedup", "50"]) == 0
    assert f"error against the ground truth {material}" in capsys.readouterr().out
    truth = json.loads((session / "report.json").read_text())["ground_truth"]
    assert np.isfinite(truth["log_relative_mse"]) and np.isfinite(truth["log_relative_mse_exact_samples"])
    # compare reads a tensor file as the BRDF it is (cells without data left out of its numbers)
    assert main(["compare", str(session), str(tmp_path / "red-plastic-50.bsdf"), "--out", str(tmp_path / "c.png"),
                 "--json"]) == 0
    pair = json.loads(capsys.readouterr().out)["pairs"][0]
    # on the session's grid, over the file's measured cells: the reconstruction's error against it
    assert pair["log_relative_mse"] is not None and 0 < pair["log_relative_mse"] < 5
