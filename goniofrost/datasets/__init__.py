"""Material datasets behind one interface: ``open_dataset(SPEC)``.

SPEC is ``builtin``, ``builtin-random:SEED:COUNT``, ``nbrdf:PATH.npz``, ``merl:DIR`` or
``rgl:PATH``; ``SPEC:NAME`` names one material (``parse_material_spec``).
"""
from __future__ import annotations

from goniofrost.datasets.base import Dataset, DatasetError, UnknownMaterialError
from goniofrost.datasets.specs import ShownMaterial, material_brdf, open_dataset, parse_material_spec, shown_material
from goniofrost.datasets.tabulate import Material, collect_materials, open_datasets, tabulate_cached, tabulate_materials

__all__ = ["Dataset", "DatasetError", "UnknownMaterialError", "open_dataset", "parse_material_spec", "material_brdf",
           "ShownMaterial", "shown_material",
           "Material", "collect_materials", "open_datasets", "tabulate_cached", "tabulate_materials"]
