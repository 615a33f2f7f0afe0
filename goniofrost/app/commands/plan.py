"""goniofrost plan: choose the m measurement directions (Bayesian design or FROST) and write PLAN.json."""
from __future__ import annotations

import argparse
import sys

HELP = "select sample directions (Bayesian A-optimal design by default, or FROST's SOMP) and write PLAN.json"


def add_arguments(parser) -> None:
    parser.add_argument("--model", required=True, metavar="MODEL", help="model directory from goniofrost train")
    how = parser.add_mutually_exclusive_group(required=True)
    how.add_argument("--samples", type=int, metavar="M", help="number of samples to select")
    how.add_argument("--max-error", type=float, metavar="E",
                     help="select until the error target E is met: with --selector bayes, the predicted "
                          "log-relative MSE of a typical material (e.g. 0.05); with frost, the relative "
                          "residual ||R||_F/||Y||_F (paper eq. 8)")
    parser.add_argument("--selector", choices=("bayes", "frost"), default="bayes",
                        help="bayes (default): greedy Bayesian A-optimal design for the posterior-mean "
                             "reconstruction, nested (the first m samples are the best m); frost: SOMP as in "
                             "the paper")
    parser.add_argument("--max-angle", type=float, metavar="DEG",
                        help="skip cells whose theta_i or theta_o exceeds DEG degrees (not needed with --rig: "
                             "the rig's camera model keeps only cells it can measure)")
    parser.add_argument("--y-form", choices=("all", "firstm"), default=None,
                        help="frost only: training signals in Y: the first m columns (default, as the authors' "
                             "code) or all of them")
    parser.add_argument("--atoms", type=int, metavar="K",
                        help="frost only: atoms k used in selection (default m; all with --max-error)")
    parser.add_argument("--rig", metavar="RIG.yaml",
                        help="select only cells this rig can reach and its camera can measure, add joint targets and "
                             "order them for least motion")
    parser.add_argument("--alignment", metavar="ALIGNMENT.json",
                        help="with --rig: the axes' zero offsets from goniofrost align (overrides the rig file's "
                             "alignment key); the plan records it and capture refuses another")
    parser.add_argument("--usage", metavar="USAGE.npy",
                        help="bayes only: a scene's use of every cell (goniofrost usage): the design minimises the "
                             "expected error of what that scene sees instead of the whole BRDF's")
    parser.add_argument("--sentinels", action=argparse.BooleanOptionalAction, default=None,
                        help="bayes without --usage: add the model's 3 sentinel samples to the first batch (the default "
                             "when the model has their calibration), cells in the region the design leaves empty "
                             "(theta_d > 80 or theta_h > 70 deg), never fitted: capture --target-error checks the "
                             "design's reconstruction there and does not stop when they disagree (a material unlike "
                             "the training set); --no-sentinels: the design's samples only")
    parser.add_argument("--objective", choices=("time", "samples"), default=None,
                        help="bayes with --rig: time (each sample the largest expected error reduction per second of "
                             "rig time: move, settle and the expected exposure bracket, from where the rig stands) or "
                             f"samples (per sample, whatever it costs); default {DEFAULT_OBJECTIVE}")
    parser.add_argument("--out", required=True, metavar="PLAN.json", help="plan file to write (a .json name)")


# docs/decisions/0200-time-aware-design.md: what the benchmark on the simulated rig's clock measured
DEFAULT_OBJECTIVE = "samples"


def _objective(args) -> str:
    """The design's objective: --objective, else the default when it applies (a Bayesian plan of the
    whole BRDF with --rig), else samples. An explicit time that does not apply is one line, exit 2."""
    from goniofrost.core.errors import ConfigError

    applies = args.selector == "bayes" and args.rig is not None and args.usage is None
    if args.objective == "time" and not applies:
        raise ConfigError("command line", "--objective", "time only with --selector bayes, --rig and no --usage",
                          "time")
    return (args.objective or DEFAULT_OBJECTIVE) if applies else "samples"


def run(args) -> int:
    from goniofrost.capture.plan_file import model_path_for_plan, plan_document, write_plan
    from goniofrost.core.errors import GoniofrostError
    from goniofrost.frost.model import FrostModel

    if args.selector == "bayes" and (args.y_form is not None or args.atoms is not None):
        raise GoniofrostError("--y-form and --atoms apply to --selector frost only")
    if args.sentinels and (args.selector != "bayes" or args.usage is not None):
        raise GoniofrostError("--sentinels applies to --selector bayes without --usage (the whole BRDF's bound)")
    if args.usage is not None and args.selector != "bayes":
        raise GoniofrostError("--usage applies to --selector bayes only (the scene-weighted Bayesian design)")
    from goniofrost.core.errors import ConfigError
    if args.max_angle is not None and not 0 < args.max_angle <= 90:  # 0 left one direction, nan none
        raise ConfigError("command line", "--max-angle", "degrees in (0, 90]", args.max_angle)
    if args.samples is not None and args.samples < 1:  # the selection's own error said "samples m"
        raise ConfigError("command line", "--samples", "a positive integer", args.samples)
    from goniofrost.core.atomic_file import check_not_an_input, check_output_file, check_output_suffix
    # before the model is read: --out plan.yaml held JSON under a name that says YAML, and a folder
    # named plan.json was found only when the plan was written, after the selection
    check_output_suffix(args.out, ".json", "the plan is written as JSON")
    check_output_file(args.out)
    check_not_an_input(args.out, {"--model": args.model, "--usage": args.usage, "--rig": args.rig,
                                  "--alignment": args.alignment})  # --out MODEL/model.json destroyed the model
    objective = _objective(args)
    model = FrostModel.load(args.model)
    usage = None
    if args.usage is not None:
        from goniofrost.brdf.usage import load_usage
        usage = load_usage(args.usage, model.grid.n_valid)
    mask = None
    if args.max_angle is not None:
        from goniofrost.frost.selection import candidate_mask_max_angle
        mask = candidate_mask_max_angle(model.grid, args.max_angle)
    rig = None
    if args.alignment is not None and args.rig is None:
        from goniofrost.core.errors import ConfigError
        raise ConfigError("command line", "--alignment", "--rig RIG.yaml as well (an alignment belongs to a rig)",
                          args.alignment)
    if args.rig is not None:
        from goniofrost.capture.rig_file import load_checked_rig
        from planner.reach import reachability
        rig = load_checked_rig(args.rig, args.alignment)
        reach = reachability(rig, model.grid, progress=True)
        mask = reach.mask if mask is None else mask & reach.mask
        why = ", ".join(f"{k} {v}" for k, v in reach.counts().items() if k != "OK" and v)
        aligned = "" if rig.alignment is None else f" (aligned: {rig.alignment.source})"
        print(f"rig {rig.name}{aligned}: {int(reach.mask.sum())} of {reach.mask.size} valid cells reachable "
              f"({100 * reach.fraction:.1f} %); unreachable: {why or 'none'}")
    # A scene's calibration depends on the design measured, whose sensitivity power, prior spread
    # and floor depend on the number of samples (usage_design.BANDS): fitted for each design (p, t, F,
    # and the mix share when mixed: usage_design.design_key) the selection asks for. (A uniform map
    # is the plain design whatever the power: one calibration.)
    scenes: dict = {}
    calibrating = [0.0]  # seconds spent fitting the scenes' calibrations (s)

    def scene_for(power, spread, floor, mix=0.0):
        import time

        from goniofrost.frost.usage_design import design_key, is_uniform
        key = None if is_uniform(usage) else design_key(power, spread, floor, mix)
        if key not in scenes:
            start = time.perf_counter()
            scenes[key] = _scene_error(model, usage, power, spread, floor, mix)
            calibrating[0] += time.perf_counter() - start
        return scenes[key]

    time_objective = None
    if objective == "time":
        from goniofrost.frost.time_design import TimeObjective
        time_objective = TimeObjective(rig)
    selection = _select(model, args, mask, usage, scene_for, time_objective)
    # the selection asks for the scene's calibrations as it goes (its predicted errors use them):
    # their fit on the training materials (a minute) is not the selection's time, which a plan
    # without --usage reports alone (0.4 s); it is printed, not written: a plan made again is the
    # same file but for selection_seconds
    selection.seconds -= calibrating[0]
    scene = None
    if usage is not None:
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
        scene = scene_for(*key)
        powers, cells = BAND_POWERS[band(selection.m)[0]]
        print(f"scene-aware design: each cell's use weighted by the image's sensitivity^{power:g} "
              + ("at the prior mean" if spread == 0 else f"averaged over the prior (spread t = {spread:.3g})")
              + (f" (the largest of {', '.join(f'{p:g}' for p in powers)} keeping {cells:g} effective cells, for "
                 f"{selection.m} samples" if len(powers) > 1 else f" (the power for {selection.m} samples")
              + (f"; t the largest up to {prior_spread(selection.m):g} keeping {floor:g} effective cells)" if floor
                 else ")")
              + (f", mixed {1 - mix:g} / {mix:g} with the weights of p = {MIX_DESIGN[0]:g} (t up to "
                 f"{MIX_DESIGN[1]:g}, {MIX_DESIGN[2]:g} effective cells)" if mix else ""))
    doc = plan_document(model_path_for_plan(args.model, args.out), model, selection)
    if args.sentinels is not False and args.selector == "bayes" and usage is None:
        from goniofrost.capture.plan_file import with_sentinels
        doc, said = with_sentinels(doc, model, selection.positions, mask, asked=bool(args.sentinels))
        print(said)
    design_said = None
    if args.selector == "bayes" and usage is None:  # the whole BRDF's calibration: of its designs only
        from goniofrost.capture.plan_file import with_design_check
        doc, design_said = with_design_check(doc, model, selection.positions)
    if usage is not None:
        # the predicted errors are of what the scene sees (usage-weighted), not of the whole BRDF;
        # the capture judges its samples by the same error (usage.error: frost.scene_error)
        doc["usage"] = {"file": str(args.usage), "hash": scene.usage_hash, "cells_used": int((usage > 0).sum()),
                        "sensitivity_power": power, "prior_spread": spread, "spread_floor": floor, "mix": mix,
                        "predicted_errors": "usage-weighted", "error": scene.to_plan()}
    if rig is not None:
        from planner.schedule import format_table, schedule_batches, schedule_plan

        from goniofrost.capture.rig_file import command_steps
        from goniofrost.frost.cell_sensitivity import axis_weights
        # A Bayesian plan is measured batch by batch (capture --target-error may stop after any):
        # each batch is ordered for motion on its own.
        # the joints on the axes' command lattices, each axis's miss weighed by what the model
        # expects it to cost at the sample's cell (planner.steps, frost.cell_sensitivity)
        lattice = {"steps": command_steps(rig),
                   "axis_weights": axis_weights(model, [s["cell"] for s in doc["samples"]])}
        doc = (schedule_batches(doc, rig, doc["batch_ends"], **lattice) if "batch_ends" in doc
               else schedule_plan(doc, rig, **lattice))
        from goniofrost.capture.plan_times import with_expected_times
        doc = with_expected_times(doc, model, rig, objective)
        print(format_table(doc))
    write_plan(args.out, doc)
    extra = f" + {doc['sentinels']} sentinels" if doc.get("sentinels") else ""
    extra += f" + {doc['checks']} check cells" if doc.get("checks") else ""
    calibrated = f" (and {calibrating[0]:.1f} s calibrating the scene's error)" if usage is not None else ""
    print(f"{args.out}: m = {selection.m} samples{extra}{_outcome(args, selection, doc)}, selection "
          f"{selection.seconds:.3f} s{calibrated}")
    if design_said:
        print(design_said)
    return 0


def _scene_error(model, usage, power, spread, floor, mix=0.0):
    """The plan's SceneError: the usage-weighted error and its calibration on the model's training
    materials at the design of sensitivity power ``power``, largest prior spread ``spread``,
    floor ``floor`` on its effective cells and share ``mix`` of the mixed-in design (mapped again;
    without them the plan has no calibrated bound, and says why)."""
    import hashlib

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


def _select(model, args, mask, usage=None, scene_for=None, time_objective=None):
    """The selection; ``scene_for(power, spread, floor[, mix])``: the scene's SceneError for a design of that
    sensitivity power, largest prior spread and floor (with ``usage``), whose calibration the
    predicted errors use."""
    if args.selector == "bayes":
        from goniofrost.frost.bayes_selection import select_bayes
        return select_bayes(model, args.samples, max_error=args.max_error, candidates=mask, usage=usage,
                            calibration=None if usage is None else (lambda *design: scene_for(*design).calibration),
                            time_objective=time_objective)
    from goniofrost.frost.selection import DEFAULT_Y_FORM, select_cells
    return select_cells(model, args.samples, max_error=args.max_error, candidates=mask,
                        y_form=args.y_form or DEFAULT_Y_FORM, k=args.atoms)


def _outcome(args, selection, doc) -> str:
    if selection.selector == "bayes":
        weighted = " weighted by the scene's use" if args.usage is not None else ""
        # the prediction stated is the whole plan's: flagged when its last batch end is
        outside = "; an extrapolation" if doc.get("extrapolation") and \
            doc["out_of_model_batch_ends"][-1] == doc["batch_ends"][-1] else ""
        return (f", predicted error of a typical material {selection.residuals[-1]:.4g} (log-relative MSE{weighted}"
                f"{outside})")
    # With k = m atoms the residual after the m-th pick is 0 by construction; it only says
    # something for --max-error (k = all atoms).
    return f", residual {selection.residuals[-1]:.4f}" if args.max_error is not None else ""
