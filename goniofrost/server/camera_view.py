"""The page's live camera view: one frame at the current pose, as a small PNG with levels and the
saturated pixels painted red.

``check_view`` reads a request (``exposure_s``; ``black`` and ``white``, fractions of full scale,
or neither: auto levels); ``take_view`` takes the frame on the held hardware with the session's
``Expose`` step on the engine core, with no target change and the lamp as it is; ``view_png``
makes the picture: one RGB pixel per 2 x 2 Bayer cell, block means down to at most MAX_WIDTH px,
gamma 2.2 between the levels, a block with any saturated pixel red.
"""
from __future__ import annotations

import math
import tempfile

import numpy as np

from goniofrost.server.entries import RequestError, _number

MAX_WIDTH = 320              # px of the view (a bigger frame is averaged down in whole blocks)
AUTO_PERCENTILES = (1.0, 99.5)   # the auto levels: these percentiles of the half-resolution RGB
SATURATED_BGR = (0, 0, 255)


def check_view(body, rig) -> tuple[float, tuple[float, float] | None]:
    """(exposure s, (black, white) or None for auto) of a view request; RequestError naming the field.
    Without ``exposure_s``: the middle rung of the rig's exposure ladder (camera.exposures_s)."""
    body = body if isinstance(body, dict) else {}
    ladder = list(rig.camera["exposures_s"])
    exposure = body.get("exposure_s")
    if exposure is None:
        exposure = ladder[len(ladder) // 2]
    if not (_number(exposure) and 0 < exposure <= 10 * max(ladder)):
        raise RequestError("exposure_s", f"exposure_s: expected seconds > 0 and at most {10 * max(ladder):g} "
                           f"(10 x the longest of camera.exposures_s), found {exposure!r}")
    if "black" not in body and "white" not in body:
        return float(exposure), None
    levels = []
    for key in ("black", "white"):
        value = body.get(key)
        if not (_number(value) and math.isfinite(value) and 0 <= value <= 1):
            raise RequestError(key, f"{key}: expected a level between 0 and 1 (fraction of full scale), "
                               f"found {value!r}")
        levels.append(float(value))
    if levels[1] <= levels[0]:
        raise RequestError("white", f"white: expected a level above black ({levels[0]:g}), found {levels[1]:g}")
    return float(exposure), (levels[0], levels[1])


def take_view(hw, rig, exposure_s: float):
    """One frame (``steps.Frame``) of ``exposure_s`` at the current pose, on ``hw`` (the instrument's
    thread only); the nearest of the camera's own shutter speeds when it has a list of them."""
    from calib.config import shutter_label, shutter_seconds
    from goniofrost.capture.plan_runner import PlanRunner
    from goniofrost.capture.steps import Expose

    if rig.camera.get("shutter_speeds"):
        exposure_s = shutter_seconds(shutter_label(rig.camera["shutter_speeds"], exposure_s))

    def plan():
        return (yield Expose(float(exposure_s), "view.dng"))
    with tempfile.TemporaryDirectory(prefix="goniofrost-view-") as folder:
        return PlanRunner(hw, folder, program="serve view").execute_plan(plan())


def view_png(raw, saturation: float, levels: tuple[float, float] | None) -> tuple[bytes, dict]:
    """The PNG of ``raw`` (``drivers.rawfile.RawImage``) and what it shows: its size (px), the
    levels used (``auto`` or given), and the saturated fraction of the frame's pixels."""
    from drivers.rawfile import bayer_rgb
    from goniofrost.monitor.images import encode_png

    rgb = bayer_rgb(raw.linear, raw.channels)
    clipped = raw.clipped(saturation)
    h2, w2 = rgb.shape[:2]
    step = max(1, math.ceil(w2 / MAX_WIDTH))
    h, w = h2 // step, w2 // step
    small = rgb[:h * step, :w * step].reshape(h, step, w, step, 3).mean(axis=(1, 3))
    cells = clipped[:2 * h2, :2 * w2].reshape(h2, 2, w2, 2).any(axis=(1, 3))
    red = cells[:h * step, :w * step].reshape(h, step, w, step).any(axis=(1, 3))
    black, white = levels if levels is not None else (float(np.percentile(rgb, AUTO_PERCENTILES[0])),
                                                      float(np.percentile(rgb, AUTO_PERCENTILES[1])))
    span = white - black if white > black else 1.0
    bgr = np.ascontiguousarray((np.clip((small - black) / span, 0, 1) ** (1 / 2.2) * 255).astype(np.uint8)[..., ::-1])
    bgr[red] = SATURATED_BGR
    info = {"width": int(w), "height": int(h), "auto": levels is None, "black": round(black, 6),
            "white": round(white, 6), "saturated_fraction": float(np.mean(clipped)),
            "saturated_px": int(red.sum())}
    return encode_png(bgr), info
