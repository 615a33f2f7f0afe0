"""A capture that stops when the material is known: the assessments after each batch.

With ``capture --target-error E`` the plan (a nested Bayesian design, scheduled batch by batch;
PLAN.json ``batch_ends``) is measured one batch at a time. After a batch the samples measured
so far are reconstructed and this material's predicted error (``frost.prediction``, from its
own samples) decides (``frost.stopping.stop_reason``): stop when it is at most E, or when the
plan is used up. Everything here is a pure function of the journaled samples, so a resumed
session replays the same decisions and the report can show them.
"""
from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

from goniofrost.frost.stopping import stop_reason

CONTINUE = "continue"


def make_assessor(model, positions: np.ndarray) -> Callable:
    """``assess(records) -> predicted error`` of the samples ``records`` (SampleRecords; their
    plan indices index ``positions``, the plan samples' rows in the model), uncertainties used."""
    from goniofrost.frost.reconstruction import predicted_error

    def assess(records) -> float:
        order = np.array([r.plan_index for r in records], dtype=np.int64)
        values = np.array([r.rgb for r in records], dtype=np.float64)
        sigmas = np.array([r.sigma for r in records], dtype=np.float64)
        return predicted_error(model, positions[order], values, sigmas)

    return assess


def assessment(assess: Callable, batch: int, end: int, n_samples: int, target: float, records) -> dict:
    """The assessment after batch ``batch`` (0-based) ending at ``end`` samples: a dict of
    batch, samples, predicted_error, target and decision (CONTINUE or a stopping reason)."""
    predicted = float(assess(records))
    decision = stop_reason(predicted, target, end, n_samples) or CONTINUE
    return {"batch": batch, "samples": end, "predicted_error": predicted, "target": target, "decision": decision}


def history(assess: Callable, batch_ends: Sequence[int], target: float, records) -> list[dict]:
    """The assessments of every batch whose samples are all in ``records``, in order, up to the
    first that stops (the decisions a session made, replayed from its journal)."""
    by_index = {r.plan_index: r for r in records}
    n, out = int(batch_ends[-1]), []
    for batch, end in enumerate(batch_ends):
        if any(i not in by_index for i in range(end)):
            break
        out.append(assessment(assess, batch, end, n, target, [by_index[i] for i in range(end)]))
        if out[-1]["decision"] != CONTINUE:
            break
    return out


def finished(assess: Callable, batch_ends: Sequence[int], target: float, records) -> bool:
    """True when the journaled samples already made the session stop (nothing left to capture)."""
    done = history(assess, batch_ends, target, records)
    return bool(done) and done[-1]["decision"] != CONTINUE


def batch_of(batch_ends: Sequence[int], plan_index: int) -> int:
    """The 1-based batch number of plan sample ``plan_index``."""
    return int(np.searchsorted(np.asarray(batch_ends), plan_index, side="right")) + 1
