"""Order of samples and pose per sample that minimise the total motion time from home to home.

A small generalised travelling-salesman problem, solved by nearest neighbour from several starts,
then local search (best pose per sample by dynamic programming, 2-opt, or-opt). Relies on move
times being symmetric.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .motion import time_matrix
from .rig import Rig

# An improvement smaller than this (seconds) is rounding noise, not progress.
_GAIN_EPS = 1e-9


@dataclass(frozen=True)
class Tour:
    """A planned tour: ``order`` (n,) sample indices in capture order, ``choice`` (n,) candidate
    index chosen for each sample in that order, ``total_s`` seconds home -> samples -> home."""

    order: np.ndarray
    choice: np.ndarray
    total_s: float


def plan_tour(rig: Rig, poses: np.ndarray, valid: np.ndarray, home, *, restarts: int = 8) -> Tour:
    """The fastest tour found over candidate poses (n, k, 3) deg with reachability valid (n, k).

    Every sample needs at least one valid candidate. Deterministic.
    """
    dist, ids = _pose_matrix(rig, poses, valid, home)
    n = poses.shape[0]
    if n == 0:
        return Tour(np.zeros(0, np.int64), np.zeros(0, np.int64), 0.0)
    firsts = np.argsort(dist[0, ids].min(axis=1), kind="stable")[:max(1, restarts)]
    best = None
    for first in firsts:
        order = _nearest_neighbour(dist, ids, int(first))
        tour = _local_search(dist, ids, order)
        if best is None or tour.total_s < best.total_s - _GAIN_EPS:
            best = tour
    return best


def fixed_order_tour(rig: Rig, poses: np.ndarray, valid: np.ndarray, home, order) -> Tour:
    """The tour visiting samples in the given order with the best pose per sample (no reordering)."""
    dist, ids = _pose_matrix(rig, poses, valid, home)
    order = np.asarray(order, dtype=np.int64)
    choice, total = _best_choice(dist, ids, order)
    return Tour(order, choice, total)


def _pose_matrix(rig: Rig, poses: np.ndarray, valid: np.ndarray, home) -> tuple[np.ndarray, np.ndarray]:
    """Move times between home (node 0) and every candidate (node 1 + s*k + c), inf to invalid ones."""
    n, k, _ = poses.shape
    if n and not valid.any(axis=1).all():
        raise ValueError("every sample needs at least one reachable pose")
    nodes = np.concatenate([np.asarray(home, dtype=np.float64)[None], poses.reshape(-1, 3)])
    dist = time_matrix(rig, nodes)
    bad = np.concatenate([[False], ~valid.reshape(-1)])
    dist[bad, :] = np.inf
    dist[:, bad] = np.inf
    return dist, 1 + np.arange(n * k).reshape(n, k)


def _nearest_neighbour(dist: np.ndarray, ids: np.ndarray, first: int) -> np.ndarray:
    """Sample order built greedily from home, starting with sample ``first``."""
    n = ids.shape[0]
    left = np.ones(n, dtype=bool)
    left[first] = False
    order = [first]
    here = ids[first][np.argmin(dist[0, ids[first]])]
    for _ in range(n - 1):
        cost = np.where(left[:, None], dist[here, ids], np.inf)
        s, c = np.unravel_index(np.argmin(cost), cost.shape)
        order.append(int(s))
        left[s] = False
        here = ids[s, c]
    return np.array(order, dtype=np.int64)


def _local_search(dist: np.ndarray, ids: np.ndarray, order: np.ndarray) -> Tour:
    """Alternate the best pose choice with 2-opt and or-opt moves until none improves."""
    choice, total = _best_choice(dist, ids, order)
    while True:
        nodes = ids[order, choice]
        moved = _two_opt(dist, nodes, order, choice) or _or_opt(dist, nodes, order, choice)
        if moved is None:
            return Tour(order, choice, total)
        # The move gained with the poses fixed; re-choosing poses can only gain more,
        # so the total falls strictly and the loop ends.
        order = moved[0]
        choice, total = _best_choice(dist, ids, order)


def _best_choice(dist: np.ndarray, ids: np.ndarray, order: np.ndarray) -> tuple[np.ndarray, float]:
    """Exact best candidate per sample for a fixed order (Viterbi over the path home -> ... -> home)."""
    n = order.size
    cost = dist[0, ids[order[0]]]
    back = np.zeros((n, ids.shape[1]), dtype=np.int64)
    for t in range(1, n):
        step = cost[:, None] + dist[np.ix_(ids[order[t - 1]], ids[order[t]])]
        back[t] = np.argmin(step, axis=0)
        cost = step[back[t], np.arange(ids.shape[1])]
    cost = cost + dist[ids[order[-1]], 0]
    choice = np.empty(n, dtype=np.int64)
    choice[-1] = int(np.argmin(cost))
    for t in range(n - 1, 0, -1):
        choice[t - 1] = back[t, choice[t]]
    return choice, float(cost[choice[-1]])


def _two_opt(dist, nodes, order, choice):
    """The best 2-opt move (reverse positions i..j), or None if none gains."""
    seq = np.concatenate([[0], nodes, [0]])
    n = nodes.size
    i = np.arange(1, n + 1)[:, None]
    j = np.arange(1, n + 1)[None, :]
    with np.errstate(invalid="ignore"):
        gain = (dist[seq[i - 1], seq[i]] + dist[seq[j], seq[j + 1]]
                - dist[seq[i - 1], seq[j]] - dist[seq[i], seq[j + 1]])
    gain = np.where((j > i) & np.isfinite(gain), gain, -np.inf)
    bi, bj = np.unravel_index(np.argmax(gain), gain.shape)
    if gain[bi, bj] <= _GAIN_EPS:
        return None
    a, b = bi, bj + 1  # positions in order/choice (0-based), reverse a..b-1
    order, choice = order.copy(), choice.copy()
    order[a:b], choice[a:b] = order[a:b][::-1].copy(), choice[a:b][::-1].copy()
    return order, choice


def _or_opt(dist, nodes, order, choice):
    """The first improving or-opt move of a stretch of 1-3 samples, or None."""
    n = nodes.size
    for length in (1, 2, 3):
        for i in range(n - length + 1):
            moved = _move_stretch(dist, nodes, i, length)
            if moved is not None:
                perm = moved
                return order[perm], choice[perm]
    return None


def _move_stretch(dist, nodes, i: int, length: int):
    """Best reinsertion of nodes[i:i+length] (either direction) as a permutation, if it gains."""
    seq = np.concatenate([[0], nodes, [0]])
    s, e = i + 1, i + length  # stretch positions in seq
    removal = dist[seq[s - 1], seq[s]] + dist[seq[e], seq[e + 1]] - dist[seq[s - 1], seq[e + 1]]
    rest = np.concatenate([seq[:s], seq[e + 1:]])
    p, q = rest[:-1], rest[1:]
    fwd = dist[p, seq[s]] + dist[seq[e], q] - dist[p, q]
    rev = dist[p, seq[e]] + dist[seq[s], q] - dist[p, q]
    with np.errstate(invalid="ignore"):
        gains = removal - np.stack([fwd, rev])
    gains[~np.isfinite(gains)] = -np.inf
    gains[:, s - 1] = -np.inf  # putting it back where it was
    d, at = np.unravel_index(np.argmax(gains), gains.shape)
    if gains[d, at] <= _GAIN_EPS:
        return None
    idx = np.arange(nodes.size)
    stretch = idx[i:i + length][::-1] if d else idx[i:i + length]
    others = np.concatenate([idx[:i], idx[i + length:]])
    return np.concatenate([others[:at], stretch, others[at:]])
