"""Compiled (numba) kernels of the Bayesian selection: one fused pass over D per greedy step,
shared by several designs on the same dictionary.

Per candidate cell they keep q = d^T Sigma d and p = d^T Sigma S^2 Sigma d and return the best
score p / (noise + q) of a range of cells (lowest index on ties; thread-independent). Arrays:
dictionary float32 (n_valid, K); rows int64 (n_c,); q, p float64 (S, n_c); noise (S, n_c) (+inf
closes a cell); prior_var, u, v float64 (S, K). The algebra: docs/explanations/bayesian-design.md.
"""
from __future__ import annotations

import numpy as np
from numba import njit, types

_OPTIONS = dict(nogil=True, fastmath=True, cache=True, boundscheck=False)
_DICTIONARY = types.Array(types.float32, 2, "C", readonly=True)
_F64 = types.float64[::1]
_F32 = types.float32[::1]
_I64 = types.int64
_F64_2 = types.float64[:, ::1]
# The noise array's two types (see the module doc): one compiled version each.
_NOISE = (types.float64[:, ::1], types.float32[:, ::1])
# Candidates per tile of the several-design pass: 512 rows of D (K = 60) are 123 kB, in L2.
TILE_ROWS = 512


@njit([types.void(_DICTIONARY, types.int64[::1], _F64_2, _F64_2, _F64_2, noise, _F64, _F64, types.int64[::1],
                  _I64, _I64) for noise in _NOISE], **_OPTIONS)
def init_forms(dictionary, rows, prior_var, q, p, noise, s2, best, best_i, i0, i1):
    """q, p for the prior Sigma = diag(prior_var[s]) of every design s on candidates [i0, i1).

    s2: (K,) squared singular values S^2.
    """
    k, designs = dictionary.shape[1], q.shape[0]
    every_row = rows.size == 0
    best[:] = -1.0
    best_i[:] = -1
    for i in range(i0, i1):
        row = dictionary[i if every_row else rows[i]]
        for s in range(designs):
            var = prior_var[s]
            qc = 0.0
            pc = 0.0
            for j in range(k):
                x = np.float64(row[j]) * var[j]
                qc += x * np.float64(row[j])
                pc += x * x * s2[j]
            q[s, i] = qc
            p[s, i] = pc
            score = pc / (noise[s, i] + qc)
            if score > best[s]:
                best[s], best_i[s] = score, i


@njit(inline="always", **_OPTIONS)
def _step_score(row, u, v, inv_delta, usu_delta2, q, p, noise, i):
    """Candidate i's step: q[i], p[i] updated from its row of D; its score p / (noise + q).
    Inlined (numba IR) into both loops below, so their arithmetic is the same to the bit."""
    # float64 sums: a and g are small differences of large terms once Sigma has shrunk
    # (float32 sums moved scores by 0.2 %); the pass stays memory-bound.
    a = 0.0
    g = 0.0
    for j in range(row.size):
        x = np.float64(row[j])
        a += x * u[j]
        g += x * v[j]
    qc = q[i] - a * a * inv_delta
    pc = p[i] - 2.0 * a * g * inv_delta + a * a * usu_delta2
    # Rounding can leave a fully determined cell a tiny negative form; neither can be < 0.
    qc = max(qc, 0.0)
    pc = max(pc, 0.0)
    q[i] = qc
    p[i] = pc
    return pc / (noise[i] + qc)


@njit(**_OPTIONS)
def _update_one(dictionary, rows, u, v, inv_delta, usu_delta2, q, p, noise, i0, i1):
    """One design's step on candidates [i0, i1) (the single-design kernel's loop, unchanged, so
    a design's numbers are the same to the bit with or without others); (best, its index)."""
    every_row = rows.size == 0
    best, best_i = -1.0, -1
    for i in range(i0, i1):
        score = _step_score(dictionary[i if every_row else rows[i]], u, v, inv_delta, usu_delta2, q, p, noise, i)
        if score > best:
            best, best_i = score, i
    return best, best_i


@njit([types.void(_DICTIONARY, types.int64[::1], _F64_2, _F64_2, _F64, _F64, _F64_2, _F64_2, noise, _F64,
                  types.int64[::1], _I64, _I64) for noise in _NOISE], **_OPTIONS)
def update_forms(dictionary, rows, u, v, inv_delta, usu_delta2, q, p, noise, best, best_i, i0, i1):
    """One greedy step of every design s on candidates [i0, i1): a = d.u[s], g = d.v[s], update
    q[s] and p[s].

    inv_delta[s] = 1 / delta; usu_delta2[s] = (u^T S^2 u) / delta^2. The candidates go in tiles
    of TILE_ROWS rows: every design's step on a tile while its rows of D are in cache.
    """
    best[:] = -1.0
    best_i[:] = -1
    for t0 in range(i0, i1, TILE_ROWS):
        t1 = min(t0 + TILE_ROWS, i1)
        for s in range(q.shape[0]):
            score, index = _update_one(dictionary, rows, u[s], v[s], inv_delta[s], usu_delta2[s], q[s], p[s],
                                       noise[s], t0, t1)
            if score > best[s]:
                best[s], best_i[s] = score, index


# ----- the time-aware design: one design, its score divided by each cell's rig time ----------------
@njit(**_OPTIONS)
def _within(poses, i, c, here, speed, accel, tolerance, budget):
    """Whether candidate pose c of cell i may be reached from ``here`` in less than ``budget`` s:
    every axis's distance under what its trapezoid covers in that time (v (T - v/a) once at top
    speed, else a T^2 / 4), or within its tolerance. No square root; a hair of slack so that
    rounding never rules out a pose that is in time."""
    for a in range(3):
        d = abs(np.float64(poses[i, c, a]) - here[a])
        if d <= tolerance[a]:
            continue
        v, acc = speed[a], accel[a]
        reach = v * (budget - v / acc) if budget >= 2.0 * v / acc else acc * budget * budget / 4.0
        if d > reach * (1.0 + 1e-9):
            return False
    return True


@njit(**_OPTIONS)
def _timed_score(gain, best, poses, fixed, i, here, speed, accel, tolerance, overhead):
    """gain / (overhead + rig seconds of candidate i), or -1 when it cannot beat ``best``.

    A score beats ``best`` only when a pose's fixed time + move is under gain / best - overhead:
    the trapezoids (and their square roots) are computed only for poses that ``_within`` that
    budget, so most cells cost a few multiplications. The result is the unpruned one's."""
    budget = gain / best - overhead if best > 0.0 else np.inf
    score = -1.0
    for c in range(fixed.shape[1]):
        fixed_c = np.float64(fixed[i, c])
        if not fixed_c < budget:  # unusable (inf) or too slow whatever the move
            continue
        if budget < np.inf and not _within(poses, i, c, here, speed, accel, tolerance, budget - fixed_c):
            continue
        move = 0.0
        for a in range(3):
            d = abs(np.float64(poses[i, c, a]) - here[a])
            if d <= tolerance[a]:
                t = 0.0
            elif d >= speed[a] * speed[a] / accel[a]:
                t = d / speed[a] + speed[a] / accel[a]
            else:
                t = 2.0 * np.sqrt(d / accel[a])
            move = max(move, t)
        score = max(score, gain / (overhead + move + fixed_c))
    return score


@njit(**_OPTIONS)
def timed_scan(q, p, noise, poses, fixed, here, speed, accel, tolerance, overhead, floor, best, best_i, i0, i1):
    """The best score gain / (overhead + rig seconds from ``here``) of candidates [i0, i1) whose
    gain p / (noise + q) is above 0 and at least ``floor``, and its index (lowest on ties), from
    the forms a pass over D has just updated (this reads q, p and noise, 20 bytes a cell, and the
    poses of the cells that qualify only).

    q, p, noise: (n_c,) one design's; poses: float32 (n_c, k, 3); fixed: float32 (n_c, k); here,
    speed, accel, tolerance: float64 (3,); overhead: seconds added to every cell's time; best,
    best_i: (1,) outputs.
    """
    best[0], best_i[0] = -1.0, -1
    for i in range(i0, i1):
        gain = p[i] / (noise[i] + q[i])
        if gain > 0.0 and gain >= floor:
            score = _timed_score(gain, best[0], poses, fixed, i, here, speed, accel, tolerance, overhead)
            if score > best[0]:
                best[0], best_i[0] = score, i


@njit([types.void(_DICTIONARY, types.int64[::1], _F64, _F64, types.float64, types.float64, _F64, _F64, noise,
                  types.float64, types.int32[::1], _F64, types.int64[::1], _I64, _I64)
       for noise in (_F64, _F32)], **_OPTIONS)
def update_collect(dictionary, rows, u, v, inv_delta, usu_delta2, q, p, noise, share, found, best, best_i, i0, i1):
    """One design's greedy step on candidates [i0, i1) (``_update_one``'s arithmetic) that also
    collects every candidate whose score (gain) is above 0 and at least ``share`` of the running
    best: their indices in found[i0:], in index order, then -1 if there is room. Every cell
    whose gain reaches ``share`` of the step's best is among them (the running best is never
    above the step's), so ``timed_found`` on them is ``timed_scan``. 4 bytes written a
    collected cell (most of them may be: the gains are flat).

    u, v, q, p: float64 (K,), (K,), (n_c,), (n_c,); found int32 (n_c,); best, best_i: (1,)
    outputs (the step's best gain and its index on [i0, i1)).
    """
    every_row = rows.size == 0
    top, top_i, n = -1.0, -1, i0
    for i in range(i0, i1):
        score = _step_score(dictionary[i if every_row else rows[i]], u, v, inv_delta, usu_delta2, q, p, noise, i)
        if score > top:
            top, top_i = score, i
        if score > 0.0 and score >= share * top:
            found[n] = i
            n += 1
    if n < i1:
        found[n] = -1
    best[0], best_i[0] = top, top_i


@njit(**_OPTIONS)
def timed_found(found, q, p, noise, poses, fixed, here, speed, accel, tolerance, overhead, floor, best, best_i, i0, i1):
    """``timed_scan`` of the candidates ``update_collect`` collected on [i0, i1): the best score
    gain / (overhead + rig seconds from ``here``) of those whose gain p / (noise + q) is at
    least ``floor``, and its index (lowest on ties). The same result as ``timed_scan`` on
    [i0, i1), reading the collected cells only."""
    best[0], best_i[0] = -1.0, -1
    for n in range(i0, i1):
        i = found[n]
        if i < 0:
            break
        gain = p[i] / (noise[i] + q[i])
        if gain >= floor:
            score = _timed_score(gain, best[0], poses, fixed, i, here, speed, accel, tolerance, overhead)
            if score > best[0]:
                best[0], best_i[0] = score, i
