"""Pictures for the monitor page, as PNG bytes: the latest frame with its region of interest, and
the reconstruction so far as preview spheres.

Both are computed from the session's files with the capture's own code (``calib.roi.find_patch``
finds the same region of interest the calibrator measured; ``capture.reconstruction.reconstruct_session``
is the session's reconstruction), read-only, and encoded with OpenCV.
"""
from __future__ import annotations

import time
from functools import lru_cache
from pathlib import Path

import numpy as np

from drivers.rawfile import bayer_rgb
from goniofrost.monitor.safe_path import UnsafePath, inside

THUMB_WIDTH = 320      # px of the frame thumbnail (a small sensor is enlarged, a big one reduced)
PREVIEW_SIZE = 96      # px of each preview sphere
ROI_BGR = (60, 220, 60)
MAX_SATURATED = 0.01   # a frame whose patch has more saturated pixels is shown only if no other is
PATCH_LEVEL = 0.8      # display level of the patch's bright pixels


class PictureUnavailable(Exception):
    """A picture that cannot be made now (the message says why; the page shows it)."""


# ----- the latest frame ----------------------------------------------------------------------
def frame_png(view, plan_index: int) -> tuple[bytes, dict]:
    """The frame of journaled sample ``plan_index`` that shows its patch best, with the patch's
    region of interest outlined; and a dict (file, exposure_s when the file records it, roi_pixels).

    The region of interest is found as the calibrator finds it (once per bracket, from the
    markers of the first frame that shows them); the frame shown is the brightest one whose patch
    is not saturated (the same scene at several exposures: brightest = longest).
    """
    from calib.config import validate_camera_section
    from calib.errors import MarkerError
    from calib.holder import SAMPLE_MARKER_IDS
    from calib.roi import find_patch
    from drivers.rawfile import RawFileError, read_raw
    from goniofrost.monitor.session_view import camera_settings

    sample = next((d for d in view.done if d.plan_index == plan_index), None)
    if sample is None:
        raise PictureUnavailable(f"sample {plan_index} is not in the journal")
    margin = validate_camera_section(camera_settings(view), "journaled rig file")["roi_margin"]
    frames, mask, problems = [], None, []
    for journaled in sample.raw_paths:
        try:
            raw = read_raw(frame_path(view.session_dir, journaled))
            if mask is None:
                mask = find_patch(raw.linear, SAMPLE_MARKER_IDS, margin, f"sample {plan_index}")
        except (UnsafePath, RawFileError, MarkerError) as exc:
            problems.append(str(exc))
            continue
        frames.append(raw)
    if mask is None:
        raise PictureUnavailable(f"no frame of sample {plan_index} shows the region of interest: "
                                 + "; ".join(problems[-2:]))

    def merit(raw) -> tuple:
        return (np.mean(raw.saturated[mask]) <= MAX_SATURATED, float(np.median(raw.linear[mask])))

    best = max(frames, key=merit)
    info = {"file": best.path.name, "exposure_s": best.metadata.get("exposure_s"), "roi_pixels": int(mask.sum()),
            "plan_index": plan_index}
    return encode_png(_thumbnail(best.linear, best.channels, mask, view.white_rates)), info


def frame_path(session_dir, journaled: str) -> Path:
    """A journaled RAW path as a file inside the session (the folder may have moved since: then
    the same name under its ``raw/`` folder); UnsafePath for anything outside the session."""
    try:
        return inside(session_dir, journaled)
    except UnsafePath:
        return inside(session_dir, Path(session_dir) / "raw" / Path(journaled).name, journaled)


def _thumbnail(linear: np.ndarray, channels: np.ndarray, mask: np.ndarray, white_rates=None) -> np.ndarray:
    """BGR uint8 image THUMB_WIDTH wide: the frame with the region of interest outlined.

    White-balanced with the calibration's white reference rates (R, G, B) when known; gamma 2.2;
    exposed for the sample patch (its 99th percentile at PATCH_LEVEL), so the sample looks right
    even when the holder card around it is much brighter or darker.
    """
    import cv2

    gains = np.ones(3) if white_rates is None else np.mean(white_rates) / np.asarray(white_rates, dtype=np.float64)
    linear = linear * gains[channels]
    rgb = bayer_rgb(linear, channels)
    patch = linear[mask]
    white = float(np.percentile(patch, 99)) / PATCH_LEVEL if patch.size else 0.0
    white = white if white > 0 else float(np.percentile(rgb, 99.5)) or 1.0
    display = (np.clip(rgb / white, 0, 1) ** (1 / 2.2) * 255).astype(np.uint8)[..., ::-1]
    scale = THUMB_WIDTH / linear.shape[1]
    size = (THUMB_WIDTH, max(1, round(linear.shape[0] * scale)))
    image = np.ascontiguousarray(cv2.resize(display, size, interpolation=cv2.INTER_AREA if scale < 0.5 else cv2.INTER_LINEAR))
    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    outline = [np.rint((c.astype(np.float64) + 0.5) * scale).astype(np.int32) for c in contours]
    cv2.polylines(image, outline, True, ROI_BGR, 2, cv2.LINE_AA)
    return image


def encode_png(bgr: np.ndarray) -> bytes:
    import cv2

    ok, data = cv2.imencode(".png", bgr)
    if not ok:
        raise PictureUnavailable("OpenCV could not encode the PNG")
    return data.tobytes()


# ----- the reconstruction so far ---------------------------------------------------------------
def preview_png(view, rig) -> tuple[bytes, dict]:
    """Spheres (front, side, back light) of the session's reconstruction from the samples journaled
    so far, side by side; and a dict (samples used, work_s: seconds of this preview's own work, not
    counting what is loaded once: the model, the spheres' cells)."""
    from goniofrost.brdf.preview import exposure_for, preview_of, tone_map

    if not view.done:
        raise PictureUnavailable("no sample journaled yet")
    inputs = session_inputs(view, rig)
    sphere_positions(inputs.model.grid)  # once per grid (cached): not part of a preview's own cost
    t0 = time.perf_counter()
    estimate = estimate_for_preview(inputs, view.done)
    hdr = preview_of(estimate, inputs.model.grid, size=PREVIEW_SIZE).estimate
    exposure = exposure_for(hdr)
    image = np.concatenate([tone_map(hdr[k], exposure) for k in range(hdr.shape[0])], axis=1)
    png = encode_png((image[..., ::-1] * 255 + 0.5).astype(np.uint8))
    return png, {"samples": len(view.done), "work_s": time.perf_counter() - t0}


def estimate_for_preview(inputs, records) -> np.ndarray:
    """The session's reconstruction, as ``capture.reconstruction.reconstruct_session`` computes it (the
    Bayesian posterior mean, the samples' sigmas used), but only at the cells the preview spheres
    look up: (grid.size, 3) in 1/sr, NaN elsewhere. On the full grid that is a few thousand of 1.1
    million cells, so a preview costs milliseconds instead of a pass over the whole dictionary.
    The same numbers as the whole reconstruction at those cells (the posterior mean depends on
    the sampled rows only; tests/test_monitor.py compares them; when the capture's estimator
    changes, change this function with it)."""
    from goniofrost.frost.reconstruction import reconstruct_bayes

    model, grid = inputs.model, inputs.model.grid
    shown = sphere_positions(grid)
    sampled = inputs.positions[[r.plan_index for r in records]]
    rows, inverse = np.unique(np.concatenate([shown, sampled]), return_inverse=True)
    estimate = reconstruct_bayes(restricted_model(model, rows), inverse[shown.size:], [r.rgb for r in records],
                                 sigmas=[r.sigma for r in records], with_std=False).brdf
    full = np.full((grid.size, 3), np.nan)
    full[grid.valid_cells[rows]] = estimate
    return full


@lru_cache(maxsize=4)
def sphere_positions(grid) -> np.ndarray:
    """Valid positions (int64, ascending) of the cells the preview spheres look up: found by
    rendering them once from a stand-in table that records every lookup."""
    from goniofrost.brdf.preview import DEFAULT_LIGHTS, render_set

    class Lookups:
        def __init__(self) -> None:
            self.flat = []

        def __getitem__(self, flat):
            self.flat.append(np.asarray(flat, dtype=np.int64).ravel())
            return np.zeros(np.shape(flat) + (3,))

    table = Lookups()
    render_set(table, grid, DEFAULT_LIGHTS, PREVIEW_SIZE)
    cells = np.unique(np.concatenate(table.flat))
    return grid.valid_position(cells[grid.valid_mask[cells]])


def restricted_model(model, rows: np.ndarray):
    """The model with only the dictionary, mean, mapping and noise rows ``rows`` (valid positions):
    a reconstruction from samples among those rows gives the full model's values there (its
    predicted error and std, which average over every cell, do not hold)."""
    from dataclasses import replace

    noise = None if model.noise_variance is None else np.asarray(model.noise_variance[rows])
    if noise is None:  # the scalar noise of a format-1 model: keep its value, not its length
        from goniofrost.frost.posterior import SCALAR_ETA
        noise = np.full(rows.size, SCALAR_ETA / model.n_signals, dtype=np.float32)
    return replace(model, dictionary=np.asarray(model.dictionary[rows]), mean=np.asarray(model.mean[rows]),
                   reference=np.asarray(model.reference[rows]), weight=np.asarray(model.weight[rows]),
                   noise_variance=noise, content_hash=f"{model.content_hash} rows {rows.size}")


def session_inputs(view, rig):
    """The session's ``SessionInputs`` rebuilt from the journal (its plan, rig and model); the
    white reference pose is not needed to reconstruct."""
    from goniofrost.capture.inputs import SessionInputs, plan_cells

    if rig is None:
        raise PictureUnavailable("the journaled rig file cannot be read")
    model, model_path = load_model(view.model_path, view.plan_file, view.model_hash)
    plan_path = Path(view.plan_file)
    cells = plan_cells(view.plan_doc, plan_path, model.grid)
    return SessionInputs(rig, view.plan_doc, plan_path, model, model_path, cells,
                         model.grid.valid_position(cells), {})


@lru_cache(maxsize=2)
def load_model(model_path: str, plan_file: str, model_hash: str):
    """(model, its folder): the journaled model path, else the plan's model path beside the plan
    file; refused if its content hash is not the journaled one."""
    from goniofrost.core.errors import GoniofrostError
    from goniofrost.frost.model import FrostModel

    candidates = [Path(model_path), Path(plan_file).parent / Path(model_path).name]
    tried = []
    for path in candidates:
        try:
            model = FrostModel.load(path)
        except (GoniofrostError, OSError) as exc:
            tried.append(str(exc))
            continue
        if model.content_hash != model_hash:
            tried.append(f"{path}: another model (hash {model.content_hash[:12]}..., the session used {model_hash[:12]}...)")
            continue
        return model, path
    raise PictureUnavailable("the session's model cannot be opened: " + "; ".join(tried))
