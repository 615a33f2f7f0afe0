"""The first commands: ``goniofrost materials`` and ``goniofrost convert``."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from goniofrost.app.cli import main
from goniofrost.datasets.builtin import BuiltinDataset
from goniofrost.core.grid import FULL_GRID
from goniofrost.brdf.merl_file import read_merl


def test_materials_prints_one_name_per_line(capsys):
    assert main(["materials", "--dataset", "builtin"]) == 0
    assert capsys.readouterr().out.splitlines() == BuiltinDataset().names()


def test_materials_of_an_nbrdf_archive(rgl_npz, capsys):
    assert main(["materials", "--dataset", f"nbrdf:{rgl_npz}"]) == 0
    names = capsys.readouterr().out.splitlines()
    assert len(names) == 51 and "spectralon_rgb" in names


def direct_network(npz, name: str, theta_h, theta_d, phi_d, dtype=np.float32) -> np.ndarray:
    """The README's formula written out: exp(relu(relu(x W1 + b1) W2 + b2) W3 + b3) - 1, >= 0,
    with x = (sin th, 0, cos th, sin td cos pd, sin td sin pd, cos td) in float32 (as the
    networks are stored); the layers in ``dtype``."""
    with np.load(npz) as archive:
        i = list(archive["names"]).index(name)
        w = {k: archive[k][i].astype(dtype) for k in ("W1", "b1", "W2", "b2", "W3", "b3")}
    s = np.sin(theta_d)
    x = np.stack([np.sin(theta_h), 0 * theta_h, np.cos(theta_h), s * np.cos(phi_d), s * np.sin(phi_d),
                  np.cos(theta_d)], -1).astype(np.float32).astype(dtype)
    h = np.maximum(x @ w["W1"] + w["b1"], 0)
    h = np.maximum(h @ w["W2"] + w["b2"], 0)
    return np.maximum(np.expm1(h @ w["W3"] + w["b3"]), 0)


def test_convert_spectralon_matches_the_network(rgl_npz, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)  # no --out: NAME.binary in the current folder
    assert main(["convert", "--dataset", f"nbrdf:{rgl_npz}", "--material", "spectralon_rgb"]) == 0
    assert "spectralon_rgb.binary" in capsys.readouterr().out
    path = tmp_path / "spectralon_rgb.binary"
    stored = np.fromfile(path, "<f8", offset=12).reshape(3, FULL_GRID.size).T
    assert np.all(stored[~FULL_GRID.valid_mask] == -1.0)  # invalid cells are exactly -1
    assert np.all(stored[FULL_GRID.valid_mask] >= 0)
    brdf = read_merl(path, FULL_GRID)
    valid = ~np.isnan(brdf).any(axis=1)
    assert int(valid.sum()) == 1_111_432 and np.array_equal(valid, FULL_GRID.valid_mask)
    angles = FULL_GRID.flat_angles(FULL_GRID.valid_cells)
    # equal to the network evaluated in float32, to float32 rounding: the batched and the plain
    # matrix products sum in different orders, so y = log(1 + f) differs by a few float32 ulps
    # of its terms (|error in f| <= (1 + f) 1e-6)
    np.testing.assert_allclose(brdf[valid], direct_network(rgl_npz, "spectralon_rgb", *angles),
                               rtol=1e-6, atol=1e-6)
    # and within float32 accuracy of the same network in float64
    exact = direct_network(rgl_npz, "spectralon_rgb", *angles, dtype=np.float64)
    np.testing.assert_allclose(brdf[valid], exact, rtol=1e-3, atol=2e-5)


def test_convert_builtin_to_a_named_file(tmp_path):
    out = tmp_path / "sub" / "gold.binary"
    assert main(["convert", "--dataset", "builtin", "--material", "gold", "--out", str(out)]) == 0
    brdf = read_merl(out, FULL_GRID)
    cells = FULL_GRID.valid_cells[::997]
    expected = BuiltinDataset().evaluate("gold", *FULL_GRID.flat_angles(cells))
    np.testing.assert_allclose(brdf[cells], expected, rtol=1e-6)


@pytest.mark.parametrize("args, message", [
    (["--dataset", "builtin", "--material", "goldd"], "unknown material 'goldd' in dataset 'builtin'; did you mean gold"),
    (["--dataset", "bulitin", "--material", "gold"], "unknown dataset spec 'bulitin'"),
    (["--dataset", "merl:/nonexistent/folder", "--material", "gold"], "/nonexistent/folder: no such folder"),
])
def test_convert_bad_input_exits_2_and_writes_nothing(tmp_path, capsys, args, message):
    out = tmp_path / "x.binary"
    assert main(["convert", *args, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("goniofrost convert: error: ") and message in err
    assert list(tmp_path.iterdir()) == []


def test_the_installed_command_reports_errors_in_one_line(tmp_path):
    result = subprocess.run([sys.executable, "-m", "goniofrost", "materials", "--dataset", "nbrdf:nothing.npz"],
                            capture_output=True, text=True, cwd=tmp_path, timeout=60)
    assert result.returncode == 2 and result.stdout == ""
    assert result.stderr == ("goniofrost materials: error: nothing.npz: no such Neural-BRDF archive "
                             "(expected an .npz file)\n")


def test_bench_default_data_is_the_shared_folder_beside_the_project(monkeypatch):
    import importlib

    import goniofrost.app.commands.bench as bench_command

    monkeypatch.delenv("GONIOFROST_SHARED_DATA", raising=False)
    module = importlib.reload(bench_command)
    assert module.SHARED_DATA == Path(__file__).resolve().parents[2] / "shared" / "data"


def _commands() -> list[str]:
    import argparse

    from goniofrost.app.cli import build_parser
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return list(sub.choices)


@pytest.mark.parametrize("command", [None] + _commands())
def test_help_of_every_command_prints_and_exits_0(command, capsys):
    # argparse %-formats every help string when --help is asked for: one literal "%" (the
    # demo's "95 % confidence") made `goniofrost --help` a TypeError
    argv = ["--help"] if command is None else [command, "--help"]
    with pytest.raises(SystemExit) as done:
        main(argv)
    assert done.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: ") and ("demo" in out if command is None else command in out.splitlines()[0])
    assert "%%" not in out  # a command's description is printed as written, not %-formatted


@pytest.mark.parametrize("angle", ["0", "-10", "nan", "95"])
def test_plan_refuses_a_max_angle_outside_0_to_90_degrees(angle, tmp_path, capsys):
    # --max-angle 0 planned every sample at normal incidence (predicted error 39), nan found no cell
    out = tmp_path / "plan.json"
    assert main(["plan", "--model", str(tmp_path / "model"), "--samples", "10", "--max-angle", angle,
                 "--out", str(out)]) == 2
    assert capsys.readouterr().err == (f"goniofrost plan: error: command line: --max-angle: expected degrees in "
                                       f"(0, 90], found {float(angle)!r}\n")
    assert not out.exists()


@pytest.mark.parametrize("args, message", [
    (["--alignment", "a.json"], "--alignment"),
    (["--rig", "no-such-rig.yaml"], "no-such-rig.yaml"),
])
def test_train_with_a_bad_rig_exits_2_before_training_and_writes_nothing(tmp_path, capsys, args, message):
    out = tmp_path / "model"
    assert main(["train", "--dataset", "builtin", "--only", "gold", *args, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("goniofrost train: error: ") and message in err and err.count("\n") == 1
    assert list(tmp_path.iterdir()) == []


def test_train_grid_trains_plans_and_calibrates_on_that_grid(tmp_path, capsys):
    """train --grid 10,10,20: the model, its rig's measurable cells and a plan are all of that grid."""
    import json

    from goniofrost.frost.model import FrostModel

    rig, model = str(Path(__file__).parents[1] / "config" / "rigs" / "sim.yaml"), tmp_path / "model"
    assert main(["train", "--dataset", "builtin", "--only", "gold", "--only", "red-plastic", "--only",
                 "white-diffuse", "--components", "2", "--grid", "10,10,20", "--rig", rig,
                 "--out", str(model)]) == 0
    loaded = FrostModel.load(model)
    assert loaded.grid.shape == (10, 10, 20) and loaded.grid.n_valid == 1670
    assert "1670 valid cells" in capsys.readouterr().out
    plan = tmp_path / "plan.json"
    assert main(["plan", "--model", str(model), "--samples", "4", "--rig", rig,
                 "--out", str(plan)]) == 0
    cells = [s["cell"] for s in json.loads(plan.read_text())["samples"]]
    assert len(cells) >= 4 and all(c[0] < 10 and c[1] < 10 and c[2] < 20 for c in cells)


def test_train_refuses_a_grid_that_is_not_three_positive_bins(tmp_path, capsys):
    with pytest.raises(SystemExit) as done:
        main(["train", "--dataset", "builtin", "--grid", "10,0,20", "--out", str(tmp_path / "m")])
    assert done.value.code == 2
    assert ("argument --grid: expected three positive integers like 30,30,60, found '10,0,20'"
            in capsys.readouterr().err)
    assert list(tmp_path.iterdir()) == []
