"""Compiled (numba) kernels of the FROST selection: one fused pass per SOMP step.

Cells are stored in blocks of W, cell-minor: ``qb[b, :, r]`` (k,) is the atom of cell b*W + r and
``cb[b, :, r]`` (t,) its row of C = Q^T R. Each kernel takes a range of blocks [b0, b1) and
releases the GIL; the result does not depend on the split. Arrays are float32 except
``positions`` (int64) and ``inv_s2`` (float64); ``scores`` (n_blocks * W,) float32.
"""
from __future__ import annotations

import numpy as np
from numba import njit, types

# Explicit signatures: compiled (or loaded from numba's on-disk cache) at import, so no
# selection's timing includes a compilation.
_OPTIONS = dict(nogil=True, fastmath=True, cache=True, boundscheck=False)
_F32_1 = types.float32[::1]
_F32_3 = types.float32[:, :, ::1]
_DICTIONARY = types.Array(types.float32, 2, "C", readonly=True)  # (a memory-mapped model)
_I64 = types.int64


@njit(types.void(_DICTIONARY, types.int64[::1], _I64, types.float64[::1], _F32_3, _I64, _I64),
      **_OPTIONS)
def pack_atoms(dictionary, positions, k, inv_s2, qb, b0, b1):
    """Fill blocks [b0, b1) of qb (n_blocks, k, W): the first k entries of dictionary rows
    ``positions`` (float32 (n_valid, K) -> cells), times inv_s2 (k,), scaled to unit l2 norm
    (a zero row stays zero); cells past positions.size are zero padding.

    Each block is written entry by entry along its W cells while its rows are still in cache, so
    every store goes to the cache line of the one before.
    """
    w = qb.shape[2]
    n = positions.size
    scale = np.empty(w)
    tile = np.empty((k, w))  # the block's x = d * inv_s2, entry-major (in L2)
    for b in range(b0, b1):
        cells = min(w, n - b * w)
        for r in range(cells):
            row = dictionary[positions[b * w + r]]
            norm2 = 0.0
            for i in range(k):
                x = np.float64(row[i]) * inv_s2[i]
                tile[i, r] = x
                norm2 += x * x
            scale[r] = 1.0 / np.sqrt(norm2) if norm2 > 0.0 else 0.0
        for i in range(k):
            out = qb[b, i]
            for r in range(cells):
                out[r] = np.float32(tile[i, r] * scale[r])
            for r in range(cells, w):
                out[r] = 0.0


@njit(types.void(_F32_3, _F32_1, _I64, _I64), **_OPTIONS)
def block_scores(cb, scores, b0, b1):
    """scores of the cells of blocks [b0, b1): the l1 norms sum_t |C[cell, t]|."""
    t, w = cb.shape[1], cb.shape[2]
    for b in range(b0, b1):
        s = scores[b * w:(b + 1) * w]
        s[:] = 0.0
        for i in range(t):
            for r in range(w):
                s[r] += abs(cb[b, i, r])


@njit(**_OPTIONS)
def _update_block(c, v, u, s):
    """c (t, W) -= u v^T in place; s (W,) = column l1 norms of the new c."""
    t, w = c.shape
    s[:] = 0.0
    for i in range(t):
        ui = u[i]
        for r in range(w):
            x = c[i, r] - ui * v[r]
            c[i, r] = x
            s[r] += abs(x)


@njit(types.void(_F32_3, _F32_1, _F32_3, _F32_1, _F32_1, _I64, _I64), **_OPTIONS)
def rank1_step(source, w, cb, u, scores, b0, b1):
    """One SOMP step on blocks [b0, b1): v = source_blk^T w, C_blk -= u v^T (u (t,)), scores.

    source is qb with w = b (k,) (v = Q^T b), or cb itself with w = z (t,) (v = C z: each
    block's v is complete before that block is updated).
    """
    n_rows, w_cells = source.shape[1], source.shape[2]
    v = np.empty(w_cells, np.float32)
    for blk in range(b0, b1):
        v[:] = 0.0
        for i in range(n_rows):
            wi = w[i]
            for r in range(w_cells):
                v[r] += wi * source[blk, i, r]
        _update_block(cb[blk], v, u, scores[blk * w_cells:(blk + 1) * w_cells])
