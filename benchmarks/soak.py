"""Soak: one long capture session on the simulated rig, watched for leaks.

Usage (from the repository root)::

    .venv/bin/python benchmarks/soak.py [--samples 1000] [--speedup 1000] [--out soak.json]

Builds a plan of N cells (random reachable cells of the test model's 30 x 30 x 60 grid with
theta_i, theta_o <= 60 deg, seeded, scheduled on the rig: FROST selects at most K cells, a soak
needs more), then runs ``goniofrost capture`` as a user would (a child process) on the simulated rig (the default
rig's ladder, a 192 x 144 sensor, one dark and one flat frame) at a high clock speed-up, sampling
every 0.2 s the samples journaled and the child's open file descriptors, threads and resident
memory (/proc). It reports the wall time, the time per sample, the child's peak memory, and its
descriptors, threads and memory at the first and at the last sample captured (devices connected:
they must not grow); and checks that every plan sample is in the journal and in samples.csv
exactly once.
"""
from __future__ import annotations

import argparse
import contextlib
import csv
import json
import os
import sqlite3
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))  # the project's packages before this folder's scripts (planner.py)
TRAINING = ["white-diffuse", "blue-plastic", "gold", "white-ceramic", "blue-car-paint", "green-felt"]
MAX_ANGLE_DEG = 60.0


def prepare(folder: Path, n: int, seed: int) -> tuple[Path, Path]:
    """The soak rig file and a scheduled plan of ``n`` random reachable cells."""
    from goniofrost.plan.file import plan_document, write_plan
    from goniofrost.rig.file import load_checked_rig
    from goniofrost.core.cache import cache_path
    from goniofrost.core.grid import MerlGrid
    from goniofrost.frost.selection import Selection, candidate_mask_max_angle
    from goniofrost.frost.training import train
    from planner.reach import reachability
    from planner.schedule import schedule_plan

    grid = MerlGrid(30, 30, 60)
    model = train(["builtin"], only=TRAINING, grid=grid, k_max=18, cache=True)
    doc = yaml.safe_load((REPO / "config" / "rigs" / "sim.yaml").read_text())
    doc["camera"].update(dark_frames=1, flat_frames=1)
    # a small sensor (2.4 px/mm at the sample): the card still fits the frame at every pose
    doc["camera"]["intrinsics"].update(image_size_px=[240, 180], focal_px=[2400.0, 2400.0],
                                    principal_point_px=[119.5, 89.5])
    rig_path = folder / "rig.yaml"
    rig_path.write_text(yaml.safe_dump(doc, sort_keys=False))
    rig = load_checked_rig(rig_path)
    candidates = reachability(rig, grid).mask & candidate_mask_max_angle(grid, MAX_ANGLE_DEG)
    positions = np.sort(np.random.default_rng(seed).choice(np.flatnonzero(candidates), n, replace=False))
    selection = Selection(positions, grid.valid_cells[positions], np.zeros(n), 0.0, "all", model.n_components)
    # one restart of the tour search: the order does not matter to a soak, and 1000 samples take minutes
    plan = schedule_plan(plan_document(cache_path("models", model.info["cache_key"], ""), model, selection), rig,
                         restarts=1)
    write_plan(folder / "plan.json", plan)
    return rig_path, folder / "plan.json"


def process_state(pid: int) -> dict:
    """Open file descriptors, threads, resident memory and its peak so far (MB) of process ``pid``."""
    proc = Path(f"/proc/{pid}")
    status = dict(line.split(":", 1) for line in (proc / "status").read_text().splitlines() if ":" in line)
    return {"fds": len(os.listdir(proc / "fd")), "threads": len(os.listdir(proc / "task")),
            "rss_mb": int(status["VmRSS"].split()[0]) / 1024, "peak_mb": int(status["VmHWM"].split()[0]) / 1024}


def watch(proc: subprocess.Popen, journal: Path, period_s: float = 0.2) -> list[tuple[int, dict]]:
    """(samples journaled, process state) every ``period_s`` until the process ends."""
    seen, db = [], None
    while proc.poll() is None:
        try:
            if db is None and journal.exists():
                db = sqlite3.connect(f"file:{journal}?mode=ro", uri=True)
            n = db.execute("SELECT COUNT(*) FROM samples").fetchone()[0] if db is not None else 0
            seen.append((n, process_state(proc.pid)))
        except (sqlite3.Error, OSError, KeyError):
            pass  # the journal is being created, or the process just ended (no VmRSS)
        time.sleep(period_s)
    if db is not None:
        db.close()
    return seen


def capturing(seen: list, n: int, which: str) -> dict:
    """The state at the first journaled sample, or at the last one taken while samples were still
    being captured (devices connected)."""
    during = [(k, s) for k, s in seen if 0 < k < n] or [(k, s) for k, s in seen if k > 0]
    k, state = during[0] if which == "first" else during[-1]
    return {"samples_done": k, **state}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--samples", type=int, default=1000)
    parser.add_argument("--speedup", type=float, default=1000.0, help="simulated clock speed-up (default 1000)")
    parser.add_argument("--material", default="builtin:red-plastic")
    parser.add_argument("--seed", type=int, default=0, help="the plan's random cells")
    parser.add_argument("--out", type=Path, help="also write the figures as JSON")
    args = parser.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        t0 = time.perf_counter()
        rig, plan = prepare(folder, args.samples, args.seed)
        print(f"plan of {args.samples} samples made in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
        session = folder / "session"
        command = [sys.executable, "-m", "goniofrost", "capture", "--rig", str(rig), "--plan", str(plan),
                   "--session", str(session), "--material", args.material, "--speedup", str(args.speedup),
                   "--no-progress"]
        t0 = time.perf_counter()
        proc = subprocess.Popen(command, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        seen = watch(proc, session / "session.sqlite")
        err = proc.stderr.read().decode()
        wall = time.perf_counter() - t0
        if proc.wait() != 0:
            sys.exit(f"capture failed ({proc.returncode}): {err}")
        peak_mb = max(state["peak_mb"] for _, state in seen)  # VmHWM, read up to 0.2 s before the end
        with contextlib.closing(sqlite3.connect(session / "session.sqlite")) as db:
            journaled = [r[0] for r in db.execute("SELECT plan_index FROM samples ORDER BY plan_index")]
        with open(session / "samples.csv") as handle:
            in_csv = sorted(int(row["plan_index"]) for row in csv.DictReader(handle))
        report = json.loads((session / "report.json").read_text())
    figures = {
        "samples": args.samples, "speedup": args.speedup, "wall_s": wall, "per_sample_ms": 1000 * wall / args.samples,
        "calibration_wall_s": report["times_s"]["calibration_wall_this_run"],
        "simulated_motion_and_capture_s": report["times_s"]["motion_and_capture"],
        "wall_in_session_s": report["times_s"]["wall_this_run"], "peak_rss_mb": peak_mb,
        "first_sample": capturing(seen, args.samples, "first"), "last_sample": capturing(seen, args.samples, "last"),
        "terminal_lines": err.count("\n"),
        "every_sample_once": journaled == list(range(args.samples)) and in_csv == list(range(args.samples)),
    }
    first, last = figures["first_sample"], figures["last_sample"]
    print(f"soak: {args.samples} samples at speed-up {args.speedup:g}: `goniofrost capture` took {wall:.1f} s "
          f"({figures['per_sample_ms']:.1f} ms per sample; the engine's run {figures['wall_in_session_s']:.1f} s, "
          f"calibration {figures['calibration_wall_s']:.1f} s), {figures['terminal_lines']} lines on stderr")
    print(f"  every plan sample exactly once in journal and samples.csv: {figures['every_sample_once']}")
    print(f"  peak resident memory of the capture process: {figures['peak_rss_mb']:.0f} MB")
    for name, state in ((f"at sample {first['samples_done']}", first), (f"at sample {last['samples_done']}", last)):
        print(f"  {name:>15}: {state['fds']} open fds, {state['threads']} threads, {state['rss_mb']:.0f} MB resident")
    if args.out:
        args.out.write_text(json.dumps(figures, indent=1))


if __name__ == "__main__":
    main()
