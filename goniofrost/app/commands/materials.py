"""``goniofrost materials --dataset SPEC [--domain]``: print the dataset's material names, one per line.

With ``--domain`` each line is ``NAME<TAB>DOMAIN``: the cells the material has data for (``every
valid cell``, or an RGL file's kind, measured elevations and covered cells).
"""
from __future__ import annotations

import argparse

HELP = ("list the materials of a dataset (builtin, nbrdf:PATH.npz, merl:DIR, rgl:PATH, builtin-random:SEED:COUNT), "
        "one name per line")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--dataset", required=True, metavar="SPEC",
                        help="builtin, nbrdf:PATH.npz (Neural-BRDF networks), merl:DIR (MERL .binary files), rgl:PATH "
                             "(RGL tensor files: a .bsdf file or a folder of them) or "
                             "builtin-random:SEED:COUNT (seeded analytic materials of the built-in families)")
    parser.add_argument("--domain", action="store_true",
                        help="also print each material's domain (the cells it has data for), after a tab")


def run(args: argparse.Namespace) -> int:
    from goniofrost.datasets import open_dataset

    dataset = open_dataset(args.dataset)
    names = dataset.names()
    if args.domain:
        names = [f"{name}\t{dataset.domain(name)}" for name in names]
    print("\n".join(names))
    return 0
