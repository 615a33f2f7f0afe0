"""Dataset SPECs: ``open_dataset(SPEC)``, ``parse_material_spec(SPEC:NAME)``,
``material_brdf(SPEC:NAME)`` (a BRDF for the simulated camera) and ``shown_material(SPEC:NAME)``
(what a simulated rig shows and a report compares against). Re-exported by
``goniofrost.datasets``.
"""
from __future__ import annotations

import difflib
from dataclasses import dataclass
from typing import Callable

from goniofrost.datasets.base import Dataset, DatasetError


def open_dataset(spec: str) -> Dataset:
    """Open the dataset named by SPEC; raise DatasetError for an unknown or unreadable spec."""
    if spec == "builtin":
        from goniofrost.datasets.builtin import BuiltinDataset
        return BuiltinDataset()
    kind, sep, arg = spec.partition(":")
    if sep and kind == "nbrdf" and arg:
        from goniofrost.datasets.nbrdf import NbrdfDataset
        return NbrdfDataset(arg)
    if sep and kind == "merl" and arg:
        from goniofrost.datasets.merl_dir import MerlDirDataset
        return MerlDirDataset(arg)
    if sep and kind == "rgl" and arg:
        from goniofrost.datasets.rgl import RglDataset
        return RglDataset(arg)
    if kind == RANDOM:
        return _random_dataset(spec, arg)
    close = difflib.get_close_matches(kind, ["builtin", "nbrdf", "merl", "rgl"], n=1, cutoff=0.5)
    hint = f"; did you mean {close[0] if close[0] == 'builtin' else close[0] + ':' + (arg or 'PATH')}?" if close else ""
    raise DatasetError(
        f"unknown dataset spec {spec!r}: expected 'builtin', 'nbrdf:PATH.npz', 'merl:DIR', 'rgl:PATH' or "
        f"'{RANDOM}:SEED:COUNT'{hint}"
    )


RANDOM = "builtin-random"
MAX_RANDOM = 1000  # materials of one builtin-random spec


def spec_read_from(spec: str, folder: str) -> str:
    """SPEC with a relative PATH of ``nbrdf:PATH``, ``merl:DIR`` or ``rgl:PATH`` read from ``folder`` (joined to it);
    every other spec as it is. A model records the folder its datasets' relative paths were given in
    (``train``), so they open again from any working folder."""
    import os

    kind, sep, arg = spec.partition(":")
    if sep and kind in ("nbrdf", "merl", "rgl") and arg and not os.path.isabs(arg):
        return f"{kind}:{os.path.join(folder, arg)}"
    return spec


def _random_dataset(spec: str, arg: str) -> Dataset:
    """``builtin-random:SEED:COUNT``: COUNT seeded analytic materials (``builtin.random_library``)."""
    from goniofrost.datasets.builtin import BuiltinDataset, random_library

    seed, sep, count = arg.partition(":")
    if not (sep and seed.isdigit() and count.isdigit() and 1 <= int(count) <= MAX_RANDOM):
        raise DatasetError(f"dataset spec {spec!r}: expected {RANDOM}:SEED:COUNT, SEED an integer >= 0 and "
                           f"COUNT an integer 1-{MAX_RANDOM}, e.g. {RANDOM}:1:24")
    return BuiltinDataset(random_library(int(seed), int(count)), spec=f"{RANDOM}:{int(seed)}:{int(count)}")


def material_option(text: str, option: str | None = "--material") -> str:
    """A SPEC:NAME resolved (``builtin:gold``), or DatasetError naming the command's ``option``
    ("command line: --material: unknown material ..."; None: the error as it is, for a caller that
    names its own file and key)."""
    from goniofrost.datasets.base import UnknownMaterialError

    try:
        dataset, name = parse_material_spec(text)
    except (DatasetError, UnknownMaterialError) as exc:  # the second is a KeyError, not a DatasetError
        if option is None:
            raise
        kind = UnknownMaterialError if isinstance(exc, UnknownMaterialError) else DatasetError
        raise kind(f"command line: {option}: {exc}") from None
    return f"{dataset.spec}:{name}"


def parse_material_spec(text: str) -> tuple[Dataset, str]:
    """Split ``SPEC:NAME`` (e.g. ``builtin:gold``, ``nbrdf:data/x.npz:chrome``) into an open
    dataset and a resolved material name."""
    spec, sep, name = text.rpartition(":")
    if not sep or not spec or not name:
        raise DatasetError(f"material {text!r}: expected SPEC:NAME, e.g. builtin:red-plastic")
    dataset = open_dataset(spec)
    return dataset, dataset.resolve(name)


def material_brdf(text: str):
    """``(name, brdf)`` of ``SPEC:NAME``: the resolved ``SPEC:NAME`` and a function
    ``brdf(w_i, w_o) -> (3,) float64`` RGB in 1/sr of unit directions (3,) in the sample frame
    (what ``sim.camera.SimCamera`` renders)."""
    dataset, name = parse_material_spec(text)
    return f"{dataset.spec}:{name}", _brdf(dataset, name)


def _brdf(dataset: Dataset, name: str):
    """``brdf(w_i, w_o)`` of the material ``name`` of ``dataset`` (see ``material_brdf``)."""
    import numpy as np

    from goniofrost.core.grid import dirs_to_half_diff

    def brdf(w_i, w_o):
        th, td, pd = dirs_to_half_diff(np.asarray(w_i, float), np.asarray(w_o, float))
        # phi_d folded into [0, pi) as the grid's cells hold it (MerlGrid.angle_cells): the
        # material is reciprocal by construction, and at a cell's directions it is the table's
        # value whichever of light and camera plays w_i. The small networks of the shared data
        # are not reciprocal at grazing: RGL acrylic_felt_white at (2.8, 86, 179) deg gives
        # 0.00028 1/sr, at its reciprocal (phi_d -1 deg) 26.5, and a rig measuring with light
        # and camera swapped read a value 95 000 x the table's.
        # ``rendered``: where a measurement has no data (rgl:PATH beyond its elevations) the camera
        # sees what a renderer of the file shows.
        return np.asarray(dataset.rendered(name, th, td, np.mod(pd, np.pi)), dtype=np.float64)

    return brdf


@dataclass(frozen=True)
class ShownMaterial:
    """A material a simulated rig shows: ``spec`` its resolved ``SPEC:NAME``; ``brdf(w_i, w_o)``
    RGB (3,) float64 in 1/sr of unit directions (3,) in the sample frame (``material_brdf``);
    ``table(grid)`` its values on the grid's valid cells, float64 (n_valid, 3) in 1/sr."""

    spec: str
    brdf: Callable
    table: Callable


def shown_material(text: str, option: str | None = "--material") -> ShownMaterial:
    """``SPEC:NAME`` resolved into a ShownMaterial; an unknown dataset or name fails as
    ``material_option`` says (naming ``option``)."""
    import numpy as np

    spec = material_option(text, option)
    dataset, name = parse_material_spec(spec)

    def table(grid):
        return dataset.tabulate([name], grid)[0].astype(np.float64)

    return ShownMaterial(spec, _brdf(dataset, name), table)
