"""The rig file's ``camera:`` section: allowed keys, defaults and one error pattern (ConfigError)."""
from __future__ import annotations

from goniofrost.core.config_check import check_section, is_number as _num
from goniofrost.core.errors import ConfigError

CAMERA_KINDS = ("sim", "rawfile")


def _ladder_ok(v) -> bool:
    return (isinstance(v, list) and len(v) >= 1 and all(_num(x) and x > 0 for x in v)
            and all(a < b for a, b in zip(v, v[1:])))


# key: (check, expected, default; None = required)
_CAMERA_KEYS = {
    "kind": (lambda v: v in CAMERA_KINDS, f"one of {list(CAMERA_KINDS)}", None),
    "exposures_s": (_ladder_ok, "a non-empty list of exposures > 0 s, shortest first, strictly increasing", None),
    "target_snr": (lambda v: _num(v) and v > 0, "a number > 0", None),
    "min_snr": (lambda v: _num(v) and v > 0, "a number > 0 (below it a sample is an error)", 10.0),
    "saturation": (lambda v: _num(v) and 0 < v <= 1, "a number in (0, 1] (fraction of the white level)", 0.95),
    "dark_frames": (lambda v: isinstance(v, int) and not isinstance(v, bool) and v >= 1, "an integer >= 1", 2),
    "flat_frames": (lambda v: isinstance(v, int) and not isinstance(v, bool) and v >= 1, "an integer >= 1", 2),
    "roi_margin": (lambda v: _num(v) and 0 <= v < 0.45, "a number in [0, 0.45) (fraction of the patch side)", 0.15),
    "photodiode_rel_sigma": (lambda v: _num(v) and 0 <= v < 0.1, "a number in [0, 0.1)", 0.001),
    "white_reference": (lambda v: isinstance(v, dict), "a mapping", {}),
    # kind rawfile only: the folder the camera's tethering software writes RAW files to, and the
    # command that triggers one exposure ({exposure_s} is replaced); without it the operator is asked
    "folder": (lambda v: v is None or (isinstance(v, str) and v != ""), "a folder path", None),
    "trigger_command": (lambda v: v is None or (isinstance(v, str) and "{exposure_s}" in v),
                        "a command containing {exposure_s}", None),
    "timeout_s": (lambda v: _num(v) and v > 0, "a number > 0 (seconds to wait for a RAW file)", 30.0),
    "operator_timeout_s": (lambda v: _num(v) and v > 0,
                           "a number > 0 (seconds the operator has to answer a prompt)", 600.0),
}
_OPTIONAL = {"folder", "trigger_command"}
_WHITE_KEYS = {
    "reflectance": (lambda v: _num(v) and 0 < v <= 1, "a number in (0, 1]", 0.95),
    "theta_i_deg": (lambda v: _num(v) and 0 <= v < 60, "a number in [0, 60)", 0.0),
    "theta_o_deg": (lambda v: _num(v) and 0 <= v <= 60, "a number in [0, 60]", 30.0),
}


def validate_camera_section(section, source, keypath: str = "camera") -> dict:
    """Check the rig file's ``camera:`` mapping; return a copy with every default filled in.

    Raises ConfigError (``SOURCE: camera.KEY: expected ..., found ...``) for a missing, unknown
    or out-of-range value. ``white_reference`` holds the reflectance of the white tile and the
    pose (theta_i, theta_o in degrees) the session moves to before it takes the white reference.
    """
    out = check_section(section, _CAMERA_KEYS, source, keypath, optional=_OPTIONAL)
    out["white_reference"] = check_section(out["white_reference"], _WHITE_KEYS, source, f"{keypath}.white_reference")
    if out["min_snr"] > out["target_snr"]:
        raise ConfigError(source, f"{keypath}.min_snr", f"<= target_snr {out['target_snr']}", out["min_snr"])
    out["exposures_s"] = [float(x) for x in out["exposures_s"]]
    return out
