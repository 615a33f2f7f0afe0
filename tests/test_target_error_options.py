"""benchmarks/target_error.py's camera noise, learning curve and joined folds (issue 49), on
small arrays: no model is trained here."""
from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from goniofrost.bench import camera_noise
from goniofrost.bench.config import BenchConfig, fold_split

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("target_error_bench", REPO / "benchmarks" / "target_error.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_camera_noise_is_the_rig_cameras_snr_and_the_same_for_a_seed():
    from goniofrost.rig.file import load_checked_rig

    sd = camera_noise.relative_sd(load_checked_rig(REPO / "goniofrost" / "rigs" / "sim.yaml").camera)
    assert sd == 0.01  # target_snr: 100
    values = np.exp(np.random.default_rng(3).normal(-2, 1, size=(3, 4000, 3)))
    values[1, 7, 2] = np.nan  # a cell without data
    names = ["a", "b", "c"]
    once = camera_noise.noisy(values, names, sd, seed=0)
    assert np.array_equal(once, camera_noise.noisy(values, names, sd, seed=0), equal_nan=True)
    # each material's noise from the seed and its name alone: the same when noised alone or reordered
    assert np.array_equal(once[2], camera_noise.noisy(values[2:], ["c"], sd, seed=0)[0])
    assert np.array_equal(once[[1, 0]], camera_noise.noisy(values[[1, 0]], ["b", "a"], sd, seed=0), equal_nan=True)
    assert not np.array_equal(once[0], camera_noise.noisy(values, names, sd, seed=1)[0])
    assert np.isnan(once[1, 7, 2]) and np.isfinite(np.delete(once.reshape(-1), 1 * 12000 + 7 * 3 + 2)).all()
    relative = (once / values - 1).reshape(-1)
    relative = relative[np.isfinite(relative)]
    # 36 000 draws: the standard deviation within 3 % of 0.01 (its own sd is 0.4 %), mean ~ 0
    assert np.std(relative) == pytest.approx(0.01, rel=0.03)
    assert abs(np.mean(relative)) < 0.0003


def test_the_learning_curves_subsets_are_nested_training_materials(bench):
    config = BenchConfig(("merl", "rgl"), n_train=131, n_test=20)
    for fold in (0, 1):
        train, test = fold_split(151, config, fold)
        subsets = {n: bench.training_subset(train, n, config.seed, fold) for n in (30, 60, 90, 131)}
        for n, kept in subsets.items():
            assert kept.size == n and np.unique(kept).size == n and np.all(np.diff(kept) > 0)
            assert np.isin(kept, train).all() and not np.isin(kept, test).any()
        assert np.array_equal(subsets[131], train)
        assert np.isin(subsets[30], subsets[60]).all() and np.isin(subsets[60], subsets[90]).all()
        assert np.array_equal(subsets[30], bench.training_subset(train, 30, config.seed, fold))
    assert not np.array_equal(bench.training_subset(fold_split(151, config, 0)[0], 30, config.seed, 0),
                              bench.training_subset(fold_split(151, config, 0)[0], 30, config.seed, 1))
    with pytest.raises(bench.BadOption, match="expected 1 to 131 materials, found 132"):
        bench.training_subset(train, 132, config.seed, 0)


def test_the_learning_curve_row_is_the_held_out_spread_at_m_20(bench):
    ratios = np.array([0.5, 1.0, 2.0, 4.0])
    per_m = [{"material": f"x{i}", "m": 20, "mse": 0.01 * r, "median": 0.02, "median_unchecked": 0.01,
              "upper_unchecked": 0.03} for i, r in enumerate(ratios)]
    results = {"split n=30": [{"fold": 0, "per_m": per_m, "stops": [], "bound_scale": {"20": 0.5}}]}
    stats = {"split n=30": {"targets": {"0.02": {"target": 0.02, "sentinels": False, "bound": "split",
                                                 "bound_over_actual": {"20": 2.0, "40": 1.5}, "over_oracle": 1.7,
                                                 "clearly_could_stopped": 3, "clearly_could": 4,
                                                 "within_when_stopped": 0.96}}}}
    [row] = bench.learning_curve(results, stats)
    assert row == {"setting": "split", "training_materials": 30, "folds": 1, "test_materials": 4,
                   "spread": pytest.approx(np.std(np.log(ratios))), "training_spread": 0.5,
                   "bound_over_actual": 2.0, "over_oracle": {"0.02": 1.7}, "clearly_could": {"0.02": [3, 4]},
                   "coverage": {"0.02": 0.96}}
    assert "| split | 30 | 1 x 4 | 0.77 | 0.50 | 2.00 | 1.70 | 3 of 4 | 96.0 % |" in bench.curve_markdown([row])


def test_runs_of_disjoint_folds_join_and_a_fold_twice_is_refused(bench, tmp_path, capsys):
    def doc(folds):
        return {"command": "c", "wall_s": 1.0, "load_average": [1.0], "summary": {}, "results": {"split": [
            {"fold": f, "per_m": [], "stops": [{"bound": "split"}, {"bound": "per-look"}]} for f in folds]}}

    both = bench.joined([doc([5, 6]), doc([0])], ("split",))
    assert [f["fold"] for f in both["results"]["split"]] == [0, 5, 6]
    assert all(f["stops"] == [{"bound": "split"}] for f in both["results"]["split"])
    for name, folds in (("a", [0, 1]), ("b", [1])):
        (tmp_path / f"{name}.json").write_text(json.dumps(doc(folds)))
    assert bench.main(["--summarise", f"{tmp_path / 'a.json'},{tmp_path / 'b.json'}", "--out", str(tmp_path)]) == 2
    assert capsys.readouterr().err == ("target_error.py: --summarise: expected each fold once, "
                                       "found split fold 1 twice\n")
    assert not (tmp_path / "target_error.json").exists()


def test_a_learning_curve_beyond_the_training_materials_is_refused_before_it_runs(bench, tmp_path, capsys):
    assert bench.main(["--settings", "builtin", "--train-sizes", "30,65", "--out", str(tmp_path / "out")]) == 2
    assert capsys.readouterr().err == ("target_error.py: --train-sizes: expected 1 to 64 materials for builtin, "
                                       "found 30,65\n")
    assert bench.main(["--settings", "split,rgl-merl", "--train-sizes", "30", "--out", str(tmp_path / "out")]) == 2
    assert capsys.readouterr().err == ("target_error.py: --train-sizes: expected the settings split or builtin, "
                                       "found rgl-merl\n")
    assert not (tmp_path / "out").exists()


def test_camera_noise_without_a_rig_is_refused(bench, tmp_path, capsys):
    assert bench.main(["--camera-noise", "--out", str(tmp_path / "out")]) == 2
    assert capsys.readouterr().err == ("target_error.py: --camera-noise: expected --rig (the camera whose noise is "
                                       "simulated), found none\n")
    assert not (tmp_path / "out").exists()
