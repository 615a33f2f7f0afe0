"""Which materials a training run uses, and their tabulated values.

Resolves ``--dataset`` (repeatable), ``--only`` and ``--exclude`` into an ordered list of
materials, then tabulates them on the grid's valid cells. When the datasets engineer's
``goniofrost.datasets.tabulate`` (multi-dataset combination + tabulation cache) is present it is
used for tabulation; otherwise each dataset's ``Dataset.tabulate`` is called directly.
"""
from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .datasets import Dataset, open_dataset
from .errors import GoniofrostError
from .grid import MerlGrid


class SelectionOfMaterialsError(GoniofrostError, ValueError):
    """--only/--exclude name a material none of the datasets holds, or nothing is left."""


@dataclass(frozen=True)
class TrainingMaterial:
    """One material of a training run: where it comes from and what identifies its values."""

    dataset: Dataset
    name: str
    content_id: str


def collect_training_materials(specs: Sequence[str], only: Sequence[str] | None = None,
                               exclude: Sequence[str] | None = None) -> list[TrainingMaterial]:
    """Materials of the datasets in order, filtered by ``only`` / ``exclude`` (exact names).

    A name in ``only`` or ``exclude`` that no dataset holds is an error (a typo would otherwise
    silently change the training set); so is an empty result or a name held twice.
    """
    if not specs:
        raise SelectionOfMaterialsError("training: at least one --dataset is required")
    datasets = [open_dataset(spec) for spec in specs]
    pairs = [(ds, name) for ds in datasets for name in ds.names()]
    known = {name for _, name in pairs}
    for option, names in (("--only", only), ("--exclude", exclude)):
        unknown = sorted(set(names or ()) - known)
        if unknown:
            raise SelectionOfMaterialsError(
                f"training: {option} names {unknown} that none of the datasets {list(specs)} holds")
    if only:
        pairs = [p for p in pairs if p[1] in set(only)]
    if exclude:
        pairs = [p for p in pairs if p[1] not in set(exclude)]
    _check_unique(pairs)
    if not pairs:
        raise SelectionOfMaterialsError("training: no materials left after --only/--exclude")
    return [TrainingMaterial(ds, name, ds.content_id(name)) for ds, name in pairs]


def _check_unique(pairs) -> None:
    seen: dict[str, str] = {}
    for ds, name in pairs:
        if name in seen:
            raise SelectionOfMaterialsError(
                f"training: material {name!r} is in both {seen[name]!r} and {ds.spec!r}; "
                "use --exclude to keep only one")
        seen[name] = ds.spec


def tabulate_materials(materials: Sequence[TrainingMaterial], grid: MerlGrid,
                       progress: bool = False) -> np.ndarray:
    """float32 (M, n_valid, 3) BRDF in 1/sr of the materials, in order."""
    out = np.empty((len(materials), grid.n_valid, 3), dtype=np.float32)
    groups: dict[int, list[int]] = {}
    for i, material in enumerate(materials):
        groups.setdefault(id(material.dataset), []).append(i)
    bar = _bar(len(materials), progress)
    for indices in groups.values():
        dataset = materials[indices[0]].dataset
        # A few materials per call: batched evaluation without a huge temporary.
        for start in range(0, len(indices), 8):
            part = indices[start:start + 8]
            out[part] = dataset.tabulate([materials[i].name for i in part], grid)
            if bar is not None:
                bar.update(len(part))
    if bar is not None:
        bar.close()
    return out


def _bar(total: int, progress: bool):
    if not progress:
        return None
    from tqdm import tqdm
    return tqdm(total=total, desc="tabulating", unit="material", file=sys.stderr, leave=False)
