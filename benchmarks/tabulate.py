"""Time tabulating materials on the full MERL grid (1,111,432 valid cells), no cache.

    .venv/bin/python benchmarks/tabulate.py [--data ../shared/data] [--skip-nbrdf] [--skip-builtin]

Prints: one Neural-BRDF material (median of 3), all materials of both archives (151), one
built-in material (median of 3) and the whole built-in library (including its one-off
albedo-table set-up). Timings on a shared machine are noisy: the load average is printed.
"""
from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

from goniofrost.datasets import open_dataset
from goniofrost.datasets.tabulate import MATERIALS_PER_BATCH
from goniofrost.core.grid import FULL_GRID

REPO = Path(__file__).resolve().parents[1]


def timed(fn) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


class Clock:
    """Wall and CPU time (all threads) of a block: CPU time is less sensitive to other load."""

    def __enter__(self):
        self.wall, self.cpu = time.perf_counter(), time.process_time()
        return self

    def __exit__(self, *exc) -> None:
        self.wall, self.cpu = time.perf_counter() - self.wall, time.process_time() - self.cpu

    def __str__(self) -> str:
        return f"{self.wall:.1f} s wall, {self.cpu:.1f} s CPU"


def tabulate_all(dataset) -> int:
    """Tabulate every material in batches, as tabulate_cached does (without the disk cache)."""
    names = dataset.names()
    for start in range(0, len(names), MATERIALS_PER_BATCH):
        dataset.tabulate(names[start:start + MATERIALS_PER_BATCH], FULL_GRID)
    return len(names)


def bench_nbrdf(data: Path) -> None:
    archives = [open_dataset(f"nbrdf:{data / f}") for f in ("nbrdf_merl.npz", "nbrdf_rgl.npz")]
    first = archives[0]
    first.tabulate([first.names()[0]], FULL_GRID)  # warm up: weights loaded, grid cached
    one = statistics.median(timed(lambda: first.tabulate([first.names()[0]], FULL_GRID)) for _ in range(3))
    print(f"nbrdf: one material, full grid: {one:.2f} s (median of 3)")
    with Clock() as clock:
        count = sum(tabulate_all(archive) for archive in archives)
    print(f"nbrdf: all {count} materials, full grid: {clock}")


def bench_builtin() -> None:
    dataset = open_dataset("builtin")
    with Clock() as clock:
        count = tabulate_all(dataset)
    print(f"builtin: all {count} materials, full grid (incl. albedo tables): {clock}")
    one = statistics.median(timed(lambda: dataset.tabulate(["red-plastic"], FULL_GRID)) for _ in range(3))
    print(f"builtin: one material (red-plastic), full grid: {one:.2f} s (median of 3)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=REPO.parent / "shared" / "data")
    parser.add_argument("--skip-nbrdf", action="store_true")
    parser.add_argument("--skip-builtin", action="store_true")
    args = parser.parse_args()
    FULL_GRID.valid_cells  # the valid mask is computed once per process; not part of the timings
    print(f"cores: {os.cpu_count()}, load average before: {os.getloadavg()[0]:.1f}")
    if not args.skip_nbrdf:
        bench_nbrdf(args.data)
    if not args.skip_builtin:
        bench_builtin()
    print(f"load average after: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
