"""``goniofrost compare A B [C ...] --out compare.png [--json]``: BRDFs side by side, with the pairwise numbers.

Each input is a session folder (its ``brdf.binary``, as its report.json names it), a MERL
.binary file or an RGL tensor file (``.bsdf``: evaluated as Mitsuba 3's ``measured`` plugin does,
``rgl:PATH``, on the grid of the first .binary input, else the full grid; the cells it has no data
for are missing, left out of the numbers and black on the spheres). Writes the spheres of every input under the same lights (``goniofrost.brdf.compare``)
and prints the pairwise rendering SNR and log-relative MSE, or with ``--json`` the numbers as one
JSON document. Nothing is written when an input is refused.
"""
from __future__ import annotations

import argparse

HELP = "render several BRDFs (session folders, .binary or .bsdf files) side by side; pairwise rendering SNR and log-relative MSE"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("inputs", nargs="+", metavar="SESSION_OR_BINARY",
                        help="two or more session folders, MERL .binary files or RGL tensor files (.bsdf), keyed A, B, "
                             "C, ... in this order")
    parser.add_argument("--out", required=True, metavar="FILE.png", help="the PNG to write")
    parser.add_argument("--json", action="store_true", help="print the numbers as JSON instead of lines")
    parser.add_argument("--size", type=int, default=128, help="sphere diameter in pixels, 16 to 2048 (default 128)")


def resolve(path_text: str):
    """(MERL file, label) of an input: a session folder's BRDF (label: the folder name) or a .binary."""
    import json
    from pathlib import Path

    from goniofrost.core.errors import GoniofrostError

    path = Path(path_text)
    if path.is_dir():
        name = "brdf.binary"
        report = path / "report.json"
        if report.is_file():
            try:
                name = json.loads(report.read_text())["outputs"]["brdf"]
            except (ValueError, KeyError, TypeError):
                raise GoniofrostError(f"{report}: expected a session report with outputs.brdf, found an unreadable "
                                      f"or different document") from None
        binary = path / name
        if path.resolve() not in (path / name).resolve().parents:  # report.json named /etc/passwd or ../x
            raise GoniofrostError(f"{report}: outputs.brdf: expected a file in the session folder {path}, "
                                  f"found {name!r}")
        if not binary.is_file():
            raise GoniofrostError(f"{path}: no {name}: expected a finished session folder (its reconstruction "
                                  f"{binary}) or a MERL .binary file")
        return binary, path.resolve().name
    if not path.exists():
        raise GoniofrostError(f"{path}: no such session folder or file")
    return path, path.name


def load_tables(paths) -> list:
    """(brdf (grid.size, 3) in 1/sr, grid) of every input, each checked before any is rendered."""
    import numpy as np

    from goniofrost.brdf.merl_file import read_merl_complete, valid_to_full
    from goniofrost.core.grid import FULL_GRID
    from goniofrost.datasets.rgl import RglDataset

    merl = {str(p): read_merl_complete(p) for p in paths if p.suffix != ".bsdf"}
    grid = next(iter(merl.values()))[1] if merl else FULL_GRID
    tables = []
    for path in paths:
        if str(path) in merl:
            tables.append(merl[str(path)])
            continue
        values = RglDataset(path).tabulate(None, grid)[0].astype(np.float64)
        tables.append((valid_to_full(values, grid), grid))
    return tables


def run(args: argparse.Namespace) -> int:
    import json

    from goniofrost.app.png_out import check_png_name, check_sphere_size
    import dataclasses

    from goniofrost.brdf.compare import KEYS, compare_tables, write_png
    from goniofrost.brdf.preview import record_figure
    from goniofrost.core.errors import GoniofrostError

    if len(args.inputs) < 2:
        raise GoniofrostError(f"inputs: expected at least 2 session folders or .binary files, found {len(args.inputs)}")
    if len(args.inputs) > len(KEYS):
        raise GoniofrostError(f"inputs: expected at most {len(KEYS)}, found {len(args.inputs)}")
    check_png_name(args.out)
    check_sphere_size(args.size)
    resolved = [resolve(text) for text in args.inputs]
    paths = [p for p, _ in resolved]
    comparison = compare_tables(load_tables(paths), [label for _, label in resolved], paths, size=args.size)
    # each input's error figure, from the record beside it (a session's brdf.json; none for a .bsdf)
    comparison = dataclasses.replace(comparison, figures=tuple(
        None if p.suffix == ".bsdf" else record_figure(p) for p in paths))
    write_png(args.out, comparison, title="goniofrost compare")
    if args.json:
        print(json.dumps(comparison.to_json() | {"picture": str(args.out)}, indent=2))
        return 0
    print(f"wrote {args.out}")
    for key, (path, label) in zip(comparison.keys, resolved):
        print(f"{key}: {label} ({path})")
    for line in comparison.table():
        print(line)
    return 0
