"""The fault matrix: every fault kind on every protocol, rehearsed from the rig file, then resumed.

Usage (from the repository root)::

    .venv/bin/python benchmarks/fault_matrix.py [--samples 5] [--at-sample 2] [--kinds K ...] [--axes A ...]
        [--out matrix.json]

For each kind (no_reply, bad_checksum, drop_byte, alarm, stall, disconnect) on each protocol
(Modbus TCP camera_arm, Dynamixel sample_yaw, SMC100 sample_tilt) it writes a copy of the small
test rig with ``sim: faults: [{axis, kind, at_sample}]``, runs ``goniofrost capture`` on a short
plan (in this process, as ``goniofrost.app.cli.main``), then the same command with ``--resume``.
It prints one row per case: the exit code and the one-line error of the faulted run, the lines
the terminal showed, how each axis took the stop as the session reported it and what the
simulated device really did, whether the lamp confirmed it is off (and really is), and the resumed
run: its exit code, every plan sample exactly once in journal and samples.csv, and samples.csv,
brdf.binary and every RAW frame byte-identical to an uninterrupted run without the drill.

The rig, plan and model are the test suite's (tests/test_session.py): a 6-material model on the
30 x 30 x 60 grid, a 192 x 144 simulated sensor, a four-exposure ladder, clock speed-up 50.
"""
from __future__ import annotations

import argparse
import contextlib
import csv
import dataclasses
import io
import json
import sqlite3
import sys
import tempfile
import time
from pathlib import Path
from unittest import mock

import yaml

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))  # the project's packages before this folder's scripts (planner.py)
AXES = {"camera_arm": "Modbus TCP", "sample_yaw": "Dynamixel", "sample_tilt": "SMC100"}
KINDS = ("no_reply", "bad_checksum", "drop_byte", "alarm", "stall", "disconnect")
TRAINING = ["white-diffuse", "blue-plastic", "gold", "white-ceramic", "blue-car-paint", "green-felt"]
MATERIAL = "builtin:red-plastic"


def prepare(folder: Path, samples: int) -> tuple[Path, Path]:
    """The test rig file and a plan of ``samples`` samples on it (model trained and cached)."""
    from goniofrost.app.demo import plan_on_rig
    from goniofrost.core.cache import cache_path
    from goniofrost.plan.make import PlanRequest
    from goniofrost.rig.file import load_checked_rig
    from goniofrost.core.grid import MerlGrid
    from goniofrost.frost.training import train

    model = train(["builtin"], only=TRAINING, grid=MerlGrid(30, 30, 60), k_max=18, cache=True)
    rig = yaml.safe_load((REPO / "config" / "rigs" / "sim.yaml").read_text())
    rig["camera"].update(exposures_s=[0.002, 0.008, 0.032, 0.128], dark_frames=1, flat_frames=1)
    # a small sensor (2.4 px/mm at the sample): the card still fits the frame at every pose
    rig["camera"]["intrinsics"].update(image_size_px=[240, 180], focal_px=[2400.0, 2400.0],
                                    principal_point_px=[119.5, 89.5])
    (folder / "rig.yaml").write_text(yaml.safe_dump(rig, sort_keys=False))
    request = PlanRequest(samples=samples, selector="frost", rig=load_checked_rig(folder / "rig.yaml"))
    plan = plan_on_rig(model, cache_path("models", model.info["cache_key"], ""), request, folder / "plan.json")
    return folder / "rig.yaml", plan


def drill_rig(rig: Path, out: Path, axis: str, kind: str, at_sample: int) -> Path:
    doc = yaml.safe_load(rig.read_text())
    doc["sim"]["faults"] = [{"axis": axis, "kind": kind, "at_sample": at_sample}]
    out.write_text(yaml.safe_dump(doc, sort_keys=False))
    return out


def run_cli(argv: list[str], seen: dict | None = None) -> tuple[int, str]:
    """``goniofrost`` ARGV in this process: (exit code, what the terminal's stderr showed).
    ``seen``: filled with the simulated rig (``simulation``) once its devices are connected."""
    from goniofrost.app.cli import main
    from goniofrost.capture import runner

    capture = runner.capture

    def watched(*args, **kwargs):
        ready = dataclasses.replace(kwargs["sim"], on_ready=lambda hw: seen.update(simulation=hw.simulation))
        return capture(*args, **kwargs | {"sim": ready})

    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        with mock.patch.object(runner, "capture", watched) if seen is not None else contextlib.nullcontext():
            code = main(argv)
    return code, err.getvalue()


def capture_args(rig: Path, plan: Path, session: Path, *extra: str) -> list[str]:
    return ["capture", "--rig", str(rig), "--plan", str(plan), "--session", str(session), "--material", MATERIAL,
            "--no-progress", "--speedup", "50", *extra]


def journal_facts(session: Path) -> dict:
    with contextlib.closing(sqlite3.connect(f"file:{session / 'session.sqlite'}?mode=ro", uri=True)) as db:
        indices = [r[0] for r in db.execute("SELECT plan_index FROM samples ORDER BY plan_index")]
        events = [(k, json.loads(d)) for k, d in db.execute("SELECT kind, data FROM events ORDER BY id")]
    with open(session / "samples.csv") as handle:
        csv_indices = sorted(int(row["plan_index"]) for row in csv.DictReader(handle))
    return {"journal": indices, "csv": csv_indices, "events": events}


def frames(session: Path) -> dict:
    """{relative path: bytes} of every RAW frame of a session."""
    return {str(p.relative_to(session)): p.read_bytes() for p in sorted(session.glob("*/*.dng"))}


def one_case(folder: Path, rig: Path, plan: Path, reference: Path, axis: str, kind: str, at_sample: int,
             n: int) -> dict:
    drilled = drill_rig(rig, folder / f"rig-{axis}-{kind}.yaml", axis, kind, at_sample)
    session = folder / f"s-{axis}-{kind}"
    seen: dict = {}
    t0 = time.perf_counter()
    code, err = run_cli(capture_args(drilled, plan, session), seen)
    fault_s = time.perf_counter() - t0
    simulation = seen["simulation"]
    facts = journal_facts(session)
    [stop] = [d for k, d in facts["events"] if k == "stop"] or [{"stops": []}]
    lamp = [d for k, d in facts["events"] if k == "lamp" and "off" in d]
    real = {"lamp_on": simulation.lamp_model.is_on,
            "axes": {name: round(simulation.truth_after[name], 2) for name in AXES}}
    t0 = time.perf_counter()
    code2, err2 = run_cli(capture_args(drilled, plan, session, "--resume"))
    resume_s = time.perf_counter() - t0
    after = journal_facts(session)
    struck_again = sum(1 for k, d in after["events"] if k == "drill" and d.get("state") == "struck")
    return {
        "axis": axis, "protocol": AXES[axis], "kind": kind, "exit": code, "error": err.strip(),
        "terminal_lines": err.count("\n"), "done_before_resume": len(facts["journal"]),
        "stops": stop["stops"], "real_axes": real["axes"],
        "lamp_confirmed_off": bool(lamp and lamp[-1]["off"]), "lamp_really_on": real["lamp_on"],
        "resume_exit": code2, "resume_error": err2.strip(),
        "every_sample_once": after["journal"] == list(range(n)) and after["csv"] == list(range(n)),
        "identical": all((session / f).read_bytes() == (reference / f).read_bytes()
                         for f in ("samples.csv", "brdf.binary")) and frames(session) == frames(reference),
        "drill_struck_times": struck_again, "fault_s": fault_s, "resume_s": resume_s,
    }


def install_truth_probe() -> None:
    """Record, as the simulated rig stops, where each simulated axis really came to rest (after any
    motion it kept up) and keep it on the rig as ``truth_after`` {axis: degrees}."""
    from sim.rig import SimulatedRig

    stop = SimulatedRig.stop

    def probing_stop(self):
        devices = dict(self._devices)
        if devices:
            deadline = time.monotonic() + 2.0
            while any(d.motion.is_moving() and not d.motion.stalled for d in devices.values()) \
                    and time.monotonic() < deadline:
                time.sleep(0.01)
            self.truth_after = {name: d.true_position_deg() for name, d in devices.items()}
        stop(self)

    SimulatedRig.stop = probing_stop


def stop_cell(row: dict) -> str:
    """The stops as the session reported them, with the truth beside each unconfirmed axis."""
    parts = []
    for s in row["stops"]:
        if s["confirmed"]:
            parts.append(f"{s['axis']} ok")
        else:
            going = f"->{s['moving_to']:.1f}" if s["moving_to"] is not None else ""
            parts.append(f"{s['axis']} NOT CONFIRMED{going} (really at {row['real_axes'][s['axis']]:.1f})")
    return ", ".join(parts)


def print_table(rows: list[dict]) -> None:
    print("| kind | protocol (axis) | exit | terminal lines | stops as reported (truth for unconfirmed) "
          "| lamp off confirmed (really off) | resume: exit, every sample once, identical files |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        lamp = f"{'yes' if r['lamp_confirmed_off'] else 'no'} ({'yes' if not r['lamp_really_on'] else 'NO'})"
        resume = f"{r['resume_exit']}, {'yes' if r['every_sample_once'] else 'NO'}, {'yes' if r['identical'] else 'NO'}"
        print(f"| {r['kind']} | {r['protocol']} ({r['axis']}) | {r['exit']} | {r['terminal_lines']} | "
              f"{stop_cell(r)} | {lamp} | {resume} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--samples", type=int, default=5, help="plan samples (default 5)")
    parser.add_argument("--at-sample", type=int, default=2, help="the drills' at_sample (default 2)")
    parser.add_argument("--kinds", nargs="+", choices=KINDS, default=list(KINDS), help="fault kinds (default all)")
    parser.add_argument("--axes", nargs="+", choices=list(AXES), default=list(AXES), help="axes (default all)")
    parser.add_argument("--out", type=Path, help="also write the rows as JSON")
    args = parser.parse_args()
    install_truth_probe()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        rig, plan = prepare(folder, args.samples)
        reference = folder / "reference"
        code, err = run_cli(capture_args(rig, plan, reference))
        if code != 0:
            sys.exit(f"the uninterrupted reference run failed: {err}")
        rows = []
        for kind in args.kinds:
            for axis in args.axes:
                rows.append(one_case(folder, rig, plan, reference, axis, kind, args.at_sample, args.samples))
                print(f"{kind} on {axis}: exit {rows[-1]['exit']}, {rows[-1]['fault_s']:.1f} s + resume "
                      f"{rows[-1]['resume_s']:.1f} s", file=sys.stderr)
    print_table(rows)
    if args.out:
        args.out.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
