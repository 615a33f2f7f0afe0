"""Every benchmark script listed here runs at its smallest setting, so none can rot unseen (a key
renamed in the rig file once crashed two of them at start). Each runs as the operator runs it:
``python benchmarks/NAME.py ARGS``, and must exit 0."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

SMALLEST = {
    "fault_matrix": ["--samples", "3", "--at-sample", "1"],
    "soak": ["--samples", "3", "--speedup", "1000"],
    "session": ["--repeats", "1", "--samples", "3"],
    "drivers_roundtrip": ["--repeats", "3"],
    "planner": ["--small", "--samples", "5", "--repeats", "1"],
}


@pytest.mark.parametrize("name", sorted(SMALLEST))
def test_a_benchmark_runs_at_its_smallest_setting(name, tmp_path):
    run = subprocess.run([sys.executable, str(REPO / "benchmarks" / f"{name}.py"), *SMALLEST[name]],
                         cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, f"{name}: exit {run.returncode}\n{run.stderr[-3000:]}"
