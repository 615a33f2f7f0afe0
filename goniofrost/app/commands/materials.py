"""``goniofrost materials --dataset SPEC``: print the dataset's material names, one per line."""
from __future__ import annotations

import argparse

HELP = "list the materials of a dataset (builtin, nbrdf:PATH.npz, merl:DIR, builtin-random:SEED:COUNT), one name per line"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--dataset", required=True, metavar="SPEC",
                        help="builtin, nbrdf:PATH.npz (Neural-BRDF networks), merl:DIR (MERL .binary files) or "
                             "builtin-random:SEED:COUNT (seeded analytic materials of the built-in families)")


def run(args: argparse.Namespace) -> int:
    from goniofrost.datasets import open_dataset

    names = open_dataset(args.dataset).names()
    print("\n".join(names))
    return 0
