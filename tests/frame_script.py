"""Frames taken beforehand with the simulated camera, for tests that script what a camera returns.

``render_table(folder)`` writes one DNG per (what the camera sees, ladder exposure): "dark" (lamp
off), "flat" (the diffuser), "white" (the white card), "sample" (a matte sample, normal light,
30 deg view) and "bright" (the same sample 8x brighter: rendered 8x longer).
"""
from __future__ import annotations

from pathlib import Path

from goniofrost.datasets import material_brdf
from sim.camera_bench import CameraBench

LADDER = [0.002, 0.008, 0.032, 0.128]
SIM_CAMERA = {"black_level": 512, "white_level": 16383, "read_noise_e": 3.0,
              "full_well_e": 30000.0, "dark_current_e_s": 5.0, "vignetting": 0.15}
# a small camera model (1.9 px/mm at the sample: the 68 mm card fills most of 192 x 144)
CAMERA_MODEL = {"intrinsics": {"image_size_px": [192, 144], "focal_px": [1900.0, 1900.0],
                               "principal_point_px": [95.5, 71.5]},
                "mount": {"distance_mm": 1000.0}}
SEEN = {"dark": ("sample", False, 1), "flat": ("flat", True, 1), "white": ("white", True, 1),
        "sample": ("sample", True, 1), "bright": ("sample", True, 8)}


def render(folder: Path, target: str, lamp: bool, seconds: float) -> Path:
    """One DNG of the simulated camera (matte sample, normal light, 30 deg view), ``seconds`` long."""
    bench = CameraBench(material_brdf("builtin:white-diffuse"), SIM_CAMERA,
                        {"kind": "sim", "exposures_s": LADDER, "target_snr": 100.0, **CAMERA_MODEL}, seed=0)
    bench.set_angles(0.0, 30.0)
    bench.camera.set_target(target)
    if lamp:
        bench.lamp.on()
    return bench.camera.capture(seconds, Path(folder) / f"{target}_{lamp}_{seconds}.dng").path


def render_table(folder: Path) -> dict:
    """{(seen, exposure_s): DNG path} for every kind in SEEN and every exposure of LADDER."""
    return {(seen, t): render(folder, target, lamp, factor * t)
            for seen, (target, lamp, factor) in SEEN.items() for t in LADDER}
