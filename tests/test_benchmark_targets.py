"""The smallest settings of ``benchmarks/frost_speed.py targets`` and ``kernels``: a small grid, one run each."""
from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import made_once

REPO = Path(__file__).resolve().parents[1]
ENV = {"PATH": "/usr/bin:/bin"}
# The model each command trains first when given no --model (bench_targets, bench_kernels, bench_flatness)
TRAIN = ("from goniofrost.core.grid import MerlGrid; from goniofrost.frost.training import train; "
         "train(['builtin'], exclude=['red-plastic'], grid=MerlGrid(8, 8, 16))")


@pytest.fixture(scope="session")
def trained_cache() -> Path:
    """A cache holding that model, trained once per test run: each command's run starts from a
    copy of it (every run trained the same model, 5-8 s of its 6-10 s of CPU)."""
    def train(folder):
        subprocess.run([sys.executable, "-c", TRAIN], env=ENV | {"GONIOFROST_CACHE": str(folder)}, check=True,
                       timeout=600)

    return made_once("frost-speed-cache", train)


def smallest_run(command: str, trained_cache: Path, cache: Path) -> str:
    """What ``frost_speed.py COMMAND`` prints at its smallest setting (its cache ``cache``, a copy
    of ``trained_cache``)."""
    shutil.copytree(trained_cache, cache)
    result = subprocess.run([sys.executable, str(REPO / "benchmarks" / "frost_speed.py"), command,
                             "--grid", "8", "8", "16", "--repeat", "1"], capture_output=True, text=True,
                            env=ENV | {"GONIOFROST_CACHE": str(cache)}, timeout=600)
    assert result.returncode == 0, result.stderr
    return result.stdout


def test_targets_report_each_figure_beside_its_target_and_the_bandwidth(trained_cache, tmp_path):
    out = smallest_run("targets", trained_cache, tmp_path / "cache")
    assert re.search(r"streaming read bandwidth .*: [\d.]+ GB/s  \(load [\d.]+ [\d.]+ [\d.]+\)", out), out
    for name, target in (("bayes m=20", "0.25"), ("bayes m=60", "0.75"), ("somp m=20", "0.25")):
        line = re.search(rf"^{name}: median ([\d.]+) s  target {target} s  (met|MISSED); bandwidth limit ([\d.e-]+) s "
                         rf"\(\d+ reads of [DC]\), ratio ([\d.]+)  \(runs [\d.]+; load ", out, re.M)
        assert line, (name, out)
        median, _, limit, ratio = line.groups()
        # the median is printed to the millisecond: its rounding bounds the ratio it implies
        low, high = (float(median) - 5e-4) / float(limit), (float(median) + 5e-4) / float(limit)
        assert 0.99 * low - 0.01 <= float(ratio) <= 1.01 * high + 0.01, (median, limit, ratio)


def test_kernels_report_each_pass_with_its_bytes_and_the_stream(trained_cache, tmp_path):
    out = smallest_run("kernels", trained_cache, tmp_path / "cache")
    assert re.search(r"streaming read [\d.]+ GB/s; n = \d+, K = \d+", out), out
    for name in ("bayes step, 1 design", "bayes step, 3 designs", r"somp Q pass \(k = t = \d+\)", r"somp C pass \(t = \d+\)"):
        assert re.search(rf"^{name}: [\d.]+ ms, \d+ MB moved, [\d.]+ GB/s; one read of \d+ MB at the stream: "
                         rf"[\d.]+ ms, ratio [\d.]+  \(load ", out, re.M), (name, out)
    assert re.search(r"^somp pack \(k = \d+, one run\): [\d.]+ ms$", out, re.M), out


def test_flatness_reports_each_step_s_share_of_cells_near_the_best(trained_cache, tmp_path):
    out = smallest_run("flatness", trained_cache, tmp_path / "cache")  # --m 20 steps by default
    steps = re.findall(r"^step +(\d+): best score ([\d.e+-]+); cells within a factor 2 of it ([\d.]+)%; "
                       r"ruled out by the bound ([\d.]+)%$", out, re.M)
    assert [int(s[0]) for s in steps] == list(range(1, 21)), out
    for _, best, near, ruled_out in steps:
        # the best cell itself is within a factor 2 of the best; a cell at the best is never ruled out
        assert float(best) > 0 and 0 < float(near) <= 100 and 0 <= float(ruled_out) < 100
