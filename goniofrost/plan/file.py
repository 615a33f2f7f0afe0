"""PLAN.json: the selected samples in measurement order, with their angles and directions.

The document holds the model (path, hash), ``m``, the selector (``bayes`` or ``frost``) and its
outputs (a Bayesian design's ``predicted_errors``, ``batch_ends``, ``sentinels``, ``checks``,
``extrapolation``), and ``samples``: per sample its cell ``[i_th, i_td, i_pd]``, the cell's lower
edges in degrees (``theta_h_deg``, ``theta_d_deg``, ``phi_d_deg``, ``theta_i_deg``,
``theta_o_deg``) and unit vectors ``w_i``, ``w_o`` (3,) in the sample frame (z = normal, phi_h =
0), in selection order. The planner adds joint targets and motion times; ``plan.times`` the
expected rig times. docs/reference/file-formats.md has the full layout.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from goniofrost.core.atomic_file import write_text_atomic
from goniofrost.core.config_check import Key, check_section, is_int, is_number, read_json_file
from goniofrost.core.errors import ConfigError
from goniofrost.frost.model import FrostModel
from goniofrost.frost.selection import Selection

SAMPLE_FIELDS = ("cell", "theta_h_deg", "theta_d_deg", "phi_d_deg", "theta_i_deg", "theta_o_deg", "w_i", "w_o")
TOP_FIELDS = ("model", "m", "selection_seconds", "samples")


def model_path_for_plan(model_path, plan_path) -> str:
    """The model folder as PLAN.json at ``plan_path`` records it: relative to the plan's folder, or
    absolute when given so. Why not as typed: a path relative to the folder ``plan`` ran in named
    nothing to a capture run from the plan's folder or anywhere else (``plan --model model --out
    sub/plan.json``, then ``capture --plan plan.json`` in ``sub``); ``capture.inputs.resolve_model_path``
    reads it beside the plan."""
    import os

    if Path(model_path).is_absolute():
        return str(model_path)
    return os.path.relpath(os.path.abspath(model_path), os.path.abspath(Path(plan_path).parent))


def plan_document(model_path, model: FrostModel, selection: Selection) -> dict:
    """The PLAN.json content (a JSON-ready dict) for a selection made with ``model``."""
    doc = {
        "model": {"path": str(model_path), "hash": model.content_hash},
        "m": selection.m,
        "selection_seconds": round(float(selection.seconds), 6),
        "selector": selection.selector,
        "k": int(selection.k),
    }
    values = [float(r) for r in selection.residuals]
    if selection.selector == "bayes":
        from goniofrost.frost.stopping import batch_ends

        doc["predicted_errors"] = values
        doc["batch_ends"] = batch_ends(selection.m)
    else:
        doc |= {"y_form": selection.y_form, "residuals": values}
    return doc | {"samples": sample_entries(model.grid, selection.cells)}


def add_sentinels(doc: dict, grid, positions, checks=None) -> dict:
    """A Bayesian plan with sentinel samples (``frost.sentinel``) at the valid-cell ``positions``
    (int64 (s,)) and check samples (``frost.check_cells``) at ``checks`` (int64 (k,), None: none):
    their entries, marked ``"sentinel": true`` (the checks also ``"check": true``), right after
    the first batch's and measured with it; ``m`` and every ``batch_ends`` grow by s + k,
    ``sentinels`` = s and ``checks`` = k (when k > 0). The capture checks them against the
    design's samples and never fits them into the bound (the checks' error is a feature of the
    checked calibration's median and bound)."""
    positions = np.asarray(positions, dtype=np.int64)
    checks = np.zeros(0, dtype=np.int64) if checks is None else np.asarray(checks, dtype=np.int64)
    first = int(doc["batch_ends"][0])
    cells = np.asarray(grid.valid_cells)
    extra = [entry | {"sentinel": True} for entry in sample_entries(grid, cells[positions])]
    extra += [entry | {"sentinel": True, "check": True} for entry in sample_entries(grid, cells[checks])]
    added = positions.size + checks.size
    return doc | {"m": int(doc["m"]) + added, "sentinels": int(positions.size),
                  "batch_ends": [int(e) + added for e in doc["batch_ends"]],
                  "samples": list(doc["samples"][:first]) + extra + list(doc["samples"][first:])} \
        | ({"checks": int(checks.size)} if checks.size else {})


def with_design_check(doc: dict, model, positions) -> tuple[dict, str | None]:
    """(the Bayesian plan ``doc`` with whether the whole BRDF's predicted error at each of its
    batch ends is an extrapolation, a line saying why or None): the design's first m samples
    (``positions``: the design's valid-cell positions, without sentinels and check cells) against
    the designs the model's calibration was fitted on (``frost.confidence.design_outside``). Adds
    ``extrapolation`` (bool: at some batch end) and, when it is, ``out_of_model`` ["design"],
    ``out_of_model_batch_ends`` (those batch ends, as ``batch_ends``) and ``design`` (at the last
    of them, as a report's: ``frost.confidence.extrapolation_fields``). A capture never stops on
    the target at those batch ends. A model whose bound records no range of its designs (trained
    before it was) is not checked: the plan unchanged and a line saying so (None for a model
    without a bound: the capture says it has none)."""
    from goniofrost.frost.confidence import (ErrorBound, describe_design, design_detail, design_range,
                                             extrapolation_fields)
    from goniofrost.frost.prediction import calibration_of
    from goniofrost.frost.reconstruction import design_error

    added = int(doc.get("sentinels", 0)) + int(doc.get("checks", 0))
    positions, calibration = np.asarray(positions, dtype=np.int64), calibration_of(model)
    if design_range(calibration, 1) is None:
        return doc, (None if not calibration.get("bound") else "design check: none (the model records no range of "
                     "its calibration's designs: train it again with this version to have designs unlike them flagged)")
    details = [design_detail(calibration, design_error(model, positions[:end - added]), end - added)
               for end in doc["batch_ends"]]
    flagged = [end for end, detail in zip(doc["batch_ends"], details) if detail]
    if not flagged:
        return doc | {"extrapolation": False}, None
    last = [detail for detail in details if detail][-1]
    fields = extrapolation_fields(ErrorBound(math.nan, math.inf, math.nan, ("design",), design=last))
    ends = ", ".join(map(str, flagged)) + " samples" + (
        f" ({', '.join(str(e - added) for e in flagged)} of them the design's)" if added else "")
    return doc | {"extrapolation": True, "out_of_model": fields["out_of_model"], "out_of_model_batch_ends": flagged,
                  "design": fields["design"]}, \
        (f"EXTRAPOLATION: {describe_design(last)}: the predicted error is not backed by the calibration, and "
         f"capture --target-error does not stop on the target after {ends}")


def sentinel_flags(samples) -> list[bool]:
    """Per entry of a plan's ``samples``, whether it is a sentinel (``add_sentinels``); an entry
    that is not a mapping (a plan being written, read by the monitor) is not one."""
    return [isinstance(entry, dict) and bool(entry.get("sentinel", False)) for entry in samples]


def with_sentinels(doc: dict, model, design, candidates=None, asked: bool = False) -> tuple[dict, str]:
    """(the Bayesian plan ``doc`` with the model's sentinel samples, a line saying which or why
    none): as many as the model calibrated, among the ``candidates`` (bool (n_valid,), default
    every cell) outside the ``design`` (its valid-cell positions), by ``frost.sentinel.cells``.
    None for a model trained before the check, or when no candidate lies in their region:
    GoniofrostError when they were ``asked`` for, else the plan unchanged. A model whose
    held-out training materials are too few for a check at SENTINEL_CONFIDENCE (it would never
    flag) gets them only when asked (the line says so)."""
    import math

    from goniofrost.core.errors import GoniofrostError
    from goniofrost.frost import sentinel
    from goniofrost.frost.confidence import conformal_quantile
    from goniofrost.frost.prediction import calibration_of

    calibrated = sentinel.calibrated_cells(model)
    why = None
    if calibrated.size == 0:
        why = "the model has no sentinel calibration (train it again with this version)"
    else:
        scores = calibration_of(model)["bound"]["sentinel"]["scores"]
        mute = conformal_quantile(scores, sentinel.SENTINEL_CONFIDENCE) == math.inf
        allowed = np.ones(model.grid.n_valid, dtype=bool) if candidates is None else np.array(candidates, dtype=bool)
        allowed[np.asarray(design, dtype=np.int64)] = False
        cells = sentinel.cells(model.grid, calibrated.size, allowed)
        if cells.size == 0:
            why = "no candidate cell lies where the design leaves the grid empty (theta_d > 80 or theta_h > 70 deg)"
        elif mute and not asked:
            why = (f"the model's {len(scores)} held-out training materials are too few for a check at "
                   f"{sentinel.SENTINEL_CONFIDENCE:g}: it would never flag")
    if why is not None:
        if asked:
            raise GoniofrostError(f"--sentinels: {why}")
        return doc, f"sentinels: none ({why})"
    where = "the model's calibrated cells" if np.array_equal(cells, calibrated) else \
        "not the model's calibrated cells (the design samples some, or the rig or --max-angle excludes them): " \
        "the check is an approximation"
    never = f" (the model's {len(scores)} held-out training materials are too few: it never flags)" if mute else ""
    outside = allowed.copy()  # the check cells' candidates: outside the design and the sentinels
    outside[cells] = False
    checks, said = _check_cells(model, outside)
    return add_sentinels(doc, model.grid, cells, checks), \
        f"sentinels: {cells.size} samples with the first batch, {where}{never}; {said}"


def _check_cells(model, allowed) -> tuple[np.ndarray, str]:
    """(the model's check cells (``frost.check_cells``) when every one is ``allowed`` (bool
    (n_valid,): a candidate outside the design and the sentinels), else none; a line saying
    which or why none)."""
    from goniofrost.frost import check_cells

    cells = check_cells.cells_of(model)
    if cells.size == 0:
        return cells, "check cells: none (the model has none: train it again with this version)"
    if not np.all(allowed[cells]):
        return np.zeros(0, dtype=np.int64), ("check cells: none (the design samples one, or the rig or --max-angle "
                                             "excludes one: the bound is the one without them)")
    return cells, f"check cells: {cells.size} samples with the first batch (never fitted: their error sharpens the bound)"


def sample_entries(grid, cells) -> list[dict]:
    """One PLAN.json sample dict per flat cell index, in the given order."""
    cells = np.asarray(cells, dtype=np.int64)
    idx = np.stack(grid.unravel(cells), axis=1)
    th, td, pd = (np.degrees(a) for a in grid.flat_angles(cells))
    w_i, w_o = grid.cell_directions(cells)
    th_i = np.degrees(np.arccos(np.clip(w_i[:, 2], -1, 1)))
    th_o = np.degrees(np.arccos(np.clip(w_o[:, 2], -1, 1)))
    return [{"cell": [int(v) for v in idx[s]], "theta_h_deg": float(th[s]), "theta_d_deg": float(td[s]),
             "phi_d_deg": float(pd[s]), "theta_i_deg": float(th_i[s]), "theta_o_deg": float(th_o[s]),
             "w_i": [float(v) for v in w_i[s]], "w_o": [float(v) for v in w_o[s]]}
            for s in range(cells.size)]


def write_plan(path, doc: dict) -> None:
    """Write PLAN.json atomically (temporary file beside it, then rename)."""
    write_text_atomic(path, json.dumps(doc, indent=1) + "\n")


def _vector(v) -> bool:
    return isinstance(v, list) and len(v) == 3 and all(is_number(x) for x in v)


# PLAN.json's key tables (goniofrost.core.config_check): the keys read here are checked; the keys
# other layers add (the planner's joint targets and times, the selector's diagnostics) pass through.
_MODEL_KEYS = {"path": Key(lambda v: isinstance(v, str), "a text"), "hash": Key(lambda v: isinstance(v, str), "a text")}
_SAMPLE_KEYS = {
    "cell": Key(lambda v: isinstance(v, list) and len(v) == 3 and all(is_int(x) for x in v),
                "[i_th, i_td, i_pd] integers"),
    **{key: Key(is_number, "a number (degrees)") for key in SAMPLE_FIELDS[1:6]},
    "w_i": Key(_vector, "[x, y, z] numbers"),
    "w_o": Key(_vector, "[x, y, z] numbers"),
}
_TOP_KEYS = {
    "model": Key(lambda v: isinstance(v, dict), '{"path": str, "hash": str}',
                 nested=lambda v, source, kp: check_section(v, _MODEL_KEYS, source, kp, open_keys=True)),
    "m": Key(lambda v: is_int(v) and v >= 1, "an integer >= 1"),
    "selection_seconds": Key(is_number, "a number (seconds)"),
    "samples": Key(lambda v: isinstance(v, list), "a list of samples",
                   nested=lambda v, source, kp: [check_section(item, _SAMPLE_KEYS, source, f"{kp}[{i}]",
                                                               open_keys=True) for i, item in enumerate(v)]),
}
assert tuple(_TOP_KEYS) == TOP_FIELDS and tuple(_SAMPLE_KEYS) == SAMPLE_FIELDS


def read_plan(path) -> dict:
    """Read and validate PLAN.json; raise ConfigError naming the field on bad content."""
    path = Path(path)
    doc = read_json_file(path, "an existing PLAN.json file")
    if not isinstance(doc, dict):
        raise ConfigError(path, "", "a JSON object", type(doc).__name__)
    doc = check_section(doc, _TOP_KEYS, path, "", open_keys=True)
    if len(doc["samples"]) != doc["m"]:
        raise ConfigError(path, "samples", f"a list of m={doc['m']} samples", f"{len(doc['samples'])} samples")
    return doc


def check_unique_cells(path, doc: dict) -> None:
    """A cell measured twice is a plan made wrong: ConfigError naming the second sample."""
    seen: dict = {}
    for i, sample in enumerate(doc["samples"]):
        first = seen.setdefault(tuple(sample["cell"]), i)
        if first != i:
            raise ConfigError(path, f"samples[{i}].cell", f"a cell not already in the plan (samples[{first}] has it)",
                              sample["cell"])
