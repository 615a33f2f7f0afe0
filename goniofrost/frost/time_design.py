"""The time-aware design's state: where the rig stands after each pick, batch by batch.

``bayes_selection`` with a ``TimeObjective`` scores every cell by its expected error reduction per
second of rig time from the rig's pose (``rig_cost``) plus ``overhead_s`` per sample (0: the
nearest cells nearly free; large: the sample-count design). Inside a batch
(``stopping.batch_ends``) the rig stands at the last pick's fastest pose; at a batch's end the
batch is ordered as ``plan --rig`` will (``planner.order.plan_tour``) and the next batch starts
where that tour ends. The same inputs give the same cells in the same order.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from goniofrost.frost import stopping
from goniofrost.frost.rig_cost import CellCosts, cell_costs, rig_camera, rig_sensor

# Seconds added to every sample's rig time in the score (not in any reported time) and the share of
# each step's largest error reduction a pick must reach: chosen on training materials only
# (benchmarks/time_aware.py --tune: the first fold's training materials, every 7th held out,
# 45 x 45 x 90 grid; docs/decisions/0200-time-aware-design.md). Of overheads 0.25 and 2 s with
# shares 0, 0.6 and 0.8, 2 s / 0.6 took the least median rig time over both settings and targets
# (0.64-0.84 of the sample-count design's); with 0.25 s and a share below 0.8 every held-out
# analytic material's design was out of the model (unlike every design the bound was calibrated
# on) until 35-45 samples.
OVERHEAD_S = 2.0
SHARE = 0.6
# Restarts of the batch's tour inside the design (plan --rig's schedule uses planner.order's 8):
# 0.116 s against 0.013 s a 15-sample batch (load 15), ten times in a 60-sample design, which
# would take longer than the passes over D; the end pose is then an estimate of the schedule's.
TOUR_RESTARTS = 1


@dataclass(frozen=True)
class TimeObjective:
    """Plan for rig time on ``rig`` (a ``planner.rig.Rig``): ``overhead_s`` seconds added to every
    sample in the score, ``settle_s`` seconds after every move (in the costs), ``share``: a pick's
    error reduction is at least this fraction of the step's largest (0: any cell; 1: the
    sample-count design's pick, timed or not)."""

    rig: object
    overhead_s: float = OVERHEAD_S
    settle_s: float = 0.0
    share: float = SHARE


class RigTrack:
    """The rig's pose along a time-aware design of candidates ``rows`` (int64 (n_c,)).

    costs: the CellCosts of the candidates; here: float64 (3,) the joints the next pick is timed
    from; ends: the batch ends (cumulative picks) after which the batch is re-ordered.
    """

    def __init__(self, costs: CellCosts, rig, overhead_s: float, m_max: int, share: float = 0.0,
                 full_scan: bool = False) -> None:
        self.rig, self.overhead, self.costs, self.share = rig, float(overhead_s), costs, float(share)
        # True: each step's qualifying cells are found by a second sweep over the forms (the
        # reference the collecting pass over D is tested against: the same picks, slower)
        self.full_scan = bool(full_scan)
        self.here = costs.home.copy()
        self.ends = set(stopping.batch_ends(m_max))
        self._batch: list[int] = []
        self._batch_start = self.here.copy()
        self.picked_count = 0

    @classmethod
    def of_model(cls, model, objective: TimeObjective, rows: np.ndarray, m_max: int) -> "RigTrack":
        """The track of ``model``'s candidate rows on the objective's rig (``rig_cost.cell_costs``)."""
        costs = cached_costs(model, objective.rig, rows, objective.settle_s)
        return cls(costs, objective.rig, objective.overhead_s, m_max, objective.share)

    def kernel_args(self) -> tuple:
        """(poses, fixed, here, speed, accel, tolerance, overhead) for the timed kernels."""
        c = self.costs
        return c.poses, c.fixed_s, self.here, c.speed, c.accel, c.tolerance, self.overhead

    def picked(self, i: int) -> None:
        """Candidate ``i`` was picked: the rig moves there (or, at a batch end, to the end of the
        batch's motion-ordered tour)."""
        self._batch.append(int(i))
        self.picked_count += 1
        self.here = self.costs.fastest_pose(int(i), self.here)
        if self.picked_count in self.ends:
            self.here = self._tour_end()
            self._batch, self._batch_start = [], self.here.copy()

    def _tour_end(self) -> np.ndarray:
        from planner.order import plan_tour

        idx = np.asarray(self._batch, dtype=np.int64)
        poses = self.costs.poses[idx].astype(np.float64)
        tour = plan_tour(self.rig, poses, np.isfinite(self.costs.fixed_s[idx]), self._batch_start,
                         restarts=TOUR_RESTARTS)
        return poses[tour.order[-1], tour.choice[-1]]


_CACHE_VERSION = "rig-cost-v1"


def cached_costs(model, rig, rows: np.ndarray, settle_s: float = 0.0) -> CellCosts:
    """``rig_cost.cell_costs`` of the candidates ``rows``, computed once per model, rig (kinematics,
    alignment, camera model and section, sensor), candidates and settle time, then read from the
    cache (``goniofrost.core.cache``; a few seconds to compute on the full grid, like reachability)."""
    import hashlib
    import os

    from goniofrost.core.cache import atomic_replace, cache_path, content_key
    from planner.reach import rig_key

    camera, sensor = rig_camera(rig), rig_sensor(rig)
    rows = np.ascontiguousarray(rows, dtype=np.int64)
    key = content_key(_CACHE_VERSION, rig_key(rig), camera, sensor, model.content_hash, float(settle_s),
                      hashlib.sha256(rows.tobytes()).hexdigest())
    path = cache_path("rig-cost", key, ".npz")
    try:
        with np.load(path, allow_pickle=False) as stored:
            poses, fixed = stored["poses"], stored["fixed_s"]
        if poses.shape[0] == fixed.shape[0] == rows.size:
            return CellCosts(poses, fixed, *_profiles(rig))
    except (OSError, ValueError, KeyError):
        pass  # absent or unreadable: computed again
    costs = cell_costs(model, rig, rows, camera, sensor, settle_s)
    tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp.npz")
    np.savez(tmp, poses=costs.poses, fixed_s=costs.fixed_s)
    atomic_replace(tmp, path)
    return costs


def _profiles(rig) -> tuple:
    """(speed, accel, tolerance, home) of CellCosts: the axes' profiles in joint order."""
    from planner.motion import axis_params

    return (*axis_params(rig), np.asarray(rig.home, np.float64))
