"""goniofrost plan: choose the m measurement directions with FROST and write PLAN.json."""
from __future__ import annotations

HELP = "select FROST sample directions (SOMP) and write PLAN.json"


def add_arguments(parser) -> None:
    parser.add_argument("--model", required=True, metavar="MODEL", help="model directory from goniofrost train")
    how = parser.add_mutually_exclusive_group(required=True)
    how.add_argument("--samples", type=int, metavar="M", help="number of samples to select")
    how.add_argument("--max-error", type=float, metavar="E",
                     help="select until the relative residual ||R||_F/||Y||_F <= E (paper eq. 8)")
    parser.add_argument("--max-angle", type=float, metavar="DEG",
                        help="skip cells whose theta_i or theta_o exceeds DEG degrees")
    parser.add_argument("--y-form", choices=("all", "firstm"), default=None,
                        help="training signals in Y: the first m columns (default, as the authors' code) or all of them")
    parser.add_argument("--atoms", type=int, metavar="K", help="atoms k used in selection (default m; all with --max-error)")
    parser.add_argument("--rig", metavar="RIG.yaml",
                        help="select only cells this rig can reach, add joint targets and order them for least motion")
    parser.add_argument("--out", required=True, metavar="PLAN.json", help="plan file to write")


def run(args) -> int:
    from goniofrost.frost.model import FrostModel
    from goniofrost.capture.plan_file import plan_document, write_plan
    from goniofrost.frost.selection import DEFAULT_Y_FORM, candidate_mask_max_angle, select_cells

    model = FrostModel.load(args.model)
    mask = None
    if args.max_angle is not None:
        mask = candidate_mask_max_angle(model.grid, args.max_angle)
    rig = None
    if args.rig is not None:
        from goniofrost.capture.rig_file import load_checked_rig
        from planner.reach import reachability
        rig = load_checked_rig(args.rig)
        reach = reachability(rig, model.grid)
        mask = reach.mask if mask is None else mask & reach.mask
        why = ", ".join(f"{k} {v}" for k, v in reach.counts().items() if k != "OK" and v)
        print(f"rig {rig.name}: {int(reach.mask.sum())} of {reach.mask.size} valid cells reachable "
              f"({100 * reach.fraction:.1f} %); unreachable: {why or 'none'}")
    selection = select_cells(model, args.samples, max_error=args.max_error, candidates=mask,
                             y_form=args.y_form or DEFAULT_Y_FORM, k=args.atoms)
    doc = plan_document(args.model, model, selection)
    if rig is not None:
        from planner.schedule import format_table, schedule_plan
        doc = schedule_plan(doc, rig)
        print(format_table(doc))
    write_plan(args.out, doc)
    # With k = m atoms the residual after the m-th pick is 0 by construction; it only says
    # something for --max-error (k = all atoms).
    residual = f", residual {selection.residuals[-1]:.4f}" if args.max_error is not None else ""
    print(f"{args.out}: m = {selection.m} samples{residual}, selection {selection.seconds:.3f} s")
    return 0
