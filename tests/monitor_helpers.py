"""Small simulated sessions for the monitor's tests (the same rig, model and plan as test_session)."""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

import yaml

from test_session import GRID, MATERIAL, journal_rows, small_plan, write_rig


def make_plan(folder: Path, m: int) -> tuple[Path, Path]:
    """(rig file, plan file) of an m-sample plan on the small simulated rig, in ``folder``."""
    rig = write_rig(folder / "rig.yaml")
    return rig, small_plan(rig, m, folder / f"plan{m}.json")[0]


def drilled_rig(rig: Path, plan: Path, at_sample: int, out: Path) -> tuple[Path, str]:
    """A copy of ``rig`` at ``out`` with one ``sim: faults:`` drill: an alarm on an axis that moves
    at plan sample ``at_sample``, so the drill strikes there (the capture's own clock, no thread
    watching the journal); returns (the drilled rig file, the axis name)."""
    samples = json.loads(plan.read_text())["samples"]
    before, at = samples[at_sample - 1]["joints"], samples[at_sample]["joints"]
    axis = next(a for a in ("camera_arm", "sample_yaw", "sample_tilt") if abs(at[a] - before[a]) > 1.0)
    doc = yaml.safe_load(rig.read_text())
    doc["sim"]["faults"] = [{"axis": axis, "kind": "alarm", "at_sample": at_sample}]
    out.write_text(yaml.safe_dump(doc, sort_keys=False))
    return out, axis


def folder_state(folder: Path) -> dict:
    """Every file under ``folder`` (relative name -> SHA-256 of its bytes)."""
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


__all__ = ["GRID", "MATERIAL", "make_plan", "drilled_rig", "folder_state", "journal_rows"]
