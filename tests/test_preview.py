"""Sphere previews: exact radiance of known BRDFs, the rendering SNR, and the command."""
from __future__ import annotations

import numpy as np
import pytest

from goniofrost.brdf import preview as P
from goniofrost.app.cli import main
from goniofrost.core.grid import MerlGrid, half_diff_to_dirs
from goniofrost.brdf.merl_file import valid_to_full, write_merl

GRID = MerlGrid(30, 30, 60)


def lambertian(albedo=(0.8, 0.5, 0.2)) -> np.ndarray:
    return valid_to_full(np.tile(np.asarray(albedo) / np.pi, (GRID.n_valid, 1)), GRID)


def test_tangent_frame_is_orthonormal_for_every_normal_including_poles():
    rng = np.random.default_rng(1)
    n = rng.normal(size=(500, 3))
    n = np.concatenate([n, [[0, 0, 1], [0, 0, -1], [1, 0, 0], [0, 1, 0]]])
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    t, b = P.tangent_frame(n)
    frame = np.stack([t, b, n], -2)
    np.testing.assert_allclose(frame @ np.swapaxes(frame, -1, -2), np.broadcast_to(np.eye(3), frame.shape), atol=1e-12)


def test_lambertian_sphere_has_radiance_albedo_over_pi_times_cosine():
    light = ((0.0, 0.6, 0.8), 2.0)
    image = P.render_sphere(lambertian(), GRID, light, size=64)
    normals, mask = P.sphere_normals(64)
    cos_i = normals @ np.array([0.0, 0.6, 0.8])
    lit = mask & (cos_i > 0)
    expected = 2.0 * np.array([0.8, 0.5, 0.2]) / np.pi * cos_i[..., None]
    # cells at the grazing edge of the grid are invalid (missing) and render black
    valid = lit & (image.sum(-1) > 0)
    assert valid.sum() > 0.9 * lit.sum()
    np.testing.assert_allclose(image[valid], expected[valid], rtol=1e-12)
    assert np.all(image[~lit] == 0)


def test_lookup_reads_the_cell_of_each_direction_pair():
    rng = np.random.default_rng(2)
    values = valid_to_full(rng.uniform(0.1, 1.0, (GRID.n_valid, 3)), GRID)
    cells = rng.choice(GRID.valid_cells, 50, replace=False)
    i_th, i_td, i_pd = GRID.unravel(cells)
    # cell centres: away from the edges, where the half vector's azimuth is well defined
    w_i, w_o = half_diff_to_dirs(((i_th + 0.5) / 30) ** 2 * np.pi / 2, (i_td + 0.5) / 30 * np.pi / 2,
                                 (i_pd + 0.5) / 60 * np.pi)
    np.testing.assert_array_equal(P.lookup(values, GRID, w_i, w_o), values[cells])


def test_a_sphere_s_cells_are_those_of_its_directions_and_shared_read_only():
    """Every render of a grid, light and size reads one cached view: each pixel's cell is the
    lookup of its own light and view directions, and no render can change it."""
    light = (0.0, 0.6, 0.8)
    cells, lit, cos_i = P.sphere_view(GRID, light, 32)
    assert P.sphere_view(GRID, light, 32)[0] is cells and not cells.flags.writeable
    normals, mask = P.sphere_normals(32)
    frame = np.stack([*P.tangent_frame(normals), normals], -2)
    w_i, w_o = frame @ np.array(light), frame @ np.array([0.0, 0.0, 1.0])
    index = np.arange(GRID.size, dtype=np.float64)[:, None].repeat(3, axis=1)  # each cell's own number
    np.testing.assert_array_equal(cells[lit], P.lookup(index, GRID, w_i, w_o)[lit][:, 0])
    np.testing.assert_array_equal(cos_i, np.clip(w_i[..., 2], 0, None))
    with pytest.raises(ValueError, match="read-only"):
        cells[0, 0] = 1


def test_rendering_snr_is_20_db_for_a_10_percent_scale_and_inf_for_identical():
    ref = P.render_set(lambertian(), GRID, size=48)
    assert P.rendering_snr_db(ref, 0.9 * ref) == pytest.approx(20.0, abs=1e-9)
    assert P.rendering_snr_db(ref, ref) == float("inf")
    with pytest.raises(ValueError, match="shapes differ"):
        P.rendering_snr_db(ref, ref[:1])


def test_preview_command_writes_png_and_reports_snr(tmp_path, capsys):
    ref, est, png = tmp_path / "ref.binary", tmp_path / "est.binary", tmp_path / "p.png"
    write_merl(ref, lambertian(), GRID)
    write_merl(est, 0.9 * lambertian(), GRID)
    assert main(["preview", str(est), "--reference", str(ref), "--out", str(png), "--size", "40"]) == 0
    out = capsys.readouterr().out
    assert "rendering SNR: 20.00 dB" in out
    import matplotlib.image
    image = matplotlib.image.imread(png)
    assert image.ndim == 3 and image.shape[0] > 3 * 40 and image.shape[1] >= 3 * 40


def test_preview_of_a_missing_file_is_a_one_line_error_and_writes_nothing(tmp_path, capsys):
    png = tmp_path / "p.png"
    assert main(["preview", str(tmp_path / "nope.binary"), "--out", str(png)]) == 2
    assert "nope.binary: no such file" in capsys.readouterr().err
    assert not png.exists()


def test_uncertainty_panel_shows_predicted_std_beside_the_actual_log_error(tmp_path, capsys):
    from goniofrost.core.grid import cosine_weight

    ref, est, std, png = (tmp_path / n for n in ("ref.binary", "est.binary", "est.std.binary", "p.png"))
    write_merl(ref, lambertian(), GRID)
    write_merl(est, 0.9 * lambertian(), GRID)
    write_merl(std, valid_to_full(np.full((GRID.n_valid, 3), 0.1), GRID), GRID)
    preview = P.make_preview(est, ref, size=40, std_path=std)
    assert preview.errors["predicted"] == pytest.approx(0.01)
    w = cosine_weight(GRID)[:, None]
    x = lambertian()[GRID.valid_cells]
    actual = np.mean((np.log(w * x + 0.001) - np.log(0.9 * w * x + 0.001)) ** 2)
    assert preview.errors["actual"] == pytest.approx(actual, rel=1e-9)
    lit = preview.std > 0
    assert lit.any() and np.allclose(preview.std[lit], 0.1)  # each lit pixel shows its cell's std
    assert P.compose(preview).shape == (3 * 40, 5 * 40, 3)  # estimate, reference, error, std, log error
    assert main(["preview", str(est), "--reference", str(ref), "--std", str(std), "--out", str(png), "--size", "40"]) == 0
    assert f"predicted log-relative MSE 0.01, actual {actual:.4g}" in capsys.readouterr().out


def test_every_false_colour_panel_has_a_colour_bar_with_units_read_back_from_the_png(tmp_path):
    """The |error| x10 panel (a perceptual map, 0 to 1 display units) and the std / |log error| panels
    (natural-log units, their shared scale) each have a colour bar; the PNG's Description names them,
    and the title carries the caller's words (the sample, the session, the error figure)."""
    from PIL import Image

    ref, est, std = lambertian(), 0.9 * lambertian(), valid_to_full(np.full((GRID.n_valid, 3), 0.1), GRID)
    preview = P.preview_of(est, GRID, ref, size=40, std=std)
    title = "S-7, session s1\nerror <= 0.0123 with 95 % confidence (median estimate 0.00456)"
    fig = P.preview_figure(preview, title)
    bars = [ax for ax in fig.axes if ax.get_label() == "colour bar"]
    assert [ax.get_xlabel() for ax in bars] == [P.ERROR_BAR, P.STD_BAR]
    assert "display units" in P.ERROR_BAR and "natural-log units" in P.STD_BAR and P.ERROR_COLOURMAP == "viridis"
    # the std and log error panels' shared scale: the 99th percentile of both (std 0.1, |log 0.9| ~ 0.105)
    top = np.percentile(np.concatenate([m[m > 0] for m in (preview.std, preview.log_error)]), 99)
    assert [ax.get_xlim() for ax in bars] == [(0.0, 1.0), (0.0, top)] and 0.1 < top < 0.11
    assert fig._suptitle.get_text().startswith(title)
    # the |error| panel's pixels are the colour map's colours of |ref - est| x10 at the reference's exposure
    exposure = P.exposure_for(preview.reference)
    value = P.error_display(preview, 0, exposure)
    tile = P.compose(preview)[:40, 80:120]
    lit = preview.reference[0].max(axis=-1) > 0
    from matplotlib import colormaps
    np.testing.assert_allclose(tile[lit], colormaps["viridis"](np.clip(value[lit], 0, 1))[:, :3])
    P.write_png(tmp_path / "p.png", preview, title)
    assert Image.open(tmp_path / "p.png").text["Description"] == f"{P.ERROR_BAR}; {P.STD_BAR}"
    # without a reference or a std there is no false colour, and no colour bar
    plain = P.preview_of(est, GRID, size=40)
    assert P.colour_bars(P.preview_figure(plain)) == []


def test_preview_to_a_name_that_is_not_png_is_refused_and_writes_nothing(tmp_path, capsys):
    est, jpg = tmp_path / "est.binary", tmp_path / "p.jpg"
    write_merl(est, lambertian(), GRID)
    assert main(["preview", str(est), "--out", str(jpg)]) == 2
    assert capsys.readouterr().err.strip().endswith(f"--out {jpg}: expected a file name ending in .png "
                                                   "(the picture is written as PNG)")
    assert not jpg.exists()
