"""Session benchmark: `goniofrost demo` end to end (fresh or warm cache), and a held-out capture.

Usage (from the repository root)::

    .venv/bin/python benchmarks/session.py [--repeats 3] [--fresh] [--material red-plastic]
        [--samples 20] [--out results.json]

Each repeat runs the demo in a subprocess (as a user would) into a temporary folder and reads its
report.json: wall time per stage (train, plan, capture, preview), the session's motion and
capture times (simulated clock), the error of the simulated capture against the ground truth and
against reconstructing the same cells from exact values (the issue's bar: ratio <= 1.2), and the
rendering SNR. ``--fresh`` gives every repeat an empty goniofrost cache (a fresh install: training
included); otherwise the first repeat warms the cache. Timings are medians of the repeats (the
machine is shared, so single timings are noisy).
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def run_once(material: str, samples: int, cache: Path) -> dict:
    """One demo run in a subprocess; its report plus the subprocess wall time."""
    with tempfile.TemporaryDirectory() as out:
        env = {**os.environ, "GONIOFROST_CACHE": str(cache)}
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "goniofrost", "demo", "--out", out, "--material", material,
                        "--samples", str(samples), "--no-progress"], check=True, env=env, cwd=REPO,
                       stdout=subprocess.DEVNULL)
        wall = time.perf_counter() - t0
        report = json.loads((Path(out) / "report.json").read_text())
    return {"wall_s": wall, "stages_s": report["demo"]["stages_s"], "motion_s": report["times_s"]["motion"],
            "capture_s": report["times_s"]["capture"], "planned_motion_s": report["times_s"]["planned_motion"],
            "error": report["ground_truth"]["log_relative_mse"],
            "error_exact": report["ground_truth"]["log_relative_mse_exact_samples"],
            "ratio": report["ground_truth"]["ratio_to_exact"], "rendering_snr_db": report["demo"]["rendering_snr_db"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--fresh", action="store_true", help="empty cache for every repeat (fresh install)")
    parser.add_argument("--material", default="red-plastic")
    parser.add_argument("--samples", type=int, default=20)
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    runs = []
    with tempfile.TemporaryDirectory() as shared_cache:
        for i in range(args.repeats):
            with tempfile.TemporaryDirectory() as own_cache:
                runs.append(run_once(args.material, args.samples, Path(own_cache if args.fresh else shared_cache)))
            print(f"run {i + 1}: {json.dumps(runs[-1])}", flush=True)
    summary = {key: statistics.median(r[key] for r in runs)
               for key in ("wall_s", "motion_s", "capture_s", "planned_motion_s", "error", "error_exact", "ratio",
                           "rendering_snr_db")}
    summary["stages_s"] = {k: statistics.median(r["stages_s"][k] for r in runs) for k in runs[0]["stages_s"]}
    print("median:", json.dumps(summary, indent=1))
    if args.out:
        args.out.write_text(json.dumps({"runs": runs, "median": summary, "args": vars(args) | {"out": str(args.out)}},
                                       indent=1))


if __name__ == "__main__":
    main()
