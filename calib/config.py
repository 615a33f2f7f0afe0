"""The rig file's ``camera:`` section: allowed keys, defaults and one error pattern (ConfigError).

``intrinsics`` and ``mount`` form the camera model (``goniofrost.core.camera_model.CameraModel``).
"""
from __future__ import annotations

from goniofrost.core.config_check import Key, check_section, is_number as _num
from goniofrost.core.errors import ConfigError

from drivers.rig_devices import CAMERA_CLASSES, SIM_CAMERA, SIM_CAMERA_KEYS, camera_class
from drivers.tethered import shutter_label, shutter_seconds  # noqa: F401 - read from here by snap and tests


def _ladder_ok(v) -> bool:
    return (isinstance(v, list) and len(v) >= 1 and all(_num(x) and x > 0 for x in v)
            and all(a < b for a, b in zip(v, v[1:])))


# key: Key(check, expected, default: REQUIRED when none is given); every kind reads these, and
# each kind its own (camera_keys)
_CAMERA_KEYS = {
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
    "timeout_s": Key(lambda v: _num(v) and v > 0, "a number > 0 (seconds to wait for a RAW file or, beyond the "
                     "exposure, for a grabbed frame)", 30.0),
    "operator_timeout_s": Key(lambda v: _num(v) and v > 0,
                              "a number > 0 (seconds the operator has to answer a prompt)", 600.0),
}




def camera_kinds() -> tuple:
    """The camera kinds a rig file may name: the simulated camera's and every registered one's."""
    return (SIM_CAMERA, *CAMERA_CLASSES)


def kind_only_keys() -> tuple[dict, dict]:
    """(every kind's own keys: name -> Key, in CAMERA_CLASSES order; name -> the kinds that read
    it), from each camera class's KEYS. Given to another kind they would be accepted and silently
    ignored (a pylon serial on a DSLR rig, a trigger command on the emulated camera), so they are
    refused; the simulated camera reads SIM_CAMERA_KEYS (drivers.rig_devices)."""
    keys, kinds = {}, {}
    for kind in CAMERA_CLASSES:
        for name, key in camera_class(kind).KEYS.items():
            keys.setdefault(name, key)
            kinds[name] = kinds.get(name, ()) + (kind,) + ((SIM_CAMERA,) if name in SIM_CAMERA_KEYS else ())
    return keys, kinds


def camera_keys() -> dict:
    """The ``camera:`` section's key table: ``kind``, the keys every kind reads, each kind's own."""
    kinds = camera_kinds()
    return {"kind": Key(lambda v: v in kinds, f"one of {list(kinds)}"), **_CAMERA_KEYS, **kind_only_keys()[0]}


def _check_kind_keys(section, kind: str, source, keypath: str) -> None:
    """ConfigError for the first key of ``section`` that a ``kind`` camera never reads, given a value
    other than its default (a section validated before, defaults filled in, is validated again)."""
    own, readers = kind_only_keys()
    for key, kinds in readers.items():
        if section.get(key, own[key].default) != own[key].default and kind not in kinds:
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
    out = check_section(section, camera_keys(), source, keypath)
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


def _intrinsics(section, source, keypath: str) -> dict:
    out = check_section(section, _INTRINSICS_KEYS, source, keypath)
    (width, height), (cx, cy) = out["image_size_px"], out["principal_point_px"]
    if not (0 <= cx <= width - 1 and 0 <= cy <= height - 1):
        raise ConfigError(source, f"{keypath}.principal_point_px",
                          f"a point inside the {width} x {height} image", out["principal_point_px"])
    return out
