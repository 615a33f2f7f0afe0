"""A simulated rig's ground truth: the material it showed, against what the session measured.

The demo and ``capture --material`` hand a ``GroundTruth`` to the capture
(``SessionOptions.compare``); the session's report then adds its section and its preview the
reference spheres. ``ground_truth``: the material's table on the model's grid (the preview's and
the demo's reference); ``truth_section``: report.json's ``ground_truth`` (the reconstruction's
actual error beside its predicted one, the samples' relative errors, grazing samples apart). The
material is the caller's (``goniofrost.datasets.ShownMaterial``: ``spec``, ``brdf``, ``table``).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

GRAZING_DEG = 75.0  # samples whose theta_i or theta_o exceeds this are reported apart as grazing


@dataclass(frozen=True)
class GroundTruth:
    """What a session on a simulated rig is compared with: the ``material`` it showed."""

    material: object

    def reference(self, grid) -> np.ndarray:
        """The material's BRDF on the grid's valid cells (n_valid, 3), in 1/sr."""
        return ground_truth(self.material, grid)

    def section(self, inputs, records, estimate: np.ndarray, predicted: float, median: float | None) -> dict:
        """report.json's ``ground_truth`` (see ``truth_section``)."""
        return truth_section(inputs, records, self.material, estimate, predicted, median)


def truth_section(inputs, records, material, estimate: np.ndarray, predicted: float,
                  median: float | None) -> dict:
    """report.json's ``ground_truth``: ``estimate`` (n_cells, 3) against ``material``'s table, its
    ``predicted`` and ``median`` error estimates, the error with the exact values at the samples'
    cells, and the samples' relative errors."""
    from goniofrost.frost.metrics import log_relative_mse
    from goniofrost.frost.reconstruction import reconstruct_bayes

    model = inputs.model
    truth = ground_truth(material, model.grid)
    order = np.array([r.plan_index for r in records], dtype=np.int64)
    measured = np.array([r.rgb for r in records])
    true_at = truth[inputs.positions[order]]
    known = ~np.isnan(true_at).any(axis=1)  # a cell the material has no data for (rgl:PATH) gives no exact sample
    exact = reconstruct_bayes(model, inputs.positions[order][known], true_at[known], with_std=False).brdf
    error = float(log_relative_mse(model, truth, estimate[model.grid.valid_cells]))
    best = float(log_relative_mse(model, truth, exact))
    at_measured = truth_at_measured_directions(inputs, records, material)
    rel, rel_measured = relative_errors(measured, true_at), relative_errors(measured, at_measured)
    samples = inputs.plan["samples"]
    grazing = np.array([max(samples[r.plan_index]["theta_i_deg"], samples[r.plan_index]["theta_o_deg"]) > GRAZING_DEG
                        for r in records], dtype=bool)
    return {"material": material.spec, "log_relative_mse": error, "point_prediction_before_centring": predicted,
            "point_prediction_over_actual": predicted / error if error > 0 else None,
            "median_estimate": median, "median_over_actual": median / error if median is not None and error > 0 else None,
            "log_relative_mse_exact_samples": best, "ratio_to_exact": error / best if best > 0 else None,
            "sample_relative_error_median": _median(rel),
            "sample_relative_error_max": _max(rel),
            "sample_relative_error_median_at_measured_directions": _median(rel_measured),
            "grazing": {"beyond_deg": GRAZING_DEG, "samples": int(grazing.sum()),
                        "sample_relative_error_median": _median(rel[grazing]),
                        "sample_relative_error_median_at_measured_directions": _median(rel_measured[grazing])}}


def truth_at_measured_directions(inputs, records, material) -> np.ndarray:
    """The material's BRDF (n, 3) at the directions each sample was measured at, as the session
    knows them (forward kinematics of the joints reached, with the session's alignment): what the
    calibration had to reproduce. The cell's own directions differ by the axes' positioning
    resolution (e.g. 0.088 deg for the simulated yaw servo), which matters on sharp peaks.
    ``material``: its ``brdf(w_i, w_o)`` (``goniofrost.datasets.ShownMaterial``)."""
    from planner.kinematics import forward

    out = np.empty((len(records), 3))
    for k, record in enumerate(records):
        w_i, w_o = forward(inputs.rig, record.joints)
        out[k] = material.brdf(w_i, w_o)
    return out


def relative_errors(measured: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """|measured - truth| / truth per sample and channel (n, 3); NaN where the truth is 0.

    A measured material's channel can be exactly 0 (MERL black-obsidian's green and blue over a
    quarter of its cells) where the rig reads a small positive value at its detection limit: a
    relative error there is undefined, not infinite (report.json held ``Infinity``, which is not
    JSON), so it is left out of the medians and the maximum.
    """
    measured, truth = np.asarray(measured, dtype=np.float64), np.asarray(truth, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(truth > 0, np.abs(measured - truth) / truth, np.nan)


def _median(values: np.ndarray) -> float | None:
    """The median of the defined (non-NaN) values; None when there is none."""
    values = np.asarray(values, dtype=np.float64)
    return float(np.nanmedian(values)) if (~np.isnan(values)).any() else None


def _max(values: np.ndarray) -> float | None:
    """The largest defined (non-NaN) value; None when there is none."""
    values = np.asarray(values, dtype=np.float64)
    return float(np.nanmax(values)) if (~np.isnan(values)).any() else None


@lru_cache(maxsize=2)
def ground_truth(material, grid) -> np.ndarray:
    """The material's BRDF on the grid's valid cells, float64 (n_valid, 3) in 1/sr (read-only;
    kept for the demo's reference file and preview, which need the same table): its
    ``table(grid)`` (``goniofrost.datasets.ShownMaterial``)."""
    truth = np.asarray(material.table(grid), dtype=np.float64)
    truth.setflags(write=False)
    return truth
