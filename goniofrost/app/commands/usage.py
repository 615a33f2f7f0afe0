"""``goniofrost usage``: how a Mitsuba 3 scene uses the BSDF of one object, as a weight per MERL cell."""
from __future__ import annotations

HELP = "render a Mitsuba 3 scene and record where it uses one object's BSDF: a weight per valid MERL cell (USAGE.npy)"


def add_arguments(parser) -> None:
    from goniofrost.app.arg_types import grid_bins

    parser.add_argument("--scene", required=True, metavar="SCENE.xml", help="a Mitsuba 3 scene file (config/scenes/ has three)")
    parser.add_argument("--object", required=True, metavar="ID", help="the id of the shape that carries the measured material")
    parser.add_argument("--out", required=True, metavar="USAGE.npy", help="float32 (n_valid,) weights, sum 1 (for plan --usage)")
    parser.add_argument("--spp", type=int, default=None, metavar="N", help="samples per pixel (default: the scene's sampler)")
    parser.add_argument("--grid", type=grid_bins, default=None, metavar="NTH,NTD,NPD",
                        help="the grid of the model the plan uses (train --grid; default 90,90,180, the MERL grid)")


def run(args) -> int:
    import sys
    from pathlib import Path

    from goniofrost.brdf.mitsuba_usage import record_usage
    from goniofrost.brdf.usage import save_usage
    from goniofrost.core.atomic_file import check_output_dir, check_output_suffix
    from goniofrost.core.errors import ConfigError

    if args.spp is not None and args.spp < 1:
        raise ConfigError("command line", "--spp", "a whole number >= 1", args.spp)
    # usage.png held NumPy bytes under a picture's name
    check_output_suffix(args.out, ".npy", "the weights are a NumPy array")
    check_output_dir(Path(args.out).parent)
    tty = sys.stderr.isatty()

    def progress(done: int, total: int) -> None:
        if tty:
            print(f"\rrendering {args.scene}: pass {done}/{total}", end="" if done < total else "\n",
                  file=sys.stderr, flush=True)

    from goniofrost.core.grid import FULL_GRID, MerlGrid

    grid = FULL_GRID if args.grid is None else MerlGrid(*args.grid)
    usage, pairs = record_usage(args.scene, args.object, spp=args.spp, grid=grid, progress=progress)
    save_usage(args.out, usage)
    print(f"{args.out}: {pairs} light/view pairs of {args.object!r} in {int((usage > 0).sum())} cells "
          f"(largest weight {usage.max():.4g})")
    return 0
