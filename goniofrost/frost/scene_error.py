"""The error of a scene's use of a BRDF: what a usage-weighted plan predicts, bounds and reports.

The error is sum_c u_c (L_c - L_hat_c)^2 (mean over channels); its expected value is
trace(M Sigma) + sum_c u_c sigma_c^2, M = D^T diag(u) D. A ``SceneError`` (M, the weighted noise,
the calibration) travels in PLAN.json (``usage.error``). More:
docs/explanations/scene-aware-design.md.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from goniofrost.core.errors import ConfigError

# The error an assessment is of (the ``scope`` of a capture's Assess step) and how people read it.
SCOPE_BRDF, SCOPE_SCENE = "brdf", "scene"
NAMES = {SCOPE_BRDF: "error", SCOPE_SCENE: "error in the scene's use"}


@dataclass(frozen=True)
class SceneError:
    """matrix: float64 (K, K) M = D^T diag(u) D; noise_total: sum_c u_c sigma_c^2 (the model's
    reconstruction noise); calibration: the predicted-error calibration of this error (the
    model's format: coefficients, m_range, typical_log_z2/energy, bound), or None with
    ``unavailable`` saying why; usage_hash: the map's hash (PLAN.json ``usage.hash``)."""

    matrix: np.ndarray
    noise_total: float
    calibration: dict | None
    usage_hash: str = ""
    unavailable: str | None = None

    def to_plan(self) -> dict:
        """The JSON-ready section (PLAN.json ``usage.error``)."""
        return {"matrix": [[float(v) for v in row] for row in self.matrix], "noise_total": float(self.noise_total),
                "calibration": self.calibration, "unavailable": self.unavailable}


def scene_error(model, usage: np.ndarray, calibration: dict | None, usage_hash: str = "",
                unavailable: str | None = None) -> SceneError:
    """The SceneError of ``usage`` (n_valid,) sum 1 on ``model`` (M from one pass over its rows
    the scene uses)."""
    from goniofrost.frost.posterior import cell_noise
    from goniofrost.frost.usage_design import scene_matrix

    usage = np.asarray(usage, dtype=np.float64)
    return SceneError(scene_matrix(model.dictionary, usage), float(usage @ cell_noise(model)), calibration,
                      usage_hash, unavailable)


def from_plan(plan: dict, model, source: str = "PLAN.json") -> SceneError | None:
    """The plan's SceneError (None for a plan without a usage map); SceneErrorError naming the
    field (ConfigError) when the section does not fit the model."""
    usage = plan.get("usage")
    if not usage:
        return None
    section = usage.get("error")
    if not isinstance(section, dict):
        raise ConfigError(source, "usage.error", "the usage-weighted error of the plan's scene (plan --usage "
                          "with this version of goniofrost)", section)
    k = model.n_components
    matrix = np.asarray(section.get("matrix"), dtype=np.float64)
    if matrix.shape != (k, k) or not np.all(np.isfinite(matrix)):
        raise ConfigError(source, "usage.error.matrix", f"{k} x {k} finite numbers (the model's components)",
                          f"shape {matrix.shape}")
    noise_total = section.get("noise_total")
    if not isinstance(noise_total, (int, float)) or not noise_total >= 0:
        raise ConfigError(source, "usage.error.noise_total", "a number >= 0", noise_total)
    return SceneError(matrix, float(noise_total), section.get("calibration"), str(usage.get("hash", "")),
                      section.get("unavailable"))
