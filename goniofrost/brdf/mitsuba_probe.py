"""Probe an exported ``.bsdf`` with Mitsuba 3's ``measured`` BSDF, against the table it came from.

Mitsuba's eval at direction pairs, its sampled weights, its pdf's integral and the table's albedo.
Mitsuba's convention: ``si.wi`` towards the viewer, ``wo`` towards the light, eval = f cos theta_o.
A spectral file is probed in ``scalar_spectral`` and turned into linear sRGB. Needs ``mitsuba``.
"""
from __future__ import annotations

import numpy as np

from goniofrost.brdf.mitsuba_export import elevation_dir, lookup, u_to_theta
from goniofrost.brdf.mitsuba_render import SPECTRAL_VARIANT, VARIANT, load_mitsuba
from goniofrost.core.grid import MerlGrid


def load_bsdf(path, variant: str = VARIANT):
    """The ``measured`` BSDF of a tensor file (RGB variant; SPECTRAL_VARIANT for a spectral file)."""
    mi = load_mitsuba(variant)
    return mi.load_dict({"type": "measured", "filename": str(path)})


def _surface(w_i, variant: str = VARIANT):
    mi = load_mitsuba(variant)
    si = mi.SurfaceInteraction3f()
    si.wi = mi.Vector3f(*np.asarray(w_i, dtype=float))
    return si


def eval_pairs_spectral(bsdf, w_i: np.ndarray, w_o: np.ndarray, wavelengths: np.ndarray) -> np.ndarray:
    """Mitsuba's spectral eval (n, n_lambda) at direction pairs (n, 3) and wavelengths (nm), 4 at a time."""
    mi = load_mitsuba(SPECTRAL_VARIANT)
    lam = np.asarray(wavelengths, dtype=np.float64)
    width = mi.MI_WAVELENGTH_SAMPLES
    padded = np.concatenate([lam, np.full(-lam.size % width, lam[-1])]).reshape(-1, width)
    ctx, out = mi.BSDFContext(), np.empty((len(w_i), padded.size))
    for k in range(len(w_i)):
        si, wo = _surface(w_i[k], SPECTRAL_VARIANT), mi.Vector3f(*w_o[k])
        for j, group in enumerate(padded):
            si.wavelengths = mi.Spectrum(*group)
            out[k, j * width:(j + 1) * width] = np.array(bsdf.eval(ctx, si, wo))
    return out[:, :lam.size]


def spectral_to_rgb_weights(wavelengths: np.ndarray) -> np.ndarray:
    """W (n_lambda, 3): linear sRGB = values @ W of a spectrum given at its nodes (Mitsuba's colour functions).

    The spectrum between the nodes is linear and constant beyond them (as the renderer
    interpolates the file), integrated at 1 nm over 360-830 nm against CIE 1931 x D65 and
    normalised so that a spectrum of 1 is Y = 1; then Mitsuba's ``xyz_to_srgb``.
    """
    mi = load_mitsuba(SPECTRAL_VARIANT)
    lam = np.asarray(wavelengths, dtype=np.float64)
    fine = np.arange(mi.MI_CIE_MIN, mi.MI_CIE_MAX + 0.5, 1.0)
    xyz = np.array([mi.cie1931_xyz(float(x)) for x in fine], dtype=np.float64).reshape(fine.size, 3)
    d65 = np.array([mi.cie_d65(float(x)) for x in fine])
    weight = xyz * d65[:, None] / np.sum(d65 * xyz[:, 1])
    hats = np.stack([np.interp(fine, lam, e) for e in np.eye(lam.size)], axis=0)    # (n_lambda, fine)
    to_srgb = np.array([np.array(mi.xyz_to_srgb(mi.Color3f(*e))) for e in np.eye(3)]).T
    return hats @ weight @ to_srgb.T


def eval_pairs_spectral_rgb(bsdf, w_i: np.ndarray, w_o: np.ndarray, wavelengths: np.ndarray) -> np.ndarray:
    """Mitsuba's spectral eval at direction pairs converted to linear sRGB (n, 3), as its film does."""
    return eval_pairs_spectral(bsdf, w_i, w_o, wavelengths) @ spectral_to_rgb_weights(wavelengths)


def eval_pairs(bsdf, w_i: np.ndarray, w_o: np.ndarray) -> np.ndarray:
    """Mitsuba's eval, f cos theta_o (n, 3), at unit direction pairs (n, 3)."""
    mi = load_mitsuba()
    ctx, out = mi.BSDFContext(), np.empty((len(w_i), 3))
    for k in range(len(w_i)):
        out[k] = bsdf.eval(ctx, _surface(w_i[k]), mi.Vector3f(*w_o[k]))
    return out


def sampled_weights(bsdf, w_i: np.ndarray, samples: np.ndarray) -> np.ndarray:
    """The weights (f cos / pdf, 0 when rejected) (n, 3) of Mitsuba's sample at uniforms (n, 2)."""
    mi = load_mitsuba()
    ctx, si = mi.BSDFContext(), _surface(w_i)
    return np.array([np.array(bsdf.sample(ctx, si, 0.5, mi.Point2f(*u))[1]) for u in samples])


def half_vector_quadrature(theta_i: float, n: int = 300):
    """(w_i (3,), w_o (N, 3), weights (N,)): a midpoint rule over w_o in the upper hemisphere.

    Parameterised by the half vector with theta_h = u^2 pi / 2 (the MERL grid's spacing, fine
    where a glossy lobe is) and phi_h, n x 2n points; d omega_o = 4 <w_i, h> d omega_h.
    Directions below the horizon get weight 0.
    """
    u = (np.arange(n) + 0.5) / n
    phi = (np.arange(2 * n) + 0.5) / (2 * n) * 2 * np.pi
    theta_h, phi = np.meshgrid(u_to_theta(u), phi, indexing="ij")
    h = np.stack([np.sin(theta_h) * np.cos(phi), np.sin(theta_h) * np.sin(phi), np.cos(theta_h)], -1).reshape(-1, 3)
    w_i = elevation_dir(theta_i)
    c = h @ w_i
    w_o = 2 * c[:, None] * h - w_i
    d_theta = np.repeat(np.pi * u / n, 2 * n)                      # d theta_h = pi u du
    weight = 4 * c * np.sin(theta_h).ravel() * d_theta * (np.pi / n)
    return w_i, w_o, np.where((c > 0) & (w_o[:, 2] > 0), weight, 0.0)


def table_albedo(table: np.ndarray, grid: MerlGrid, theta_i: float, n: int = 300) -> np.ndarray:
    """Directional albedo (3,) of a prepared table: integral of f cos theta_o over w_o."""
    w_i, w_o, weight = half_vector_quadrature(theta_i, n)
    f = lookup(table, grid, np.broadcast_to(w_i, w_o.shape), w_o)
    return (f * (w_o[:, 2] * weight)[:, None]).sum(axis=0)


def pdf_integral(bsdf, theta_i: float, n: int = 250) -> float:
    """Integral of Mitsuba's pdf over the upper hemisphere at incident elevation theta_i (rad)."""
    mi = load_mitsuba()
    w_i, w_o, weight = half_vector_quadrature(theta_i, n)
    ctx, si = mi.BSDFContext(), _surface(w_i)
    inside = np.flatnonzero(weight > 0)
    pdf = np.array([bsdf.pdf(ctx, si, mi.Vector3f(*w_o[k])) for k in inside])
    return float(pdf @ weight[inside])
