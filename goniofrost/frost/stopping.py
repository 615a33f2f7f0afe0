"""Capture until the material is known: batches in design order and the stopping rule.

A nested design (``bayes_selection``: its first m picks are the m-pick design) is measured in
batches: the first FIRST_BATCH picks, then BATCH more at a time, up to the whole plan. After
each batch the samples so far are reconstructed and the capture stops as soon as this
material's predicted error (``prediction.py``, from its own samples) is at most the target,
or when the plan is used up. These functions hold no device and no file: the capture engine
and the benchmark's simulation both use them.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# The first batch: fewer samples say too little about a material to stop on. Measured on the
# 45 x 45 x 90 grid, 10 folds, target 0.05 (every other setting as the benchmark): the share
# of materials stopping with a true error above 1.5 x the target was 13.7 / 11.1 / 10.2 % on
# the held-out training materials of training's cross-validation and 11.0 / 8.5 / 8.0 % on the
# test materials for a first batch of 10 / 15 / 20 samples (mean samples 19 / 22 / 26).
FIRST_BATCH = 15
BATCH = 5

REASON_TARGET = "target reached"
REASON_PLAN = "plan used up"


def batch_ends(m_max: int, first: int = FIRST_BATCH, step: int = BATCH) -> list[int]:
    """Cumulative sample counts after each batch: first, first + step, ..., m_max (always last).

    >>> batch_ends(22)
    [15, 20, 22]
    """
    if m_max < 1 or first < 1 or step < 1:
        raise ValueError(f"batch_ends: expected positive m_max, first and step, found {m_max}, {first}, {step}")
    ends = list(range(min(first, m_max), m_max, step))
    return ends + [m_max] if not ends or ends[-1] != m_max else ends


def batches(order: np.ndarray, first: int = FIRST_BATCH, step: int = BATCH) -> list[np.ndarray]:
    """The plan indices of each batch, in design order: ``order`` split at ``batch_ends``."""
    order = np.asarray(order)
    ends = batch_ends(order.size, first, step)
    return [order[a:b] for a, b in zip([0] + ends[:-1], ends)]


def stop_reason(predicted_error: float, target: float, done: int, total: int) -> str | None:
    """Why to stop after a batch (REASON_TARGET or REASON_PLAN), or None to go on."""
    if predicted_error <= target:
        return REASON_TARGET
    if done >= total:
        return REASON_PLAN
    return None


@dataclass
class StopOutcome:
    """Where a capture with a target error stopped.

    samples: samples measured; predicted_error: after the last batch; reason: REASON_*;
    history: [(samples, predicted error)] after each batch.
    """

    samples: int
    predicted_error: float
    reason: str
    history: list


def run_batches(m_max: int, target: float, predict_after, first: int = FIRST_BATCH,
                step: int = BATCH) -> StopOutcome:
    """Go through the batches of an m_max-sample plan until ``stop_reason`` says stop.

    predict_after(m) -> the predicted error after the first m samples (it measures and
    reconstructs whatever it needs).
    """
    history = []
    for end in batch_ends(m_max, first, step):
        predicted = float(predict_after(end))
        history.append((end, predicted))
        reason = stop_reason(predicted, target, end, m_max)
        if reason is not None:
            return StopOutcome(end, predicted, reason, history)
    raise AssertionError("unreachable: the last batch ends the plan")
