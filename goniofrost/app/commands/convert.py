"""``goniofrost convert --dataset SPEC --material NAME --out FILE.binary``.

Writes one material tabulated on the full MERL grid as a MERL .binary file: negative values
clamped to 0, invalid cells -1, and cells the material has no data for (``rgl:PATH`` beyond the
file's measured elevations) -1 too, MERL's missing value. The file appears only when complete (temporary name, then
rename); an unknown dataset or material writes nothing.
"""
from __future__ import annotations

import argparse
from pathlib import Path

HELP = "write a dataset material as a MERL .binary file (full 90x90x180 grid)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--dataset", required=True, metavar="SPEC",
                        help="builtin, nbrdf:PATH.npz, merl:DIR or rgl:PATH")
    parser.add_argument("--material", required=True, metavar="NAME",
                        help="material name, as listed by 'goniofrost materials'")
    parser.add_argument("--out", metavar="FILE.binary",
                        help="output file, ending in .binary (default: NAME.binary in the current folder)")


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from goniofrost.datasets import open_dataset
    from goniofrost.datasets.tabulate import tabulate_cached
    from goniofrost.core.atomic_file import check_output_file, check_output_suffix
    from goniofrost.core.grid import FULL_GRID
    from goniofrost.brdf.merl_file import valid_to_full, write_merl

    if args.out is not None:  # before the dataset is opened: --out gold.txt held a MERL file
        check_output_suffix(args.out, ".binary", "the file is written in MERL's .binary format")
    dataset = open_dataset(args.dataset)
    name = dataset.resolve(args.material)
    out = Path(args.out) if args.out else Path(f"{name}.binary")
    # before tabulating the full grid, not after it
    check_output_file(out, f"it is a directory; give a file name such as {name}.binary")
    values = tabulate_cached(dataset, [name], FULL_GRID)[0]
    write_merl(out, valid_to_full(np.maximum(values, 0.0), FULL_GRID), FULL_GRID)
    missing = int(np.isnan(values).any(axis=-1).sum())
    note = f" ({missing} not measured, written as -1)" if missing else ""
    print(f"wrote {out}: {name} from {dataset.spec}, {FULL_GRID.n_valid} valid cells{note}")
    return 0
