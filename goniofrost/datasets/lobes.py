"""Small vectorised BRDF lobes for the built-in analytic library.

Each lobe takes a ``Geometry`` (the four cosines an isotropic BRDF needs) and returns 1/sr, shape
(N,) or (N, 3), symmetric in (mu_i, mu_o). GGX is written ``D F L(mu_i) L(mu_o)`` with
``L(mu) = 1 / (mu + sqrt(a^2 + (1 - a^2) mu^2))``: finite at grazing angles.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

# Resolution of the 1-D tables (Fresnel over cos theta_d, albedo over mu_i), both on [0, 1].
FRESNEL_NODES = 513
ALBEDO_NODES = 33
# Quadrature of the albedo integral: Gauss-Legendre in t with polar angle pi t^2 about the
# lobe axis (dense near the axis, so lobes with alpha ~ 0.01 are integrated accurately).
QUAD_T, QUAD_AZIMUTH = 48, 32
# Ceiling of a specular lobe's shape, 1/sr (times Fresnel <= 1); see soft_limit.
SPEC_LIMIT = 1000.0
# The sheen visibility term diverges when both directions graze; its denominator is floored.
SHEEN_MIN_DENOM = 0.05


@dataclass(frozen=True)
class Geometry:
    """Cosines of N direction pairs: mu_i = cos theta_i, mu_o = cos theta_o, cos_h = cos theta_h,
    cos_d = cos theta_d (= w_i . h); ``above`` is True where both directions have z > 0."""

    mu_i: np.ndarray
    mu_o: np.ndarray
    cos_h: np.ndarray
    cos_d: np.ndarray
    above: np.ndarray

    @classmethod
    def from_angles(cls, theta_h, theta_d, phi_d) -> "Geometry":
        """Geometry of Rusinkiewicz angles (radians, any broadcastable shapes, flattened)."""
        th, td, pd = (np.ravel(a) for a in np.broadcast_arrays(
            *(np.asarray(a, dtype=np.float64) for a in (theta_h, theta_d, phi_d))))
        st, ct, sd, cd = np.sin(th), np.cos(th), np.sin(td), np.cos(td)
        cross = st * sd * np.cos(pd)
        # w_i = R_y(theta_h) d and w_o its mirror about h (goniofrost.core.grid.half_diff_to_dirs)
        mu_i, mu_o = ct * cd - cross, ct * cd + cross
        return cls._make(mu_i, mu_o, ct, cd)

    @classmethod
    def from_dirs(cls, w_i, w_o) -> "Geometry":
        """Geometry of unit directions (N, 3); w_o = -w_i (no half vector) counts as below."""
        h = w_i + w_o
        norm = np.linalg.norm(h, axis=-1)
        with np.errstate(invalid="ignore", divide="ignore"):
            h = h / norm[:, None]
        cos_d = np.nan_to_num(np.sum(w_i * h, axis=-1))
        geo = cls._make(w_i[:, 2], w_o[:, 2], np.nan_to_num(h[:, 2]), cos_d)
        return cls(geo.mu_i, geo.mu_o, geo.cos_h, geo.cos_d, geo.above & (norm > 1e-9))

    @classmethod
    def _make(cls, mu_i, mu_o, cos_h, cos_d) -> "Geometry":
        above = (mu_i > 0) & (mu_o > 0)
        return cls(np.clip(mu_i, 0.0, 1.0), np.clip(mu_o, 0.0, 1.0),
                   np.clip(cos_h, 0.0, 1.0), np.clip(cos_d, 0.0, 1.0), above)

    def segment(self, which: str, nodes: int) -> tuple[np.ndarray, np.ndarray]:
        """(segment index, position * (nodes - 1)) of cosine ``which`` on a uniform table.

        Cached: every material of a tabulation chunk shares them (lookups dominate the time).
        """
        cache = self.__dict__.setdefault("_segments", {})
        if (which, nodes) not in cache:
            pos = getattr(self, which) * (nodes - 1)
            cache[which, nodes] = (np.minimum(pos.astype(np.intp), nodes - 2), pos[:, None])
        return cache[which, nodes]


# ----- 1-D tables --------------------------------------------------------------------------
class Table:
    """A (K, 3) function of a cosine sampled uniformly on [0, 1], linearly interpolated.

    ``at`` returns (N, 3), or (N, 1) for a grey table (all channels equal), which broadcasts.
    """

    def __init__(self, values: np.ndarray) -> None:
        self.values = np.asarray(values, dtype=np.float64)
        k = self.values.shape[0]
        if np.all(self.values == self.values[:, :1]):
            # grey (e.g. a dielectric's Fresnel): look up one column, broadcast to three
            self.values = self.values[:, :1]
        # Per segment, value = base + slope * pos: one gather of each per lookup.
        self.slope = np.diff(self.values, axis=0)
        self.base = self.values[:-1] - self.slope * np.arange(k - 1)[:, None]

    def at(self, geo: "Geometry", which: str) -> np.ndarray:
        """Values (N, 3) or (N, 1) at the cosine ``which`` ("mu_i", "mu_o", "cos_d") of ``geo``."""
        seg, pos = geo.segment(which, self.values.shape[0])
        return np.take(self.base, seg, axis=0) + np.take(self.slope, seg, axis=0) * pos


def fresnel_table(eta, k=(0.0, 0.0, 0.0)) -> Table:
    """Unpolarised Fresnel reflectance (FRESNEL_NODES, 3) over cos theta_d in [0, 1].

    ``eta``, ``k``: per-channel real and imaginary index of refraction (k = 0: dielectric).
    """
    cos_t = np.linspace(0.0, 1.0, FRESNEL_NODES)[:, None]
    eta_c = np.asarray(eta, dtype=np.float64) + 1j * np.asarray(k, dtype=np.float64)
    cos_tr = np.sqrt(1.0 - (1.0 - cos_t ** 2) / eta_c ** 2 + 0j)
    r_s = (cos_t - eta_c * cos_tr) / (cos_t + eta_c * cos_tr)
    r_p = (eta_c * cos_t - cos_tr) / (eta_c * cos_t + cos_tr)
    return Table(0.5 * (np.abs(r_s) ** 2 + np.abs(r_p) ** 2))


def schlick_table(f0) -> Table:
    """Schlick's Fresnel approximation (FRESNEL_NODES, 3) over cos theta_d, normal reflectance f0."""
    cos_t = np.linspace(0.0, 1.0, FRESNEL_NODES)[:, None]
    f0 = np.asarray(f0, dtype=np.float64)
    return Table(f0 + (1.0 - f0) * (1.0 - cos_t) ** 5)


# ----- lobes ---------------------------------------------------------------------------------
def ggx_d(cos_h: np.ndarray, alpha: float) -> np.ndarray:
    """GGX (Trowbridge-Reitz) normal distribution in 1/sr; peak 1 / (pi alpha^2)."""
    a2 = alpha * alpha
    denom = cos_h * cos_h * (a2 - 1.0) + 1.0
    return a2 / (np.pi * denom * denom)


def smith_l(mu: np.ndarray, alpha: float) -> np.ndarray:
    """G1(mu) / (2 mu) of GGX's Smith shadowing; finite at mu = 0 (see module Notes)."""
    a2 = alpha * alpha
    return 1.0 / (mu + np.sqrt(a2 + (1.0 - a2) * mu * mu))


def microfacet(geo: Geometry, alpha: float, fresnel: Table) -> np.ndarray:
    """GGX specular lobe (N, 3) with a Fresnel table from ``fresnel_table``/``schlick_table``.

    The lobe's shape D L L is soft-limited to SPEC_LIMIT (see ``soft_limit``).
    """
    shape = ggx_d(geo.cos_h, alpha) * smith_l(geo.mu_i, alpha) * smith_l(geo.mu_o, alpha)
    return soft_limit(shape)[:, None] * fresnel.at(geo, "cos_d")


def soft_limit(x: np.ndarray) -> np.ndarray:
    """x / (1 + (x / SPEC_LIMIT)^4)^(1/4): the identity below SPEC_LIMIT / 2 (to 1.5 %), never
    above SPEC_LIMIT.

    A near-mirror GGX lobe grows like 1 / cos^2(theta_d) towards grazing (1e6 1/sr for chrome);
    a real instrument's finite angular resolution caps measured peaks (chrome in the
    Neural-BRDF data peaks near 500 1/sr). Lowering values keeps reciprocity and energy bounds.
    """
    return x / np.sqrt(np.sqrt(1.0 + (x * (1.0 / SPEC_LIMIT)) ** 4))


def sheen(geo: Geometry, alpha: float) -> np.ndarray:
    """Cloth sheen (N,): 'Charlie' distribution (Estevez and Kulla 2017) with Ashikhmin's
    visibility 1 / (4 (mu_i + mu_o - mu_i mu_o)); bright at grazing, as velvet is."""
    sin_h = np.sqrt(np.clip(1.0 - geo.cos_h ** 2, 0.0, 1.0))
    dist = (2.0 + 1.0 / alpha) * sin_h ** (1.0 / alpha) / (2.0 * np.pi)
    denom = np.maximum(geo.mu_i + geo.mu_o - geo.mu_i * geo.mu_o, SHEEN_MIN_DENOM)
    return dist / (4.0 * denom)


def retro(geo: Geometry, alpha: float) -> np.ndarray:
    """Retro-reflection lobe (N,) peaking at w_o = w_i (theta_d = 0).

    ``D(theta_d) G1(mu_i) G1(mu_o) / (2 (mu_i + mu_o))``: its albedo is about 1 away from
    grazing (the retro analogue of a microfacet lobe), and it vanishes at grazing.
    """
    ratio = geo.mu_i * geo.mu_o / np.maximum(geo.mu_i + geo.mu_o, 1e-12)
    return 2.0 * ggx_d(geo.cos_d, alpha) * smith_l(geo.mu_i, alpha) * smith_l(geo.mu_o, alpha) * ratio


# ----- directional albedo -------------------------------------------------------------------
def albedo_nodes() -> np.ndarray:
    """mu_i values (ALBEDO_NODES,) at which albedo tables are sampled: uniform on [0, 1]."""
    return np.linspace(0.0, 1.0, ALBEDO_NODES)


def directional_albedo(lobe, axis: str) -> np.ndarray:
    """Albedo table (ALBEDO_NODES, 3): integral of lobe(geometry) * mu_o over w_o, per mu_i node.

    ``lobe``: Geometry -> (N,) or (N, 3) in 1/sr. ``axis``: "mirror" for lobes around the
    mirror direction, "incident" for lobes around w_i (retro-reflection) or broad lobes.
    """
    mu = albedo_nodes()
    w_i = np.stack([np.sqrt(1.0 - mu ** 2), np.zeros_like(mu), mu], -1)
    axes = w_i * np.array([-1.0, -1.0, 1.0]) if axis == "mirror" else w_i
    dirs, weights = _cone_quadrature(axes)  # (nodes, P, 3), (P,)
    n_nodes, n_points = dirs.shape[:2]
    w_i_all = np.repeat(w_i, n_points, axis=0)
    geo = Geometry.from_dirs(w_i_all, dirs.reshape(-1, 3))
    values = np.asarray(lobe(geo), dtype=np.float64)
    values = (values if values.ndim == 2 else values[:, None]) * np.ones((1, 3))
    integrand = np.where(geo.above[:, None], values * geo.mu_o[:, None], 0.0)
    return np.einsum("npc,p->nc", integrand.reshape(n_nodes, n_points, 3), weights)


def _cone_quadrature(axes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Directions (n_axes, P, 3) and solid-angle weights (P,) covering the sphere about each axis."""
    t, wt = _gauss_legendre01(QUAD_T)
    gamma, d_gamma = np.pi * t ** 2, 2.0 * np.pi * t * wt
    beta = (np.arange(QUAD_AZIMUTH) + 0.5) * (2.0 * np.pi / QUAD_AZIMUTH)
    g, b = (a.ravel() for a in np.meshgrid(gamma, beta, indexing="ij"))
    weights = (np.sin(gamma) * d_gamma)[:, None].repeat(QUAD_AZIMUTH, 1).ravel() * (2.0 * np.pi / QUAD_AZIMUTH)
    e1, e2 = _frame(axes)
    dirs = (np.cos(g)[None, :, None] * axes[:, None, :]
            + (np.sin(g) * np.cos(b))[None, :, None] * e1[:, None, :]
            + (np.sin(g) * np.sin(b))[None, :, None] * e2[:, None, :])
    return dirs, weights


@lru_cache(maxsize=4)
def _gauss_legendre01(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Legendre nodes and weights on [0, 1] (computed once: an eigenproblem)."""
    t, w = np.polynomial.legendre.leggauss(n)
    return (t + 1.0) / 2.0, w / 2.0


def _frame(axes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors (n, 3) orthogonal to each unit axis (n, 3) and to each other."""
    helper = np.where(np.abs(axes[:, 1:2]) < 0.9, [[0.0, 1.0, 0.0]], [[1.0, 0.0, 0.0]])
    e1 = np.cross(axes, helper)
    e1 /= np.linalg.norm(e1, axis=-1, keepdims=True)
    return e1, np.cross(axes, e1)


def hemispherical_average(table: np.ndarray) -> np.ndarray:
    """2 * integral of E(mu) mu dmu over [0, 1] of an albedo table (ALBEDO_NODES, 3) -> (3,),
    integrating its linear interpolant exactly (so the diffuse normalisation below is exact)."""
    mu = albedo_nodes()
    a, b = table[:-1], table[1:]
    m0, m1 = mu[:-1, None], mu[1:, None]
    slope = (b - a) / (m1 - m0)
    # integral over [m0, m1] of (a + slope (mu - m0)) mu dmu
    seg = (a - slope * m0) * (m1 ** 2 - m0 ** 2) / 2.0 + slope * (m1 ** 3 - m0 ** 3) / 3.0
    return 2.0 * seg.sum(axis=0)
