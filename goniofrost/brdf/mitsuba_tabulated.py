"""Render a scene with a BRDF table evaluated directly, and sampled the same way whatever the BRDF.

The BSDF ``goniofrost_tabulated`` (a Python plugin, ``llvm_ad_rgb``) looks up a MERL-grid table at
the nearest cell and samples the cosine hemisphere, so two renders with the same seed trace the
same paths; ``set_table`` swaps the table. Why: docs/explanations/scene-aware-design.md. Needs
``mitsuba``.
"""
from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np

from goniofrost.core.grid import MerlGrid, dirs_to_half_diff

VARIANT = "llvm_ad_rgb"
PLUGIN = "goniofrost_tabulated"


def _mitsuba():
    """Mitsuba in the LLVM RGB variant, wavefront loops, the tabulated BSDF registered."""
    import drjit as dr

    from goniofrost.brdf.mitsuba_render import load_with_bsdf

    mi = load_with_bsdf(VARIANT, PLUGIN, lambda mi: _tabulated_class(mi, dr))
    # evaluated loops and calls: the BSDF receives computed arrays that numpy can read
    dr.set_flag(dr.JitFlag.SymbolicLoops, False)
    dr.set_flag(dr.JitFlag.SymbolicCalls, False)
    return mi


def lookup(grid: MerlGrid, table: np.ndarray, w_i: np.ndarray, w_o: np.ndarray) -> np.ndarray:
    """BRDF values (N, 3) of ``table`` (grid.size, 3) (1/sr; 0 on invalid cells) at direction
    pairs (N, 3) in the local frame; 0 where either direction is at or below the surface."""
    theta_h, theta_d, phi_d = dirs_to_half_diff(w_i, w_o)
    above = (w_i[:, 2] > 0) & (w_o[:, 2] > 0) & np.isfinite(theta_h) & np.isfinite(theta_d) & np.isfinite(phi_d)
    out = np.zeros((w_i.shape[0], 3), dtype=np.float32)
    if above.any():
        out[above] = table[grid.angles_to_flat(theta_h[above], theta_d[above], phi_d[above])]
    return out


def full_table(grid: MerlGrid, values: np.ndarray) -> np.ndarray:
    """float32 (grid.size, 3) of values (n_valid, 3) on the valid cells, 0 elsewhere; negative
    and non-finite values become 0 (a BRDF is non-negative)."""
    table = np.zeros((grid.size, 3), dtype=np.float32)
    clean = np.nan_to_num(np.asarray(values, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    table[grid.valid_cells] = np.maximum(clean, 0.0)
    return table


def _tabulated_class(mi, dr):
    """The tabulated BSDF class of the active variant (defined once the variant is set)."""

    def as_numpy(v) -> np.ndarray:
        return np.asarray(v, dtype=np.float64).reshape(3, -1).T

    class Tabulated(mi.BSDF):
        """A MERL-grid table, nearest cell; cosine-hemisphere sampling (module doc)."""

        def __init__(self, props):
            mi.BSDF.__init__(self, props)
            self.grid = MerlGrid()
            self.table = np.zeros((self.grid.size, 3), dtype=np.float32)
            self.m_flags = mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide
            self.m_components = [self.m_flags]

        def set_table(self, grid: MerlGrid, table: np.ndarray) -> None:
            self.grid, self.table = grid, np.asarray(table, dtype=np.float32)

        def _value(self, si, wo):
            """f(w_i, w_o) cos(theta_o), Color3f."""
            w_i, w_o = as_numpy(si.wi), as_numpy(wo)
            f = lookup(self.grid, self.table, w_i, w_o) * np.clip(w_o[:, 2:3], 0.0, None).astype(np.float32)
            return mi.Color3f(np.ascontiguousarray(f.T))

        def sample(self, ctx, si, sample1, sample2, active=True):
            wo = mi.warp.square_to_cosine_hemisphere(sample2)
            bs = mi.BSDFSample3f()
            bs.wo = wo
            bs.pdf = dr.select(mi.Frame3f.cos_theta(si.wi) > 0, mi.warp.square_to_cosine_hemisphere_pdf(wo), 0.0)
            bs.eta = 1.0
            bs.sampled_type = mi.UInt32(+mi.BSDFFlags.DiffuseReflection)
            bs.sampled_component = mi.UInt32(0)
            value = self._value(si, wo)
            weight = dr.select(bs.pdf > 0, value / dr.maximum(bs.pdf, 1e-20), 0.0)
            return bs, weight

        def eval(self, ctx, si, wo, active=True):
            return self._value(si, wo)

        def pdf(self, ctx, si, wo, active=True):
            ok = (mi.Frame3f.cos_theta(si.wi) > 0) & (mi.Frame3f.cos_theta(wo) > 0)
            return dr.select(ok, mi.warp.square_to_cosine_hemisphere_pdf(wo), 0.0)

        def eval_pdf(self, ctx, si, wo, active=True):
            return self.eval(ctx, si, wo, active), self.pdf(ctx, si, wo, active)

        def traverse(self, callback):
            pass

        def to_string(self):
            return f"{PLUGIN}[grid {self.grid.shape}]"

    return Tabulated


class TabulatedScene:
    """A scene whose object ``object_id`` carries the tabulated BSDF; render it with any table.

    ``render(grid, values, spp, seed)``: float32 (H, W, 3) linear RGB of the scene with the
    object's BRDF = values (n_valid, 3) on ``grid``'s valid cells.
    """

    def __init__(self, scene_path, object_id: str) -> None:
        from goniofrost.brdf.mitsuba_usage import _find_shape, load_scene

        self.mi = _mitsuba()
        self.scene = load_scene(scene_path, object_id, ET.Element("bsdf", {"type": PLUGIN}), mi=self.mi)
        self.bsdf = _find_shape(self.scene, object_id).bsdf()

    def render(self, grid: MerlGrid, values: np.ndarray, spp: int, seed: int = 0) -> np.ndarray:
        mi = _mitsuba()
        self.bsdf.set_table(grid, full_table(grid, values))
        return np.asarray(mi.render(self.scene, seed=seed, spp=int(spp)), dtype=np.float32)[..., :3]

