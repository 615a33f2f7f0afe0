"""QUEUE.yaml: several samples to measure in one run, one session folder each.

```
rig: config/rigs/sim.yaml
plan: plan.json
root: sessions            # one session folder per sample, named after its sample_id
operator: A. Operator
drift_limit: 0.05         # optional: the white scale's relative change that calls for a full recalibration
samples:
  - {sample_id: S-001, material: builtin:red-plastic}   # material: simulated rig only
  - {sample_id: S-002, material: builtin:gold, note: second coat}
```

Paths are relative to the queue file. Every key is checked with the project's key tables
(``goniofrost.core.config_check``); a problem is one ConfigError naming the file and the key.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from goniofrost.core.config_check import Key, check_section, is_number
from goniofrost.core.errors import ConfigError

DEFAULT_DRIFT_LIMIT = 0.05  # 5 %: the white scale moved more than the flat field's own uncertainty allows
SAMPLE_ID = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")  # a folder name on any file system


def _text(value) -> bool:
    return isinstance(value, str) and value.strip() != "" and "\n" not in value


def _optional_text(value) -> bool:
    return value is None or _text(value)


QUEUE_KEYS = {
    "rig": Key(_text, "the rig file (a path relative to the queue file)"),
    "plan": Key(_text, "the plan file from goniofrost plan --rig (relative to the queue file)"),
    "root": Key(_text, "the folder of the sessions (relative to the queue file)"),
    "operator": Key(_optional_text, "a one-line text (who measures)", None),
    "alignment": Key(_optional_text, "an ALIGNMENT.json (relative to the queue file)", None),
    "drift_limit": Key(lambda v: is_number(v) and 0 < v < 1,
                       "the white scale's relative change beyond which everything is calibrated again, in (0, 1)",
                       DEFAULT_DRIFT_LIMIT),
    "samples": Key(lambda v: isinstance(v, list) and len(v) > 0, "a list of samples ({sample_id: ID, ...})"),
}
SAMPLE_KEYS = {
    "sample_id": Key(lambda v: isinstance(v, str) and SAMPLE_ID.fullmatch(v) is not None,
                     "a sample id of letters, digits, '.', '_', '-' (it names the session folder)"),
    "material": Key(_optional_text, "SPEC:NAME of the material the simulated rig shows", None),
    "operator": Key(_optional_text, "a one-line text (who measures this sample)", None),
    "note": Key(_optional_text, "a one-line note", None),
    "notes": Key(lambda v: v is None or (isinstance(v, list) and all(_text(n) for n in v)),
                 "a list of one-line notes", None),
}


@dataclass(frozen=True)
class QueueSample:
    """One sample of a queue: its id (and session folder name), material (simulated rig), operator
    and notes."""

    sample_id: str
    material: str | None
    operator: str | None
    notes: tuple[str, ...]


@dataclass(frozen=True)
class Queue:
    """A checked queue file: absolute paths, the drift limit and the samples in order."""

    path: Path
    rig: Path
    plan: Path
    root: Path
    alignment: Path | None
    drift_limit: float
    samples: tuple[QueueSample, ...]

    def session_dir(self, sample: QueueSample) -> Path:
        return self.root / sample.sample_id


def read_queue(path) -> Queue:
    """Read and check QUEUE.yaml (ConfigError on the first problem: file, key, expected, found)."""
    from planner.schema import read_yaml

    path = Path(path).resolve()
    top = check_section(read_yaml(path), QUEUE_KEYS, path, "")
    samples, seen = [], set()
    for i, raw in enumerate(top["samples"]):
        keypath = f"samples[{i}]"
        s = check_section(raw, SAMPLE_KEYS, path, keypath)
        if s["sample_id"] in seen:
            raise ConfigError(path, f"{keypath}.sample_id", "a sample id not used before in the queue", s["sample_id"])
        seen.add(s["sample_id"])
        notes = tuple(([s["note"]] if s["note"] else []) + list(s["notes"] or []))
        samples.append(QueueSample(s["sample_id"], s["material"], s["operator"] or top["operator"], notes))
    here = path.parent
    return Queue(path, here / top["rig"], here / top["plan"], here / top["root"],
                 None if top["alignment"] is None else here / top["alignment"], float(top["drift_limit"]),
                 tuple(samples))
