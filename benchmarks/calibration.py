"""Calibration benchmark: a 20-sample plan of a glossy material through the simulated camera
with noise on -> median relative error per channel against the ground truth, per-sample capture
and calibration time, frames taken and skipped.

Usage (from the repository root)::

    .venv/bin/python benchmarks/calibration.py
        [--material nbrdf:../shared/data/nbrdf_merl.npz:gold-metallic-paint2] [--samples 20]
        [--max-angle 75] [--seed 0] [--repeats 3] [--rig config/rigs/sim.yaml] [--out results.json]

The plan: ``--samples`` random valid cells of the full MERL grid with theta_i, theta_o <= the
max angle (each at its cell's lower-edge directions, rotated about z by a random azimuth so the
holder is seen from every side). One calibration (dark, flat, white) per repeat, then every
sample measured (the calibration and sample plans of goniofrost.capture run on a camera bench).
Times are wall seconds on this machine: ``capture`` is inside ``camera.capture`` (render, noise,
DNG write), ``calibration`` is the rest of a sample's plan (RAW decode, markers, HDR, scale);
medians over samples and repeats (the machine is shared).
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml
from tqdm import tqdm

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from calib import validate_camera_section  # noqa: E402
from goniofrost.capture.calibration_steps import calibration_steps  # noqa: E402
from goniofrost.capture.executor import BenchHardware, StepExecutor  # noqa: E402
from goniofrost.capture.sample_steps import sample_steps  # noqa: E402
from goniofrost.capture.steps import drive  # noqa: E402
from goniofrost.core.grid import FULL_GRID  # noqa: E402
from goniofrost.datasets import material_brdf  # noqa: E402
from sim.camera_bench import CameraBench  # noqa: E402

DEFAULT_MATERIAL = f"nbrdf:{REPO.parent / 'shared' / 'data' / 'nbrdf_merl.npz'}:gold-metallic-paint2"


def plan(n: int, max_angle_deg: float, seed: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """``n`` random valid cells with both zenith angles <= max: (w_i, w_o) pairs, each (3,)."""
    rng = np.random.default_rng(seed)
    cells = rng.choice(FULL_GRID.valid_cells, size=20 * n, replace=False)
    w_i, w_o = FULL_GRID.cell_directions(cells)
    limit = np.cos(np.radians(max_angle_deg))
    keep = np.flatnonzero((w_i[:, 2] >= limit) & (w_o[:, 2] >= limit))[:n]
    out = []
    for k in keep:
        a = rng.uniform(0, 2 * np.pi)
        rot = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
        out.append((rot @ w_i[k], rot @ w_o[k]))
    return out


def run_once(material: str, rig: dict, poses, seed: int, work: Path) -> dict:
    """Calibrate, measure every pose; per-sample rows and the calibration time."""
    bench = CameraBench(material_brdf(material), rig["sim"]["camera"], rig["camera"], seed=seed, speedup=rig["sim"]["clock_speedup"])
    settings = validate_camera_section(rig["camera"], "rig file")
    devices = StepExecutor(BenchHardware(bench.lamp, bench.camera, bench.clock), work)
    t0 = time.perf_counter()
    record = drive(calibration_steps(settings, white_pose=bench.pose), devices)
    calib_s = time.perf_counter() - t0
    rows, expected = [], None
    for k, (w_i, w_o) in enumerate(tqdm(poses, desc="samples", file=sys.stderr, leave=False)):
        bench.pose = (w_i, w_o)
        t0 = time.perf_counter()
        m = drive(sample_steps(settings, record, (w_i, w_o), k, expected), devices)
        if not hasattr(m, "rgb"):   # calib.NotMeasured: too dark for this ladder
            raise SystemExit(f"benchmark pose {k}: {m.text()}")
        sample_s, expected = time.perf_counter() - t0, np.maximum(m.rgb, 1e-6)
        truth = bench.camera.ground_truth(w_i, w_o)
        rows.append({"sample": k, "theta_i_deg": float(np.degrees(np.arccos(w_i[2]))),
                     "theta_o_deg": float(np.degrees(np.arccos(w_o[2]))), "truth": truth.tolist(),
                     "rgb": m.rgb.tolist(), "rel_error": (m.rgb / truth - 1).tolist(),
                     "z": ((m.rgb - truth) / m.sigma).tolist(), "frames_taken": m.frames_taken,
                     "frames_skipped": m.frames_skipped, "exposures_s": m.exposures_s,
                     "capture_s": m.capture_seconds, "calibration_s": sample_s - m.capture_seconds,
                     "flags": m.flags})
    return {"calibrate_s": calib_s, "rows": rows}


def summarise(runs: list[dict]) -> dict:
    rows = [r for run in runs for r in run["rows"]]
    rel = np.abs(np.array([r["rel_error"] for r in rows]))
    z = np.abs(np.array([r["z"] for r in rows]))
    med = lambda key: statistics.median(r[key] for r in rows)  # noqa: E731
    return {"samples": len(runs[0]["rows"]), "repeats": len(runs),
            "median_rel_error": dict(zip("RGB", np.median(rel, axis=0).round(5).tolist())),
            "max_rel_error": dict(zip("RGB", rel.max(axis=0).round(5).tolist())),
            "fraction_within_2sigma": float(np.mean(z <= 2)),
            "median_capture_s": med("capture_s"), "median_calibration_s": med("calibration_s"),
            "median_sample_s": statistics.median(r["capture_s"] + r["calibration_s"] for r in rows),
            "frames_taken_total": sum(r["frames_taken"] for r in runs[0]["rows"]),
            "frames_skipped_total": sum(r["frames_skipped"] for r in runs[0]["rows"]),
            "calibrate_s_median": statistics.median(run["calibrate_s"] for run in runs),
            "low_snr_samples": sum("low-snr" in r["flags"] for r in runs[0]["rows"])}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--material", default=DEFAULT_MATERIAL)
    ap.add_argument("--rig", type=Path, default=REPO / "config" / "rigs" / "sim.yaml")
    ap.add_argument("--samples", type=int, default=20)
    ap.add_argument("--max-angle", type=float, default=75.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", type=Path)
    args = ap.parse_args(argv)
    rig = yaml.safe_load(args.rig.read_text())
    poses = plan(args.samples, args.max_angle, args.seed)
    runs = []
    for rep in range(args.repeats):
        with tempfile.TemporaryDirectory() as tmp:
            runs.append(run_once(args.material, rig, poses, args.seed + rep, Path(tmp)))
    print(f"{'#':>3} {'th_i':>5} {'th_o':>5} {'truth G':>9} {'err R%':>7} {'err G%':>7} {'err B%':>7} "
          f"{'taken':>5} {'skip':>4} {'capt s':>7} {'calib s':>7}  exposures (first repeat)")
    for r in runs[0]["rows"]:
        e = np.array(r["rel_error"]) * 100
        print(f"{r['sample']:>3} {r['theta_i_deg']:5.1f} {r['theta_o_deg']:5.1f} {r['truth'][1]:9.4f} "
              f"{e[0]:7.2f} {e[1]:7.2f} {e[2]:7.2f} {r['frames_taken']:>5} {r['frames_skipped']:>4} "
              f"{r['capture_s']:7.3f} {r['calibration_s']:7.3f}  {r['exposures_s']}{' ' + str(r['flags']) if r['flags'] else ''}")
    summary = summarise(runs)
    print(json.dumps(summary, indent=2))
    if args.out:
        args.out.write_text(json.dumps({"summary": summary, "runs": runs}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
