"""The spectral RGL export (pbrt-v4, Mitsuba 3's spectral variants), checked with the real Mitsuba 3 scalar_spectral.

Upsampling against Mitsuba's own table and model; the fields against pbrt-v4's reader; the round
trip RGB -> spectrum -> RGB of every node and Mitsuba's spectral eval against the RGB export's
eval on three built-in materials at full resolution; the command and its bad input.
"""
from __future__ import annotations

import re
from pathlib import Path

import mitsuba as mi
import numpy as np
import pytest

from goniofrost.app.cli import main
from goniofrost.brdf import mitsuba_export as me
from goniofrost.brdf import formats
from goniofrost.brdf import rgl_spectral as rs
from goniofrost.brdf import srgb_spectra
from goniofrost.brdf.merl_file import valid_to_full, write_merl
from goniofrost.brdf.mitsuba_probe import eval_pairs, eval_pairs_spectral, eval_pairs_spectral_rgb, load_bsdf, \
    spectral_to_rgb_weights
from goniofrost.brdf.mitsuba_render import SPECTRAL_VARIANT
from goniofrost.brdf.rgl_tensor import read_tensor_file, write_tensor_file
from goniofrost.core.grid import MerlGrid
from goniofrost.datasets import open_dataset
from goniofrost.datasets.tabulate import tabulate_cached

README = Path(__file__).resolve().parents[1] / "docs" / "explanations" / "mitsuba-export.md"  # the claim below
SMALL = MerlGrid(30, 30, 60)
SMALL_OPTIONS = me.ExportOptions(theta_i=6, ndf=31, vndf_theta=31, vndf_phi=16, sample=12)
MATERIALS = ("terracotta", "red-plastic", "gold")
MAX_THETA = np.radians(75.0)


@pytest.fixture(autouse=True, scope="module")
def rgb_variant_after():
    """Leave Mitsuba in the RGB variant the other modules set at import."""
    yield
    mi.set_variant("scalar_rgb")


def builtin_table(name: str, grid: MerlGrid) -> np.ndarray:
    values = tabulate_cached(open_dataset("builtin"), [name], grid, progress=False)[0]
    return valid_to_full(values.astype(np.float64), grid)


def cap_directions(rng, n: int) -> np.ndarray:
    cos = rng.uniform(np.cos(MAX_THETA), 1.0, n)
    phi, sin = rng.uniform(0.0, 2 * np.pi, n), np.sqrt(1.0 - cos ** 2)
    return np.stack([sin * np.cos(phi), sin * np.sin(phi), cos], -1)


def node_rgb(fields: dict) -> np.ndarray:
    """The rgb field's nodes as (N, 3)."""
    return fields["rgb"].transpose(0, 1, 3, 4, 2).reshape(-1, 3).astype(np.float64)


def node_spectra(fields: dict) -> np.ndarray:
    """The spectra field's nodes as (N, n_lambda), in the same order as node_rgb."""
    return fields["spectra"].transpose(0, 1, 3, 4, 2).reshape(-1, fields["wavelengths"].size).astype(np.float64)


@pytest.fixture(scope="module")
def exported(tmp_path_factory, full_grid_exports):
    """name -> (RGB fields, RGB .bsdf, spectral fields, spectral .bsdf): full grid, default options
    (the RGB files: conftest's full_grid_exports, read back; the spectral ones made of their fields)."""
    folder, result = tmp_path_factory.mktemp("spectral"), {}
    for name in MATERIALS:
        rgb_fields = read_tensor_file(full_grid_exports[name])
        spectral = rs.spectral_fields(rgb_fields)
        write_tensor_file(folder / f"{name}-spectral.bsdf", spectral)
        result[name] = (rgb_fields, full_grid_exports[name], spectral, folder / f"{name}-spectral.bsdf")
    return result


# ----- the upsampling is Mitsuba's ----------------------------------------------------------------
def test_shipped_table_is_the_half_slice_of_mitsubas_srgb_coeff():
    shipped = np.load(srgb_spectra.TABLE_PATH)
    assert shipped.shape == (3, 64, 64, 3) and shipped.dtype == np.float32
    np.testing.assert_array_equal(shipped, srgb_spectra.slice_of_coeff_file(Path(mi.__file__).parent / "data" / "srgb.coeff"))


def test_spectra_are_mitsubas_upsampling_of_unbounded_rgb():
    # Mitsuba's d65 emitter spectrum of an RGB value is D65 x 2 max(rgb) x model(rgb / (2 max)):
    # the unbounded rule; ours must be the same function of wavelength
    mi.set_variant(SPECTRAL_VARIANT)
    rng = np.random.default_rng(1)
    colours = np.concatenate([rng.uniform(0, 1, (40, 3)) * rng.uniform(0.01, 30, (40, 1)),
                              [[1, 0, 0], [0, 0.3, 0], [2, 2, 2], [0.05, 0.05, 0.05], [1e-4, 3e-4, 0]]])
    lam = np.array([360.0, 402.5, 455.0, 512.0, 560.0, 611.0, 700.0, 830.0])
    ours = srgb_spectra.unbounded_spectra(colours, lam)
    si, plain = mi.SurfaceInteraction3f(), mi.load_dict({"type": "d65"})
    for colour, spectrum in zip(colours, ours):
        emitter = mi.load_dict({"type": "d65", "color": colour.tolist()})
        for group in lam.reshape(-1, 4):
            si.wavelengths = mi.Spectrum(*group)
            theirs = np.array(emitter.eval(si)) / np.array(plain.eval(si))
            k = np.searchsorted(lam, group)
            np.testing.assert_allclose(spectrum[k], theirs, rtol=2e-5, atol=1e-7 * colour.max(), err_msg=str(colour))
    assert np.all(srgb_spectra.unbounded_spectra(np.zeros((2, 3)), lam) == 0)


def test_upsampled_gamut_surface_round_trips_within_one_percent():
    # the hardest colours (a channel at 0 or at the max) with the default wavelength nodes, read
    # by the renderer linearly between them: the reason for 32 nodes over 380-780 nm
    g = np.linspace(0, 1, 41)
    a, b = (v.ravel() for v in np.meshgrid(g, g))
    faces = [np.roll(np.stack([np.ones_like(a), a, b], -1), k, axis=-1) for k in range(3)]
    rgb = np.concatenate(faces) * 3.0
    lam = rs.wavelength_nodes()
    back = srgb_spectra.unbounded_spectra(rgb, lam) @ spectral_to_rgb_weights(lam)
    error = np.abs(back - rgb).max(axis=-1) / rgb.max(axis=-1)
    assert error.max() <= 0.01
    assert np.median(error) <= 0.005


def test_readme_round_trip_bound_holds_on_a_fine_gamut_surface():
    # the README's worst case was read on 41 x 41 colours per face (0.882 %) and stated as 0.88 %;
    # 101 x 101 finds 0.886 % near (1, 0, 0.37), and MERL black-obsidian's export had a node at 0.887 %
    claim = re.search(r"gamut the worst is ([0-9.]+) % of the largest channel", " ".join(README.read_text().split()))
    g = np.linspace(0, 1, 101)
    a, b = (v.ravel() for v in np.meshgrid(g, g))
    rgb = np.concatenate([np.roll(np.stack([np.ones_like(a), a, b], -1), k, axis=-1) for k in range(3)])
    lam = rs.wavelength_nodes()
    back = srgb_spectra.unbounded_spectra(rgb, lam) @ spectral_to_rgb_weights(lam)
    assert (np.abs(back - rgb).max(axis=-1) / rgb.max(axis=-1)).max() <= float(claim.group(1)) / 100


# ----- the fields follow pbrt-v4's reader ---------------------------------------------------------
@pytest.fixture(scope="module")
def small(tmp_path_factory):
    folder = tmp_path_factory.mktemp("small")
    table = builtin_table("red-plastic", SMALL)
    rgb = me.export_mitsuba(folder / "rgb.bsdf", table, SMALL, SMALL_OPTIONS)
    spectral = rs.export_spectral(folder / "spectral.bsdf", table, SMALL, SMALL_OPTIONS)
    return rgb, spectral, folder


def test_spectral_fields_are_the_rgb_fields_with_spectra_as_pbrt_reads_them(small):
    rgb, spectral, folder = small
    stored = read_tensor_file(folder / "spectral.bsdf")
    assert list(stored) == ["description", "phi_i", "theta_i", "ndf", "sigma", "vndf", "luminance", "wavelengths",
                            "spectra", "jacobian"]
    for name in ("phi_i", "theta_i", "ndf", "sigma", "vndf", "luminance", "jacobian"):
        assert stored[name].dtype == rgb[name].dtype
        np.testing.assert_array_equal(stored[name], rgb[name], err_msg=name)  # the same NDF, sigma, VNDF, luminance
    o, lam, spectra = SMALL_OPTIONS, stored["wavelengths"], stored["spectra"]
    # MeasuredBxDFData::Create's structure check (pbrt-v4 src/pbrt/bxdfs.cpp), condition by condition
    assert lam.dtype == np.float32 and lam.ndim == 1 and lam.size == rs.DEFAULT_WAVELENGTHS
    assert lam[0] == 380.0 and lam[-1] == 780.0 and np.all(np.diff(lam) > 0)
    assert spectra.dtype == np.float32 and spectra.shape == (1, o.theta_i, lam.size, o.sample, o.sample)
    assert stored["luminance"].shape[2:] == spectra.shape[3:] and spectra.shape[3] == spectra.shape[4]
    assert stored["vndf"].shape[:2] == (stored["phi_i"].size, stored["theta_i"].size)
    assert stored["description"].dtype == np.uint8 and stored["jacobian"].shape == (1,)
    description = bytes(stored["description"]).decode()
    assert "32 wavelengths 380-780 nm" in description and "Jakob-Hanika 2019" in description
    np.testing.assert_array_equal(node_spectra(stored), node_spectra(rs.spectral_fields(rgb)))
    # evaluated in float32 as the renderers do: the float64 model to float32 precision
    expected = srgb_spectra.unbounded_spectra(node_rgb(rgb), lam.astype(np.float64))
    np.testing.assert_allclose(node_spectra(stored), expected, rtol=2e-5, atol=1e-6 * expected.max())


def test_spectral_export_is_deterministic(small, tmp_path):
    _, _, folder = small
    rs.export_spectral(tmp_path / "again.bsdf", builtin_table("red-plastic", SMALL), SMALL, SMALL_OPTIONS)
    assert (tmp_path / "again.bsdf").read_bytes() == (folder / "spectral.bsdf").read_bytes()


def test_mitsuba_spectral_reads_the_spectra_linearly_between_the_wavelengths(small):
    # what the eval-to-RGB conversion relies on: linear between the nodes, constant beyond
    _, spectral, folder = small
    bsdf, lam = load_bsdf(folder / "spectral.bsdf", SPECTRAL_VARIANT), spectral["wavelengths"].astype(np.float64)
    rng = np.random.default_rng(2)
    w_i, w_o = cap_directions(rng, 5), cap_directions(rng, 5)
    at = eval_pairs_spectral(bsdf, w_i, w_o, np.concatenate([lam, (lam[:-1] + lam[1:]) / 2, [360.0, 830.0]]))
    n = lam.size
    assert at[:, :n].max() > 0
    np.testing.assert_allclose(at[:, n:2 * n - 1], (at[:, :n - 1] + at[:, 1:n]) / 2, rtol=1e-4, atol=1e-9)
    np.testing.assert_array_equal(at[:, -2], at[:, 0])
    np.testing.assert_array_equal(at[:, -1], at[:, n - 1])


# ----- Mitsuba 3 scalar_spectral against the RGB export (full grid) --------------------------------
@pytest.mark.parametrize("name", MATERIALS)
def test_round_trip_rgb_spectrum_rgb_of_every_node_within_one_percent(exported, name):
    rgb_fields, _, spectral, _ = exported[name]
    rgb = node_rgb(rgb_fields)
    back = node_spectra(spectral) @ spectral_to_rgb_weights(spectral["wavelengths"])
    lit = rgb.max(axis=-1) > 0
    assert lit.sum() > 0.5 * len(rgb)
    error = np.abs(back[lit] - rgb[lit]).max(axis=-1) / rgb[lit].max(axis=-1)
    assert error.max() <= 0.01
    assert np.all(back[~lit] == 0)


@pytest.mark.parametrize("name", MATERIALS)
def test_mitsuba_spectral_eval_in_rgb_matches_the_rgb_exports_eval(exported, name):
    _, rgb_path, spectral, spectral_path = exported[name]
    rng = np.random.default_rng(7)
    w_i, w_o = cap_directions(rng, 1000), cap_directions(rng, 1000)
    rgb_eval = eval_pairs(load_bsdf(rgb_path), w_i, w_o)
    spectral_eval = eval_pairs_spectral_rgb(load_bsdf(spectral_path, SPECTRAL_VARIANT), w_i, w_o,
                                            spectral["wavelengths"])
    rel = np.abs(spectral_eval - rgb_eval) / np.abs(rgb_eval)
    assert np.median(rel) <= 0.03 and np.percentile(rel, 95) <= 0.15
    assert np.median(rel) <= 0.01  # measured about 0.1-0.5 %: the round trip, not the warp


def test_sphere_rendered_spectrally_looks_like_the_rgb_render(tmp_path):
    from goniofrost.brdf.mitsuba_render import render_set_mitsuba
    from goniofrost.brdf.preview import DEFAULT_LIGHTS, rendering_snr_db

    table = builtin_table("terracotta", SMALL)
    me.export_mitsuba(tmp_path / "rgb.bsdf", table, SMALL, SMALL_OPTIONS)
    rs.export_spectral(tmp_path / "spectral.bsdf", table, SMALL, SMALL_OPTIONS)
    rgb = render_set_mitsuba(tmp_path / "rgb.bsdf", DEFAULT_LIGHTS[:1], 24, spp=32)
    spectral = render_set_mitsuba(tmp_path / "spectral.bsdf", DEFAULT_LIGHTS[:1], 24, SPECTRAL_VARIANT, spp=32)
    assert spectral.shape == rgb.shape == (1, 24, 24, 3)
    np.testing.assert_allclose(spectral.sum(axis=(0, 1, 2)), rgb.sum(axis=(0, 1, 2)), rtol=0.03)  # same colour
    assert rendering_snr_db(rgb, spectral) > 15


# ----- the command and bad input ------------------------------------------------------------------
def small_binary(path) -> None:
    write_merl(path, builtin_table("red-plastic", SMALL), SMALL)


def test_export_command_writes_the_spectral_file_and_pbrt_is_its_alias(tmp_path, capsys):
    small_binary(tmp_path / "m.binary")
    for fmt in ("rgl-spectral", "pbrt"):
        out = tmp_path / f"{fmt}.bsdf"
        assert main(["export", str(tmp_path / "m.binary"), "--format", fmt, "--out", str(out), "--theta-i", "8",
                     "--sample", "16", "--wavelengths", "12"]) == 0
        assert capsys.readouterr().out.startswith(f"wrote {out}: ")
    assert (tmp_path / "pbrt.bsdf").read_bytes() == (tmp_path / "rgl-spectral.bsdf").read_bytes()
    fields = read_tensor_file(tmp_path / "pbrt.bsdf")
    assert fields["spectra"].shape == (1, 8, 12, 16, 16) and "rgb" not in fields
    bsdf = load_bsdf(tmp_path / "pbrt.bsdf", SPECTRAL_VARIANT)
    value = eval_pairs_spectral(bsdf, np.array([[0.0, 0.0, 1.0]]), np.array([[0.6, 0.0, 0.8]]), [450.0, 650.0])
    assert value[0, 1] > value[0, 0] > 0  # red plastic: more red than blue


@pytest.mark.parametrize("fmt", ["rgl-spectral", "pbrt"])
@pytest.mark.parametrize("damage, message", [
    (lambda p: p.write_bytes(p.read_bytes()[:-8]), "truncated MERL file: 1296004 bytes, expected 1296012 bytes"),
    (lambda p: p.write_bytes(p.read_bytes()[:12] + np.full(3 * SMALL.size, -1.0).tobytes()),
     f"valid cells without a value (negative in the file): {SMALL.n_valid}, first at (i_th, i_td, i_pd) = (0, 0, 0); "
     "expected a BRDF value >= 0 at every cell above the horizon"),
    (lambda p: p.write_bytes(p.read_bytes()[:12] + np.where(np.arange(3 * SMALL.size) == 40000, np.nan,
                                                            np.fromfile(p, "<f8", offset=12)).tobytes()),
     "cells holding NaN or inf: 1, first at (i_th, i_td, i_pd) = (22, 6, 40); expected finite values (-1 marks a missing "
     "value)"),
])
def test_bad_binary_exits_2_with_one_line_and_writes_nothing(tmp_path, capsys, fmt, damage, message):
    source = tmp_path / "m.binary"
    small_binary(source)
    damage(source)
    assert main(["export", str(source), "--format", fmt, "--out", str(tmp_path / "out.bsdf")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"goniofrost export: error: {source}: {message}") and err.count("\n") == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.binary"]


@pytest.mark.parametrize("args, message", [
    (["--wavelengths", "1"], "--wavelengths: expected an integer >= 2, found 1"),
    (["--sample", "0"], "--sample: expected an integer >= 2, found 0"),
    (["--out", "m.binary"], "--out m.binary: is the input file; expected another name such as m.bsdf"),
])
def test_bad_options_exit_2(tmp_path, capsys, monkeypatch, args, message):
    monkeypatch.chdir(tmp_path)
    small_binary(tmp_path / "m.binary")
    assert main(["export", "m.binary", "--format", "pbrt", *args]) == 2
    assert capsys.readouterr().err == f"goniofrost export: error: {message}\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.binary"]


def test_bad_wavelength_count_in_the_api_is_refused_before_anything_is_written(tmp_path):
    with pytest.raises(me.ExportError, match=r"^wavelengths: expected an integer >= 2, found 1$"):
        rs.export_spectral(tmp_path / "x.bsdf", builtin_table("red-plastic", SMALL), SMALL, SMALL_OPTIONS, 1)
    with pytest.raises(me.ExportError, match=r"^format: expected one of mitsuba, rgl-spectral, pbrt, found 'exr'$"):
        formats.export_file(tmp_path / "m.binary", tmp_path / "x.bsdf", "exr")
    assert not any(tmp_path.iterdir())


def test_benchmark_smallest_setting_runs(capsys):
    import runpy
    import sys

    repo = Path(__file__).resolve().parents[1]
    argv = sys.argv
    sys.argv = ["spectral_export.py", "--smallest"]
    try:
        runpy.run_path(str(repo / "benchmarks" / "spectral_export.py"), run_name="__main__")
    finally:
        sys.argv = argv
    out = capsys.readouterr().out
    assert "builtin:red-plastic" in out and "round trip" in out


@pytest.mark.slow  # a whole simulated capture (about 4 min on the loaded machine): the wiring of one flag
def test_capture_with_bsdf_format_pbrt_writes_the_spectral_export_of_its_binary(tmp_path, capsys):
    from test_mitsuba_export import capture_small_session

    session = capture_small_session(tmp_path, "--bsdf-format", "pbrt")
    assert capsys.readouterr().out.endswith(f"wrote {session / 'brdf.bsdf'} (spectral, for pbrt-v4 and Mitsuba 3)\n")
    formats.export_file(session / "brdf.binary", tmp_path / "again.bsdf", "rgl-spectral")
    assert (session / "brdf.bsdf").read_bytes() == (tmp_path / "again.bsdf").read_bytes()
    assert read_tensor_file(session / "brdf.bsdf")["spectra"].shape[1:] == (48, 32, 128, 128)
