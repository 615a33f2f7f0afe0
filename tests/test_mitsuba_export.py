"""Export to Mitsuba 3's RGL tensor format, checked with the real Mitsuba 3 (scalar_rgb).

The accuracy and sampling tests use three built-in materials on the full MERL grid (diffuse
terracotta, glossy red-plastic, metallic gold), each exported once per module. Format, warp and
NDF tests use small grids and small resolutions.
"""
from __future__ import annotations

import contextlib
import io
import struct
from pathlib import Path

import mitsuba as mi
import numpy as np
import pytest

from goniofrost.app.cli import main
from goniofrost.brdf import marginal2d
from goniofrost.brdf import mitsuba_export as me
from goniofrost.brdf.mitsuba_probe import eval_pairs, load_bsdf, pdf_integral, sampled_weights, table_albedo
from goniofrost.brdf.merl_file import read_merl, valid_to_full, write_merl
from goniofrost.brdf.rgl_tensor import TensorFileError, decode, encode, read_tensor_file
from goniofrost.core.grid import FULL_GRID, MerlGrid
from goniofrost.datasets import open_dataset
from goniofrost.datasets.tabulate import tabulate_cached

from conftest import train_once

mi.set_variant("scalar_rgb")

SMALL = MerlGrid(30, 30, 60)
SMALL_OPTIONS = me.ExportOptions(theta_i=6, ndf=31, vndf_theta=31, vndf_phi=16, sample=12)
MATERIALS = {"diffuse": "terracotta", "glossy": "red-plastic", "metallic": "gold"}
MAX_THETA = np.radians(75.0)
INCIDENT_DEG = (0.0, 30.0, 60.0, 75.0)


@pytest.fixture(autouse=True)
def scalar_rgb():
    """Mitsuba in the scalar RGB variant this module's own ``mi`` calls assume: a test of another
    module run before in the same process may have left another one (the scene tests' TabulatedScene
    sets llvm_ad_rgb, where mi.Point2f of float64 values fails)."""
    mi.set_variant("scalar_rgb")


def builtin_table(name: str, grid: MerlGrid) -> np.ndarray:
    """A built-in material as a (grid.size, 3) table in 1/sr, NaN on invalid cells."""
    values = tabulate_cached(open_dataset("builtin"), [name], grid, progress=False)[0]
    return valid_to_full(values.astype(np.float64), grid)


def surface(w_i) -> mi.SurfaceInteraction3f:
    si = mi.SurfaceInteraction3f()
    si.wi = mi.Vector3f(*np.asarray(w_i, dtype=float))
    return si


def cap_directions(rng, n: int) -> np.ndarray:
    """n directions uniform on the spherical cap theta <= 75 degrees."""
    cos = rng.uniform(np.cos(MAX_THETA), 1.0, n)
    phi = rng.uniform(0.0, 2 * np.pi, n)
    sin = np.sqrt(1.0 - cos ** 2)
    return np.stack([sin * np.cos(phi), sin * np.sin(phi), cos], -1)


@pytest.fixture(scope="module")
def exported(full_grid_exports):
    """kind -> (prepared table, .bsdf path) of the three materials, full grid, default options (the
    files: conftest's full_grid_exports, export_mitsuba's of each material)."""
    return {kind: (me.prepared_table(builtin_table(name, FULL_GRID), FULL_GRID), full_grid_exports[name])
            for kind, name in MATERIALS.items()}


@pytest.fixture(scope="module")
def small_export(tmp_path_factory):
    """(prepared table, fields, path) of red-plastic on the small grid with small resolutions."""
    table = builtin_table("red-plastic", SMALL)
    path = tmp_path_factory.mktemp("small") / "small.bsdf"
    fields = me.export_mitsuba(path, table, SMALL, SMALL_OPTIONS)
    return me.prepared_table(table, SMALL), fields, path


# ----- the tensor file format ------------------------------------------------------------------
def test_tensor_file_bytes_equal_mitsubas_own_writer(tmp_path):
    fields = {"description": "héllo", "theta_i": np.linspace(0, 1.5, 5, dtype=np.float32),
              "flags": np.arange(6, dtype=np.uint8).reshape(2, 3), "big": np.ones((1, 2, 3), np.float64)}
    with contextlib.redirect_stdout(io.StringIO()):  # tensor_io.write prints a line
        mi.tensor_io.write(str(tmp_path / "mi.bsdf"), **fields)
    assert encode(fields) == (tmp_path / "mi.bsdf").read_bytes()
    back = decode(encode(fields))
    assert list(back) == list(fields) and bytes(back["description"]) == "héllo".encode()
    np.testing.assert_array_equal(back["flags"], fields["flags"])
    assert back["big"].dtype == np.float64 and back["big"].shape == (1, 2, 3)


def test_tensor_file_layout_field_by_field():
    raw = encode({"ab": np.array([1.5, 2.5], np.float32), "c": np.array([[7]], np.uint8)})
    assert raw[:12] == b"tensor_file\x00" and raw[12:14] == bytes([1, 0])
    assert struct.unpack_from("<I", raw, 14) == (2,)
    # field "ab": name length, name, rank 1, dtype 10 (float32), offset, shape (2,)
    # (23 bytes; the header ends at 18 + 23 + 30 = 71, so the data starts at the 8-aligned 72)
    assert struct.unpack_from("<H2sHBQQ", raw, 18) == (2, b"ab", 1, 10, 72, 2)
    # field "c": rank 2, dtype 1 (uint8), offset 80 (right after the 8 bytes of "ab"), shape (1, 1)
    assert struct.unpack_from("<H1sHBQQQ", raw, 41) == (1, b"c", 2, 1, 80, 1, 1)
    assert raw[71:72] == bytes(1)  # zero padding up to the 8-byte boundary
    assert np.frombuffer(raw, np.float32, 2, 72).tolist() == [1.5, 2.5] and raw[80:] == bytes([7])


@pytest.mark.parametrize("mutate, message", [
    (lambda raw: raw[:10], "truncated tensor file: 10 bytes, expected at least 18"),
    (lambda raw: b"tensor_fild\x00" + raw[12:], "not a tensor file: header b'tensor_fild\\x00'"),
    (lambda raw: raw[:12] + bytes([2, 0]) + raw[14:], "tensor file version (2, 0), expected (1, 0)"),
    (lambda raw: raw[:24] + bytes([12]) + raw[25:], "field 'ab': dtype code 12, expected one of 1..11"),
    (lambda raw: raw[:-1], "field 'c' needs bytes 80..81, the file has 80"),
])
def test_a_damaged_tensor_file_is_refused_with_the_reason(tmp_path, mutate, message):
    path = tmp_path / "x.bsdf"
    path.write_bytes(mutate(encode({"ab": np.array([1.5, 2.5], np.float32), "c": np.array([[7]], np.uint8)})))
    with pytest.raises(TensorFileError) as info:
        read_tensor_file(path)
    assert str(info.value).startswith(f"{path}: {message}")


# ----- the warp, the NDF, sigma and the incident elevations ------------------------------------
def test_numpy_warp_is_mitsubas_marginal2d():
    rng = np.random.default_rng(0)
    data = rng.uniform(0.0, 1.0, (3, 7, 11))
    data[1, 2:4] = 0.0  # empty rows: the constant-segment branch
    points = rng.uniform(0.0, 1.0, (3, 300, 2))
    warped, pdf = marginal2d.sample(marginal2d.build(data), points)
    for s in range(3):
        theirs = mi.MarginalContinuous2D0(data[s].astype(np.float32))
        for k in range(300):
            position, density = theirs.sample(mi.Point2f(*points[s, k]))
            np.testing.assert_allclose(np.array(position), warped[s, k], atol=2e-5)
            assert density == pytest.approx(pdf[s, k], rel=2e-5)


def test_projected_area_of_known_distributions():
    u = np.linspace(0.0, 1.0, 181)
    area = me.projected_area_matrix(u)
    theta = me.u_to_theta(u)
    uniform = area @ np.full(u.size, 1 / np.pi)  # D = 1/pi: sigma(0) = 1, sigma(90 deg) = 1/2
    assert uniform[0] == pytest.approx(1.0, rel=1e-4) and uniform[-1] == pytest.approx(0.5, rel=1e-3)
    alpha = 0.3  # GGX: sigma = cos theta (1 + Lambda), Lambda = (sqrt(1 + a^2 tan^2) - 1) / 2
    ggx = area @ ggx_ndf(theta, alpha)
    inside = theta < np.radians(85)
    expected = np.cos(theta) * (1 + 0.5 * (np.sqrt(1 + alpha ** 2 * np.tan(theta) ** 2) - 1))
    np.testing.assert_allclose(ggx[inside], expected[inside], rtol=3e-3)


def ggx_ndf(theta, alpha):
    t2 = np.tan(theta) ** 2
    return alpha ** 2 / (np.pi * np.cos(theta) ** 4 * (alpha ** 2 + t2) ** 2)


def test_power_iteration_recovers_the_ndf_of_a_microfacet_table():
    # f = D(h) G(wi, wo) / (4 cos cos) with G = min(G1, G1): fully correlated at retro-reflection,
    # the paper's assumption, so the retro slice determines D exactly (up to the grid).
    grid, alpha = MerlGrid(90, 4, 4), 0.2
    w_i, w_o = grid.cell_directions(np.arange(grid.size))
    h = (w_i + w_o) / np.linalg.norm(w_i + w_o, axis=-1, keepdims=True)

    def g1(w):
        tan2 = (1 - w[..., 2] ** 2) / w[..., 2] ** 2
        return 2 / (1 + np.sqrt(1 + alpha ** 2 * tan2))

    with np.errstate(all="ignore"):
        f = ggx_ndf(np.arccos(h[..., 2]), alpha) * np.minimum(g1(w_i), g1(w_o)) / (4 * w_i[..., 2] * w_o[..., 2])
    table = np.where(grid.valid_mask[:, None], f[:, None] * np.ones(3), np.nan)
    ndf = me.recover_ndf(me.prepared_table(table, grid), grid, me.ExportOptions(ndf=91))
    theta = me.u_to_theta(ndf.u)
    inside = theta < np.radians(80)
    np.testing.assert_allclose(ndf.d[inside], ggx_ndf(theta, alpha)[inside], rtol=0.01)
    assert ndf.sigma[0] == pytest.approx(1.0, abs=1e-6)


def test_incident_elevations_space_sigma_evenly():
    u = np.linspace(0, 1, 91)
    sigma = np.cos(me.u_to_theta(u)) * 0.9 + 0.1
    ndf = me.Ndf(u, np.ones(91, np.float32), sigma.astype(np.float32), np.ones(91))
    theta = me.incident_elevations(ndf, 10)
    assert theta[0] == 0.0 and theta[-1] == pytest.approx(np.pi / 2)
    at = np.interp(me.theta_to_u(theta), u, sigma)
    np.testing.assert_allclose(at, np.linspace(1.0, 0.1, 10), atol=2e-4)
    flat = me.Ndf(u, np.ones(91, np.float32), np.ones(91, np.float32), np.ones(91))
    np.testing.assert_allclose(me.incident_elevations(flat, 5), np.linspace(0, np.pi / 2, 5))


def test_valid_cells_of_each_column_are_a_prefix_along_theta_d():
    # what the fill of invalid cells (the last valid cell along theta_d) relies on
    valid = FULL_GRID.valid_mask.reshape(FULL_GRID.shape)
    count = valid.sum(axis=1, keepdims=True)
    np.testing.assert_array_equal(valid, np.arange(90)[None, :, None] < count)
    assert count.min() >= 1


# ----- the fields -------------------------------------------------------------------------------
def test_fields_have_the_names_dtypes_and_shapes_measured_cpp_checks(small_export):
    _, fields, path = small_export
    o = SMALL_OPTIONS
    assert list(fields) == ["description", "phi_i", "theta_i", "ndf", "sigma", "vndf", "luminance", "rgb", "jacobian"]
    expected = {"phi_i": (np.float32, (1,)), "theta_i": (np.float32, (o.theta_i,)),
                "ndf": (np.float32, (2, o.ndf)), "sigma": (np.float32, (2, o.ndf)),
                "vndf": (np.float32, (1, o.theta_i, o.vndf_phi, o.vndf_theta)),
                "luminance": (np.float32, (1, o.theta_i, o.sample, o.sample)),
                "rgb": (np.float32, (1, o.theta_i, 3, o.sample, o.sample)), "jacobian": (np.uint8, (1,))}
    stored = read_tensor_file(path)
    for name, (dtype, shape) in expected.items():
        assert stored[name].dtype == dtype and stored[name].shape == shape, name
        np.testing.assert_array_equal(stored[name], fields[name])
    assert bytes(stored["description"]).decode().startswith("isotropic BRDF from BRDF, exported by goniofrost")
    assert stored["jacobian"][0] == 1 and stored["phi_i"][0] == 0.0
    assert stored["theta_i"][0] == 0.0 and stored["theta_i"][-1] == np.float32(np.pi / 2)
    assert np.all(np.diff(stored["theta_i"]) > 0)
    np.testing.assert_array_equal(stored["ndf"][0], stored["ndf"][1])  # isotropic: constant in phi


def test_export_is_deterministic(small_export, tmp_path):
    table, _, path = small_export
    me.export_mitsuba(tmp_path / "again.bsdf", builtin_table("red-plastic", SMALL), SMALL, SMALL_OPTIONS)
    assert (tmp_path / "again.bsdf").read_bytes() == path.read_bytes()


def test_paper_options_store_the_vndf_of_d_and_the_luminance_of_rgb():
    table = me.prepared_table(builtin_table("gold", SMALL), SMALL)
    options = me.ExportOptions(theta_i=4, ndf=31, vndf_theta=31, vndf_phi=16, sample=8, warp_exponent=1.0,
                               uniform_share=0.0)
    fields = me.build_fields(table, SMALL, options)
    u_t, u_p = np.linspace(0, 1, 31), np.linspace(0, 1, 16)
    theta_m, phi = me.u_to_theta(u_t)[None, :], (2 * u_p[:, None] - 1) * np.pi
    for k, theta_i in enumerate(fields["theta_i"].astype(np.float64)):
        cosine = np.maximum(np.sin(theta_i) * np.sin(theta_m) * np.cos(phi) + np.cos(theta_i) * np.cos(theta_m), 0)
        paper = fields["ndf"][0] * cosine * 2 * np.pi ** 2 * u_t * np.sin(theta_m)
        ratio = fields["vndf"][0, k][paper > 1e-6 * paper.max()] / paper[paper > 1e-6 * paper.max()]
        np.testing.assert_allclose(ratio, ratio[0], rtol=1e-5)
    luminance = np.einsum("c,pkcyx->pkyx", me.LUMINANCE, fields["rgb"].astype(np.float64))
    np.testing.assert_allclose(fields["luminance"], luminance, rtol=1e-5, atol=1e-12)


def test_mitsuba_eval_at_every_node_is_the_table_value(small_export):
    # the node (theta_i, s) stands for w_o = reflect(w_i, m(s)): Mitsuba must return f cos theta_o
    table, fields, path = small_export
    bsdf = load_bsdf(path)
    warp = marginal2d.build(fields["vndf"][0].astype(np.float64))
    s = np.linspace(0.0, 1.0, SMALL_OPTIONS.sample)[1:-1]  # inner nodes (edges are clipped)
    points = np.stack(np.broadcast_arrays(s[None, :], s[:, None]), -1).reshape(1, -1, 2)
    u_m, _ = marginal2d.sample(warp, np.repeat(points, SMALL_OPTIONS.theta_i, axis=0))
    checked = 0
    for k, theta_i in enumerate(fields["theta_i"].astype(np.float64)[:-1]):  # theta_i < 90 deg
        m = me._normal(u_m[k, :, 0], u_m[k, :, 1])
        w_i = me.elevation_dir(theta_i)
        w_o = 2 * (m @ w_i)[:, None] * m - w_i
        keep = w_o[:, 2] > 0.05
        w_i = np.broadcast_to(w_i, w_o.shape)[keep]
        expected = me.lookup(table, SMALL, w_i, w_o[keep]) * w_o[keep, 2:3]
        np.testing.assert_allclose(eval_pairs(bsdf, w_i, w_o[keep]), expected, rtol=2e-3, atol=1e-7)
        checked += int(keep.sum())
    assert checked > 300


# ----- Mitsuba against the table (full grid) ---------------------------------------------------
@pytest.mark.parametrize("kind", list(MATERIALS))
def test_mitsuba_eval_matches_the_table_at_random_directions(exported, kind):
    table, path = exported[kind]
    rng = np.random.default_rng(7)
    w_i, w_o = cap_directions(rng, 3000), cap_directions(rng, 3000)
    expected = me.lookup(table, FULL_GRID, w_i, w_o) * w_o[:, 2:3]
    rel = np.abs(eval_pairs(load_bsdf(path), w_i, w_o) - expected) / expected
    assert np.median(rel) <= 0.03 and np.percentile(rel, 95) <= 0.15


@pytest.mark.parametrize("kind", list(MATERIALS))
def test_white_furnace_mean_sampled_weight_is_the_albedo(exported, kind):
    table, path = exported[kind]
    bsdf, rng = load_bsdf(path), np.random.default_rng(3)
    for degrees in INCIDENT_DEG:
        theta_i = np.radians(degrees)
        weights = sampled_weights(bsdf, me.elevation_dir(theta_i), rng.random((20000, 2)))
        np.testing.assert_allclose(weights.mean(axis=0), table_albedo(table, FULL_GRID, theta_i), rtol=0.02,
                                   err_msg=f"theta_i {degrees} deg")


@pytest.mark.parametrize("kind", list(MATERIALS))
def test_pdf_integrates_to_one_and_is_the_sampling_density(exported, kind):
    _, path = exported[kind]
    bsdf, ctx = load_bsdf(path), mi.BSDFContext()
    for degrees in INCIDENT_DEG:
        assert pdf_integral(bsdf, np.radians(degrees)) == pytest.approx(1.0, abs=0.02), f"theta_i {degrees} deg"
    si, rng = surface(me.elevation_dir(np.radians(60.0))), np.random.default_rng(5)
    for u in rng.random((200, 2)):  # sample's pdf and weight are pdf() and eval() / pdf()
        sample, value = bsdf.sample(ctx, si, 0.5, mi.Point2f(*u))
        if sample.wo[2] > 0 and sample.pdf > 0:  # below the horizon: weight 0, pdf() 0
            assert bsdf.pdf(ctx, si, sample.wo) == pytest.approx(sample.pdf, rel=1e-3)
            np.testing.assert_allclose(np.array(value), np.array(bsdf.eval(ctx, si, sample.wo)) / sample.pdf, rtol=1e-3)


# ----- the command and bad input ---------------------------------------------------------------
def small_binary(path) -> None:
    write_merl(path, builtin_table("red-plastic", SMALL), SMALL)


def test_export_command_writes_a_file_mitsuba_loads(tmp_path, capsys):
    small_binary(tmp_path / "m.binary")
    assert main(["export", str(tmp_path / "m.binary"), "--format", "mitsuba", "--theta-i", "8", "--sample", "16"]) == 0
    out = tmp_path / "m.bsdf"  # the default name: beside the input
    assert capsys.readouterr().out.startswith(f"wrote {out}: ")
    fields = read_tensor_file(out)
    assert fields["rgb"].shape == (1, 8, 3, 16, 16)
    assert bytes(fields["description"]).decode().startswith(f"isotropic BRDF from {tmp_path / 'm.binary'}")
    value = load_bsdf(out).eval(mi.BSDFContext(), surface([0.0, 0.0, 1.0]), mi.Vector3f(0.6, 0.0, 0.8))
    assert np.all(np.array(value) > 0)


def stored(path) -> np.ndarray:
    return np.fromfile(path, "<f8", offset=12)


@pytest.mark.parametrize("damage, message", [
    (lambda p: p.write_bytes(p.read_bytes()[:-8]), "truncated MERL file: 1296004 bytes, expected 1296012 bytes"),
    (lambda p: p.write_bytes(p.read_bytes() + bytes(8)), "oversized MERL file: 1296020 bytes, expected 1296012 bytes"),
    (lambda p: p.write_bytes(p.read_bytes()[:12] + np.full(3 * SMALL.size, -1.0).tobytes()),
     f"valid cells without a value (negative in the file): {SMALL.n_valid}, first at (i_th, i_td, i_pd) = (0, 0, 0); "
     "expected a BRDF value >= 0 at every cell above the horizon"),
    (lambda p: p.write_bytes(p.read_bytes()[:12] + np.zeros(3 * SMALL.size).tobytes()),
     "no valid value: every valid cell is missing or zero"),
    (lambda p: p.write_bytes(p.read_bytes()[:12] + np.where(np.arange(3 * SMALL.size) == 40000, np.nan,
                                                            stored(p)).tobytes()),
     "cells holding NaN or inf: 1, first at (i_th, i_td, i_pd) = (22, 6, 40); expected finite values (-1 marks a missing "
     "value)"),
    (lambda p: p.write_bytes(p.read_bytes()[:12] + np.where(np.arange(3 * SMALL.size) == SMALL.size + 7, np.inf,
                                                            stored(p)).tobytes()),
     "cells holding NaN or inf: 1, first at (i_th, i_td, i_pd) = (0, 0, 7)"),
])
def test_bad_binary_exits_2_with_one_line_and_writes_nothing(tmp_path, capsys, damage, message):
    source = tmp_path / "m.binary"
    small_binary(source)
    damage(source)
    assert main(["export", str(source), "--out", str(tmp_path / "out.bsdf")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"goniofrost export: error: {source}: {message}") and err.count("\n") == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.binary"]


def test_bad_in_memory_tables_are_refused(tmp_path):
    good = builtin_table("red-plastic", SMALL)
    cases = [(np.where(np.arange(SMALL.size)[:, None] == 5, np.inf, good), "BRDF: 3 infinite values"),
             (np.where(np.arange(SMALL.size)[:, None] == int(SMALL.valid_cells[0]), -0.5, good),
              "BRDF: 3 negative values on valid cells; expected >= 0 (missing values are NaN)"),
             (np.full_like(good, np.nan), "BRDF: no valid value: every valid cell is missing or zero"),
             (good[:-1], f"BRDF: expected a BRDF table of shape ({SMALL.size}, 3), found ({SMALL.size - 1}, 3)")]
    for table, message in cases:
        with pytest.raises(me.ExportError, match=f"^{message.replace('(', '[(]').replace(')', '[)]')}"):
            me.export_mitsuba(tmp_path / "x.bsdf", table, SMALL, SMALL_OPTIONS)
    assert not (tmp_path / "x.bsdf").exists()


@pytest.mark.parametrize("args, message", [
    (["--sample", "1"], "--sample: expected an integer >= 2, found 1"),
    (["--out", "m.binary"], "--out m.binary: is the input file; expected another name such as m.bsdf"),
    (["--wavelengths", "8"], "--wavelengths: applies to the spectral formats only (--format rgl-spectral or pbrt)"),
])
def test_bad_options_exit_2(tmp_path, capsys, monkeypatch, args, message):
    monkeypatch.chdir(tmp_path)
    small_binary(tmp_path / "m.binary")
    assert main(["export", "m.binary", *args]) == 2
    assert capsys.readouterr().err == f"goniofrost export: error: {message}\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.binary"]


def test_export_reads_back_what_read_merl_reads(tmp_path):
    # the checked reader changes nothing about the values (negative stored values are missing)
    from goniofrost.brdf.merl_file import read_merl_complete

    small_binary(tmp_path / "m.binary")
    brdf, grid = read_merl_complete(tmp_path / "m.binary")
    assert grid == SMALL
    np.testing.assert_array_equal(np.isnan(brdf), np.isnan(read_merl(tmp_path / "m.binary")))
    np.testing.assert_array_equal(np.nan_to_num(brdf), np.nan_to_num(read_merl(tmp_path / "m.binary")))


# ----- capture --bsdf and demo --bsdf ----------------------------------------------------------
def capture_small_session(tmp_path, *flags) -> Path:
    """A 4-sample capture of builtin:red-plastic on a small simulated rig, with the command-line
    ``flags`` (e.g. ``--bsdf``); returns the session folder (the run must succeed)."""
    import yaml

    from goniofrost.app.demo import plan_on_rig
    from goniofrost.plan.make import PlanRequest
    from goniofrost.rig.file import load_checked_rig
    from goniofrost.core.cache import cache_path

    repo = Path(__file__).resolve().parents[1]
    rig = yaml.safe_load((repo / "config" / "rigs" / "sim.yaml").read_text())
    rig["camera"].update(exposures_s=[0.002, 0.008, 0.032, 0.128], dark_frames=1, flat_frames=1)
    rig["camera"]["intrinsics"].update(image_size_px=[192, 144], focal_px=[1900.0, 1900.0],   # a small sensor
                                       principal_point_px=[95.5, 71.5])
    (tmp_path / "rig.yaml").write_text(yaml.safe_dump(rig, sort_keys=False))
    model = train_once("four-materials", ["builtin"], only=["white-diffuse", "blue-plastic", "gold", "green-felt"],
                       grid=SMALL, k_max=12)
    request = PlanRequest(samples=4, rig=load_checked_rig(tmp_path / "rig.yaml"))
    plan = plan_on_rig(model, cache_path("models", model.info["cache_key"], ""), request, tmp_path / "plan.json")
    session = tmp_path / "s"
    assert main(["capture", "--rig", str(tmp_path / "rig.yaml"), "--plan", str(plan), "--session", str(session),
                 "--material", "builtin:red-plastic", "--speedup", "50", "--no-progress", *flags]) == 0
    return session


def test_capture_with_bsdf_writes_the_export_of_its_binary(tmp_path, capsys):
    session = capture_small_session(tmp_path, "--bsdf")
    assert capsys.readouterr().out.endswith(f"wrote {session / 'brdf.bsdf'} (for Mitsuba 3)\n")
    me.export_binary_file(session / "brdf.binary", tmp_path / "again.bsdf")
    assert (session / "brdf.bsdf").read_bytes() == (tmp_path / "again.bsdf").read_bytes()
    assert read_tensor_file(session / "brdf.bsdf")["rgb"].shape[1:] == (48, 3, 128, 128)


@pytest.mark.slow
def test_demo_with_bsdf_exports_the_session_brdf(tmp_path):
    import subprocess
    import sys

    out = tmp_path / "demo"
    proc = subprocess.run([sys.executable, "-m", "goniofrost", "demo", "--out", str(out), "--no-progress", "--bsdf"],
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr
    assert f"wrote {out / 'session' / 'brdf.bsdf'} (for Mitsuba 3)" in proc.stdout
    me.export_binary_file(out / "session" / "brdf.binary", tmp_path / "again.bsdf")
    assert (out / "session" / "brdf.bsdf").read_bytes() == (tmp_path / "again.bsdf").read_bytes()


# ----- preview --renderer mitsuba --------------------------------------------------------------
def test_preview_rendered_by_mitsuba_matches_goniofrosts_own(tmp_path, capsys):
    from goniofrost.brdf.mitsuba_render import make_preview_mitsuba
    from goniofrost.brdf.preview import make_preview, rendering_snr_db

    small_binary(tmp_path / "m.binary")
    ours, theirs = make_preview(tmp_path / "m.binary", size=48), make_preview_mitsuba(tmp_path / "m.binary", size=48)
    assert theirs.estimate.shape == ours.estimate.shape == (3, 48, 48, 3)
    assert rendering_snr_db(ours.estimate, theirs.estimate) > 15  # the same spheres, lit alike
    assert main(["preview", str(tmp_path / "m.binary"), "--reference", str(tmp_path / "m.binary"),
                 "--renderer", "mitsuba", "--size", "32", "--out", str(tmp_path / "p.png")]) == 0
    wrote, snr = capsys.readouterr().out.splitlines()
    assert wrote == f"wrote {tmp_path / 'p.png'}" and snr.endswith(f" dB against {tmp_path / 'm.binary'}")
    # the same file against itself: Mitsuba's multi-threaded render agrees to float rounding
    assert float(snr.split()[2]) > 100 and (tmp_path / "p.png").is_file()


def test_preview_with_mitsuba_missing_says_how_to_install_it(tmp_path, capsys, monkeypatch):
    import sys

    small_binary(tmp_path / "m.binary")
    monkeypatch.setitem(sys.modules, "mitsuba", None)  # import mitsuba now raises ImportError
    assert main(["preview", str(tmp_path / "m.binary"), "--renderer", "mitsuba", "--out", str(tmp_path / "p.png")]) == 2
    assert capsys.readouterr().err == ("goniofrost preview: error: rendering with Mitsuba needs Mitsuba 3: "
                                       "pip install 'goniofrost[render]' (or pip install mitsuba)\n")
    assert not (tmp_path / "p.png").exists()
