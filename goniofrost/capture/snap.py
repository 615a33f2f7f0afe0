"""``rig snap``: one frame (or the bracket a capture would take) of the target at the current pose.

The operator's exposure check before a session: per-channel levels and saturated fraction, the
holder markers read, the calibration's region of interest (its pixels and, over the bracket, its
SNR), the exposures a capture would take, and a PNG with region and markers drawn. The frames run
on the engine core (``PlanRunner``), so the axes are stopped and the lamp off on every exit. No
dark frames or flat field: levels and SNR are of the raw linear values.
"""
from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from goniofrost.capture.steps import Expose, LampOff, LampOn, SetTarget

# what a simulated rig's stage shows without --material (its sample card needs something on it)
DEFAULT_MATERIAL = "builtin:red-plastic"


@dataclass
class SnapResult:
    """What one snap found. Levels: linear sensor values (0 = black level, 1 = white level) inside
    the region of interest, per channel (R, G, B), in the longest unsaturated frame. Saturated
    fractions count the pixels a capture leaves out: the sensor's flag or a level at or above the
    camera section's ``saturation``."""

    target: str
    pose_deg: dict
    exposures_s: list
    capture_exposures_s: list | None
    markers_found: list
    markers_expected: list
    roi_source: str | None
    roi_pixels: list
    levels_median: list
    levels_p99: list
    saturated_fraction: float
    roi_saturated_fraction: float
    snr: list | None
    png: str
    problem: str | None = None

    def as_dict(self) -> dict:
        return dict(self.__dict__)


def snap_plan(judge: "_Judge", exposure_s: float | None, folder: str = "snap", move=None):
    """Yield the snap's steps; return the frames taken ({exposure s: Frame}). ``judge`` holds the
    capture's bracket rule (a pure computation on the frames, as in ``sample_steps``); ``move``: a
    Move step to take first (None: snap where the axes are)."""
    if move is not None:
        reached = yield move
        judge.set_pose({**judge.joints, **reached.joints})
    yield SetTarget(judge.target)
    yield LampOn()
    frames = {}
    ladder = list(judge.settings["exposures_s"])
    if exposure_s is not None:
        frames[exposure_s] = yield Expose(float(exposure_s), f"{folder}/snap.dng")
    else:
        i = len(ladder) // 2  # the middle of the ladder; the bracket rule goes up or down from there
        while i is not None:
            frames[ladder[i]] = frame = yield Expose(ladder[i], f"{folder}/snap_e{i}.dng")
            i = judge.next_index(i, frame)
    yield LampOff()
    return frames


def snap(rig, *, target: str, exposure_s: float | None, out, material=None,
         move_to: dict | None = None, devices=None) -> SnapResult:
    """Connect the rig (``devices``: the opener, see ``goniofrost.capture.runner.capture``), take the
    snap at the current pose (after moving to ``move_to``, {axis: deg}, when given), write the PNG
    ``out``; return the findings. ``material``: what a simulated rig's stage shows, resolved by the
    caller (``DEFAULT_MATERIAL`` when the operator names none)."""
    from calib.config import shutter_label, shutter_seconds
    from goniofrost.capture.console import check_referenced, check_targets, move_plan

    from goniofrost.capture.holder import held_hardware
    from goniofrost.rig.hardware import SimOptions
    from goniofrost.capture.plan_runner import PlanRunner
    from goniofrost.capture.runner import check_material
    from goniofrost.core.atomic_file import output_errors

    # as capture: none on a real rig (it shows what is on the stage), a known one on a simulated
    # rig, checked before anything is made or moved
    material = check_material(rig, material)
    out = Path(out)
    with output_errors(out):
        out.parent.mkdir(parents=True, exist_ok=True)
    settings = rig.camera
    if exposure_s is not None and settings.get("shutter_speeds"):
        # the trigger sets the nearest of the camera's own speeds (as for the ladder's rungs); asking
        # for the value given refused the camera's file as exposed other than asked (0.004 s for 0.003)
        exposure_s = shutter_seconds(shutter_label(settings["shutter_speeds"], exposure_s))
    with tempfile.TemporaryDirectory(prefix="goniofrost-snap-") as folder, \
            held_hardware(rig, devices, SimOptions(material=material), program="rig snap") as hardware:
        joints = {name: float(axis.position()) for name, axis in hardware.axes.items()}
        judge = _Judge(rig, settings, target, joints)
        move = None
        if move_to:
            check_targets(rig, move_to)
            check_referenced(rig, hardware.axes, move_to)  # before the other axes start
            move = next(move_plan(rig, move_to))
        frames = PlanRunner(hardware, folder, program="rig snap").execute_plan(snap_plan(judge, exposure_s, move=move))
    return judge.result(frames, out)


def _pose(rig, joints: dict):
    from planner.kinematics import forward

    return forward(rig, [joints[name] for name in rig.joint_names])


def _arm_side(rig) -> float:
    from planner.kinematics import arm_side

    return arm_side(rig)


class _Judge:
    """The capture's own bracket rule and region of interest, on frames without darks or flat."""

    def __init__(self, rig, settings: dict, target: str, joints: dict) -> None:
        from calib.holder import SAMPLE_MARKER_IDS, WHITE_MARKER_IDS

        self.rig, self.settings, self.target = rig, settings, target
        self.ids = WHITE_MARKER_IDS if target == "white" else SAMPLE_MARKER_IDS
        self.arm_side = _arm_side(rig)
        self.bracket, self.problem = None, None
        self.set_pose(joints)

    def set_pose(self, joints: dict) -> None:
        """The axes' positions (degrees by name) the frames are taken at."""
        self.joints = {name: float(joints[name]) for name in self.rig.joint_names}
        self.pose = _pose(self.rig, self.joints)

    def next_index(self, i: int, frame):
        """The bracket's next ladder index after the frame of index ``i`` (None: done)."""
        from calib import Bracket, CalibrationRecord
        from calib.roi import expected_view

        if self.bracket is None:
            ladder = self.settings["exposures_s"]
            shape = frame.raw.linear.shape
            dark = np.broadcast_to(np.zeros((1,) + shape, np.float32), (len(ladder),) + shape)  # no darks: zero
            record = CalibrationRecord(ladder, dark, np.ones(shape, np.float32), np.ones(3), np.zeros(3))
            self.bracket = Bracket(ladder, self.settings, record, self.ids, f"{self.target} card",
                                   view=expected_view(self.settings, self.pose, self.ids, self.arm_side))
        try:
            return self.bracket.add(i, frame.raw, max(frame.lamp_relative, 1e-9), frame.path,
                                    exposure_s=frame.exposure_s)  # the exposure the camera reports
        except Exception as exc:  # noqa: BLE001 - a finding of the snap (saturated, markers), not a crash
            self.problem = " ".join(str(exc).split())
            return None

    def result(self, frames: dict, out: Path) -> SnapResult:
        from calib.roi import expected_view, locate_patch, read_markers

        exposures = sorted(frame.exposure_s for frame in frames.values())  # as the camera took them
        raw = _best_frame(frames, self.settings["saturation"])
        found, _ = read_markers(raw.linear, self.ids)
        mask, source = None, None
        try:
            mask, source, _ = locate_patch(raw.linear, self.ids, self.settings["roi_margin"], f"{self.target} card",
                                           expected_view(self.settings, self.pose, self.ids, self.arm_side),
                                           self.settings["marker_tolerance_px"], raw.channels, 1)
        except Exception as exc:  # noqa: BLE001 - reported, with the picture
            self.problem = self.problem or " ".join(str(exc).split())
        clipped = raw.clipped(self.settings["saturation"])  # as the capture counts them
        pixels, med, p99 = _roi_levels(raw, mask)
        saturated = [float(np.mean(clipped)), float(np.mean(clipped[mask])) if mask is not None else 0.0]
        if self.bracket is None:  # one exposure the operator chose: its being unreadable is the first finding
            self.problem = _exposure_problem(raw, exposures[0], *saturated) or self.problem
        snr = None
        if self.bracket is not None and self.bracket.mask_ is not None:
            mean, se = self.bracket._stats()
            snr = [float(v) for v in mean / se]
        _write_png(raw, mask, found, out, clipped, _legend(pixels, med, p99, saturated))
        return SnapResult(self.target, self.joints, exposures,
                          self.bracket.exposures_s if self.bracket is not None and self.problem is None else None,
                          sorted(found), list(self.ids), source, pixels, med, p99, *saturated,
                          snr, str(out), self.problem)


def _best_frame(frames: dict, saturation: float):
    """The longest exposure whose frame is at most a quarter saturated (else the shortest)."""
    ordered = [frames[t].raw for t in sorted(frames)]
    usable = [r for r in ordered if np.mean(r.clipped(saturation)) <= 0.25]
    return usable[-1] if usable else ordered[0]


def _exposure_problem(raw, exposure_s: float, frame_saturated: float, roi_saturated: float) -> str | None:
    """Why a frame of a chosen exposure is too bright or too dark to read (the bracket's own limits,
    ``calib.bracket.markers_exposed``, on the frame and on the region of interest), or None."""
    from calib.bracket import MAX_SATURATED_FRACTION, MIN_BRIGHT_END

    worst, where = max((frame_saturated, "frame"), (roi_saturated, "region of interest"))
    if worst > MAX_SATURATED_FRACTION:
        return (f"the frame taken at {exposure_s:g} s (--exposure): {100 * worst:.1f} % of the {where} is "
                f"saturated (more than {100 * MAX_SATURATED_FRACTION:g} %: its levels are clipped); take a shorter "
                f"--exposure, or leave it out for the capture's own bracket")
    bright_end = float(np.percentile(raw.linear, 99))
    if bright_end < MIN_BRIGHT_END:
        return (f"the frame taken at {exposure_s:g} s (--exposure): its 99th percentile is {bright_end:.4f} of full "
                f"scale (below {MIN_BRIGHT_END:g}: too dark to read); take a longer --exposure, or leave it out for "
                f"the capture's own bracket")
    return None


def _roi_levels(raw, mask):
    """The region's pixels, median and 99th percentile level per channel (R, G, B; None where empty)."""
    if mask is None:
        return [0, 0, 0], [None] * 3, [None] * 3
    pixels, med, p99 = [], [], []
    for c in range(3):
        v = raw.linear[mask & (raw.channels == c)]
        pixels.append(int(v.size))
        med.append(float(np.median(v)) if v.size else None)
        p99.append(float(np.percentile(v, 99)) if v.size else None)
    return pixels, med, p99


def _legend(pixels, med, p99, saturated) -> list[str]:
    """The picture's legend: the colours' meaning and the levels the snap prints (R/G/B, fraction of
    full scale)."""
    def triple(values):
        return "/".join("-" if v is None else f"{v:.3f}" for v in values)

    return ["green: region of interest; yellow: markers; red: saturated",
            f"saturated {100 * saturated[0]:.2f} % of the frame, {100 * saturated[1]:.2f} % of the region",
            f"region R/G/B median {triple(med)}, p99 {triple(p99)}",
            "(levels: fraction of full scale)"]


def _write_png(raw, mask, found: dict, out: Path, clipped=None, legend=()) -> None:
    """The frame (half resolution, gamma 2.2) with the region outlined in green, the markers in
    yellow, the saturated pixels (``clipped``, bool like raw.linear) in red, and the ``legend``
    lines written on a band under it."""
    import cv2

    from drivers.rawfile import bayer_rgb
    from goniofrost.core.atomic_file import write_bytes_atomic

    h, w = raw.linear.shape[0] // 2 * 2, raw.linear.shape[1] // 2 * 2
    rgb = bayer_rgb(raw.linear, raw.channels)
    top = float(np.percentile(rgb, 99.5)) or 1.0
    image = np.ascontiguousarray((np.clip(rgb / top, 0, 1) ** (1 / 2.2) * 255).astype(np.uint8)[..., ::-1])
    if clipped is not None:  # a 2 x 2 block with any clipped pixel shows red, under the outlines
        block = clipped[:h, :w].reshape(h // 2, 2, w // 2, 2).any(axis=(1, 3))
        image[block] = (0, 0, 255)
    if mask is not None:
        contours, _ = cv2.findContours(mask[:h:2, :w:2].astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        cv2.polylines(image, contours, True, (0, 220, 0), 1, cv2.LINE_AA)
    for corners in found.values():
        cv2.polylines(image, [np.rint((corners + 0.5) / 2).astype(np.int32)], True, (0, 220, 255), 1, cv2.LINE_AA)
    if legend:
        band = np.full((16 * len(legend) + 6, image.shape[1], 3), 255, np.uint8)
        for k, line in enumerate(legend):
            cv2.putText(band, line, (4, 16 * k + 14), cv2.FONT_HERSHEY_SIMPLEX, 0.37, (0, 0, 0), 1, cv2.LINE_AA)
        image = np.concatenate([image, band], axis=0)
    ok, data = cv2.imencode(".png", image)
    write_bytes_atomic(out, data.tobytes())


def snap_text(result: SnapResult) -> str:
    """The findings for the operator, a few lines."""
    def triple(values, fmt):
        return " / ".join("-" if v is None else format(v, fmt) for v in values)

    lines = [f"{result.target} card at " + ", ".join(f"{k} {v:.2f} deg" for k, v in result.pose_deg.items()),
             f"frames: {', '.join(f'{t:g} s' for t in result.exposures_s)}",
             f"markers found: {result.markers_found or 'none'} of {result.markers_expected}",
             f"region of interest ({result.roi_source or 'not found'}): pixels R/G/B {triple(result.roi_pixels, 'd')}, "
             f"median level {triple(result.levels_median, '.4f')}, 99th percentile {triple(result.levels_p99, '.4f')}",
             f"saturated: {100 * result.saturated_fraction:.2f} % of the frame, "
             f"{100 * result.roi_saturated_fraction:.2f} % of the region"]
    if result.snr is not None:
        lines.append(f"SNR R/G/B {triple(result.snr, '.1f')} (raw values, no dark frames subtracted: a patch near "
                     f"the dark level reads higher here than in the capture)")
    if result.capture_exposures_s is not None:
        lines.append(f"the capture would take: {', '.join(f'{t:g} s' for t in result.capture_exposures_s)}")
    if result.problem:
        lines.append(f"problem: {result.problem}")
    lines.append(f"picture: {result.png}")
    return "\n".join(lines)
