"""Small simulated sessions for the monitor's tests (the same rig, model and plan as test_session)."""
from __future__ import annotations

import hashlib
import json
import threading
import time
from pathlib import Path

from test_session import GRID, MATERIAL, TRAINING, journal_rows, write_rig


def make_plan(folder: Path, m: int) -> tuple[Path, Path]:
    """(rig file, plan file) of an m-sample plan on the small simulated rig, in ``folder``."""
    from goniofrost.app.demo import plan_on_rig
    from goniofrost.core.cache import cache_path
    from goniofrost.frost.training import train

    model = train(["builtin"], only=TRAINING, grid=GRID, k_max=18, cache=True)
    rig = write_rig(folder / "rig.yaml")
    plan = plan_on_rig(model, cache_path("models", model.info["cache_key"], ""), m, rig, folder / f"plan{m}.json")
    return rig, plan


def fault_after(session: Path, plan: Path, n_done: int):
    """An ``on_ready`` that injects an alarm into an axis that still has to move once ``n_done``
    samples are journaled; returns (on_ready, the axis name)."""
    samples = json.loads(plan.read_text())["samples"]

    def turns_later(axis: str) -> bool:
        return any(abs(a["joints"][axis] - b["joints"][axis]) > 1.0
                   for a, b in zip(samples[n_done - 1:], samples[n_done:]))

    axis = next(a for a in ("camera_arm", "sample_yaw", "sample_tilt") if turns_later(a))

    def on_ready(hardware):
        def watch():
            while len(journal_rows(session)) < n_done:
                time.sleep(0.005)
            hardware.simulation.device(axis).inject_fault("alarm")
        threading.Thread(target=watch, daemon=True).start()
    return on_ready, axis


def folder_state(folder: Path) -> dict:
    """Every file under ``folder`` (relative name -> SHA-256 of its bytes)."""
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


__all__ = ["GRID", "MATERIAL", "make_plan", "fault_after", "folder_state", "journal_rows"]
