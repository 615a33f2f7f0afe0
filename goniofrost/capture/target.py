"""A capture that stops when the material is known: the assessments after each batch.

With ``capture --target-error E`` the plan is measured batch by batch (PLAN.json ``batch_ends``).
After each batch the samples so far are reconstructed and the calibrated bound at the session's
confidence (``frost.confidence``) decides (``frost.stopping.stop_reason``): stop when the error is
at most E and the samples are not unlike every training material, or when the plan is used up. A
scene plan (``plan --usage``) is judged by the scene's error (``frost.scene_error``; ``scope``).
Everything is a pure function of the journaled samples, so a resume replays the same decisions.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable, Sequence

import math

import numpy as np

from goniofrost.frost.confidence import ErrorBound
from goniofrost.frost.scene_error import NAMES, SCOPE_BRDF, SCOPE_SCENE
from goniofrost.frost.stopping import Decision, stop_reason
from goniofrost.capture.options import DEFAULT_CONFIDENCE

CONTINUE = Decision.CONTINUE


@dataclass(frozen=True)
class Assessor:
    """``assess(records) -> ErrorBound`` of the samples ``records`` (SampleRecords; their plan
    indices index ``positions``, the plan samples' rows in the model), uncertainties used;
    ``scene``: the plan's ``scene_error.SceneError`` (the error in the scene's use) or None;
    ``sentinel``: bool (n,) per plan sample, the sentinels (``plan --sentinels``) or None."""

    model: object
    positions: np.ndarray
    confidence: float = DEFAULT_CONFIDENCE
    scene: object = None
    sentinel: np.ndarray | None = None

    @property
    def scope(self) -> str:
        return SCOPE_BRDF if self.scene is None else SCOPE_SCENE

    def __call__(self, records) -> ErrorBound:
        from goniofrost.frost.reconstruction import error_bound

        order = np.array([r.plan_index for r in records], dtype=np.int64)
        values = np.array([r.rgb for r in records], dtype=np.float64)
        sigmas = np.array([r.sigma for r in records], dtype=np.float64)
        return error_bound(self.model, self.positions[order], values, sigmas, self.confidence, scene=self.scene,
                           sentinel=None if self.sentinel is None else self.sentinel[order])


def make_assessor(model, positions: np.ndarray, confidence: float = DEFAULT_CONFIDENCE, scene=None,
                  sentinel=None) -> Assessor:
    """The ``Assessor`` of a session's samples (see there)."""
    return Assessor(model, positions, confidence, scene, sentinel)


def assessment(assess: Callable, batch: int, end: int, n_samples: int, target: float, records,
               not_measured: int = 0, earlier: Sequence[dict] = ()) -> dict:
    """The assessment after batch ``batch`` (0-based) ending at ``end`` samples, of the measured
    ``records`` among them (``not_measured`` of the ``end`` have no value and are left out): the
    fields of an ``Assess`` step (batch, samples, predicted_error = the median estimate, target,
    decision = CONTINUE or a stopping reason, bound = the upper bound or None, confidence,
    out_of_model, scope = the error assessed: the assessor's, "brdf" for a plain callable,
    not_measured, design = the ErrorBound's: why its design is out of the model, or None).
    ``earlier``: the session's assessments before this one: once its sentinels flagged the
    material, it stays out of the model ("sentinel_earlier"; see ``sticky``)."""
    bound = sticky(assess(records), earlier)
    decision = stop_reason(bound, target, end, n_samples) or CONTINUE
    return {"batch": batch, "samples": end, "predicted_error": float(bound.median), "target": target,
            "decision": decision, "bound": float(bound.upper) if math.isfinite(bound.upper) else None,
            "confidence": float(bound.confidence), "out_of_model": tuple(bound.out_of_model),
            "scope": getattr(assess, "scope", SCOPE_BRDF), "not_measured": int(not_measured),
            "design": None if bound.design is None else tuple(bound.design)}


def sticky(bound: ErrorBound, earlier: Sequence[dict]) -> ErrorBound:
    """``bound`` still out of the model ("sentinel_earlier") when the sentinels flagged any of the
    ``earlier`` assessments. The check is calibrated on the largest of a held-out training
    material's standardized sentinel scores over every look (``confidence._sentinel_spread``):
    at most 5 % of materials like the training ones are ever flagged, so a flag speaks of the
    material, not of one look, and a later look that happens to agree does not undo it. Measured
    (BENCHMARKS.md@8b3941b, issue 28, "On a rig"): trained on MERL among the simulated rig's cells,
    9 RGL captures stopped at 0.05 with the flag per look, 4 of them above it, all flagged at an
    earlier batch; with the flag kept 1 stopped (within)."""
    flagged = any({"sentinel", "sentinel_earlier"} & set(a.get("out_of_model") or ()) for a in earlier)
    if not flagged or "sentinel" in bound.out_of_model:
        return bound
    return replace(bound, out_of_model=tuple(bound.out_of_model) + ("sentinel_earlier",))


def bound_of(assessed: dict) -> ErrorBound:
    """The ErrorBound an assessment (a dict of ``assessment`` or an Assess step's fields) holds."""
    upper, design = assessed.get("bound"), assessed.get("design")
    return ErrorBound(float(assessed["predicted_error"]), math.inf if upper is None else float(upper),
                      float(assessed["confidence"]), tuple(assessed.get("out_of_model") or ()),
                      design=None if design is None else tuple(design))


def statement(assessed: dict) -> str:
    """The operator's sentence of an assessment: "error <= E with 95 % confidence (median
    estimate X)" ("error in the scene's use <= E ..." for a scene's plan) or why not
    (``frost.stopping.statement``)."""
    from goniofrost.frost.stopping import statement as sentence

    return sentence(bound_of(assessed), float(assessed["target"]), NAMES[assessed.get("scope", SCOPE_BRDF)])


def history(assess: Callable, batch_ends: Sequence[int], target: float, records, not_measured=()) -> list[dict]:
    """The assessments of every batch whose samples are all journaled (measured, in ``records``,
    or not measured, plan indices ``not_measured``), in order, up to the first that stops (the
    decisions a session made, replayed from its journal); a batch without a measured sample is
    not assessed, as the session did not assess it."""
    by_index, skipped = {r.plan_index: r for r in records}, set(not_measured)
    n, out = int(batch_ends[-1]), []
    for batch, end in enumerate(batch_ends):
        if any(i not in by_index and i not in skipped for i in range(end)):
            break
        measured = [by_index[i] for i in range(end) if i in by_index]
        if not measured:
            continue
        out.append(assessment(assess, batch, end, n, target, measured, end - len(measured), out))
        if out[-1]["decision"] != CONTINUE:
            break
    return out


def finished(assess: Callable, batch_ends: Sequence[int], target: float, records, not_measured=()) -> bool:
    """True when the journaled samples already made the session stop, or every plan sample is
    journaled (nothing left to capture)."""
    done = history(assess, batch_ends, target, records, not_measured)
    everything = len(records) + len(set(not_measured)) >= int(batch_ends[-1])
    return everything or (bool(done) and done[-1]["decision"] != CONTINUE)


def batch_of(batch_ends: Sequence[int], plan_index: int) -> int:
    """The 1-based batch number of plan sample ``plan_index``."""
    return int(np.searchsorted(np.asarray(batch_ends), plan_index, side="right")) + 1
