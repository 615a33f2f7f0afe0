"""Time evaluating RGL tensor files on the full MERL grid (1,111,432 valid cells), no cache.

    .venv/bin/python benchmarks/rgl_dataset.py DIR_OR_FILE [--repeats 3] [--out rgl_time.json]

For every ``.bsdf`` of ``rgl:DIR_OR_FILE``: the wall and CPU time of reading the file and
tabulating it on the full grid (median of the repeats, the file read again each time), its kind
and domain. Timings on a shared machine are noisy: the load average is printed with them.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import time

from goniofrost.core.grid import FULL_GRID
from goniofrost.datasets.rgl import RglDataset


def time_file(path, name: str, repeats: int) -> dict:
    """Median wall and CPU seconds of a fresh read + full-grid tabulation of one material."""
    walls, cpus = [], []
    for _ in range(repeats):
        dataset = RglDataset(path)  # nothing kept from the last repeat
        wall, cpu = time.perf_counter(), time.process_time()
        dataset.tabulate([name], FULL_GRID)
        walls.append(time.perf_counter() - wall)
        cpus.append(time.process_time() - cpu)
    return {"material": name, "wall_s": statistics.median(walls), "cpu_s": statistics.median(cpus),
            "domain": RglDataset(path).domain(name)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("path")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out")
    args = parser.parse_args()
    rows = [time_file(args.path, name, args.repeats) for name in RglDataset(args.path).names()]
    for row in rows:
        print(f"{row['material']}: {row['wall_s']:.2f} s wall, {row['cpu_s']:.2f} s CPU ({row['domain']})")
    summary = {"files": len(rows), "median_wall_s": statistics.median(r["wall_s"] for r in rows),
               "median_cpu_s": statistics.median(r["cpu_s"] for r in rows), "load_average": os.getloadavg(),
               "cores": os.cpu_count(), "rows": rows}
    print(f"{len(rows)} files: median {summary['median_wall_s']:.2f} s wall, {summary['median_cpu_s']:.2f} s CPU "
          f"per file; load average {summary['load_average'][0]:.1f} on {summary['cores']} cores")
    if args.out:
        with open(args.out, "w") as handle:
            json.dump(summary, handle, indent=1)


if __name__ == "__main__":
    main()
