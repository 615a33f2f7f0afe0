"""A scripted journal writer: a session's journal written through the Journal API one call at a time,
deterministically, so that a reader (the monitor page in a browser) can be checked after each step
instead of racing a live capture."""
from __future__ import annotations

import json
import time
from pathlib import Path

from goniofrost.capture.journal import Journal, SampleRecord
from goniofrost.capture.records import EventKind, RunEnd, RunStart, RunStatus

REPO = Path(__file__).resolve().parents[1]


def plan_samples(n: int) -> list[dict]:
    """``n`` plan samples on the simulated rig of config/rigs/sim.yaml (1 s moves)."""
    return [{"cell": [10, 20, 30 + i], "theta_i_deg": 20.0 + i, "theta_o_deg": 40.0, "move_s": 1.0,
             "joints": {"camera_arm": 60.0, "sample_yaw": 10.0 * i, "sample_tilt": 5.0}} for i in range(n)]


class ScriptedSession:
    """The journal of a session in ``folder`` with an ``n``-sample plan (``batch_ends`` for a
    target-error capture); each method is one thing the engine journals."""

    def __init__(self, folder: Path, n: int, batch_ends=None, target=None) -> None:
        self.folder, self.samples = Path(folder), plan_samples(n)
        plan = {"samples": self.samples, **({"batch_ends": list(batch_ends)} if batch_ends else {})}
        meta = {"plan": plan, "plan_sha256": "p", "rig_text": (REPO / "config" / "rigs" / "sim.yaml").read_text(),
                "rig_name": "sim-rig", "model_path": str(self.folder / "no-model"), "model_hash": "m",
                "plan_file": str(self.folder / "plan.json"), "target_error": target}
        self.journal = Journal.create(self.folder / "session.sqlite", meta)
        self.start = None
        self.batches = 0

    def start_run(self) -> None:
        done = len(self.journal.done_indices())
        self.start = RunStart(self.journal.next_run(), "capture", time.time(), len(self.samples), done)
        self.journal.start_run(self.start)
        self.journal.add_event(EventKind.SESSION, f"capture run {self.start.run} started")

    def calibrate(self) -> None:
        self.journal.set_calibration({"version": 1, "scale": [1.0, 1.0, 1.0]})
        self.journal.add_event(EventKind.CALIBRATION, "dark, flat and white reference taken")

    def capture(self, index: int, snr: float = 80.0) -> None:
        """Sample ``index``: its Move step, then its Commit step with the sample in one transaction."""
        joints = self.samples[index]["joints"]
        row = self.journal.start_step(self.start.run, "Move", index, {"index": index, "joints": joints})
        self.journal.end_step(row, "done", {"joints": joints, "seconds": 1.0})
        row = self.journal.start_step(self.start.run, "Commit", index, {"index": index})
        now = time.time()
        record = SampleRecord(index, 7, 1.0, 2.0, 3.0 + index, (0.1, 0.2, 0.3), (0.01,) * 3, snr, joints=joints,
                              exposures_s=(0.032,), started_utc=now - 0.5, committed_utc=now)
        self.journal.commit_sample(record, step=(row, {"snr": snr}))

    def batch(self, samples: int, predicted: float, target: float, decision: str, bound: float | None = None,
              confidence: float = 0.95, out_of_model=()) -> None:
        """An Assess step's fields as the engine journals them (``predicted``: the median estimate)."""
        self.batches += 1
        self.journal.add_event(EventKind.BATCH, f"batch {self.batches}: {decision}",
                               data={"batch": self.batches - 1, "samples": samples, "predicted_error": predicted,
                                     "target": target, "decision": decision, "bound": bound,
                                     "confidence": confidence, "out_of_model": list(out_of_model)})

    def end_run(self, status: RunStatus, reason: str) -> RunEnd:
        end = RunEnd(self.start.run, status, reason, len(self.samples), len(self.journal.done_indices()),
                     self.batches, self.start.started_utc, time.time())
        self.journal.end_run(end)
        self.journal.add_event(EventKind.SESSION, reason)
        return end

    def write_report(self, predicted: float) -> None:
        """report.json and summary.txt, as the capture writes them at the end (atomically)."""
        n = len(self.journal.done_indices())
        report = {"samples": n, "prediction": {"predicted_log_relative_mse": predicted}}
        (self.folder / "report.json.tmp").write_text(json.dumps(report))
        (self.folder / "report.json.tmp").rename(self.folder / "report.json")
        (self.folder / "summary.txt").write_text(f"session {self.folder}: {n} samples on rig 'sim-rig'\n")

    def close(self) -> None:
        self.journal.close()
