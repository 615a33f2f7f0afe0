"""Material datasets behind one interface: ``open_dataset(SPEC)``.

SPEC is ``builtin`` (the analytic library shipped with goniofrost), ``nbrdf:PATH.npz``
(Neural-BRDF networks), ``merl:DIR`` (a folder of MERL .binary files) or
``builtin-random:SEED:COUNT`` (seeded analytic materials of the built-in families). Several specs can be
combined with ``open_datasets``. ``SPEC:NAME`` names one material (``parse_material_spec``).
The SPECs are read by ``specs``, the tables made and cached by ``tabulate``.
"""
from __future__ import annotations

from goniofrost.datasets.base import Dataset, DatasetError, UnknownMaterialError
from goniofrost.datasets.specs import ShownMaterial, material_brdf, open_dataset, parse_material_spec, shown_material
from goniofrost.datasets.tabulate import Material, collect_materials, open_datasets, tabulate_cached, tabulate_materials

__all__ = ["Dataset", "DatasetError", "UnknownMaterialError", "open_dataset", "parse_material_spec", "material_brdf",
           "ShownMaterial", "shown_material",
           "Material", "collect_materials", "open_datasets", "tabulate_cached", "tabulate_materials"]
