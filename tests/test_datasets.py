"""Datasets behind one interface: Neural-BRDF networks, the built-in library, MERL folders,
the tabulation cache and multi-dataset selection."""
from __future__ import annotations

import os
import re

import numpy as np
import pytest

from goniofrost.datasets import DatasetError, UnknownMaterialError, open_dataset, parse_material_spec
from goniofrost.datasets.builtin import LIBRARY_VERSION, BuiltinDataset
from goniofrost.datasets.tabulate import cache_entry, collect_materials, tabulate_cached
from goniofrost.core.grid import MerlGrid, dirs_to_half_diff
from goniofrost.brdf.merl_file import MerlFileError, valid_to_full, write_merl

SMALL = MerlGrid(30, 30, 60)
BUILTIN = BuiltinDataset()
NAMES = BUILTIN.names()


# ----- Neural-BRDF networks ------------------------------------------------------------------
@pytest.mark.parametrize("name, expected, rtol", [
    ("white-diffuse-bball", (0.148, 0.132, 0.104), 0.01),
    ("chrome", (511, 547, 544), 0.005),
])
def test_nbrdf_readme_check_values(merl_npz, name, expected, rtol):
    value = open_dataset(f"nbrdf:{merl_npz}").evaluate(name, 0.0, 0.3, np.pi / 2)
    np.testing.assert_allclose(value, expected, rtol=rtol)


def test_nbrdf_batched_tabulation_equals_one_material_at_a_time(rgl_npz):
    ds = open_dataset(f"nbrdf:{rgl_npz}")
    names = ds.names()[:3]
    together = ds.tabulate(names, SMALL)
    for i, name in enumerate(names):
        np.testing.assert_allclose(together[i], ds.tabulate([name], SMALL)[0], rtol=1e-6)
    assert together.dtype == np.float32 and together.shape == (3, SMALL.n_valid, 3)


def test_unreadable_archive_and_unknown_names(tmp_path):
    (tmp_path / "x.npz").write_bytes(b"not a zip")
    with pytest.raises(DatasetError, match=r"x\.npz: not a readable \.npz archive \(not in NumPy's \.npz format\)$"):
        open_dataset(f"nbrdf:{tmp_path / 'x.npz'}").names()
    with pytest.raises(DatasetError, match=r"unknown dataset spec 'bultin'.*did you mean builtin\?"):
        open_dataset("bultin")
    with pytest.raises(UnknownMaterialError, match=r"unknown material 'golld' in dataset 'builtin'; did you mean gold"):
        parse_material_spec("builtin:golld")


# ----- built-in library ----------------------------------------------------------------------
def test_builtin_library_is_large_named_and_versioned():
    assert len(NAMES) >= 60 and len(set(NAMES)) == len(NAMES)
    assert all(re.fullmatch(r"[a-z]+(-[a-z]+)*", n) for n in NAMES)
    for name in ("red-plastic", "gold", "chrome", "white-diffuse", "black-rubber", "blue-satin-fabric"):
        assert name in NAMES
    ids = {BUILTIN.content_id(n) for n in NAMES}
    assert len(ids) == len(NAMES) and all(LIBRARY_VERSION in i for i in ids)


def test_builtin_values_are_on_the_merl_scale():
    white = BUILTIN.evaluate("white-diffuse", [0.1, 0.5], [0.2, 0.9], [0.3, 2.0])
    np.testing.assert_allclose(white, 0.8 / np.pi)  # a white diffuse is about 0.25 1/sr
    chrome_peak = BUILTIN.evaluate("chrome", 0.0, 0.3, 0.0)
    assert np.all((chrome_peak > 100) & (chrome_peak < 1000))  # near-mirror, yet finite
    red = BUILTIN.evaluate("red-plastic", 0.6, 0.4, 1.0)
    assert red[0] > 5 * red[1]  # coloured


def test_builtin_is_finite_and_non_negative_on_a_grid():
    table = BUILTIN.tabulate(NAMES, SMALL)
    assert table.shape == (len(NAMES), SMALL.n_valid, 3)
    assert np.all(np.isfinite(table)) and np.all(table >= 0)
    assert np.all(table.max(axis=1) > 0)


def random_pairs(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(2, n, 3))
    v[..., 2] = np.abs(v[..., 2]) + 1e-3
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    return v[0], v[1]


def test_builtin_is_reciprocal():
    w_i, w_o = random_pairs(400)
    # concentrate some pairs near the specular direction, where lobes are sharp
    near = np.stack([-w_i[:50, 0], -w_i[:50, 1], w_i[:50, 2]], -1) + 0.01 * w_o[:50]
    w_o[:50] = near / np.linalg.norm(near, axis=-1, keepdims=True)
    forward = BUILTIN._evaluate_many(NAMES, *dirs_to_half_diff(w_i, w_o))
    backward = BUILTIN._evaluate_many(NAMES, *dirs_to_half_diff(w_o, w_i))
    np.testing.assert_allclose(forward, backward, rtol=1e-9, atol=1e-12)
    assert forward.max() > 10  # the sharp lobes were probed


def albedo(dataset, names, theta_i: float, n_t: int = 96, n_phi: int = 64) -> np.ndarray:
    """Directional albedo (len(names), 3): integral of f cos theta_o over the hemisphere.

    Integrated over half vectors (polar angle pi/2 t^2, Gauss-Legendre in t, dense near the
    normal where specular peaks are) with d omega_o = 4 (w_i . h) d omega_h.
    """
    t, wt = np.polynomial.legendre.leggauss(n_t)
    t, wt = (t + 1) / 2, wt / 2
    th, phi = np.pi / 2 * t ** 2, (np.arange(n_phi) + 0.5) * 2 * np.pi / n_phi
    weight = np.repeat(np.sin(th) * np.pi * t * wt * 2 * np.pi / n_phi, n_phi)
    th, phi = np.repeat(th, n_phi), np.tile(phi, n_t)
    h = np.stack([np.sin(th) * np.cos(phi), np.sin(th) * np.sin(phi), np.cos(th)], -1)
    w_i = np.array([np.sin(theta_i), 0.0, np.cos(theta_i)])
    cos_d = h @ w_i
    w_o = 2 * cos_d[:, None] * h - w_i
    ok = (cos_d > 0) & (w_o[:, 2] > 0)
    values = dataset._evaluate_many(names, *dirs_to_half_diff(np.broadcast_to(w_i, w_o.shape)[ok], w_o[ok]))
    return np.einsum("mnc,n->mc", values, (w_o[ok, 2] * 4 * cos_d[ok] * weight[ok]))


def test_albedo_integrator_is_exact_on_a_lambertian():
    np.testing.assert_allclose(albedo(BUILTIN, ["white-diffuse"], 0.7), [[0.8, 0.8, 0.8]], rtol=1e-4)


@pytest.mark.parametrize("theta_i_deg", [0, 40, 70, 85])
def test_builtin_conserves_energy(theta_i_deg):
    a = albedo(BUILTIN, NAMES, np.radians(theta_i_deg))
    worst = int(np.argmax(a.max(axis=1)))
    assert a.max() <= 1.0, f"{NAMES[worst]} reflects {a[worst]} at theta_i = {theta_i_deg} deg"
    assert a.min() > 0.0


# ----- seeded random analytic materials (builtin-random:SEED:COUNT) -----------------------------
RANDOM = open_dataset("builtin-random:3:40")  # 40 draws: every family (checked below)


def test_random_materials_are_seeded_nested_and_none_of_the_library():
    from goniofrost.datasets.builtin import FAMILIES, LIBRARY, random_library

    first = random_library(3, 40)
    assert first == random_library(3, 40) and list(random_library(3, 7).items()) == list(first.items())[:7]
    assert random_library(4, 40) != first
    assert {n.split("-", 2)[2] for n in first} == set(FAMILIES)
    assert not set(first.values()) & set(LIBRARY.values()) and not set(first) & set(LIBRARY)
    assert RANDOM.names() == list(first) and RANDOM.spec == "builtin-random:3:40"
    dataset, name = parse_material_spec("builtin-random:3:40:r3-002-" + RANDOM.names()[1].split("-", 2)[2])
    assert name == RANDOM.names()[1] and dataset.content_id(name) == RANDOM.content_id(name)


def test_random_materials_are_finite_reciprocal_and_conserve_energy():
    names = RANDOM.names()
    table = RANDOM.tabulate(names, SMALL)
    assert np.all(np.isfinite(table)) and np.all(table >= 0) and np.all(table.max(axis=1) > 0)
    w_i, w_o = random_pairs(300, seed=1)
    np.testing.assert_allclose(RANDOM._evaluate_many(names, *dirs_to_half_diff(w_i, w_o)),
                               RANDOM._evaluate_many(names, *dirs_to_half_diff(w_o, w_i)), rtol=1e-9, atol=1e-12)
    for theta_i_deg in (0, 70, 85):
        a = albedo(RANDOM, names, np.radians(theta_i_deg))
        assert 0.0 < a.min() and a.max() <= 1.0, f"{names[int(np.argmax(a.max(axis=1)))]} at {theta_i_deg} deg"


@pytest.mark.parametrize("spec", ["builtin-random", "builtin-random:3", "builtin-random:x:5", "builtin-random:3:0",
                                  "builtin-random:-1:5", "builtin-random:3:1001"])
def test_a_bad_random_spec_says_what_it_expects(spec):
    with pytest.raises(DatasetError, match=r"expected builtin-random:SEED:COUNT, SEED an integer >= 0 and COUNT an "
                                           r"integer 1-1000, e\.g\. builtin-random:1:24"):
        open_dataset(spec)


# ----- MERL folders ----------------------------------------------------------------------------
@pytest.fixture()
def merl_dir(tmp_path):
    """Two builtin materials written as small-grid MERL files."""
    names = ["gold", "red-plastic"]
    values = BUILTIN.tabulate(names, SMALL).astype(np.float64)
    for name, table in zip(names, values):
        write_merl(tmp_path / f"{name}.binary", valid_to_full(table, SMALL), SMALL)
    return tmp_path, names, values


def test_merl_dir_round_trip(merl_dir):
    folder, names, values = merl_dir
    ds = open_dataset(f"merl:{folder}")
    assert ds.names() == sorted(names)
    np.testing.assert_allclose(ds.tabulate(names, SMALL), values, rtol=1e-15)
    # evaluation at any angles inside a cell gives that cell's value
    cell = SMALL.valid_cells[1234]
    th, td, pd = SMALL.flat_angles(cell)
    inside = ds.evaluate("gold", th * 1.001 + 1e-6, td + 0.01, pd + 0.02)
    np.testing.assert_allclose(inside, values[0, 1234], rtol=1e-15)
    assert ds.content_id("gold") != ds.content_id("red-plastic")


def test_merl_dir_missing_valid_cells_are_an_error(merl_dir):
    folder, names, values = merl_dir
    full = valid_to_full(values[0], SMALL)
    full[SMALL.valid_cells[[7, 9]]] = np.nan
    write_merl(folder / "holey.binary", full, SMALL)
    i = tuple(int(v) for v in SMALL.unravel(SMALL.valid_cells[7]))
    with pytest.raises(DatasetError, match=re.escape(
            f"holey.binary: valid cells without a value (negative in the file): 2, first at (i_th, i_td, i_pd) = {i}")):
        open_dataset(f"merl:{folder}").tabulate(["holey"], SMALL)


def test_merl_dir_bad_folders_and_files(tmp_path):
    with pytest.raises(DatasetError, match=r"nowhere: no such folder"):
        open_dataset(f"merl:{tmp_path / 'nowhere'}").names()
    with pytest.raises(DatasetError, match=r"no \*\.binary files found"):
        open_dataset(f"merl:{tmp_path}").names()
    (tmp_path / "broken.binary").write_bytes(b"\0" * 20)
    with pytest.raises(MerlFileError, match=r"broken\.binary: wrong MERL header"):
        open_dataset(f"merl:{tmp_path}").tabulate(["broken"], SMALL)


# ----- cache -----------------------------------------------------------------------------------
class CountingBuiltin(BuiltinDataset):
    """The built-in library, counting how many materials it really tabulates."""

    def __init__(self) -> None:
        super().__init__()
        self.computed: list[str] = []

    def tabulate(self, names=None, grid=SMALL, cells=None):
        self.computed += list(names)
        return super().tabulate(names, grid, cells)


def test_cache_hit_is_identical_and_does_not_recompute(tmp_path, monkeypatch):
    # a cache of its own: other tests in this process may have tabulated these materials already
    monkeypatch.setenv("GONIOFROST_CACHE", str(tmp_path / "cache"))
    first_ds, second_ds = CountingBuiltin(), CountingBuiltin()
    names = ["copper", "green-felt"]
    first = tabulate_cached(first_ds, names, SMALL)
    entry = cache_entry(first_ds, "copper", SMALL)
    assert first_ds.computed == names and entry.is_file()
    assert entry.parent.parent == __import__("goniofrost.core.cache").core.cache.cache_dir()
    assert str(entry).startswith(os.environ["GONIOFROST_CACHE"])
    second = tabulate_cached(second_ds, names, SMALL)
    assert second_ds.computed == []
    assert np.array_equal(first, second)
    np.testing.assert_array_equal(first, BUILTIN.tabulate(names, SMALL))
    # a damaged entry is recomputed, not trusted
    entry.write_bytes(b"garbage")
    np.testing.assert_array_equal(tabulate_cached(second_ds, ["copper"], SMALL)[0], first[0])
    assert second_ds.computed == ["copper"]


def test_cache_key_follows_the_content(merl_dir):
    folder, names, values = merl_dir
    ds = open_dataset(f"merl:{folder}")
    before = tabulate_cached(ds, ["gold"], SMALL)[0]
    write_merl(folder / "gold.binary", valid_to_full(values[0] * 2.0, SMALL), SMALL)
    after = tabulate_cached(open_dataset(f"merl:{folder}"), ["gold"], SMALL)[0]
    np.testing.assert_allclose(after, 2.0 * before, rtol=1e-6)


# ----- several datasets ------------------------------------------------------------------------
def test_collect_materials_labels_clashes_and_filters(merl_dir):
    folder, names, _ = merl_dir
    specs = ["builtin", f"merl:{folder}"]
    everything = collect_materials(specs)
    labels = [m.label for m in everything]
    assert len(labels) == len(NAMES) + 2 and len(set(labels)) == len(labels)
    assert "builtin:gold" in labels and f"merl:{folder}:gold" in labels and "gold" not in labels
    assert "chrome" in labels
    only = collect_materials(specs, only=["gold", "chrome"])
    assert [m.label for m in only] == ["builtin:gold", "chrome", f"merl:{folder}:gold"]
    assert [m.label for m in collect_materials(specs, only=["gold"], exclude=["builtin:gold"])] == [f"merl:{folder}:gold"]
    with pytest.raises(UnknownMaterialError, match=r"--exclude 'chrom': no such material in the datasets; did you mean chrome"):
        collect_materials(specs, exclude=["chrom"])
    with pytest.raises(DatasetError, match="no materials left"):
        collect_materials(["builtin"], exclude=NAMES)


def test_a_simulated_material_is_reciprocal_and_the_table_at_its_cells(rgl_npz):
    """material_brdf folds phi_d into [0, pi) as the grid's cells do: RGL acrylic_felt_white's
    network gives 0.00028 1/sr at the cell (16, 86, 179) and 26.5 at its reciprocal (phi_d -1 deg);
    the simulated material now gives the table's value both ways."""
    from goniofrost.core.grid import FULL_GRID
    from goniofrost.datasets import material_brdf, parse_material_spec

    spec = f"nbrdf:{rgl_npz}:acrylic_felt_white_rgb"
    brdf = material_brdf(spec)[1]
    dataset, name = parse_material_spec(spec)
    cells = np.array([[16, 86, 179], [0, 86, 0], [40, 30, 100]])
    flat = FULL_GRID.flat_index(*cells.T)
    table = dataset.tabulate([name], FULL_GRID, cells=flat)[0].astype(np.float64)
    w_i, w_o = FULL_GRID.cell_directions(flat)
    forward_, reverse = np.asarray(brdf(w_i, w_o)), np.asarray(brdf(w_o, w_i))
    assert np.allclose(forward_, table, rtol=1e-6, atol=0) and np.allclose(reverse, table, rtol=1e-6, atol=0)
    assert table[0, 0] < 1e-3 < 20.0 < dataset.evaluate(name, *np.radians([2.8444, 86.0, -1.0]))[0]
