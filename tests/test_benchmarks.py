"""Every benchmark script runs at its smallest setting, so none can rot unseen (a key renamed in
the rig file once crashed two of them at start). Each runs as the operator runs it,
``python benchmarks/NAME.py ARGS`` in a scratch folder, and must exit 0.

QUICK ones run in the default suite; the others train a model, tabulate the full grid or run the
demo even at their smallest setting (a minute or more on a loaded machine): ``-m slow``.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

QUICK = {
    "drivers_roundtrip": ["--repeats", "3"],
    "frost_speed": ["pca", "--rows", "2000", "--repeat", "1"],
}
SLOW = {
    "fault_matrix": ["--samples", "2", "--at-sample", "1", "--kinds", "alarm", "--axes", "camera_arm"],
    "soak": ["--samples", "3", "--speedup", "1000"],
    "calibration": ["--samples", "2", "--repeats", "1"],
    "planner": ["--small", "--samples", "5", "--repeats", "1"],
    "tabulate": ["--skip-nbrdf"],
    "frost_accuracy": ["--grid", "small", "--m", "5"],
    "selection_vs_nielsen": ["--grid", "30,30,60", "--m", "5", "--nielsen-max-iter", "1"],
    "bayes_noise": ["--grid", "30,30,60"],
    "error_where": ["--grid", "10,10,20", "--setting", "builtin", "--draws", "50"],
    "mitsuba_export": ["--repeats", "1", "--skip-variants"],
    "mitsuba_sphere": ["--size", "16", "--out", "sphere.png"],
    "monitor": ["overhead", "--repeats", "1", "--samples", "2"],
    "session": ["--repeats", "1", "--samples", "3"],
    # also run in the default suite by the tests of their own features (test_usage, test_spectral_export,
    # test_confidence, test_steps), at these settings
    "camera_kinds": ["--smallest", "--out", "out"],
    "command_steps": ["--smallest", "--repeats", "1", "--out", "steps.json"],
    "scene_design": ["--smallest", "--scenes", "retro-sphere", "--out", "out"],
    "spectral_export": ["--smallest"],
    "spectral_sphere": ["--size", "16", "--spp", "4", "--out", "sphere.png"],
    "rgl_dataset": ["--smallest"],
    "rgl_fits_vs_files": ["--smallest"],
    "target_error": ["--grid", "10,10,20", "--folds", "1", "--settings", "builtin", "--m-max", "20", "--out", "out"],
    "time_aware": ["--grid", "10,10,20", "--folds", "1", "--settings", "builtin", "--m-max", "20", "--out", "out"],
}


def run_benchmark(name: str, args: list, folder: Path, timeout_s: float) -> None:
    run = subprocess.run([sys.executable, str(REPO / "benchmarks" / f"{name}.py"), *args],
                         cwd=folder, capture_output=True, text=True, timeout=timeout_s)
    assert run.returncode == 0, f"{name}: exit {run.returncode}\n{run.stderr[-3000:]}"


def test_every_benchmark_script_has_a_smallest_setting():
    scripts = sorted(p.stem for p in (REPO / "benchmarks").glob("*.py"))
    assert sorted([*QUICK, *SLOW]) == scripts


@pytest.mark.parametrize("name", sorted(QUICK))
def test_a_benchmark_runs_at_its_smallest_setting(name, tmp_path):
    run_benchmark(name, QUICK[name], tmp_path, 300)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(SLOW))
def test_a_slow_benchmark_runs_at_its_smallest_setting(name, tmp_path):
    run_benchmark(name, SLOW[name], tmp_path, 1800)
