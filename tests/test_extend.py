"""docs/how-to/extend.md's promise: a camera kind and an export format are each one new file plus
one registry line (tests/toy_camera.py, tests/toy_format.py), and work end to end."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from goniofrost.core.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]


def _rig_file(tmp_path, **camera) -> Path:
    doc = yaml.safe_load((ROOT / "config/rigs/sim.yaml").read_text())
    doc["camera"].update(camera)
    doc["camera"]["intrinsics"].update(image_size_px=[64, 48], principal_point_px=[31.5, 23.5])
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def test_a_toy_camera_registered_in_one_line_is_a_rig_file_s_camera_kind(tmp_path, monkeypatch):
    from drivers.rawfile import read_raw
    from drivers.rig_devices import CAMERA_CLASSES
    from goniofrost.rig.file import load_checked_rig
    from goniofrost.rig.hardware import open_camera

    monkeypatch.setitem(CAMERA_CLASSES, "toy", ("toy_camera", "ToyCamera"))  # the registry line
    camera = open_camera(load_checked_rig(_rig_file(tmp_path, kind="toy", toy_level=2.0)))
    camera.connect()
    frame = camera.capture(0.25, tmp_path / "frame")
    image = read_raw(frame.path)
    assert image.linear.shape == (48, 64) and frame.exposure_s == 0.25
    np.testing.assert_allclose(image.linear, 0.5, atol=1 / 4031)  # 2 x 0.25 s of the white level
    # its key is its own: another kind refuses it in one line naming the file and the key
    rig = _rig_file(tmp_path, kind="rawfile", folder=str(tmp_path), toy_level=2.0)
    with pytest.raises(ConfigError) as error:
        load_checked_rig(rig)
    assert str(error.value) == (f"{rig}: camera.toy_level: expected no toy_level for camera kind 'rawfile' "
                                f"(only kind toy reads it), found 2.0")


def test_without_its_registry_line_the_toy_kind_is_unknown(tmp_path):
    from goniofrost.rig.file import load_checked_rig

    rig = _rig_file(tmp_path, kind="toy")
    with pytest.raises(ConfigError, match=r"camera\.kind: expected one of \['sim', 'rawfile', 'pylon'\], found 'toy'"):
        load_checked_rig(rig)


def test_a_toy_format_registered_in_one_line_is_an_export_format(tmp_path, monkeypatch, capsys):
    from goniofrost.app.cli import main
    from goniofrost.brdf.formats import FORMATS, ExportFormat
    from goniofrost.brdf.merl_file import write_merl
    from goniofrost.brdf.rgl_tensor import read_tensor_file
    from goniofrost.core.grid import MerlGrid

    monkeypatch.setitem(FORMATS, "toy-mean", ExportFormat("toy_format", "export_mean", False, "a toy",
                                                          "read it with read_tensor_file"))  # the registry line
    grid = MerlGrid(30, 30, 60)
    brdf = np.full((grid.size, 3), np.nan)
    valid = np.asarray(grid.valid_cells)
    brdf[valid] = [0.1, 0.2, 0.4]
    write_merl(tmp_path / "m.binary", brdf, grid)
    out = tmp_path / "m.bsdf"
    assert main(["export", str(tmp_path / "m.binary"), "--format", "toy-mean", "--out", str(out)]) == 0
    np.testing.assert_allclose(read_tensor_file(out)["mean"], [0.1, 0.2, 0.4], rtol=1e-12)
    assert capsys.readouterr().out.startswith(f"wrote {out}: ")
