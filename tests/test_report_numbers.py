"""The numbers a session report prints and writes at the edges: a ground truth with a channel that is
exactly 0 (measured materials such as MERL black-obsidian), where a relative error is undefined."""
from __future__ import annotations

import json

import numpy as np
import pytest

from goniofrost.app import ground_truth
from goniofrost.capture import report


def test_relative_error_is_undefined_not_infinite_where_the_truth_is_zero():
    # black-obsidian's simulated capture: a channel at its detection limit read 1.3e-5 1/sr where
    # the truth is 0; report.json held "sample_relative_error_max": Infinity (not JSON)
    measured = np.array([[1.4e-4, 1.3e-5, 0.0], [0.30, 0.28, 0.27]])
    truth = np.array([[1.5e-4, 0.0, 0.0], [0.30, 0.25, 0.30]])
    rel = ground_truth.relative_errors(measured, truth)
    np.testing.assert_allclose(rel, [[1e-5 / 1.5e-4, np.nan, np.nan], [0.0, 0.12, 0.1]], rtol=1e-12)
    stats = {"median": ground_truth._median(rel), "max": ground_truth._max(rel)}
    assert stats["median"] == pytest.approx(np.median([1e-5 / 1.5e-4, 0.0, 0.12, 0.1]), rel=1e-12)
    assert stats["max"] == pytest.approx(0.12, rel=1e-12)
    json.dumps(stats, allow_nan=False)


def test_no_defined_relative_error_is_none():
    rel = ground_truth.relative_errors(np.array([[1e-6, 0.0, 2e-6]]), np.zeros((1, 3)))
    assert np.isnan(rel).all()
    assert ground_truth._median(rel) is None and ground_truth._max(rel) is None
    assert ground_truth._median(np.empty(0)) is None


def test_a_small_or_negative_sample_snr_keeps_two_significant_digits():
    # black-obsidian's capture listed "5:-0 6:-1 9:-1" for SNRs -0.0385, -0.652 and -0.527 (a
    # channel at its detection limit, its patch mean below the dark level)
    assert [report.snr_text(v) for v in (-0.038505922749167705, -0.652, 1.3, 9.4, 59.57, 3219.1)] == \
        ["-0.039", "-0.65", "1.3", "9.4", "60", "3219"]
