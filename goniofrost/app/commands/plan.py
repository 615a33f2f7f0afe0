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
                     help="select until the error target E is met: with --selector bayes, a typical material's "
                          "calibrated bound on its log-relative MSE at --confidence (e.g. 0.05: the rule capture "
                          "--target-error stops on; with --usage the predicted error in the scene's use); with "
                          "frost, the relative residual ||R||_F/||Y||_F (paper eq. 8)")
    parser.add_argument("--confidence", type=float, default=None, metavar="P",
                        help="with --max-error and --selector bayes: the bound's confidence (default 0.95, "
                             "capture --confidence's)")
    from goniofrost.frost.selectors import SELECTORS

    parser.add_argument("--selector", choices=tuple(SELECTORS), default="bayes",
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
    from goniofrost.core.errors import GoniofrostError
    from goniofrost.frost.model import FrostModel
    from goniofrost.plan.file import model_path_for_plan, write_plan
    from goniofrost.plan.make import make_plan, summary_line

    if args.selector == "bayes" and (args.y_form is not None or args.atoms is not None):
        raise GoniofrostError("--y-form and --atoms apply to --selector frost only")
    if args.sentinels and (args.selector != "bayes" or args.usage is not None):
        raise GoniofrostError("--sentinels applies to --selector bayes without --usage (the whole BRDF's bound)")
    if args.confidence is not None and (args.max_error is None or args.selector != "bayes" or args.usage is not None):
        raise GoniofrostError("--confidence applies to --max-error with --selector bayes without --usage (the "
                              "confidence of the bound the plan's length is chosen on)")
    if args.confidence is not None and not 0 < args.confidence < 1:
        raise GoniofrostError(f"--confidence: expected a number between 0 and 1, found {args.confidence:g}")
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
    request = _request(args, model, objective)
    made = make_plan(model, model_path_for_plan(args.model, args.out), request, say=print, progress=True)
    write_plan(args.out, made.doc)
    # the scene's calibration time is printed, not written: a plan made again is the same file
    # but for selection_seconds
    print(summary_line(args.out, made, request))
    if made.design_said:
        print(made.design_said)
    if made.selection.bounds is not None:  # what --max-error chose the length on, last
        print(bound_line(model, made.selection, request.confidence))
    return 0


def _request(args, model, objective: str = "samples"):
    """The plan.make.PlanRequest the arguments ask for (the usage map and the rig file read)."""
    from goniofrost.core.errors import ConfigError
    from goniofrost.plan.make import PlanRequest

    usage = rig = None
    if args.usage is not None:
        from goniofrost.brdf.usage import load_usage
        usage = load_usage(args.usage, model.grid.n_valid)
    if args.alignment is not None and args.rig is None:
        raise ConfigError("command line", "--alignment", "--rig RIG.yaml as well (an alignment belongs to a rig)",
                          args.alignment)
    if args.rig is not None:
        from goniofrost.rig.file import load_checked_rig
        rig = load_checked_rig(args.rig, args.alignment)
    return PlanRequest(samples=args.samples, max_error=args.max_error, selector=args.selector,
                       max_angle=args.max_angle, y_form=args.y_form, atoms=args.atoms, usage=usage,
                       usage_file=args.usage, sentinels=args.sentinels, rig=rig, confidence=plan_confidence(args),
                       objective=objective)


def plan_confidence(args) -> float:
    """The confidence of ``--max-error``'s bound: --confidence, else capture's default."""
    from goniofrost.capture.target import DEFAULT_CONFIDENCE

    return DEFAULT_CONFIDENCE if args.confidence is None else float(args.confidence)


def bound_line(model, selection, confidence: float) -> str:
    """What ``--max-error`` chose its length on: the typical material's bound at the plan's
    length, and the held-out training materials' bounds there (10th, 50th, 90th percentiles)."""
    from goniofrost.frost.confidence import figure, training_spread
    from goniofrost.frost.prediction import calibration_of

    m = selection.m
    spread = training_spread(calibration_of(model), m, confidence)
    said = figure(selection.bounds[-1], confidence, selection.residuals[-1])
    over = "" if spread is None else (f"; the training materials' bounds at {m} samples: 10 % {spread[0]:.3g}, "
                                      f"median {spread[1]:.3g}, 90 % {spread[2]:.3g}")
    return f"a typical material at {m} samples: {said}{over}"
