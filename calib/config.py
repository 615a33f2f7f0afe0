"""The rig file's ``camera:`` section: allowed keys, defaults and one error pattern (ConfigError).

``intrinsics`` and ``mount`` are the camera model (``goniofrost.core.camera_model.CameraModel``):
the planner decides from it which cells the camera can measure, the calibration predicts where
the patch and the markers fall in every frame, and the simulated camera renders with it.
"""
from __future__ import annotations

from goniofrost.core.config_check import Key, check_section, is_number as _num
from goniofrost.core.errors import ConfigError

CAMERA_KINDS = ("sim", "rawfile", "pylon")
# kind pylon: the pixel formats a measurement can use (12 or 16 bits; Bayer for colour, Mono for grey)
PYLON_PIXEL_FORMATS = tuple(f"{cfa}{bits}" for bits in (12, 16)
                            for cfa in ("BayerRG", "BayerGR", "BayerGB", "BayerBG", "Mono"))


def _ladder_ok(v) -> bool:
    return (isinstance(v, list) and len(v) >= 1 and all(_num(x) and x > 0 for x in v)
            and all(a < b for a, b in zip(v, v[1:])))


# key: Key(check, expected, default: REQUIRED when none is given)
_CAMERA_KEYS = {
    "kind": Key(lambda v: v in CAMERA_KINDS, f"one of {list(CAMERA_KINDS)}"),
    "exposures_s": Key(_ladder_ok, "a non-empty list of exposures > 0 s, shortest first, strictly increasing"),
    "target_snr": Key(lambda v: _num(v) and v > 0, "a number > 0"),
    "min_snr": Key(lambda v: _num(v) and v > 0, "a number > 0 (a channel below it is at its detection limit; a sample with every channel below it is not measured)", 10.0),
    "saturation": Key(lambda v: _num(v) and 0 < v <= 1, "a number in (0, 1] (fraction of the white level)", 0.95),
    "dark_frames": Key(lambda v: isinstance(v, int) and not isinstance(v, bool) and v >= 1, "an integer >= 1", 2),
    "flat_frames": Key(lambda v: isinstance(v, int) and not isinstance(v, bool) and v >= 1, "an integer >= 1", 2),
    "roi_margin": Key(lambda v: _num(v) and 0 <= v < 0.45, "a number in [0, 0.45) (fraction of the patch side)", 0.15),
    # a cell is measurable when the region of interest keeps this many pixels of each colour channel
    "min_roi_pixels": Key(lambda v: _int(v) and 4 <= v <= 100_000, "an integer in [4, 100000] (pixels per colour channel)", 24),
    # readable markers may lie this far from where the camera model puts them before the rig is
    # declared misaligned (pixels; the offsets that `goniofrost align` corrects stay well inside)
    "marker_tolerance_px": Key(lambda v: _num(v) and v > 0, "a number > 0 (pixels)", 20.0),
    "intrinsics": Key(lambda v: isinstance(v, dict), "a mapping (image_size_px, focal_px, principal_point_px, distortion)"),
    "mount": Key(lambda v: isinstance(v, dict), "a mapping (distance_mm, rotation_deg)"),
    "photodiode_rel_sigma": Key(lambda v: _num(v) and 0 <= v < 0.1, "a number in [0, 0.1)", 0.001),
    "white_reference": Key(lambda v: isinstance(v, dict), "a mapping", {}),
    # kind rawfile only: the folder the camera's tethering software writes RAW files to, and the
    # command that triggers one exposure ({exposure_s} is replaced); without it the operator is asked
    "folder": Key(lambda v: v is None or (isinstance(v, str) and v != ""), "a folder path", None),
    "trigger_command": Key(lambda v: v is None or (isinstance(v, str) and ("{exposure_s}" in v or "{shutter}" in v)),
                           "a command containing {exposure_s} or {shutter} (and optionally {folder})", None),
    # command that puts a target in front of the lens ({target}: sample, white or flat), for a motorised
    # target changer (or the simulated camera of `goniofrost sim --write-rig`); without it the operator is asked
    "target_command": Key(lambda v: v is None or (isinstance(v, str) and "{target}" in v),
                          "a command containing {target}", None),
    # kind rawfile: the camera's own shutter speeds (its labels, e.g. ["1/4000", "1/2000", ..., "30"]):
    # each exposures_s rung becomes the nearest of them and the trigger gets its label as {shutter}
    "shutter_speeds": Key(lambda v: v is None or (isinstance(v, list) and len(v) >= 1
                                                  and all(shutter_seconds(x) is not None for x in v)),
                          'a list of shutter speed labels such as "1/4000", "0.3", "30"', None),
    # kind rawfile: a RAW file's own exposure (EXIF ExposureTime) may differ from the one asked for
    # by this fraction at most, else it is refused
    "exposure_tolerance": Key(lambda v: _num(v) and 0 <= v < 0.5, "a number in [0, 0.5) (relative)", 0.05),
    "timeout_s": Key(lambda v: _num(v) and v > 0, "a number > 0 (seconds to wait for a RAW file or, beyond the "
                     "exposure, for a grabbed frame)", 30.0),
    # kind pylon: the camera's serial number (none: the first camera found), its pixel format and gain
    "serial": Key(lambda v: v is None or (isinstance(v, str) and v != ""), "a serial number (a string)", None),
    "pixel_format": Key(lambda v: v in PYLON_PIXEL_FORMATS, f"one of {list(PYLON_PIXEL_FORMATS)}", "BayerRG12"),
    "gain_db": Key(lambda v: _num(v) and 0 <= v <= 48, "a number in [0, 48] (dB, fixed)", 0.0),
    "operator_timeout_s": Key(lambda v: _num(v) and v > 0,
                              "a number > 0 (seconds the operator has to answer a prompt)", 600.0),
}


# Keys that only some kinds of camera read (the rest are read by every kind). Given to another
# kind they would be accepted and silently ignored (a pylon serial on a DSLR rig, a trigger command
# on the emulated camera), so they are refused. A simulated camera keeps the folder camera's
# shutter_speeds (they move its ladder) and exposure_tolerance (`goniofrost sim --write-rig` turns
# it into a folder camera); its folder and commands are the ones --write-rig writes.
KIND_ONLY_KEYS = {
    "serial": ("pylon",), "pixel_format": ("pylon",), "gain_db": ("pylon",),
    "folder": ("rawfile",), "trigger_command": ("rawfile",), "target_command": ("rawfile",),
    "shutter_speeds": ("rawfile", "sim"), "exposure_tolerance": ("rawfile", "sim"),
}


def _check_kind_keys(section, kind: str, source, keypath: str) -> None:
    """ConfigError for the first key of ``section`` that a ``kind`` camera never reads, given a value
    other than its default (a section validated before, defaults filled in, is validated again)."""
    for key, kinds in KIND_ONLY_KEYS.items():
        if section.get(key, _CAMERA_KEYS[key].default) != _CAMERA_KEYS[key].default and kind not in kinds:
            raise ConfigError(source, f"{keypath}.{key}", f"no {key} for camera kind {kind!r} (only kind "
                              f"{' or '.join(kinds)} reads it)", section[key])


def _int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _pair(check):
    return lambda v: isinstance(v, list) and len(v) == 2 and all(check(x) for x in v)


# The pinhole model in OpenCV's conventions (pixel centres at integers); measure it with
# cv2.calibrateCamera (e.g. a ChArUco board) at the focus and zoom used on the rig.
_INTRINSICS_KEYS = {
    "image_size_px": Key(_pair(lambda x: _int(x) and 16 <= x <= 16384), "[width, height], integers in [16, 16384]"),
    "focal_px": Key(_pair(lambda x: _num(x) and x > 0), "[fx, fy], numbers > 0 (pixels)"),
    "principal_point_px": Key(_pair(_num), "[cx, cy], numbers (pixels)"),
    "distortion": Key(lambda v: isinstance(v, list) and len(v) == 5 and all(_num(x) and abs(x) < 100 for x in v),
                   "[k1, k2, p1, p2, k3], five numbers (OpenCV order)", [0.0, 0.0, 0.0, 0.0, 0.0]),
}
# Where the camera sits on its arm: its centre of projection at distance_mm from the rotation centre
# in the lamp's plane, aimed at the centre with the image up along the vertical, then turned by
# rotation_deg about its own x, y, z axes.
_MOUNT_KEYS = {
    "distance_mm": Key(lambda v: _num(v) and v > 0, "a number > 0 (millimetres from the rotation centre)"),
    "rotation_deg": Key(lambda v: isinstance(v, list) and len(v) == 3 and all(_num(x) and abs(x) <= 20 for x in v),
                     "[rx, ry, rz], three numbers within +-20 (degrees)", [0.0, 0.0, 0.0]),
}
_WHITE_KEYS = {
    "reflectance": Key(lambda v: _num(v) and 0 < v <= 1, "a number in (0, 1]", 0.95),
    "theta_i_deg": Key(lambda v: _num(v) and 0 <= v < 60, "a number in [0, 60)", 0.0),
    "theta_o_deg": Key(lambda v: _num(v) and 0 <= v <= 60, "a number in [0, 60]", 30.0),
}


def validate_camera_section(section, source, keypath: str = "camera") -> dict:
    """Check the rig file's ``camera:`` mapping; return a copy with every default filled in.

    Raises ConfigError (``SOURCE: camera.KEY: expected ..., found ...``) for a missing, unknown
    or out-of-range value. ``white_reference`` holds the reflectance of the white tile and the
    pose (theta_i, theta_o in degrees) the session moves to before it takes the white reference;
    ``intrinsics`` and ``mount`` the camera model (module doc).
    """
    out = check_section(section, _CAMERA_KEYS, source, keypath)
    _check_kind_keys(section, out["kind"], source, keypath)
    out["white_reference"] = check_section(out["white_reference"], _WHITE_KEYS, source, f"{keypath}.white_reference")
    out["intrinsics"] = _intrinsics(out["intrinsics"], source, f"{keypath}.intrinsics")
    out["mount"] = check_section(out["mount"], _MOUNT_KEYS, source, f"{keypath}.mount")
    if out["min_snr"] > out["target_snr"]:
        raise ConfigError(source, f"{keypath}.min_snr", f"<= target_snr {out['target_snr']}", out["min_snr"])
    if out["kind"] == "rawfile" and out.get("folder") is None:
        # found by `plan --rig` and `rig check`, not after every motor was connected
        raise ConfigError(source, f"{keypath}.folder",
                          "the folder the camera writes RAW files to (kind rawfile)", "nothing")
    out["exposures_s"] = [float(x) for x in out["exposures_s"]]
    if out["shutter_speeds"] is not None:
        out["exposures_s"] = _on_shutter_speeds(out, source, keypath)
    return out


def shutter_seconds(label) -> float | None:
    """Seconds of a camera's shutter speed label ("1/4000", "0.3", "30", "2.5s"); None if it is not one."""
    if not isinstance(label, str):
        return None
    text = label.strip().removesuffix("s").strip()
    num, _, den = text.partition("/")
    try:
        value = float(num) / (float(den) if den else 1.0)
    except (ValueError, ZeroDivisionError):
        return None
    return value if 0 < value < float("inf") else None


def _on_shutter_speeds(out: dict, source, keypath: str) -> list:
    """The ladder (s) with each rung moved to the nearest (in stops) of the camera's shutter
    speeds (``shutter_label`` gives a rung's label back); ConfigError when two rungs land on one."""
    import math

    labels = out["shutter_speeds"]
    seconds = [shutter_seconds(x) for x in labels]
    ladder = out["exposures_s"]
    # inside the camera's range the nearest speed is at most about half a stop away; a rung beyond
    # its ends would silently become the end speed (1e-5 s taken as 1/4000: 25 times longer)
    fast, slow = min(seconds), max(seconds)
    outside = [t for t in ladder if not fast / math.sqrt(2) <= t <= slow * math.sqrt(2)]
    if outside:
        first, last = labels[seconds.index(fast)], labels[seconds.index(slow)]
        raise ConfigError(source, f"{keypath}.exposures_s", f"rungs within half a stop of the range of "
                          f"{keypath}.shutter_speeds, {first!r} to {last!r} ({fast:g} to {slow:g} s); outside it: "
                          f"{outside}", ladder)
    picked = [min(range(len(labels)), key=lambda k: abs(math.log(seconds[k] / t))) for t in ladder]
    for k, (a, b) in enumerate(zip(picked, picked[1:])):
        if seconds[b] <= seconds[a]:
            raise ConfigError(source, f"{keypath}.exposures_s", f"rungs on different shutter speeds of "
                              f"{keypath}.shutter_speeds ({ladder[k]:g} and {ladder[k + 1]:g} s both fall on "
                              f"{labels[a]!r})", ladder)
    return [seconds[k] for k in picked]


def shutter_label(labels: list, exposure_s: float) -> str:
    """The label among ``labels`` (a camera's shutter speeds) whose seconds are ``exposure_s``
    (a rung of a ladder moved onto them), else the nearest in stops."""
    import math

    return min(labels, key=lambda x: abs(math.log(shutter_seconds(x) / exposure_s)))


def _intrinsics(section, source, keypath: str) -> dict:
    out = check_section(section, _INTRINSICS_KEYS, source, keypath)
    (width, height), (cx, cy) = out["image_size_px"], out["principal_point_px"]
    if not (0 <= cx <= width - 1 and 0 <= cy <= height - 1):
        raise ConfigError(source, f"{keypath}.principal_point_px",
                          f"a point inside the {width} x {height} image", out["principal_point_px"])
    return out
