"""Kinematics, reachability and move times on the simulated rig (DESIGN.md geometry)."""
from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from goniofrost.core.grid import MerlGrid, half_diff_to_dirs
from planner.kinematics import Reason, forward, inverse
from planner.motion import move_time, time_matrix, trapezoid_time
from planner.reach import compute_reasons, reachability
from planner.rig import load_rig, rig_from_mapping

SIM = Path(__file__).resolve().parents[1] / "config" / "rigs" / "sim.yaml"
RIG = load_rig(SIM)
SMALL = MerlGrid(30, 30, 60)


def polar(w):
    return np.arctan2(np.hypot(w[..., 0], w[..., 1]), w[..., 2])


def between(a, b):
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


def azimuth_gap(w_i, w_o):
    """phi_o - phi_i wrapped into (-pi, pi]."""
    gap = np.arctan2(w_o[..., 1], w_o[..., 0]) - np.arctan2(w_i[..., 1], w_i[..., 0])
    return np.angle(np.exp(1j * gap))


def test_forward_at_known_poses():
    # Home: arm at 90 deg, sample facing the lamp: the light along the normal, the camera grazing.
    w_i, w_o = forward(RIG, [90.0, 0.0, 0.0])
    np.testing.assert_allclose(w_i, [0, 0, 1], atol=1e-15)
    np.testing.assert_allclose(w_o, [1, 0, 0], atol=1e-15)
    # Yaw 30, tilt 0, arm 60: the normal bisects lamp and camera, both 30 deg off it.
    w_i, w_o = forward(RIG, {"camera_arm": 60.0, "sample_yaw": 30.0, "sample_tilt": 0.0})
    np.testing.assert_allclose(np.degrees(polar(np.stack([w_i, w_o]))), [30, 30], atol=1e-12)
    # Tilt 40 with yaw 0: the light is 40 deg off the normal, towards the sample's -y (downwards).
    w_i, _ = forward(RIG, [90.0, 0.0, 40.0])
    np.testing.assert_allclose(w_i, [0, -np.sin(np.radians(40)), np.cos(np.radians(40))], atol=1e-15)


def test_forward_matches_the_world_geometry_on_many_poses():
    rng = np.random.default_rng(1)
    q = rng.uniform([8, -180, -80], [172, 180, 80], size=(500, 3))
    w_i, w_o = forward(RIG, q)
    a, p, t = np.radians(q.T)
    n = np.stack([np.cos(t) * np.cos(p), np.cos(t) * np.sin(p), np.sin(t)], -1)  # DESIGN.md normal
    cam = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], -1)
    np.testing.assert_allclose(w_i[:, 2], n[:, 0], atol=1e-14)                    # n . L
    np.testing.assert_allclose(w_o[:, 2], np.sum(n * cam, -1), atol=1e-14)       # n . C
    np.testing.assert_allclose(np.linalg.norm(w_o, axis=-1), 1.0, atol=1e-14)


cells = st.tuples(st.integers(0, 89), st.integers(0, 89), st.integers(0, 179))
offsets = st.tuples(*[st.floats(0.0, 0.999)] * 3)


@settings(max_examples=200, deadline=None)
@given(cells, offsets)
def test_forward_inverse_round_trip_on_reachable_cells(cell, offset):
    """Direct branch: the same pair up to a turn about the normal; mirror: its mirror image."""
    angles = (np.array(cell) + np.array(offset)) / np.array([90, 90, 180])
    w_i, w_o = half_diff_to_dirs(angles[0] ** 2 * np.pi / 2, angles[1] * np.pi / 2, angles[2] * np.pi)
    ik = inverse(RIG, w_i, w_o)
    for branch, sign in ((0, 1.0), (1, -1.0)):
        if not ik.valid[branch]:
            continue
        f_i, f_o = forward(RIG, ik.joints[branch])
        assert abs(polar(f_i) - polar(w_i)) < 1e-9 and abs(polar(f_o) - polar(w_o)) < 1e-9
        assert abs(between(f_i, f_o) - between(w_i, w_o)) < 1e-9
        if min(np.hypot(*w_i[:2]), np.hypot(*w_o[:2])) > 1e-6:  # azimuth defined
            gap = azimuth_gap(f_i, f_o) - sign * azimuth_gap(w_i, w_o)
            assert abs(np.angle(np.exp(1j * gap))) < 1e-9


def test_inverse_is_vectorised_and_valid_joints_stay_in_limits():
    w_i, w_o = SMALL.cell_directions(SMALL.valid_cells)
    ik = inverse(RIG, w_i, w_o)
    assert ik.joints.shape == (SMALL.n_valid, 2, 3) and ik.valid.shape == ik.reason.shape == (SMALL.n_valid, 2)
    q = ik.joints[ik.valid]
    for j, axis in enumerate(RIG.ordered_axes):
        assert np.all(q[:, j] >= axis.limits_deg[0]) and np.all(q[:, j] <= axis.limits_deg[1])
    assert np.all(np.abs(q[:, 2]) <= RIG.geometry.tilt_limit_deg) and np.all(q[:, 0] >= 8.0)


@pytest.mark.parametrize("theta_i, theta_o, gap_deg, reason", [
    (30.0, 34.0, 3.0, Reason.ARM_SEPARATION),     # lamp and camera about 4 deg apart
    (80.0, 85.0, 0.0, Reason.ARM_SEPARATION),     # 5 deg apart, same side
    (89.0, 89.0, 178.0, Reason.ARM_LIMIT),        # 178 deg apart: beyond the 172 deg arm limit
    (85.0, 85.0, 90.0, Reason.STAGE_LIMIT),       # both grazing 90 deg apart: normal tilted ~85 deg
    (20.0, 40.0, 120.0, Reason.OK),
])
def test_unreachable_requests_are_refused_with_their_reason(theta_i, theta_o, gap_deg, reason):
    ti, to, gap = np.radians([theta_i, theta_o, gap_deg])
    w_i = np.array([np.sin(ti), 0.0, np.cos(ti)])
    w_o = np.array([np.sin(to) * np.cos(gap), np.sin(to) * np.sin(gap), np.cos(to)])
    ik = inverse(RIG, w_i, w_o)
    assert ik.best_reason == reason
    assert ik.any_valid == (reason == Reason.OK)


def test_reachability_counts_cache_and_reasons(tmp_path):
    reach = reachability(RIG, SMALL)
    again = reachability(RIG, SMALL)  # from the disk cache
    np.testing.assert_array_equal(reach.reason, again.reason)
    np.testing.assert_array_equal(reach.reason, compute_reasons(RIG, SMALL))
    counts = reach.counts()
    assert sum(counts.values()) == SMALL.n_valid and counts["BELOW_SURFACE"] == 0
    assert counts["OK"] == reach.mask.sum() and all(counts[k] > 0 for k in ("ARM_SEPARATION", "ARM_LIMIT", "STAGE_LIMIT"))
    # Arm separation = the angle between w_i and w_o below 8 deg, checked independently.
    w_i, w_o = SMALL.cell_directions(SMALL.valid_cells)
    close = np.degrees(between(w_i, w_o)) < 8.0 - 1e-9
    np.testing.assert_array_equal(reach.reason == Reason.ARM_SEPARATION, close)


def test_a_stricter_tilt_limit_reaches_fewer_cells():
    raw = copy.deepcopy(yaml.safe_load(SIM.read_text()))
    raw["geometry"]["tilt_limit_deg"] = 40.0
    strict = rig_from_mapping(raw, "strict")
    assert strict.kinematic_hash != RIG.kinematic_hash
    loose, tight = reachability(RIG, SMALL), reachability(strict, SMALL)
    assert tight.mask.sum() < loose.mask.sum() and not np.any(tight.mask & ~loose.mask)


def test_trapezoid_move_times_known_values():
    # tilt axis: v = 20 deg/s, a = 40 deg/s^2, so cruising starts at d = v^2/a = 10 deg.
    assert trapezoid_time(40.0, 20.0, 40.0, 0.01) == pytest.approx(40 / 20 + 20 / 40)
    assert trapezoid_time(2.5, 20.0, 40.0, 0.01) == pytest.approx(2 * np.sqrt(2.5 / 40))
    assert trapezoid_time(10.0, 20.0, 40.0, 0.01) == pytest.approx(1.0)  # both formulas meet
    assert trapezoid_time(0.005, 20.0, 40.0, 0.01) == 0.0                # within tolerance
    # Axes move together: the slowest sets the time (arm 60 deg at 30 deg/s: 2 + 0.5 s).
    assert move_time(RIG, [90, 0, 0], [30, 10, 5]) == pytest.approx(2.5)
    assert move_time(RIG, [90, 0, 0], [90.01, 0.05, 0.005]) == 0.0
    m = time_matrix(RIG, np.array([[90, 0, 0], [30, 10, 5], [100, -90, 40]], float))
    np.testing.assert_allclose(m, m.T)
    assert m[0, 1] == pytest.approx(2.5) and np.all(np.diag(m) == 0)
