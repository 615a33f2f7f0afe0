"""Checks before anything moves: the rig, the plan and the model must belong together.

A plan names the model it was selected with (``model.path`` and ``model.hash``), the rig it was
scheduled for (``rig.kinematic_hash``) and the alignment its joints were computed with
(``alignment.hash``, or null); every sample carries its joint targets, and each must be a pose
the camera can measure (``planner.candidates.measurable_reason``). Anything that does not match
is refused here with a ConfigError naming the file, the field, what was expected and what was
found, before a single device is connected.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from goniofrost.core.errors import ConfigError


@dataclass(frozen=True)
class SessionInputs:
    """A rig, a plan and its model that were checked to belong together.

    ``cells``: int64 (n,) flat grid cells of the plan's samples in capture order;
    ``positions``: int64 (n,) their rows in the model (indices into ``model.grid.valid_cells``).
    """

    rig: object
    plan: dict
    plan_path: Path
    model: object
    model_path: Path
    cells: np.ndarray
    positions: np.ndarray
    white_joints: dict
    scene: object = None  # frost.scene_error.SceneError of a plan made with a usage map, else None

    @property
    def samples(self) -> list[dict]:
        return self.plan["samples"]

    @property
    def sentinel(self) -> np.ndarray | None:
        """bool (n,): the plan's sentinel samples (``plan --sentinels``), None for a plan without."""
        from goniofrost.plan.file import sentinel_flags

        flags = np.array(sentinel_flags(self.samples), dtype=bool)
        return flags if flags.any() else None


def load_inputs(rig_path, plan_path, alignment_path=None) -> SessionInputs:
    """Load the rig file (with ``alignment_path`` overriding its alignment), the plan and the
    plan's model, and check they belong together."""
    from goniofrost.rig.file import load_checked_rig

    return inputs_on(load_checked_rig(rig_path, alignment_path), plan_path)


def inputs_on(rig, plan_path) -> SessionInputs:
    """Load the plan and the plan's model for the loaded ``rig`` (``load_checked_rig``), and check
    they belong together."""
    from goniofrost.frost.model import FrostModel
    from goniofrost.frost.scene_error import from_plan as scene_from_plan
    from goniofrost.plan.file import check_unique_cells, read_plan

    plan_path = Path(plan_path)
    plan = read_plan(plan_path)
    model_path = resolve_model_path(plan, plan_path)
    model = FrostModel.load(model_path)
    check_model(plan, plan_path, model, model_path)
    check_rig(plan, plan_path, rig)
    check_alignment(plan, plan_path, rig)
    check_joints(plan, plan_path, rig)
    check_measurable(plan, plan_path, rig)
    cells = plan_cells(plan, plan_path, model.grid)
    check_consistency(plan, plan_path, model.grid, rig, cells)
    check_unique_cells(plan_path, plan)
    check_drills(plan, rig)
    return SessionInputs(rig, plan, plan_path, model, model_path, cells, model.grid.valid_position(cells),
                         white_reference_joints(rig), scene_from_plan(plan, model, plan_path))


def check_drills(plan: dict, rig) -> None:
    """A fault drill of a simulated rig must fire within the plan: one at a sample the plan does
    not have would never fire, and the drill would pass unseen."""
    n = len(plan["samples"])
    for i, drill in enumerate((rig.sim or {}).get("faults", []) if rig.simulated else []):
        if drill["at_sample"] >= n:
            raise ConfigError(rig.source, f"sim.faults[{i}].at_sample", f"a plan sample index 0..{n - 1}",
                              drill["at_sample"])


def resolve_model_path(plan: dict, plan_path: Path) -> Path:
    """The plan's model folder: ``model.path`` relative to the plan file's folder (as ``plan``
    writes it: ``plan.file.model_path_for_plan``), else relative to the current folder (plans
    written before, which recorded the path as typed)."""
    written = Path(_field(plan, plan_path, "model", dict)["path"])
    beside = plan_path.parent / written  # the written path itself when it is absolute
    for candidate in (beside, written):
        if candidate.exists():
            return candidate
    raise ConfigError(plan_path, "model.path", f"a model folder from goniofrost train ({beside} beside the plan, "
                      f"or {written} from the current folder)", str(written))


def check_model(plan: dict, plan_path, model, model_path) -> None:
    """Refuse a plan selected with another model (content hashes differ)."""
    want = _field(plan, plan_path, "model", dict).get("hash")
    if want != model.content_hash:
        raise ConfigError(plan_path, "model.hash", f"the hash of the model {model_path} ({model.content_hash[:16]}...)",
                          f"{str(want)[:16]}... (this plan was selected with another model)")


def check_rig(plan: dict, plan_path, rig) -> None:
    """Refuse a plan scheduled for another rig (kinematic hashes or names differ) or not scheduled at all."""
    section = plan.get("rig")
    if not isinstance(section, dict) or "kinematic_hash" not in section:
        raise ConfigError(plan_path, "rig", "a plan scheduled for a rig (goniofrost plan --rig RIG.yaml)",
                          section)
    if section["kinematic_hash"] != rig.kinematic_hash:
        raise ConfigError(plan_path, "rig.kinematic_hash",
                          f"{rig.kinematic_hash} of rig {rig.name!r} ({rig.source})",
                          f"{section['kinematic_hash']} (scheduled for rig {section.get('name')!r}, "
                          f"{section.get('file')})")
    if section.get("name") != rig.name:  # same kinematics, another rig: its own alignment, its own lock
        raise ConfigError(plan_path, "rig.name", f"{rig.name!r}, the rig of {rig.source} (a plan is scheduled per rig: "
                          f"goniofrost plan --rig {rig.source})", section.get("name"))


def check_alignment(plan: dict, plan_path, rig) -> None:
    """Refuse a plan whose joints were computed with other axis zero offsets than the rig's now."""
    written = plan.get("alignment")
    want = None if rig.alignment is None else rig.alignment.hash
    found = written.get("hash") if isinstance(written, dict) else written
    if found == want:
        return
    expected = (f"{want} (the alignment {rig.alignment.source} given to this capture)" if want is not None
                else "null (no alignment given to this capture: pass the plan's with --alignment)")
    found_text = f"{found} (from {written.get('file')})" if isinstance(written, dict) else found
    raise ConfigError(plan_path, "alignment.hash", expected,
                      f"{found_text}: this plan was scheduled with another alignment; plan again or capture with it")


def check_measurable(plan: dict, plan_path, rig) -> None:
    """Refuse a sample whose pose the camera cannot measure (too few patch pixels, outside the beam)."""
    from planner.candidates import measurable_reason
    from planner.kinematics import Reason, joints_array

    samples = plan["samples"]
    joints = np.array([joints_array(rig, s["joints"]) for s in samples])
    reason = measurable_reason(rig, joints)
    for i in np.flatnonzero(reason != Reason.OK):
        raise ConfigError(plan_path, f"samples[{i}].joints",
                          "a pose the camera can measure (enough patch pixels, the patch in the lamp's beam)",
                          f"{Reason(int(reason[i])).name} at theta_i {samples[i].get('theta_i_deg', float('nan')):.1f} deg, "
                          f"theta_o {samples[i].get('theta_o_deg', float('nan')):.1f} deg")


def check_joints(plan: dict, plan_path, rig) -> None:
    """Refuse any sample whose joint targets are missing, not finite, outside an axis's limits or
    for an axis the rig does not have."""
    samples = _field(plan, plan_path, "samples", list)
    if not samples:
        raise ConfigError(plan_path, "samples", "at least one sample", [])
    for i, sample in enumerate(samples):
        joints = sample.get("joints") if isinstance(sample, dict) else None
        if not isinstance(joints, dict):
            raise ConfigError(plan_path, f"samples[{i}].joints", "joint targets {axis: degrees}", joints)
        for name in joints:  # a target for an axis the rig lacks would be ignored, silently
            if name not in rig.axes:
                raise ConfigError(plan_path, f"samples[{i}].joints.{name}", f"one of the keys {', '.join(rig.axes)} "
                                  f"(the axes of rig {rig.name!r})", f"unknown key {name!r}")
        for name, spec in rig.axes.items():
            _check_target(plan_path, f"samples[{i}].joints.{name}", joints.get(name), spec.limits_deg)


def _check_target(plan_path, keypath: str, value, limits) -> None:
    lo, hi = limits
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
        raise ConfigError(plan_path, keypath, "a finite angle in degrees", value)
    if not lo <= value <= hi:
        raise ConfigError(plan_path, keypath, f"an angle within the axis limits [{lo:g}, {hi:g}] deg", value)


def plan_cells(plan: dict, plan_path, grid) -> np.ndarray:
    """Flat cells (int64, (n,)) of the plan's samples; each must be a valid cell of the model grid."""
    cells = []
    for i, sample in enumerate(plan["samples"]):
        cell = sample.get("cell")
        flat = int(grid.flat_index(*cell)) if isinstance(cell, (list, tuple)) and len(cell) == 3 else cell
        if not isinstance(flat, (int, np.integer)) or not 0 <= flat < grid.size or not grid.valid_mask[flat]:
            raise ConfigError(plan_path, f"samples[{i}].cell", f"a valid cell of the model's {grid.shape} grid", cell)
        cells.append(int(flat))
    return np.asarray(cells, dtype=np.int64)


ANGLE_TOLERANCE_DEG = 1e-3    # a plan's numbers are computed, not measured: only rounding may differ


def check_consistency(plan: dict, plan_path, grid, rig, cells: np.ndarray) -> None:
    """Refuse a plan whose samples disagree with themselves: each sample's angles, w_i and w_o
    must be those of its cell, and the forward kinematics of its joints must reproduce them
    (light and camera exchanged where ``light_camera_swapped``: the BRDF is reciprocal)."""
    samples = plan["samples"]
    w_i, w_o = grid.cell_directions(cells)
    expected = {"theta_h_deg": np.degrees(grid.flat_angles(cells)[0]),
                "theta_d_deg": np.degrees(grid.flat_angles(cells)[1]),
                "phi_d_deg": np.degrees(grid.flat_angles(cells)[2]),
                "theta_i_deg": _zenith_deg(w_i), "theta_o_deg": _zenith_deg(w_o)}
    for key, want in expected.items():
        _check_numbers(plan_path, samples, key, want, ANGLE_TOLERANCE_DEG, "deg")
    for key, want in (("w_i", w_i), ("w_o", w_o)):
        _check_numbers(plan_path, samples, key, want, np.radians(ANGLE_TOLERANCE_DEG), "")
    _check_kinematics(plan_path, plan, samples, rig, w_i, w_o)


def _zenith_deg(w: np.ndarray) -> np.ndarray:
    """Zenith angles in degrees of unit directions (n, 3)."""
    return np.degrees(np.arccos(np.clip(w[:, 2], -1.0, 1.0)))


def _check_numbers(plan_path, samples, key: str, want: np.ndarray, tolerance: float, unit: str) -> None:
    """Each ``samples[i][key]`` (a number or a 3-vector) within ``tolerance`` of ``want[i]``."""
    for i, (sample, value) in enumerate(zip(samples, want)):
        found = sample.get(key)
        try:
            ok = np.all(np.abs(np.asarray(found, dtype=np.float64) - value) <= tolerance)
        except (TypeError, ValueError):
            ok = False
        if not ok or np.shape(found) != np.shape(value):
            shown = np.round(value, 6).tolist()
            raise ConfigError(plan_path, f"samples[{i}].{key}",
                              f"{shown}{' ' + unit if unit else ''} (the value of its cell {sample.get('cell')})", found)


def _lattice_steps(plan: dict) -> list | None:
    """The plan's ``rig.command_steps_deg`` (``planner.steps``: its joints on the axes' command
    lattices), None when it has none (or a malformed one: the joints then meet the IK's angles)."""
    steps = plan["rig"].get("command_steps_deg") if isinstance(plan.get("rig"), dict) else None
    ok = (isinstance(steps, list) and len(steps) == 3  # one per joint: arm, yaw, tilt
          and all(isinstance(v, (int, float)) and not isinstance(v, bool) and 0 <= v < 1 for v in steps))
    return steps if ok else None


def _check_kinematics(plan_path, plan, samples, rig, w_i: np.ndarray, w_o: np.ndarray) -> None:
    """The joints of each sample must put light and camera at the cell's directions; joints put
    on the axes' command lattices (``_lattice_steps``) must lie within ``planner.steps.SPAN_DEG``
    (+ half the axis's step) of one of the cell's IK poses, as ``planner.steps.on_steps`` leaves
    them."""
    from planner.kinematics import forward

    joints = np.array([[s["joints"][name] for name in rig.joint_names] for s in samples], dtype=np.float64)
    steps = _lattice_steps(plan)
    if steps is not None:
        _check_lattice_joints(plan_path, samples, rig, joints, w_i, w_o, steps)
        return
    light, camera = forward(rig, joints)
    swapped = np.array([bool(s.get("light_camera_swapped", False)) for s in samples])
    light, camera = np.where(swapped[:, None], camera, light), np.where(swapped[:, None], light, camera)
    # isotropic BRDF: only theta_i, theta_o and the angle between the directions matter
    found = np.stack([_zenith_deg(light), _zenith_deg(camera), _angle_deg(light, camera)], axis=1)
    want = np.stack([_zenith_deg(w_i), _zenith_deg(w_o), _angle_deg(w_i, w_o)], axis=1)
    for i in np.flatnonzero(np.any(np.abs(found - want) > ANGLE_TOLERANCE_DEG, axis=1)):
        raise ConfigError(plan_path, f"samples[{i}].joints",
                          f"joints whose forward kinematics give theta_i, theta_o, angle(w_i, w_o) = "
                          f"{np.round(want[i], 4).tolist()} deg (its cell {samples[i].get('cell')})",
                          f"{samples[i]['joints']} -> {np.round(found[i], 4).tolist()} deg")


def _check_lattice_joints(plan_path, samples, rig, joints, w_i, w_o, steps) -> None:
    """Each sample's joints within SPAN_DEG + half a step (per axis) of the nearer of its cell's
    two IK poses (light and camera exchanged where ``light_camera_swapped``)."""
    from planner.kinematics import inverse
    from planner.steps import SPAN_DEG

    swapped = np.array([bool(s.get("light_camera_swapped", False)) for s in samples])
    light, camera = np.where(swapped[:, None], w_o, w_i), np.where(swapped[:, None], w_i, w_o)
    poses = inverse(rig, light, camera).joints                          # (n, 2, 3): both branches
    gap = np.abs(joints[:, None, :] - poses)
    gap[..., 1] = np.minimum(gap[..., 1], 360.0 - gap[..., 1])      # the yaw turns all the way round
    allowed = SPAN_DEG + np.asarray(steps, dtype=np.float64) / 2.0 + ANGLE_TOLERANCE_DEG
    near = np.all(gap <= allowed, axis=-1).any(axis=1)
    for i in np.flatnonzero(~near):
        raise ConfigError(plan_path, f"samples[{i}].joints",
                          f"joints within {np.round(allowed, 3).tolist()} deg of a pose of its cell "
                          f"{samples[i].get('cell')} (the plan's rig.command_steps_deg lattices)", samples[i]["joints"])


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle in degrees between unit directions (n, 3) and (n, 3), row by row."""
    return np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", a, b), -1.0, 1.0)))


def _field(doc: dict, path, key: str, kind: type):
    value = doc.get(key) if isinstance(doc, dict) else None
    if not isinstance(value, kind):
        raise ConfigError(path, key, f"a {kind.__name__}", value)
    return value


def white_reference_joints(rig) -> dict:
    """The pose {axis: deg} showing the white tile at the camera section's nominal angles.

    The light lies in the tile's x-z plane at theta_i and the camera opposite it at theta_o
    (DESIGN.md: only theta_i, theta_o and their azimuth difference matter).
    """
    from calib import validate_camera_section
    from planner.kinematics import inverse

    white = validate_camera_section(rig.camera, rig.source)["white_reference"]
    ti, to = np.radians(white["theta_i_deg"]), np.radians(white["theta_o_deg"])
    w_i, w_o = np.array([np.sin(ti), 0.0, np.cos(ti)]), np.array([-np.sin(to), 0.0, np.cos(to)])
    ik = inverse(rig, w_i, w_o)
    if not ik.valid.any():
        raise ConfigError(rig.source, "camera.white_reference",
                          "angles (theta_i_deg, theta_o_deg) the rig can reach",
                          [white["theta_i_deg"], white["theta_o_deg"]])
    joints = ik.joints[int(np.argmax(ik.valid))]
    return {name: float(v) for name, v in zip(rig.joint_names, joints)}
