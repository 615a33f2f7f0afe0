"""``goniofrost align``: image the white card at poses spread over every axis and fit the zero offsets.

``alignment_steps`` is the plan (steps of ``goniofrost.capture.steps``): home, white card, lamp on,
an exposure that keeps the tile under 60 % of saturation, dark frames, then one move and one frame
per pose. Each frame gives the card's pose (``calib.card_pose.read_card``) and the tile's
brightness (``tile_rate``); ``planner.alignment.fit_alignment`` fits the offsets and
``alignment_document`` is ALIGNMENT.json, written only when the fit is good. The plan runs on the
engine core (``PlanRunner``); with ``--frames DIR`` its runs are journaled in ``DIR/align.sqlite``.
"""
from __future__ import annotations

import dataclasses
import json
import tempfile
from pathlib import Path

import numpy as np

from goniofrost.core.errors import ConfigError
from goniofrost.capture.plan_runner import PlanRunner, RunTexts
from goniofrost.capture.progress_bar import ProgressBar
from goniofrost.capture.steps import Move
from planner.alignment_file import VERSION as ALIGNMENT_VERSION

EXPOSURE_LEVEL = 0.6     # the tile's disc at the brightest pose stays under this fraction of saturation
DARK_FRAMES = 2
FRAMES_PER_POSE = 2      # averaged: the tile's brightness is what sets the yaw and arm zeros' precision


def align(rig_path, out_path, *, devices=None, sim=None, progress: bool = True,
          frames: str | Path | None = None) -> dict:
    """Measure the alignment of the rig in ``rig_path``; write and return ALIGNMENT.json's content.

    ``frames``: keep the frames in this folder (default: a temporary folder, removed). ``devices``
    and ``sim``: the opener of the rig's devices and a simulated rig's options (its seed, speed-up,
    ``on_ready``; no material: the camera sees the card), the caller's (as ``capture.runner.capture``).
    """
    from goniofrost.capture.holder import held_hardware
    from goniofrost.rig.hardware import SimOptions
    from goniofrost.rig.file import load_checked_rig
    from goniofrost.capture.runner import check_sim_options
    from goniofrost.core.atomic_file import check_not_an_input, check_output_dir, check_output_file, write_text_atomic
    from planner.alignment import fit_alignment

    # offsets are measured from the axes' readings: an alignment the rig file names is set aside
    rig = dataclasses.replace(load_checked_rig(rig_path), alignment=None)
    if rig.view is None:
        raise ConfigError(rig.source, "camera", "a camera section with the camera model (intrinsics, mount)",
                          "nothing" if not rig.camera else "a camera section without intrinsics")
    sim = SimOptions() if sim is None else sim
    check_sim_options(rig, sim.seed, sim.speedup)
    out_path = Path(out_path)
    check_not_an_input(out_path, {"--rig": rig_path})
    check_output_file(out_path)  # before any axis moves, not after the 30 poses
    if frames is not None:
        check_output_dir(frames)
    poses, disc_px = usable_poses(rig)
    with tempfile.TemporaryDirectory(prefix="goniofrost-align-") as scratch:
        folder = Path(frames) if frames is not None else Path(scratch)
        with held_hardware(rig, devices, sim, program="align") as hardware:
            observations, exposure = run_steps(rig, poses, disc_px, hardware, folder, progress,
                                                  journaled=frames is not None)
    fit = fit_alignment(rig, rig.view.camera, observations)
    doc = alignment_document(rig, fit, len(poses), exposure, disc_px)
    write_text_atomic(out_path, json.dumps(doc, indent=1) + "\n")
    return doc


def usable_poses(rig) -> tuple[np.ndarray, float]:
    """``planner.alignment.alignment_poses`` whose four white-card markers the camera model puts
    well inside the frame and thick enough to read (20 px), and the radius (px) of the brightness
    disc that stays on the tile at all of them."""
    from calib.card_pose import disc_radius_px
    from calib.holder import WHITE_MARKER_IDS
    from calib.roi import polygon_thickness, predict_view
    from planner.alignment import alignment_poses
    from planner.kinematics import arm_side, forward

    cam, side = rig.view.camera, arm_side(rig)
    keep, tiles = [], []
    for q in alignment_poses(rig):
        w_i, w_o = forward(rig, q)
        view = predict_view(cam, w_i, w_o, WHITE_MARKER_IDS, rig.camera["roi_margin"], side)
        thick = min(polygon_thickness(view.markers[i]) for i in WHITE_MARKER_IDS)
        if len(view.readable) == len(WHITE_MARKER_IDS) and thick >= 20.0:
            keep.append(q)
            tiles.append(view.patch)
    return np.array(keep).reshape(-1, 3), (disc_radius_px(cam, tiles) if tiles else 0.0)


ALIGN_JOURNAL = "align.sqlite"


def run_steps(rig, poses: np.ndarray, disc_px: float, hardware, folder: Path, progress: bool,
              journaled: bool = False):
    """Drive ``alignment_steps`` on the hardware through the engine core (a progress bar over the
    poses); return (observations, exposure). ``journaled``: journal the run in
    ``folder/align.sqlite`` (a new run appended when it exists)."""
    from goniofrost.capture.journal import Journal

    journal = None
    if journaled:
        path = Path(folder) / ALIGN_JOURNAL
        journal = (Journal.open(path) if path.is_file() else
                   Journal.create(path, {"program": "align", "rig_name": rig.name, "rig_file": str(rig.source),
                                         "kinematic_hash": rig.kinematic_hash, "poses": len(poses)}))
    journaled_in = f"; the run is journaled in {journal.path}" if journal is not None else ""
    texts = RunTexts(saved=lambda: f"No alignment was written{journaled_in}",
                     resume="Fix the cause, then run goniofrost align again")
    try:
        runner = PlanRunner(hardware, folder, journal=journal, program="align", texts=texts)
        runner.subscribe(ProgressBar(len(poses), Move, unit="pose", desc="align", show=progress))
        return runner.execute_plan(alignment_steps(rig, poses, disc_px))
    finally:
        if journal is not None:
            journal.close()


def alignment_steps(rig, poses: np.ndarray, disc_px: float, folder: str = ""):
    """Yield the steps of an alignment run; return (list of planner Observation, exposure in s).
    ``disc_px``: radius of the brightness disc (0: no brightness measured)."""
    from calib import dark_map, validate_camera_section
    from calib.card_pose import tile_disc
    from calib.holder import WHITE_MARKER_IDS
    from goniofrost.capture.sample_steps import frame_file
    from goniofrost.capture.session_steps import joint_targets
    from goniofrost.capture.steps import Expose, Home, LampOff, LampOn, Move, SetTarget

    settings = validate_camera_section(rig.camera, rig.source)
    ladder, axes, cam = settings["exposures_s"], tuple(rig.joint_names), rig.view.camera
    disc = tile_disc(cam, (cam.height, cam.width), max(disc_px, 1.0))
    yield Home(axes)
    yield SetTarget("white")
    yield LampOn()
    brightest = poses[int(np.argmax(_cos_incidence(rig, poses)))]
    yield Move(None, joint_targets(dict(zip(axes, brightest)), axes))
    for i in reversed(range(len(ladder))):
        frame = yield Expose(ladder[i], frame_file(folder, f"exposure_e{i}.dng"))
        if np.max(frame.raw.linear[disc]) < EXPOSURE_LEVEL * settings["saturation"]:
            break
    exposure = ladder[i]
    yield LampOff()
    darks = []
    for k in range(DARK_FRAMES):
        darks.append((yield Expose(exposure, frame_file(folder, f"dark_{k}.dng"))).raw)
    dark = dark_map(darks)
    yield LampOn()
    observations = []
    for k, q in enumerate(poses):
        reached = yield Move(k, joint_targets(dict(zip(axes, q)), axes))
        frames = []
        for j in range(FRAMES_PER_POSE):
            frames.append((yield Expose(exposure, frame_file(folder, f"align_{k:02d}_{j}.dng"))))
        joints = np.array([reached.joints[name] for name in axes])
        observation = observe(rig, joints, frames, dark, disc if disc_px > 0 else None, WHITE_MARKER_IDS)
        if observation is not None:
            observations.append(observation)
    yield SetTarget("sample")
    yield LampOff()
    return observations, exposure


def observe(rig, joints: np.ndarray, frames, dark, disc, ids):
    """A planner Observation of the frames of one pose at the axes' readings ``joints``: the markers
    of the first, the tile's brightness averaged over all (None without a readable marker set or
    with a pose solvePnP cannot reproduce within 1 px)."""
    from calib.card_pose import read_card, tile_rate
    from planner.alignment import Observation
    from planner.kinematics import arm_side, forward

    cam = rig.view.camera
    guess = cam.extrinsics(*forward(rig, joints), arm_side(rig))
    reading = read_card(frames[0].raw.linear, ids, cam, guess)
    if reading is None or reading.pnp_rms_px > 1.0:
        return None
    rate = None if disc is None else float(np.mean(
        [tile_rate(f.raw.linear, dark, disc, f.exposure_s, f.lamp_relative) for f in frames]))
    return Observation(joints, reading.plane_mm, reading.image_px, rate, reading.rotation)


def _cos_incidence(rig, poses: np.ndarray) -> np.ndarray:
    from planner.kinematics import forward

    return forward(rig, poses)[0][:, 2]


def alignment_document(rig, fit, planned: int, exposure_s: float, disc_px: float) -> dict:
    """ALIGNMENT.json: the offsets (what plan, capture and the rig file's ``alignment`` key read),
    their standard errors, the lamp, the residuals, and what was measured."""
    names = list(rig.joint_names)
    lamp = {"elevation_deg": round(fit.lamp_elevation_deg, 4), "elevation_stderr_deg": round(fit.lamp_elevation_stderr_deg, 4),
            "applied": False,
            "note": "the lamp's elevation above the arm's plane is measured (from the white tile's brightness at "
                    "tilted poses) but not applied: the kinematics assume a horizontal lamp, so re-aim a lamp "
                    "that is off by more than its standard error; its azimuth is not identifiable (the arm and "
                    "yaw zeros are measured from it)"}
    return {
        "version": ALIGNMENT_VERSION,  # what planner.alignment_file reads
        "rig": {"name": rig.name, "file": rig.source, "kinematic_hash": rig.kinematic_hash},
        "offsets_deg": {n: round(float(v), 4) for n, v in zip(names, fit.offsets_deg)},
        "stderr_deg": {n: round(float(v), 4) for n, v in zip(names, fit.stderr_deg)},
        "lamp": lamp,
        "residual_px": {"rms": round(fit.residual_px_rms, 4), "max": round(fit.residual_px_max, 4)},
        "photometric_residual_rms": round(fit.photometric_rms, 6),
        "images": {"poses": planned, "used": fit.images, "corners": fit.corners, "photometric": fit.photometric,
                   "frames_per_pose": FRAMES_PER_POSE, "exposure_s": exposure_s, "tile_disc_px": round(disc_px, 2)},
        "convention": "an axis reading q stands physically at q + offset",
    }
