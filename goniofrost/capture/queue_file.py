"""QUEUE.yaml: several samples to measure in one run, one session folder each.

```
rig: config/rigs/sim.yaml
plan: plan.json
root: sessions            # one folder per sample, named after its sample_id
operator: A. Operator
drift_limit: 0.05         # optional: white scale change that calls for a full recalibration
target_error: 0.05        # optional: stop each capture at this error
confidence: 0.9           # optional, with a target (default 0.95)
samples:
  - {sample_id: S-001, material: builtin:red-plastic}   # material: simulated rig only
  - {sample_id: S-002, material: builtin:gold, target_error: null}   # the whole plan
```

Paths are relative to the queue file (``Queue.folder``); a sample's keys replace the queue's. A
bad key is one ConfigError naming the file and key.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from goniofrost.core.config_check import ABSENT, Key, check_section, is_number
from goniofrost.core.errors import ConfigError
from goniofrost.capture.target import DEFAULT_CONFIDENCE

DEFAULT_DRIFT_LIMIT = 0.05  # 5 %: the white scale moved more than the flat field's own uncertainty allows
SAMPLE_ID = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")  # a folder name on any file system


def _text(value) -> bool:
    return isinstance(value, str) and value.strip() != "" and "\n" not in value


def _optional_text(value) -> bool:
    return value is None or _text(value)


def _target(value) -> bool:
    return value is None or (is_number(value) and value > 0)


def _confidence(value) -> bool:
    return is_number(value) and 0 < value < 1


TARGET = "a log-relative MSE > 0 the captures stop at (e.g. 0.05), or null"
CONFIDENCE = "a probability between 0 and 1 (e.g. 0.95)"
QUEUE_KEYS = {
    "rig": Key(_text, "the rig file (a path relative to the queue file)"),
    "plan": Key(_text, "the plan file from goniofrost plan --rig (relative to the queue file)"),
    "root": Key(_text, "the folder of the sessions (relative to the queue file)"),
    "operator": Key(_optional_text, "a one-line text (who measures)", None),
    "alignment": Key(_optional_text, "an ALIGNMENT.json (relative to the queue file)", None),
    "drift_limit": Key(lambda v: is_number(v) and 0 < v < 1,
                       "the white scale's relative change beyond which everything is calibrated again, in (0, 1)",
                       DEFAULT_DRIFT_LIMIT),
    "target_error": Key(_target, TARGET, None),
    "confidence": Key(lambda v: v is None or _confidence(v), CONFIDENCE, None),
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
    "target_error": Key(_target, TARGET, ABSENT),       # absent: the queue's
    "confidence": Key(_confidence, CONFIDENCE, ABSENT),
}
WITH_TARGET = "a target_error as well, in the sample or the queue (the confidence is that of the bound that stops " \
              "the capture at it)"


@dataclass(frozen=True)
class QueueSample:
    """One sample of a queue: its id (and session folder name), material (simulated rig), operator
    and notes; the target error its capture stops at (None: the whole plan) and the bound's
    confidence, the queue's unless ``own`` (the keys the sample set itself) names them."""

    sample_id: str
    material: str | None
    operator: str | None
    notes: tuple[str, ...]
    target_error: float | None = None
    confidence: float = DEFAULT_CONFIDENCE
    own: frozenset = frozenset()


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

    @property
    def folder(self) -> Path:
        """The folder every relative path of the queue file is read from."""
        return self.path.parent

    def key_of(self, index: int, name: str) -> str:
        """The key path that set sample ``index``'s ``name`` (its own key, else the queue's)."""
        return f"samples[{index}].{name}" if name in self.samples[index].own else name


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
        samples.append(QueueSample(s["sample_id"], s["material"], s["operator"] or top["operator"], notes,
                                   *_target_of(s, top, path, keypath)))
    if top["confidence"] is not None and all(s.target_error is None for s in samples):  # it would change nothing
        raise ConfigError(path, "confidence", WITH_TARGET, top["confidence"])
    here = path.parent
    return Queue(path, here / top["rig"], here / top["plan"], here / top["root"],
                 None if top["alignment"] is None else here / top["alignment"], float(top["drift_limit"]),
                 tuple(samples))


def _target_of(sample: dict, top: dict, path: Path, keypath: str) -> tuple:
    """(target_error, confidence, own keys) of a checked sample under the queue's ``top`` keys."""
    own = frozenset(k for k in ("target_error", "confidence") if k in sample)
    target = sample["target_error"] if "target_error" in own else top["target_error"]
    confidence = sample.get("confidence", top["confidence"])
    if "confidence" in own and target is None:
        raise ConfigError(path, f"{keypath}.confidence", WITH_TARGET, sample["confidence"])
    return (None if target is None else float(target),
            DEFAULT_CONFIDENCE if confidence is None else float(confidence), own)
