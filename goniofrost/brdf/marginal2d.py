"""Mitsuba 3's continuous marginal-conditional warp of a bilinear 2D density, in numpy.

A replica of ``Marginal2D<Float, 0, Continuous=true>`` (``distr_2d.h``), which the exporter runs to
learn which micro-normal each ``rgb`` node stands for. A table ``data[y, x]`` of shape (h, w) holds
the density at nodes ``(x / (w - 1), y / (h - 1))``; vectorised over slices.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# dr::Epsilon<float> and dr::OneMinusEpsilon<float>: the sample is clipped into this range.
EPSILON = 2.0 ** -24
ONE_MINUS_EPSILON = 1.0 - 2.0 ** -24


@dataclass(frozen=True)
class Warp2D:
    """Normalised tables of a batch of 2D densities (float64).

    ``data`` (S, h, w): each slice scaled to integrate to 1 over the unit square (bilinear);
    ``cond`` (S, h, w - 1): per row, the running integral along x; ``marg`` (S, h - 1): the
    running integral along y of the rows' integrals.
    """

    data: np.ndarray
    cond: np.ndarray
    marg: np.ndarray


def build(data) -> Warp2D:
    """The normalised CDF tables of densities ``data`` (S, h, w), h, w >= 2, each slice > 0."""
    data = np.asarray(data, dtype=np.float64)
    _, h, w = data.shape
    cond = np.cumsum((0.5 / (w - 1)) * (data[..., :-1] + data[..., 1:]), axis=-1)
    rows = cond[..., -1]
    marg = np.cumsum((0.5 / (h - 1)) * (rows[:, :-1] + rows[:, 1:]), axis=-1)
    norm = 1.0 / marg[:, -1]
    return Warp2D(data * norm[:, None, None], cond * norm[:, None, None], marg * norm[:, None])


def sample(warp: Warp2D, points) -> tuple[np.ndarray, np.ndarray]:
    """Warp uniform ``points`` (S, n, 2) as (x, y) into the densities; return (S, n, 2) and pdf (S, n)."""
    points = np.clip(np.asarray(points, dtype=np.float64), EPSILON, ONE_MINUS_EPSILON)
    n_slices, h, w = warp.data.shape
    slices = np.arange(n_slices)[:, None]
    x, y = points[..., 0], points[..., 1]
    row = _first_not_below(lambda i: warp.marg[slices, i], y, h - 2)
    y = y - np.where(row > 0, warp.marg[slices, np.maximum(row - 1, 0)], 0.0)
    r0, r1 = warp.cond[slices, row, -1], warp.cond[slices, row + 1, -1]
    t = _sample_segment(y, h - 1, r0, r1)
    x = x * (r0 + (r1 - r0) * t)

    def conditional(i):
        c0, c1 = warp.cond[slices, row, i], warp.cond[slices, row + 1, i]
        return c0 + (c1 - c0) * t

    col = _first_not_below(conditional, x, w - 2)
    x = x - np.where(col > 0, conditional(np.maximum(col - 1, 0)), 0.0)
    v00, v10 = warp.data[slices, row, col], warp.data[slices, row, col + 1]
    v01, v11 = warp.data[slices, row + 1, col], warp.data[slices, row + 1, col + 1]
    c0, c1 = v00 + (v01 - v00) * t, v10 + (v11 - v10) * t
    s = _sample_segment(x, w - 1, c0, c1)
    out = np.stack([(col + s) / (w - 1), (row + t) / (h - 1)], axis=-1)
    return out, c0 + (c1 - c0) * s


def _first_not_below(values, target: np.ndarray, last: int) -> np.ndarray:
    """Smallest index i in [0, last] with values(i) >= target (``last`` if none): dr::binary_search.

    ``values(i)`` gathers a non-decreasing table at integer indices of ``target``'s shape.
    """
    lo = np.zeros(target.shape, dtype=np.int64)
    hi = np.full(target.shape, last, dtype=np.int64)
    for _ in range(int(np.ceil(np.log2(last + 1))) + 1):
        mid = (lo + hi) >> 1
        below = values(mid) < target
        lo, hi = np.where(below, np.minimum(mid + 1, hi), lo), np.where(below, hi, mid)
    return lo


def _sample_segment(u: np.ndarray, inv_width: int, v0: np.ndarray, v1: np.ndarray) -> np.ndarray:
    """Position t in [0, 1] where the integral of lerp(v0, v1) over [0, t] / inv_width equals u.

    The quadratic of ``Marginal2D::sample_segment``, with its constant-segment branch.
    """
    non_const = np.abs(v0 - v1) > 1e-4 * (v0 + v1)
    divisor = np.where(non_const, v0 - v1, v0 + v1)
    u = u * (2.0 * inv_width)
    u = np.where(non_const, v0 - np.sqrt(np.maximum(v0 * v0 + u * (v1 - v0), 0.0)), u)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(divisor != 0.0, u / np.where(divisor != 0.0, divisor, 1.0), u)
