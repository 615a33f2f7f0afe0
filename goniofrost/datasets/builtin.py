"""The built-in analytic material library (dataset spec ``builtin``).

About 70 named, coloured, isotropic materials from diffuse to near-mirror, for users without
measured data. Values in 1/sr on the MERL absolute scale; colours are linear RGB reflectances.
Each is a GGX lobe over a Lambertian, optionally under a sheen, retro-reflection or clear-coat lobe,
layered by directional albedo so it is reciprocal and conserves energy.
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass
from functools import lru_cache
from typing import Sequence

import numpy as np

from goniofrost.core.grid import FULL_GRID, MerlGrid
from goniofrost.datasets import lobes
from goniofrost.datasets.base import Dataset
from goniofrost.datasets.lobes import Geometry
from goniofrost.datasets.parallel import tabulate_blocks

# Bump whenever any material's values change: it is part of every content_id (cache key).
LIBRARY_VERSION = "builtin-v1"
DIELECTRIC_IOR = 1.5  # plastics, lacquers, ceramics
# Cells per block when tabulating (a block's temporaries stay in cache).
BLOCK_CELLS = 32768

# Complex index of refraction (n, k) at about (650, 550, 450) nm, from refractiveindex.info.
METALS = {
    "gold": ((0.143, 0.374, 1.442), (3.983, 2.385, 1.603)),
    "silver": ((0.155, 0.117, 0.138), (4.828, 3.122, 2.147)),
    "copper": ((0.200, 0.924, 1.102), (3.912, 2.452, 2.142)),
    "aluminium": ((1.657, 0.880, 0.521), (9.224, 6.270, 4.837)),
    "chrome": ((3.180, 3.180, 2.010), (3.300, 3.330, 3.040)),
    "iron": ((2.870, 2.950, 2.650), (3.080, 2.930, 2.810)),
    "nickel": ((1.990, 1.850, 1.640), (3.740, 3.410, 2.990)),
    "titanium": ((2.740, 2.540, 2.270), (3.810, 3.430, 3.040)),
    "brass": ((0.444, 0.527, 1.094), (3.695, 2.765, 1.829)),
    "platinum": ((2.380, 2.080, 1.850), (4.260, 3.710, 3.140)),
}


@dataclass(frozen=True)
class MaterialSpec:
    """Parameters of one built-in material (colours are linear RGB in [0, 1]).

    diffuse: Lambertian albedo rho. spec_alpha: GGX roughness of the specular lobe (None: no
    lobe). spec_ior / spec_k: per-channel complex index (k = 0: dielectric); spec_f0: Schlick
    normal reflectance instead (metallic flakes). sheen / retro: (colour, roughness) top lobes.
    coat_alpha: roughness of a clear coat (None: no coat).
    """

    diffuse: tuple = (0.0, 0.0, 0.0)
    spec_alpha: float | None = None
    spec_ior: tuple = (DIELECTRIC_IOR,) * 3
    spec_k: tuple = (0.0, 0.0, 0.0)
    spec_f0: tuple | None = None
    sheen: tuple | None = None
    retro: tuple | None = None
    coat_alpha: float | None = None


def _diffuse(rho) -> MaterialSpec:
    return MaterialSpec(diffuse=rho)


def _plastic(rho, alpha) -> MaterialSpec:
    return MaterialSpec(diffuse=rho, spec_alpha=alpha)


def _metal(metal, alpha) -> MaterialSpec:
    n, k = METALS[metal]
    return MaterialSpec(spec_alpha=alpha, spec_ior=n, spec_k=k)


def _coated(rho, coat_alpha, base_alpha=None, f0=None) -> MaterialSpec:
    return MaterialSpec(diffuse=rho, spec_alpha=base_alpha, spec_f0=f0, coat_alpha=coat_alpha)


def _metallic_paint(colour) -> MaterialSpec:
    c = np.asarray(colour)
    return _coated(tuple(0.25 * c), 0.02, base_alpha=0.25, f0=tuple(0.85 * c))


def _fabric(rho, sheen_colour, sheen_alpha, spec_alpha=None) -> MaterialSpec:
    return MaterialSpec(diffuse=rho, spec_alpha=spec_alpha, sheen=(sheen_colour, sheen_alpha))


def _retro(rho, retro_colour, retro_alpha) -> MaterialSpec:
    return MaterialSpec(diffuse=rho, retro=(retro_colour, retro_alpha))


LIBRARY: dict[str, MaterialSpec] = {
    # diffuse
    "white-diffuse": _diffuse((0.80, 0.80, 0.80)),
    "grey-diffuse": _diffuse((0.18, 0.18, 0.18)),
    "black-diffuse": _diffuse((0.03, 0.03, 0.03)),
    "chalk": _diffuse((0.85, 0.84, 0.80)),
    "brown-cardboard": _diffuse((0.45, 0.30, 0.18)),
    "terracotta": _diffuse((0.55, 0.25, 0.15)),
    "sand": _diffuse((0.60, 0.50, 0.35)),
    "white-paper": _plastic((0.78, 0.78, 0.80), 0.45),
    # plastics: a rough dielectric lobe over a coloured diffuse
    "red-plastic": _plastic((0.65, 0.05, 0.04), 0.08),
    "green-plastic": _plastic((0.06, 0.45, 0.10), 0.08),
    "blue-plastic": _plastic((0.05, 0.10, 0.60), 0.08),
    "yellow-plastic": _plastic((0.75, 0.60, 0.05), 0.08),
    "orange-plastic": _plastic((0.80, 0.30, 0.04), 0.10),
    "purple-plastic": _plastic((0.35, 0.08, 0.45), 0.10),
    "white-plastic": _plastic((0.80, 0.80, 0.78), 0.10),
    "black-plastic": _plastic((0.02, 0.02, 0.02), 0.06),
    "grey-plastic": _plastic((0.25, 0.25, 0.25), 0.12),
    "glossy-white-plastic": _plastic((0.82, 0.82, 0.80), 0.03),
    "matte-red-plastic": _plastic((0.60, 0.06, 0.05), 0.35),
    "matte-blue-plastic": _plastic((0.06, 0.12, 0.55), 0.35),
    # rubbers: very rough dielectric
    "black-rubber": _plastic((0.02, 0.02, 0.02), 0.45),
    "grey-rubber": _plastic((0.15, 0.15, 0.15), 0.50),
    "red-rubber": _plastic((0.40, 0.05, 0.04), 0.50),
    # polished metals (conductor Fresnel)
    "gold": _metal("gold", 0.03),
    "silver": _metal("silver", 0.025),
    "copper": _metal("copper", 0.04),
    "aluminium": _metal("aluminium", 0.035),
    "chrome": _metal("chrome", 0.012),
    "iron": _metal("iron", 0.06),
    "nickel": _metal("nickel", 0.04),
    "titanium": _metal("titanium", 0.05),
    "brass": _metal("brass", 0.04),
    "platinum": _metal("platinum", 0.03),
    # rough metals
    "brushed-aluminium": _metal("aluminium", 0.15),
    "rough-gold": _metal("gold", 0.20),
    "rough-copper": _metal("copper", 0.25),
    "satin-steel": _metal("iron", 0.12),
    "dull-silver": _metal("silver", 0.18),
    "cast-iron": _metal("iron", 0.35),
    # metallic paints: clear coat over tinted flakes and a dark coloured base
    "red-metallic-paint": _metallic_paint((0.70, 0.08, 0.06)),
    "blue-metallic-paint": _metallic_paint((0.08, 0.20, 0.70)),
    "green-metallic-paint": _metallic_paint((0.10, 0.55, 0.20)),
    "gold-metallic-paint": _metallic_paint((0.80, 0.60, 0.25)),
    "silver-metallic-paint": _metallic_paint((0.70, 0.70, 0.72)),
    "black-metallic-paint": _metallic_paint((0.10, 0.10, 0.11)),
    # lacquers and ceramics: clear coat over a diffuse base
    "red-car-paint": _coated((0.60, 0.04, 0.03), 0.02),
    "blue-car-paint": _coated((0.04, 0.08, 0.50), 0.02),
    "white-car-paint": _coated((0.80, 0.80, 0.80), 0.02),
    "yellow-car-paint": _coated((0.75, 0.55, 0.03), 0.025),
    "piano-black": _coated((0.01, 0.01, 0.01), 0.015),
    "lacquered-wood": _coated((0.35, 0.18, 0.08), 0.04),
    "white-ceramic": _coated((0.85, 0.85, 0.83), 0.03),
    "blue-ceramic": _coated((0.10, 0.20, 0.60), 0.03),
    "green-ceramic": _coated((0.12, 0.45, 0.25), 0.03),
    "polished-marble": _coated((0.75, 0.73, 0.70), 0.05),
    # wood and stone
    "oak-wood": _plastic((0.45, 0.30, 0.16), 0.30),
    "walnut-wood": _plastic((0.20, 0.11, 0.06), 0.30),
    "slate": _plastic((0.10, 0.11, 0.12), 0.30),
    "granite": _plastic((0.35, 0.32, 0.30), 0.40),
    # fabrics: sheen over a diffuse (and sometimes a soft specular)
    "blue-satin-fabric": _fabric((0.05, 0.10, 0.45), (0.30, 0.40, 0.80), 0.30, spec_alpha=0.20),
    "red-velvet": _fabric((0.25, 0.02, 0.03), (0.80, 0.15, 0.15), 0.50),
    "black-velvet": _fabric((0.01, 0.01, 0.01), (0.25, 0.25, 0.25), 0.50),
    "purple-velvet": _fabric((0.15, 0.03, 0.20), (0.55, 0.20, 0.70), 0.50),
    "green-felt": _fabric((0.08, 0.35, 0.12), (0.15, 0.40, 0.20), 0.80),
    "white-cotton": _fabric((0.75, 0.75, 0.72), (0.40, 0.40, 0.40), 0.70),
    "grey-wool": _fabric((0.30, 0.30, 0.30), (0.35, 0.35, 0.35), 0.90),
    "yellow-silk": _fabric((0.55, 0.45, 0.05), (0.90, 0.80, 0.30), 0.25, spec_alpha=0.15),
    "brown-leather": _fabric((0.25, 0.12, 0.06), (0.15, 0.10, 0.07), 0.60, spec_alpha=0.35),
    "black-leather": _fabric((0.02, 0.02, 0.02), (0.10, 0.10, 0.10), 0.60, spec_alpha=0.30),
    # retro-reflectors
    "white-retroreflective-tape": _retro((0.25, 0.25, 0.25), (0.60, 0.60, 0.60), 0.15),
    "yellow-safety-vest": _retro((0.60, 0.65, 0.05), (0.50, 0.55, 0.10), 0.20),
    "red-road-sign": _retro((0.40, 0.04, 0.03), (0.55, 0.06, 0.05), 0.15),
    "grey-retro-paint": _retro((0.20, 0.20, 0.20), (0.30, 0.30, 0.30), 0.30),
    "lunar-dust": _retro((0.12, 0.11, 0.10), (0.10, 0.09, 0.08), 0.60),
}

# Seeded random materials (dataset spec ``builtin-random:SEED:COUNT``, ``random_library``): a
# renewable supply of materials no benchmark has seen, for test sets fixed before their first run
# (a test set is spent once run). Each is drawn from one of the library's
# families, its parameters within that family's spread in LIBRARY above: of a kind the library
# holds, none of its materials.
FAMILIES = ("diffuse", "plastic", "metal", "coated", "metallic-paint", "fabric", "retro")
# Mixed into the seed so that builtin-random:SEED draws differ from other seeded streams.
RANDOM_SALT = 0x6F6E696F


def random_library(seed: int, count: int) -> dict[str, MaterialSpec]:
    """``count`` materials drawn with ``seed`` (the same seed: the same materials; the first k of a
    larger count are the k-material library), named ``r{seed}-{index:03d}-{family}``."""
    rng = np.random.default_rng([RANDOM_SALT, int(seed)])
    out = {}
    for index in range(1, int(count) + 1):
        family = FAMILIES[int(rng.integers(len(FAMILIES)))]
        out[f"r{seed}-{index:03d}-{family}"] = _draw(family, rng)
    return out


def _colour(rng, lo: float, hi: float) -> tuple:
    return tuple(round(float(v), 4) for v in rng.uniform(lo, hi, 3))


def _log_uniform(rng, lo: float, hi: float) -> float:
    return round(float(np.exp(rng.uniform(np.log(lo), np.log(hi)))), 4)


def _draw(family: str, rng) -> MaterialSpec:
    """One material of ``family``: colours uniform per channel, roughnesses log-uniform, within the
    family's range in LIBRARY."""
    if family == "diffuse":
        return _diffuse(_colour(rng, 0.02, 0.85))
    if family == "plastic":
        return _plastic(_colour(rng, 0.02, 0.80), _log_uniform(rng, 0.03, 0.50))
    if family == "metal":
        return _metal(sorted(METALS)[int(rng.integers(len(METALS)))], _log_uniform(rng, 0.012, 0.35))
    if family == "coated":
        return _coated(_colour(rng, 0.01, 0.85), _log_uniform(rng, 0.015, 0.05))
    if family == "metallic-paint":
        return _metallic_paint(_colour(rng, 0.08, 0.80))
    if family == "fabric":
        rho, sheen, alpha = _colour(rng, 0.01, 0.75), _colour(rng, 0.10, 0.90), round(float(rng.uniform(0.25, 0.9)), 4)
        return _fabric(rho, sheen, alpha, _log_uniform(rng, 0.15, 0.35) if rng.random() < 0.3 else None)
    return _retro(_colour(rng, 0.10, 0.60), _colour(rng, 0.05, 0.60), round(float(rng.uniform(0.15, 0.60)), 4))


class CompiledMaterial:
    """A material's lookup tables (Fresnel and albedo), ready to evaluate on a Geometry."""

    def __init__(self, spec: MaterialSpec) -> None:
        self.spec = spec
        self.rho = np.asarray(spec.diffuse, dtype=np.float64)
        none = lobes.Table(np.ones((lobes.ALBEDO_NODES, 3)))
        self.spec_lobe = _spec_lobe(spec.spec_alpha, spec.spec_ior, spec.spec_k, spec.spec_f0)
        self.top_lobe = _top_lobe(spec.sheen, spec.retro)
        self.coat_lobe = _spec_lobe(spec.coat_alpha, (DIELECTRIC_IOR,) * 3, (0.0,) * 3, None)
        e_spec = _albedo(self.spec_lobe, "mirror")
        # 1 - E(mu) of each layer: the fraction a layer lets through towards what lies below
        self.below_spec = lobes.Table(1.0 - e_spec)
        self.diffuse_norm = 1.0 / (1.0 - lobes.hemispherical_average(e_spec))
        self.below_top = lobes.Table(1.0 - _albedo(self.top_lobe, "incident")) if self.top_lobe else none
        self.below_coat = lobes.Table(1.0 - _albedo(self.coat_lobe, "mirror")) if self.coat_lobe else none

    def evaluate(self, geo: Geometry) -> np.ndarray:
        """BRDF (N, 3) in 1/sr; 0 where a direction is at or below the surface.

        ``f_base = f_spec + rho / pi * (1 - E_s(mu_i)) (1 - E_s(mu_o)) / (1 - E_s_avg)``, then each
        layer above (top lobe, clear coat) ``f = f_top + (1 - E_t(mu_i)) (1 - E_t(mu_o)) f_below``, E
        the layer's directional albedo: reciprocal, and the albedo stays <= 1.
        """
        f = np.broadcast_to(self.rho / np.pi, (geo.mu_i.size, 3))
        if self.spec_lobe:
            f = self.spec_lobe(geo) + _through(self.below_spec, geo) * (self.rho * self.diffuse_norm / np.pi)
        if self.top_lobe:
            f = self.top_lobe(geo) + _through(self.below_top, geo) * f
        if self.coat_lobe:
            f = self.coat_lobe(geo) + _through(self.below_coat, geo) * f
        return np.where(geo.above[:, None], f, 0.0)


def _through(table: lobes.Table, geo: Geometry) -> np.ndarray:
    """(1 - E(mu_i)) (1 - E(mu_o)), (N, 3): what a layer above lets through, both ways."""
    return table.at(geo, "mu_i") * table.at(geo, "mu_o")


@lru_cache(maxsize=None)
def _spec_lobe(alpha, ior, k, f0):
    """A GGX lobe, Geometry -> (N, 3), or None without alpha (shared by equal parameters)."""
    if alpha is None:
        return None
    fresnel = lobes.schlick_table(f0) if f0 is not None else lobes.fresnel_table(ior, k)
    return lambda geo: lobes.microfacet(geo, alpha, fresnel)


@lru_cache(maxsize=None)
def _top_lobe(sheen, retro):
    """Sheen plus retro-reflection, Geometry -> (N, 3), or None when the material has neither."""
    parts = [(lobes.sheen, p) for p in [sheen] if p] + [(lobes.retro, p) for p in [retro] if p]
    if not parts:
        return None

    def top(geo: Geometry) -> np.ndarray:
        return sum(fn(geo, alpha)[:, None] * np.asarray(colour) for fn, (colour, alpha) in parts)
    return top


@lru_cache(maxsize=None)
def _albedo(lobe, axis: str) -> np.ndarray:
    """Directional albedo table of a lobe (zeros for None), computed once per distinct lobe."""
    if lobe is None:
        return np.zeros((lobes.ALBEDO_NODES, 3))
    return lobes.directional_albedo(lobe, axis)


@lru_cache(maxsize=None)
def compiled_spec(spec: MaterialSpec) -> CompiledMaterial:
    """The compiled material of ``spec`` (computed once per process and spec)."""
    return CompiledMaterial(spec)


class BuiltinDataset(Dataset):
    """The analytic library: ``names()`` lists LIBRARY (or ``library``, e.g. ``random_library``'s,
    under ``spec``); evaluation is exact at any angles."""

    def __init__(self, library: dict[str, MaterialSpec] | None = None, spec: str = "builtin") -> None:
        self.library = LIBRARY if library is None else dict(library)
        self.spec = spec

    def names(self) -> list[str]:
        return list(self.library)

    def content_id(self, name: str) -> str:
        params = json.dumps(asdict(self.library[self.resolve(name)]), sort_keys=True)
        digest = hashlib.sha256(params.encode()).hexdigest()[:16]
        return f"{LIBRARY_VERSION}:{name}:{digest}"

    def evaluate(self, name: str, theta_h, theta_d, phi_d) -> np.ndarray:
        return self._evaluate_many([name], theta_h, theta_d, phi_d)[0]

    def tabulate(self, names: Sequence[str] | None = None, grid: MerlGrid = FULL_GRID,
                 cells: np.ndarray | None = None) -> np.ndarray:
        """float32 (len(names), n_cells, 3): blocks of cells on one thread per core."""
        names = self.names() if names is None else [self.resolve(n) for n in names]
        for name in names:
            compiled_spec(self.library[name])  # albedo tables once, before the threads
        cells = grid.valid_cells if cells is None else np.asarray(cells, dtype=np.int64)
        return tabulate_blocks(self._evaluate_many, names, grid, cells, BLOCK_CELLS)

    def _evaluate_many(self, names: Sequence[str], theta_h, theta_d, phi_d) -> np.ndarray:
        """(len(names), *shape, 3): the geometry is computed once for all materials."""
        shape = np.broadcast_shapes(*(np.shape(a) for a in (theta_h, theta_d, phi_d)))
        geo = Geometry.from_angles(theta_h, theta_d, phi_d)
        materials = [compiled_spec(self.library[self.resolve(n)]) for n in names]
        return np.stack([m.evaluate(geo) for m in materials]).reshape(len(names), *shape, 3)
