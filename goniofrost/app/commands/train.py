"""goniofrost train: fit the FROST model (mapping + PCA dictionary) to dataset materials."""
from __future__ import annotations

HELP = "train a FROST model (log-relative map + PCA dictionary) on dataset materials"


def add_arguments(parser) -> None:
    from goniofrost.app.arg_types import grid_bins

    parser.add_argument("--dataset", action="append", required=True, metavar="SPEC",
                        help="builtin, nbrdf:PATH.npz, merl:DIR or rgl:PATH (repeatable; combined in order)")
    parser.add_argument("--only", action="append", metavar="NAME", help="train on this material only (repeatable)")
    parser.add_argument("--exclude", action="append", metavar="NAME", help="leave this material out (repeatable)")
    parser.add_argument("--components", type=int, default=60, metavar="K", help="keep up to K components (default 60)")
    parser.add_argument("--rig", metavar="RIG.yaml",
                        help="calibrate on designs among the cells this rig can reach and its camera measure, and "
                             "the sentinel check at them (plan --rig with the same rig then makes designs like the "
                             "calibration's and measures the sentinels exactly where they were calibrated; without it "
                             "both are the whole grid's and a rig's plan approximates them)")
    parser.add_argument("--alignment", metavar="ALIGNMENT.json",
                        help="with --rig: the axes' zero offsets from goniofrost align (as for plan)")
    parser.add_argument("--grid", type=grid_bins, default=None, metavar="NTH,NTD,NPD",
                        help="bins of theta_h, theta_d and phi_d (default 90,90,180, the MERL grid); a coarser grid "
                             "trains, plans and reconstructs in a fraction of the time, for rehearsal and tests")
    parser.add_argument("--no-cache", action="store_true", help="retrain even if the same inputs were trained before")
    parser.add_argument("--out", required=True, metavar="MODEL", help="model directory to write")


def run(args) -> int:
    from goniofrost.core.grid import FULL_GRID, MerlGrid
    from goniofrost.frost.model import check_model_destination
    from goniofrost.frost.training import train

    if args.components < 1:  # checked by the training too, but only after the tabulation (a minute)
        from goniofrost.core.errors import ConfigError
        raise ConfigError("command line", "--components", "a positive integer (the components kept)", args.components)
    check_model_destination(args.out)  # before training, not after it
    grid = FULL_GRID if args.grid is None else MerlGrid(*args.grid)
    candidates = _rig_cells(args, grid)
    model = train(args.dataset, only=args.only, exclude=args.exclude, grid=grid, k_max=args.components,
                  cache=not args.no_cache, progress=True, sentinel_candidates=candidates)
    model.save(args.out)
    print(f"{args.out}: {len(model.names)} materials, {model.n_components} components, "
          f"{model.grid.n_valid} valid cells, hash {model.content_hash[:16]}")
    return 0


def _rig_cells(args, grid):
    """bool (n_valid,) of ``grid``: the cells the --rig can measure (None without --rig);
    a bad rig file or alignment fails here, before the training."""
    if args.rig is None:
        if args.alignment is not None:
            from goniofrost.core.errors import ConfigError
            raise ConfigError("command line", "--alignment", "--rig RIG.yaml as well (an alignment belongs to a rig)",
                              args.alignment)
        return None
    from goniofrost.rig.file import command_steps, load_checked_rig
    from planner.reach import reachability

    rig = load_checked_rig(args.rig, args.alignment)
    reach = reachability(rig, grid, steps=command_steps(rig), progress=True)  # plan --rig's cells
    print(f"rig {rig.name}: the designs and the sentinel check are calibrated among its {int(reach.mask.sum())} "
          "measurable cells")
    return reach.mask
