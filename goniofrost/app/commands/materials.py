"""``goniofrost materials --dataset SPEC``: print the dataset's material names, one per line."""
from __future__ import annotations

import argparse

HELP = "List the materials of a dataset (builtin, nbrdf:PATH.npz, merl:DIR), one name per line."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--dataset", required=True, metavar="SPEC",
                        help="builtin, nbrdf:PATH.npz (Neural-BRDF networks) or merl:DIR (MERL .binary files)")


def run(args: argparse.Namespace) -> int:
    from goniofrost.datasets import open_dataset

    names = open_dataset(args.dataset).names()
    print("\n".join(names))
    return 0
