"""The reachability map is computed once per rig and read from the cache after: keyed on what
decides it (kinematics, alignment, camera model, grid), so a changed rig recomputes and a rig
that differs only in how its devices are reached does not."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import yaml

from goniofrost.rig.file import load_checked_rig
from goniofrost.core.grid import MerlGrid
from planner.reach import compute_reasons, is_cached, reachability

SIM = Path(__file__).resolve().parents[1] / "config" / "rigs" / "sim.yaml"
GRID = MerlGrid(16, 16, 32)


def _rig(tmp_path: Path, name: str, change=None):
    raw = yaml.safe_load(SIM.read_text())
    if change:
        change(raw)
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(raw))
    return load_checked_rig(path)


def _entries() -> set:
    folder = Path(os.environ["GONIOFROST_CACHE"]) / "reach"
    return set(folder.glob("*.npy")) if folder.is_dir() else set()


def test_the_map_is_cached_per_rig_and_a_changed_rig_recomputes(tmp_path):
    def longer_lens(raw):
        raw["camera"]["intrinsics"]["focal_px"] = [4000.0, 4000.0]

    def other_port(raw):
        raw["axes"]["camera_arm"]["driver"]["port"] = 1502

    before = _entries()
    first = reachability(_rig(tmp_path, "a"), GRID)
    added = _entries() - before
    assert len(added) == 1
    entry = added.pop()
    stamp = entry.stat().st_mtime_ns
    again = reachability(_rig(tmp_path, "b"), GRID)                     # the same rig in another file
    same = reachability(_rig(tmp_path, "c", other_port), GRID)         # only an endpoint differs
    assert _entries() - before == {entry} and entry.stat().st_mtime_ns == stamp
    np.testing.assert_array_equal(again.reason, first.reason)
    np.testing.assert_array_equal(same.reason, first.reason)
    lens = _rig(tmp_path, "d", longer_lens)
    assert is_cached(_rig(tmp_path, "e"), GRID) and not is_cached(lens, GRID)
    changed = reachability(lens, GRID)                                  # another camera: a new entry
    assert len(_entries() - before) == 2 and is_cached(lens, GRID)
    np.testing.assert_array_equal(changed.reason, compute_reasons(lens, GRID))
    assert not np.array_equal(changed.reason, first.reason)
