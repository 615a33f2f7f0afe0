"""goniofrost compare: spheres side by side and the pairwise rendering SNR and log-relative MSE."""
from __future__ import annotations

import json

import numpy as np
import pytest

from goniofrost.app.cli import main
from goniofrost.brdf import compare, preview
from goniofrost.brdf.merl_file import valid_to_full, write_merl
from goniofrost.core.grid import MerlGrid, cosine_weight
from goniofrost.datasets import open_dataset
from goniofrost.datasets.tabulate import tabulate_cached

SMALL = MerlGrid(30, 30, 60)
OTHER = MerlGrid(15, 30, 60)


def builtin_table(name: str, grid: MerlGrid = SMALL) -> np.ndarray:
    values = tabulate_cached(open_dataset("builtin"), [name], grid, progress=False)[0]
    return valid_to_full(values.astype(np.float64), grid)


def test_twice_the_brdf_is_known_numbers():
    a = builtin_table("red-plastic")
    result = compare.compare_tables([(a, SMALL), (2 * a, SMALL)], ["a", "2a"], size=32)
    # renderings are linear in the BRDF: SNR of 2a against a is 10 log10(|a|^2 / |a|^2) = 0 dB,
    # of a against 2a 10 log10(4) dB
    assert result.snr_db[0, 1] == pytest.approx(0.0, abs=1e-9)
    assert result.snr_db[1, 0] == pytest.approx(10 * np.log10(4.0), rel=1e-9)
    w = cosine_weight(SMALL)[:, None]  # over the valid cells
    cells = a[SMALL.valid_cells]
    with np.errstate(invalid="ignore"):
        expected = np.nanmean((np.log(w * 2 * cells + preview.EPS) - np.log(w * cells + preview.EPS)) ** 2)
    assert result.log_mse[0, 1] == result.log_mse[1, 0] == pytest.approx(expected, rel=1e-12)
    assert 0 < expected < np.log(2) ** 2
    np.testing.assert_array_equal(result.images[1], 2 * result.images[0])


def test_every_pair_both_ways_and_identical_inputs():
    tables = [(builtin_table(n), SMALL) for n in ("red-plastic", "gold", "red-plastic")]
    result = compare.compare_tables(tables, ["r", "g", "r again"], size=24)
    for i, j in [(0, 1), (1, 0), (1, 2), (2, 1)]:
        assert result.snr_db[i, j] == preview.rendering_snr_db(result.images[i], result.images[j])
    assert np.isinf(result.snr_db[0, 2]) and result.log_mse[0, 2] == 0.0
    doc = result.to_json()
    assert [p["a"] + p["b"] for p in doc["pairs"]] == ["AB", "AC", "BC"]
    same = doc["pairs"][1]
    assert same["identical"] is True and same["rendering_snr_db"] == {"b_against_a": None, "a_against_b": None}
    assert doc["pairs"][0]["identical"] is False and doc["pairs"][0]["rendering_snr_db"]["b_against_a"] < 0
    assert result.table()[1] == "A-C: identical renderings; log-relative MSE 0"
    json.dumps(doc, allow_nan=False)  # valid JSON: no infinities


def test_a_black_reference_is_not_identical_renderings():
    # an all-zero BRDF (a near-black channel taken to its limit) renders black: the SNR against it
    # is -inf (no signal), and compare printed "identical renderings" for it against a lit one
    black, red = np.where(builtin_table("red-plastic") >= 0, 0.0, -1.0), builtin_table("red-plastic")
    result = compare.compare_tables([(black, SMALL), (red, SMALL)], ["black", "red"], size=16)
    assert result.snr_db[0, 1] == -np.inf and result.snr_db[1, 0] == pytest.approx(0.0, abs=1e-12)
    assert result.table()[0].startswith("A-B: rendering SNR -inf dB (B against A), 0.00 dB (A against B)")
    pair = result.to_json()["pairs"][0]
    assert pair["identical"] is False and pair["rendering_snr_db"] == {"b_against_a": None, "a_against_b": 0.0}
    assert not result.identical(0, 1)


def test_different_grids_render_but_have_no_log_difference():
    result = compare.compare_tables([(builtin_table("gold"), SMALL), (builtin_table("gold", OTHER), OTHER)],
                                    ["a", "b"], size=24)
    assert np.isfinite(result.snr_db[0, 1]) and np.isnan(result.log_mse[0, 1])
    assert result.to_json()["pairs"][0]["log_relative_mse"] is None
    assert result.table()[0].endswith("log-relative MSE grids differ")


@pytest.fixture
def inputs(tmp_path):
    """A session folder (brdf.binary, report.json naming it) and two .binary files."""
    session = tmp_path / "S-001"
    session.mkdir()
    write_merl(session / "brdf.binary", builtin_table("red-plastic"), SMALL)
    (session / "report.json").write_text(json.dumps({"outputs": {"brdf": "brdf.binary"}}))
    write_merl(tmp_path / "gold.binary", builtin_table("gold"), SMALL)
    write_merl(tmp_path / "blue.binary", builtin_table("blue-plastic"), SMALL)
    return session, tmp_path / "gold.binary", tmp_path / "blue.binary"


def test_command_writes_the_picture_and_prints_the_pairs(tmp_path, capsys, inputs):
    import matplotlib.image

    session, gold, blue = inputs
    out = tmp_path / "compare.png"
    assert main(["compare", str(session), str(gold), str(blue), "--out", str(out), "--size", "32"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[:4] == [f"wrote {out}", f"A: S-001 ({session / 'brdf.binary'})", f"B: gold.binary ({gold})",
                         f"C: blue.binary ({blue})"]
    assert [line.split(":")[0] for line in lines[4:]] == ["A-B", "A-C", "B-C"]
    picture = matplotlib.image.imread(out)
    assert picture.shape[1] >= 3 * 32 and picture[..., :3].std() > 0.05  # three columns of spheres, not blank


def test_json_numbers_are_the_comparisons(tmp_path, capsys, inputs):
    session, gold, _ = inputs
    out = tmp_path / "c.png"
    assert main(["compare", str(session), str(gold), "--out", str(out), "--size", "24", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    direct = compare.compare_files([session / "brdf.binary", gold], ["S-001", "gold.binary"], size=24)
    assert doc["inputs"] == [{"key": "A", "label": "S-001", "path": str(session / "brdf.binary"),
                              "error_figure": preview.record_figure(session / "brdf.binary")},
                             {"key": "B", "label": "gold.binary", "path": str(gold), "error_figure": None}]
    pair = doc["pairs"][0]
    assert pair["rendering_snr_db"]["b_against_a"] == round(direct.snr_db[0, 1], 6)
    assert pair["rendering_snr_db"]["a_against_b"] == round(direct.snr_db[1, 0], 6)
    assert pair["log_relative_mse"] == round(direct.log_mse[0, 1], 6)
    assert doc["picture"] == str(out) and out.is_file() and doc["size_px"] == 24


def test_report_names_the_sessions_brdf(tmp_path, capsys, inputs):
    session, gold, _ = inputs
    (session / "brdf.binary").rename(session / "estimate.binary")
    (session / "report.json").write_text(json.dumps({"outputs": {"brdf": "estimate.binary"}}))
    assert main(["compare", str(session), str(gold), "--out", str(tmp_path / "c.png"), "--size", "16"]) == 0
    assert f"A: S-001 ({session / 'estimate.binary'})" in capsys.readouterr().out


@pytest.mark.parametrize("make_args, message", [
    (lambda s, g, t: [str(g)], "inputs: expected at least 2 session folders or .binary files, found 1"),
    (lambda s, g, t: [str(g), str(t / "nope")], "{t}/nope: no such session folder or file"),
    (lambda s, g, t: [str(t / "empty"), str(g)],
     "{t}/empty: no brdf.binary: expected a finished session folder (its reconstruction {t}/empty/brdf.binary) "
     "or a MERL .binary file"),
    (lambda s, g, t: [str(g), str(t / "short.binary")],
     "{t}/short.binary: truncated MERL file: 100 bytes, expected 1296012 bytes"),
    (lambda s, g, t: [str(s), str(g), "--out", str(t / "c.jpg")], "--out {t}/c.jpg: expected a file name ending in .png"),
    (lambda s, g, t: [str(s), str(g), "--size", "8"], "--size: expected at least 16 pixels, found 8"),
])
def test_bad_input_exits_2_with_one_line_and_writes_nothing(tmp_path, capsys, inputs, make_args, message):
    session, gold, _ = inputs
    (tmp_path / "empty").mkdir()
    (tmp_path / "short.binary").write_bytes(gold.read_bytes()[:100])
    args = make_args(session, gold, tmp_path)
    if "--out" not in args:
        args += ["--out", str(tmp_path / "c.png")]
    before = sorted(p.name for p in tmp_path.iterdir())
    assert main(["compare", *args]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"goniofrost compare: error: {message.format(t=tmp_path)}") and err.count("\n") == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == before


@pytest.mark.parametrize("named", ["ABSOLUTE", "../outside.binary"])
def test_a_report_naming_a_file_outside_its_session_is_refused(named, tmp_path, capsys, inputs):
    """compare opened whatever path a session's report.json named."""
    session, gold, _ = inputs
    (session.parent / "outside.binary").write_bytes(gold.read_bytes())
    name = str(session.parent / "outside.binary") if named == "ABSOLUTE" else named
    (session / "report.json").write_text(json.dumps({"outputs": {"brdf": name}}))
    assert main(["compare", str(session), str(gold), "--out", str(tmp_path / "c.png")]) == 2
    assert capsys.readouterr().err == (f"goniofrost compare: error: {session / 'report.json'}: outputs.brdf: expected "
                                       f"a file in the session folder {session}, found {name!r}\n")
    assert not (tmp_path / "c.png").exists()


def test_a_damaged_report_is_named(tmp_path, capsys, inputs):
    session, gold, _ = inputs
    (session / "report.json").write_text("{not json")
    assert main(["compare", str(session), str(gold), "--out", str(tmp_path / "c.png")]) == 2
    assert capsys.readouterr().err == (f"goniofrost compare: error: {session / 'report.json'}: expected a session "
                                       f"report with outputs.brdf, found an unreadable or different document\n")
    assert not (tmp_path / "c.png").exists()
