"""goniofrost train: fit the FROST model (mapping + PCA dictionary) to dataset materials."""
from __future__ import annotations

HELP = "train a FROST model (log-relative map + PCA dictionary) on dataset materials"


def add_arguments(parser) -> None:
    parser.add_argument("--dataset", action="append", required=True, metavar="SPEC",
                        help="builtin, nbrdf:PATH.npz or merl:DIR (repeatable; combined in order)")
    parser.add_argument("--only", action="append", metavar="NAME", help="train on this material only (repeatable)")
    parser.add_argument("--exclude", action="append", metavar="NAME", help="leave this material out (repeatable)")
    parser.add_argument("--components", type=int, default=60, metavar="K", help="keep up to K components (default 60)")
    parser.add_argument("--no-cache", action="store_true", help="retrain even if the same inputs were trained before")
    parser.add_argument("--out", required=True, metavar="MODEL", help="model directory to write")


def run(args) -> int:
    from goniofrost.frost.model import check_model_destination
    from goniofrost.frost.training import train

    check_model_destination(args.out)  # before training, not after it
    model = train(args.dataset, only=args.only, exclude=args.exclude, k_max=args.components,
                  cache=not args.no_cache, progress=True)
    model.save(args.out)
    print(f"{args.out}: {len(model.names)} materials, {model.n_components} components, "
          f"{model.grid.n_valid} valid cells, hash {model.content_hash[:16]}")
    return 0
