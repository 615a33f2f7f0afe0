"""Capture until the material is known: batches in design order and the stopping rule.

A nested design is measured in batches (FIRST_BATCH, then BATCH at a time); after each the capture
stops once the calibrated bound is at most the target and the samples are in the model, or when
the plan is used up. No device and no file. The rule: docs/explanations/error-bound.md.
"""
from __future__ import annotations

import enum
import math

from goniofrost.frost.confidence import FIRST_LOOK, ErrorBound

# The first batch: fewer samples say too little about a material to stop on. Chosen on the
# held-out training materials of training's cross-validation (45 x 45 x 90 grid, 10 benchmark
# folds, target 0.05): stopping with a true error above 1.5 x the target happened for 13.7 /
# 11.1 / 10.2 % of them with a first batch of 10 / 15 / 20 samples (mean samples 19 / 22 / 26;
# part of it is materials that stay above 1.5 x the target at 60 samples); 15 is the knee.
# (The test materials of those folds gave 11.0 / 8.5 / 8.0 %.)
FIRST_BATCH = FIRST_LOOK
BATCH = 5



class Decision(str, enum.Enum):
    """What an assessment after a batch decides: measure on, or stop and why. Journals, reports
    and the monitor's page carry the value; code compares members (the page: the names the
    server publishes, ``goniofrost.monitor.status.ENUMS``)."""

    CONTINUE = "continue"
    TARGET_REACHED = "target reached"
    PLAN_USED_UP = "plan used up"

    __str__ = str.__str__        # the value in messages and files, on every Python version
    __format__ = str.__format__


REASON_TARGET = Decision.TARGET_REACHED
REASON_PLAN = Decision.PLAN_USED_UP


def batch_ends(m_max: int, first: int = FIRST_BATCH, step: int = BATCH) -> list[int]:
    """Cumulative sample counts after each batch: first, first + step, ..., m_max (always last).

    >>> batch_ends(22)
    [15, 20, 22]
    """
    if m_max < 1 or first < 1 or step < 1:
        raise ValueError(f"batch_ends: expected positive m_max, first and step, found {m_max}, {first}, {step}")
    ends = list(range(min(first, m_max), m_max, step))
    return ends + [m_max] if not ends or ends[-1] != m_max else ends


def stop_reason(bound: ErrorBound, target: float, done: int, total: int) -> str | None:
    """Why to stop after a batch (REASON_TARGET or REASON_PLAN), or None to go on; never on a
    median estimate alone, never out of the model."""
    if bound.upper <= target and not bound.out_of_model:
        return REASON_TARGET
    if done >= total:
        return REASON_PLAN
    return None


def why_not_reached(bound: ErrorBound, target: float, error: str = "error") -> str:
    """One line: why ``bound`` does not reach ``target`` ("" when it does); ``error`` names the
    error bounded ("error in the scene's use" for a scene's plan)."""
    if bound.unavailable or not math.isfinite(bound.upper):
        return f"no bound at {100 * bound.confidence:g} % confidence: {bound.unavailable or 'none can be given'}"
    if bound.out_of_model:
        from goniofrost.frost.confidence import FEATURE_NAMES, describe_design
        if "design" in bound.out_of_model:  # the design's, whatever its samples say
            return f"{describe_design(bound.design)}: an extrapolation"
        what = " and ".join(FEATURE_NAMES[k] for k in bound.out_of_model)
        return f"the samples are unlike every training material ({what} beyond the training range): an extrapolation"
    if bound.upper > target:
        return (f"{error} <= {bound.upper:.4g} with {100 * bound.confidence:g} % confidence, above the target "
                f"{target:g} (median estimate {bound.median:.4g})")
    return ""


def statement(bound: ErrorBound, target: float, error: str = "error") -> str:
    """The operator's sentence after an assessment: the error figure ("error <= B with 95 %
    confidence (median estimate X)", ``confidence.figure``: the same words every output states)
    and ", within the target E" when the target is reached, else why not (``error``: see
    ``why_not_reached``)."""
    from goniofrost.frost.confidence import figure_of

    reason = why_not_reached(bound, target, error)
    return reason or f"{figure_of(bound, error)}, within the target {target:g}"
