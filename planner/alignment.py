"""The rig's alignment measured: each axis's zero offset fitted to images of the holder card.

``alignment_poses`` chooses where to look at the white card; ``fit_alignment`` fits the offsets to
the marker corners and the white tile's brightness. The record is ``planner.alignment_file``.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from goniofrost.core.errors import GoniofrostError


# ---- estimation ---------------------------------------------------------------------------------
class AlignmentError(GoniofrostError):
    """The alignment could not be measured well enough (names what failed)."""


# Limits of a trustworthy fit (tests/test_alignment.py; the simulated rig leaves ~0.1 px and ~0.03 %).
MIN_IMAGES = 8                  # images with a readable marker set
MIN_PHOTOMETRIC = 6             # images with the white tile's brightness
MAX_RESIDUAL_PX = 1.0           # RMS distance of the marker corners from the fitted model
MAX_PHOTOMETRIC_RESIDUAL = 0.01  # RMS relative deviation of the tile's brightness from A cos(theta_i)


@dataclass(frozen=True)
class Observation:
    """One image of the holder card at a pose.

    ``joints`` (3,): the axes' readings in joint order (degrees); ``plane_mm`` (N, 2): marker corners
    on the card; ``image_px`` (N, 2): where they were read; ``rate``: the white tile's brightness
    per second at a fixed set of pixels, normalised by the lamp's photodiode (None: not measured);
    ``pnp_rotation`` (3, 3): the camera-from-card rotation solvePnP found in this image alone (None:
    not solved).
    """

    joints: np.ndarray
    plane_mm: np.ndarray
    image_px: np.ndarray
    rate: float | None = None
    pnp_rotation: np.ndarray | None = None


@dataclass(frozen=True)
class AlignmentFit:
    """The least-squares fit: ``offsets_deg`` and ``stderr_deg`` (3,) in joint order; the lamp's
    elevation above the arm's plane and its standard error (degrees; None when not fitted);
    the marker corners' RMS and largest residual (px), the tile brightness' RMS relative residual,
    and the counts of images, corners and brightness readings used."""

    offsets_deg: np.ndarray
    stderr_deg: np.ndarray
    lamp_elevation_deg: float | None
    lamp_elevation_stderr_deg: float | None
    residual_px_rms: float
    residual_px_max: float
    photometric_rms: float
    images: int
    corners: int
    photometric: int


def fit_alignment(rig, camera, observations, *, fit_lamp: bool = True) -> AlignmentFit:
    """Fit the zero offset of every axis (and the lamp's elevation) to images of the holder card.

    ``rig``: the planner Rig (its own alignment is ignored); ``camera``: its ``CameraModel``;
    ``observations``: ``Observation`` s. Least squares against the solvePnP rotations, then the marker
    corners in pixels and the white tile's brightness, each group weighted by its own scatter; standard
    errors from the Jacobian. What is identifiable: docs/explanations/camera.md. Raises
    ``AlignmentError`` on too few images or residuals beyond the limits.
    """
    obs = [o for o in observations if len(o.image_px) >= 4]
    photometric = [k for k, o in enumerate(obs) if o.rate is not None and o.rate > 0]
    if len(obs) < MIN_IMAGES:
        raise AlignmentError(f"align: only {len(obs)} images with a readable marker set (need {MIN_IMAGES}): "
                             f"is the white card mounted and lit, and does the camera model match the camera?")
    if len(photometric) < MIN_PHOTOMETRIC:
        raise AlignmentError(f"align: the white tile's brightness was measured in only {len(photometric)} images "
                             f"(need {MIN_PHOTOMETRIC}): the yaw and arm zeros cannot be told apart without it")
    model = _Model(rig, camera, obs, photometric, fit_lamp)
    x = model.start()
    sigma = {"rot": np.radians(0.05), "px": 0.2, "ph": 0.002}
    if all(o.pnp_rotation is not None for o in obs):
        x = least_squares(lambda p: model.residuals(p, sigma, rotations=True), x, x_scale=model.scale).x
    for _ in range(2):   # fit, re-estimate each group's scatter from its residuals
        x = least_squares(lambda p: model.residuals(p, sigma), x, x_scale=model.scale).x
        px, ph = model.pixel_residuals(x), model.photometric_residuals(x)
        sigma["px"] = max(float(np.sqrt(np.sum(px ** 2) / max(px.size - 3, 1))), 1e-3)
        sigma["ph"] = max(float(np.sqrt(np.sum(ph ** 2) / max(ph.size - 2, 1))), 1e-5)
    result = least_squares(lambda p: model.residuals(p, sigma), x, x_scale=model.scale)   # with those weights
    x, cov = result.x, _covariance(result.jac)
    px = np.linalg.norm(model.pixel_residuals(x).reshape(-1, 2), axis=1)
    ph = model.photometric_residuals(x)
    fit = AlignmentFit(
        offsets_deg=x[:3].copy(), stderr_deg=np.sqrt(np.diag(cov))[:3],
        lamp_elevation_deg=float(x[4]) if fit_lamp else None,
        lamp_elevation_stderr_deg=float(np.sqrt(cov[4, 4])) if fit_lamp else None,
        residual_px_rms=float(np.sqrt(np.mean(px ** 2))), residual_px_max=float(px.max()),
        photometric_rms=float(np.sqrt(np.mean(ph ** 2))), images=len(obs), corners=int(px.size),
        photometric=len(photometric))
    check_fit(fit)
    return fit


def check_fit(fit: AlignmentFit) -> None:
    """AlignmentError when the fit leaves residuals no well-described rig would."""
    if fit.residual_px_rms > MAX_RESIDUAL_PX:
        raise AlignmentError(
            f"align: the fitted offsets leave the marker corners {fit.residual_px_rms:.2f} px RMS from the model "
            f"(limit {MAX_RESIDUAL_PX:g} px): the camera model (camera.intrinsics, camera.mount) or the holder "
            f"card does not match the rig, or an axis slips")
    if fit.photometric_rms > MAX_PHOTOMETRIC_RESIDUAL:
        raise AlignmentError(
            f"align: the white tile's brightness departs from cos(theta_i) by {100 * fit.photometric_rms:.2f} % RMS "
            f"(limit {100 * MAX_PHOTOMETRIC_RESIDUAL:g} %): is the lamp steady and its photodiode connected, and "
            f"the white card clean?")


# The poses align looks from: yaw and tilt on a grid, the arm at two angles from the card's normal.
# Yaw -30..+55 deg and tilt +-35 deg make the tile's brightness (cos theta_i) slope both ways,
# which fixes the yaw's and the tilt's zeros against the lamp (the arm's 8 deg separation from the
# lamp keeps the yaw from going further negative with a view in range); views 25-62 deg off the
# normal foreshorten the card enough for its pose to fix the arm-yaw difference and keep every
# marker readable; lamp incidence <= 70 deg keeps the tile bright. Two arm angles per (yaw,
# tilt): at most 36 poses, each one move and two frames.
ALIGN_YAWS_DEG = (-30.0, -15.0, 0.0, 20.0, 40.0, 55.0)
ALIGN_TILTS_DEG = (-35.0, 0.0, 35.0)
ALIGN_ARM_FROM_NORMAL_DEG = (25.0, 42.0, 58.0)
MAX_VIEW_DEG, MAX_INCIDENCE_DEG, SEPARATION_MARGIN_DEG = 62.0, 70.0, 4.0


def alignment_poses(rig, per_orientation: int = 2) -> np.ndarray:
    """Joint targets (n, 3) in degrees (joint order) to image the white card from: within every
    axis limit (with SEPARATION_MARGIN_DEG more arm separation, since the zeros are unknown),
    views <= MAX_VIEW_DEG and lamp incidence <= MAX_INCIDENCE_DEG off the card's normal,
    ``per_orientation`` arm angles per (yaw, tilt) at most. Deterministic."""
    from .kinematics import Reason, forward, pose_reason

    nominal = dataclasses.replace(rig, alignment=None)
    poses = []
    for yaw in ALIGN_YAWS_DEG:
        for tilt in ALIGN_TILTS_DEG:
            found = 0
            for rel in ALIGN_ARM_FROM_NORMAL_DEG:
                q = np.array([yaw + rel, yaw, tilt])
                if found == per_orientation or pose_reason(nominal, q) != Reason.OK \
                        or abs(q[0]) < rig.geometry.min_arm_separation_deg + SEPARATION_MARGIN_DEG:
                    continue
                w_i, w_o = forward(nominal, q)
                if np.degrees(np.arccos(w_o[2])) <= MAX_VIEW_DEG and np.degrees(np.arccos(w_i[2])) <= MAX_INCIDENCE_DEG:
                    poses.append(q)
                    found += 1
    return np.array(poses).reshape(-1, 3)


class _Model:
    """Residuals of the alignment fit. Parameters: offsets (3, degrees), log of the tile's
    brightness at normal incidence, [lamp elevation (degrees)]."""

    def __init__(self, rig, camera, obs, photometric, fit_lamp: bool) -> None:
        from .kinematics import arm_side

        self.rig = dataclasses.replace(rig, alignment=None)
        self.camera, self.side = camera, arm_side(rig)
        self.joints = np.array([o.joints for o in obs], dtype=np.float64)
        self.plane = [np.column_stack([o.plane_mm, np.zeros(len(o.plane_mm))]) for o in obs]
        self.image = np.concatenate([o.image_px for o in obs])
        self.rotations = [o.pnp_rotation for o in obs]
        self.photometric = np.asarray(photometric, dtype=int)
        self.log_rate = np.log([obs[k].rate for k in photometric])
        self.n_params = 5 if fit_lamp else 4
        self.scale = np.array([0.1, 0.1, 0.1, 0.01, 0.1][:self.n_params])

    def start(self) -> np.ndarray:
        """Zero offsets; the brightness scale that fits the nominal cos(theta_i) on average."""
        cos_i = self._cos_incidence(np.zeros(self.n_params))
        x = np.zeros(self.n_params)
        x[3] = float(np.mean(self.log_rate - np.log(cos_i)))
        return x

    def _poses(self, x):
        from .kinematics import forward

        w_i, w_o = forward(self.rig, self.joints + x[:3])
        return w_i, w_o

    def _cos_incidence(self, x) -> np.ndarray:
        """cos(theta_i) of the photometric images with the lamp raised by x[4] above the arm's plane."""
        w_i, _ = self._poses(x)
        horizontal = w_i[self.photometric, 2]                       # n . L for the nominal lamp
        if self.n_params < 5:
            return horizontal
        tilt = np.radians(self.joints[self.photometric, 2] + x[2])   # n . z = sin(physical tilt)
        e = np.radians(x[4])
        return np.cos(e) * horizontal + np.sin(e) * np.sin(tilt)

    def pixel_residuals(self, x) -> np.ndarray:
        w_i, w_o = self._poses(x)
        R, t = self.camera.extrinsics(w_i, w_o, self.side)
        predicted = np.concatenate([self.camera.project(p, R[k], t[k]) for k, p in enumerate(self.plane)])
        return (predicted - self.image).ravel()

    def photometric_residuals(self, x) -> np.ndarray:
        with np.errstate(invalid="ignore", divide="ignore"):
            return self.log_rate - x[3] - np.log(np.maximum(self._cos_incidence(x), 1e-9))

    def rotation_residuals(self, x) -> np.ndarray:
        from scipy.spatial.transform import Rotation

        w_i, w_o = self._poses(x)
        R, _ = self.camera.extrinsics(w_i, w_o, self.side)
        return np.concatenate([Rotation.from_matrix(self.rotations[k] @ R[k].T).as_rotvec()
                               for k in range(len(self.rotations))])

    def residuals(self, x, sigma: dict, rotations: bool = False) -> np.ndarray:
        geometric = self.rotation_residuals(x) / sigma["rot"] if rotations else self.pixel_residuals(x) / sigma["px"]
        return np.concatenate([geometric, self.photometric_residuals(x) / sigma["ph"]])


def _covariance(jac: np.ndarray) -> np.ndarray:
    """(J^T J)^-1 of whitened residuals: the parameters' covariance."""
    return np.linalg.pinv(jac.T @ jac)
