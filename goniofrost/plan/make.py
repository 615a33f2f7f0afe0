"""Make a plan: select the cells, add the sentinels and the design check, schedule them on a rig.

``make_plan`` is what ``goniofrost plan`` and the demo run; it returns the PLAN.json document
(``plan.file``) without writing it, and says what it did through ``say`` (one line a call).
"""
from __future__ import annotations

import hashlib
import sys
import time
from dataclasses import dataclass
from typing import Any, Callable


@dataclass(frozen=True)
class PlanRequest:
    """What to select and where.

    ``samples`` (m) or ``max_error`` (the selector's error target); ``selector``: "bayes" or
    "frost"; ``max_angle``: keep cells with theta_i, theta_o <= this (degrees); ``y_form`` and
    ``atoms`` (frost only: None for the defaults); ``usage``: a scene's use of every cell (float
    (n_valid,), bayes only) read from ``usage_file``; ``sentinels``: None adds the model's
    sentinels when it has them, True insists, False adds none; ``rig``: a ``planner.rig.Rig`` to
    select on and schedule for; ``candidates``: its reach mask (bool (n_valid,)) when computed;
    ``confidence``: of the bound a Bayesian ``max_error`` plan chooses its length on (no scene);
    ``objective``: "time" (error reduction per second of rig time, with a rig) or "samples".
    """

    samples: int | None = None
    max_error: float | None = None
    selector: str = "bayes"
    max_angle: float | None = None
    y_form: str | None = None
    atoms: int | None = None
    usage: Any = None
    usage_file: str | None = None
    sentinels: bool | None = None
    rig: Any = None
    candidates: Any = None
    confidence: float = 0.95
    objective: str = "samples"

    @property
    def whole_brdf(self) -> bool:
        """A Bayesian design of the whole BRDF (no scene): the one with sentinels and a design check."""
        return self.selector == "bayes" and self.usage is None


@dataclass
class MadePlan:
    """A plan made: its PLAN.json ``doc``, the ``selection`` (``frost.selection.Selection``), the
    seconds spent calibrating the scene's error (``calibrating_s``, not the selection's) and the
    design check's line (None when there is nothing to say)."""

    doc: dict
    selection: Any
    calibrating_s: float
    design_said: str | None


class SceneErrors:
    """The scene's ``frost.scene_error.SceneError`` for each design the selection asks about, fitted
    once per design key (``frost.usage_design.design_key``; a uniform map has one) and timed.

    A scene's calibration depends on the design measured, whose sensitivity power, prior spread
    and floor depend on the number of samples (``usage_design.BANDS``).
    """

    def __init__(self, model, usage):
        self.model, self.usage, self.by_key, self.seconds = model, usage, {}, 0.0

    def __call__(self, power, spread, floor, mix=0.0):
        from goniofrost.frost.usage_design import design_key, is_uniform

        key = None if is_uniform(self.usage) else design_key(power, spread, floor, mix)
        if key not in self.by_key:
            start = time.perf_counter()
            self.by_key[key] = _scene_error(self.model, self.usage, power, spread, floor, mix)
            self.seconds += time.perf_counter() - start
        return self.by_key[key]


def make_plan(model, model_path, request: PlanRequest, say: Callable[[str], None] = lambda line: None,
              progress: bool = False) -> MadePlan:
    """Select ``request``'s cells with ``model`` (recorded as at ``model_path``), add the sentinels
    and design check of a whole-BRDF Bayesian plan, the scene's error of a scene's, and schedule
    the samples on the request's rig (batch by batch for a Bayesian plan)."""
    mask = _candidates(model, request, say, progress)
    scenes = SceneErrors(model, request.usage) if request.usage is not None else None
    selection = _select(model, request, mask, scenes)
    # the scene's calibrations fitted during the selection (a minute) are not the selection's
    # time, which a plan without --usage reports alone (0.4 s)
    selection.seconds -= 0.0 if scenes is None else scenes.seconds
    usage = None if scenes is None else _usage_entry(request, selection, scenes, say)
    from goniofrost.plan.file import plan_document, with_design_check, with_sentinels

    doc = plan_document(model_path, model, selection)
    if request.sentinels is not False and request.whole_brdf:
        doc, said = with_sentinels(doc, model, selection.positions, mask, asked=bool(request.sentinels))
        say(said)
    design_said = None
    if request.whole_brdf:  # the whole BRDF's calibration: of its designs only
        doc, design_said = with_design_check(doc, model, selection.positions)
    if usage is not None:
        doc["usage"] = usage
    if request.rig is not None:
        from goniofrost.plan.times import with_expected_times

        doc = with_expected_times(_scheduled(doc, model, request.rig, say), model, request.rig, request.objective)
    return MadePlan(doc, selection, 0.0 if scenes is None else scenes.seconds, design_said)


def _candidates(model, request: PlanRequest, say, progress: bool):
    """The cells a selection may pick (bool (n_valid,)), or None for every valid cell: the rig's
    reach (computed and said here when the request has none) and ``max_angle``."""
    mask = None
    if request.max_angle is not None:
        from goniofrost.frost.selection import candidate_mask_max_angle
        mask = candidate_mask_max_angle(model.grid, request.max_angle)
    reach = request.candidates
    if request.rig is not None and reach is None:
        from goniofrost.rig.file import command_steps
        from planner.reach import reachability
        # the cells measurable at the joints the plan commands (on the axes' lattices, as scheduled)
        rig = request.rig
        found = reachability(rig, model.grid, steps=command_steps(rig), progress=progress)
        why = ", ".join(f"{k} {v}" for k, v in found.counts().items() if k != "OK" and v)
        aligned = "" if rig.alignment is None else f" (aligned: {rig.alignment.source})"
        say(f"rig {rig.name}{aligned}: {int(found.mask.sum())} of {found.mask.size} valid cells reachable "
            f"({100 * found.fraction:.1f} %); unreachable: {why or 'none'}")
        reach = found.mask
    if reach is None:
        return mask
    return reach if mask is None else mask & reach


def _select(model, request: PlanRequest, mask, scenes):
    """The selection by the request's selector (``frost.selectors.SELECTORS``), handed only the
    options the request sets; ``scenes`` (a ``SceneErrors``, with a usage map) gives the
    calibration each design's predicted errors use."""
    from goniofrost.frost.selectors import SELECTORS
    from goniofrost.frost.usage_design import SceneDesign

    options = {"y_form": request.y_form, "k": request.atoms,
               "scene": None if request.usage is None else SceneDesign(request.usage),
               "calibration": None if scenes is None else (lambda *design: scenes(*design).calibration),
               # the rule a capture stops on: a typical material's bound at this confidence
               "confidence": request.confidence if request.max_error is not None and request.selector == "bayes"
               and request.usage is None else None,
               "time_objective": _time_objective(request)}
    return SELECTORS[request.selector].select(model, request.samples, max_error=request.max_error, candidates=mask,
                                              **{key: value for key, value in options.items() if value is not None})


def _time_objective(request: PlanRequest):
    """The ``frost.time_design.TimeObjective`` of a time-aware plan on its rig; None: per sample."""
    if request.objective != "time":
        return None
    from goniofrost.frost.time_design import TimeObjective
    return TimeObjective(request.rig)


def _usage_entry(request: PlanRequest, selection, scenes: SceneErrors, say) -> dict:
    """PLAN.json's ``usage``: the predicted errors are of what the scene sees (usage-weighted), and
    the capture judges its samples by the same error (``error``: ``frost.scene_error``)."""
    from goniofrost.frost.usage_design import (BAND_POWERS, MIX_DESIGN, band, design_key, prior_spread,
                                               sensitivity_power, spread_floor)
    # the design this scene's selection made and whose calibration it used (the selection's own
    # key, not computed again: p, largest t, F and the mix share; a uniform map, the plain
    # design, records the band's power and floor), and the t its weights used (with a floor on
    # their effective cells the largest t up to the band's that keeps the floor)
    key, spread = selection.design_key, selection.prior_spread
    if key is None:
        power = sensitivity_power(selection.m)
        key = design_key(power, prior_spread(selection.m), spread_floor(selection.m, power))
    power, _, floor, mix = key + (0.0,) * (4 - len(key))
    scene = scenes(*key)
    powers, cells = BAND_POWERS[band(selection.m)[0]]
    say(f"scene-aware design: each cell's use weighted by the image's sensitivity^{power:g} "
        + ("at the prior mean" if spread == 0 else f"averaged over the prior (spread t = {spread:.3g})")
        + (f" (the largest of {', '.join(f'{p:g}' for p in powers)} keeping {cells:g} effective cells, for "
           f"{selection.m} samples" if len(powers) > 1 else f" (the power for {selection.m} samples")
        + (f"; t the largest up to {prior_spread(selection.m):g} keeping {floor:g} effective cells)" if floor
           else ")")
        + (f", mixed {1 - mix:g} / {mix:g} with the weights of p = {MIX_DESIGN[0]:g} (t up to "
           f"{MIX_DESIGN[1]:g}, {MIX_DESIGN[2]:g} effective cells)" if mix else ""))
    return {"file": str(request.usage_file), "hash": scene.usage_hash, "cells_used": int((request.usage > 0).sum()),
            "sensitivity_power": power, "prior_spread": spread, "spread_floor": floor, "mix": mix,
            "predicted_errors": "usage-weighted", "error": scene.to_plan()}


def _scheduled(doc: dict, model, rig, say) -> dict:
    """The plan's samples with joint targets, ordered for motion: a Bayesian plan batch by batch
    (``capture --target-error`` may stop after any), the joints on the axes' command lattices,
    each axis's miss weighed by what the model expects it to cost at the sample's cell
    (``planner.steps``, ``frost.cell_sensitivity``)."""
    from planner.schedule import format_table, schedule_batches, schedule_plan

    from goniofrost.frost.cell_sensitivity import axis_weights
    from goniofrost.rig.file import command_steps

    lattice = {"steps": command_steps(rig), "axis_weights": axis_weights(model, [s["cell"] for s in doc["samples"]])}
    doc = (schedule_batches(doc, rig, doc["batch_ends"], **lattice) if "batch_ends" in doc
           else schedule_plan(doc, rig, **lattice))
    say(format_table(doc))
    return doc


def _scene_error(model, usage, power, spread, floor, mix=0.0):
    """The plan's SceneError: the usage-weighted error and its calibration on the model's training
    materials at the design of sensitivity power ``power``, largest prior spread ``spread``,
    floor ``floor`` on its effective cells and share ``mix`` of the mixed-in design (mapped again;
    without them the plan has no calibrated bound, and says why)."""
    from goniofrost.frost.scene_error import scene_error
    from goniofrost.frost.training import TrainingError
    from goniofrost.frost.usage_calibration import calibrate_scene_cached

    digest = hashlib.sha256(usage.astype("float32").tobytes()).hexdigest()[:16]
    try:
        calibration, unavailable = calibrate_scene_cached(model, usage, power, progress=True, prior_spread=spread,
                                                          spread_floor=floor, mix=mix), None
    except TrainingError as exc:
        calibration, unavailable = None, f"no calibration of the error in the scene's use: {exc}"
        print(f"warning: {unavailable}; capture --target-error cannot use this plan", file=sys.stderr)
    return scene_error(model, usage, calibration, digest, unavailable)


def summary_line(out, made: MadePlan, request: PlanRequest) -> str:
    """The line ``goniofrost plan`` ends with: the plan file, its samples, its predicted error or
    residual, and the selection's time (s)."""
    doc, selection = made.doc, made.selection
    extra = f" + {doc['sentinels']} sentinels" if doc.get("sentinels") else ""
    extra += f" + {doc['checks']} check cells" if doc.get("checks") else ""
    calibrated = f" (and {made.calibrating_s:.1f} s calibrating the scene's error)" if request.usage is not None else ""
    return (f"{out}: m = {selection.m} samples{extra}{_outcome(request, selection, doc)}, selection "
            f"{selection.seconds:.3f} s{calibrated}")


def _outcome(request: PlanRequest, selection, doc) -> str:
    if selection.selector == "bayes":
        weighted = " weighted by the scene's use" if request.usage is not None else ""
        # the prediction stated is the whole plan's: flagged when its last batch end is
        outside = "; an extrapolation" if doc.get("extrapolation") and \
            doc["out_of_model_batch_ends"][-1] == doc["batch_ends"][-1] else ""
        return (f", predicted error of a typical material {selection.residuals[-1]:.4g} (log-relative MSE{weighted}"
                f"{outside})")
    # With k = m atoms the residual after the m-th pick is 0 by construction; it only says
    # something for --max-error (k = all atoms).
    return f", residual {selection.residuals[-1]:.4f}" if request.max_error is not None else ""
