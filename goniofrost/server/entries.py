"""Check what a client asks before anything is queued or moved: one ``RequestError`` naming the field.

``check_entry`` turns a queue request (a JSON object) into the row ``store.Store.add`` keeps;
``check_move``, ``check_lamp``, ``check_snap`` the bodies of the direct commands. ``inside_root``
resolves a path a client names and refuses one that leaves the server's root.
"""
from __future__ import annotations

import math
import re
from pathlib import Path

from goniofrost.capture.options import DEFAULT_CONFIDENCE
from goniofrost.core.errors import ConfigError, GoniofrostError

# field -> (JSON types, required, description): the queue entry (the API schema is built from it)
ENTRY_SCHEMA = {
    "plan": ("string", True, "the plan file (goniofrost plan), relative to the server's root"),
    "material": ("string", False, "what a simulated rig's stage shows, SPEC:NAME (e.g. builtin:red-plastic); "
                 "never on a real rig"),
    "sample_id": ("string", True, "the sample's id (one line)"),
    "operator": ("string", False, "who measures (one line)"),
    "note": ("string", False, "a note kept with the session (one line)"),
    "target_error": ("number", False, "stop once the log-relative MSE is at most this (> 0; null: the whole plan)"),
    "confidence": ("number", False, f"the probability the target is met (0 < c < 1; default {DEFAULT_CONFIDENCE:g})"),
}
OPTION_FIELDS = {"--target-error": "target_error", "--confidence": "confidence"}  # capture's option -> field
NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,99}$")


class RequestError(GoniofrostError):
    """A request the server refuses: ``field`` names what is wrong, ``status`` the HTTP status."""

    def __init__(self, field: str, message: str, status: int = 422) -> None:
        super().__init__(message)
        self.field, self.status = field, status


def inside_root(root: Path, name, field: str) -> Path:
    """``root / name`` resolved; RequestError when ``name`` is not a relative path inside ``root``."""
    if not isinstance(name, str) or not name or "\x00" in name:
        raise RequestError(field, f"{field}: expected a path relative to the server's root, found {name!r}")
    path = (root / name).resolve()
    if Path(name).is_absolute() or not path.is_relative_to(root.resolve()):
        raise RequestError(field, f"{field}: {name!r} leaves the server's root; name a file inside it")
    return path


def _text(body: dict, key: str, required: bool) -> str:
    value = body.get(key)
    if value is None and not required:
        return ""
    if not isinstance(value, str) or not value.strip() or "\n" in value or "\r" in value:
        raise RequestError(key, f"{key}: expected {ENTRY_SCHEMA[key][2]}, found {value!r}")
    return value


def check_entry(body, root: Path, rig_path: Path, rig) -> dict:
    """The queue row of the request ``body``; RequestError naming the first field that is wrong."""
    from goniofrost.capture.inputs import load_inputs
    from goniofrost.capture.runner import check_target

    if not isinstance(body, dict):
        raise RequestError("body", "body: expected a JSON object")
    unknown = sorted(set(body) - set(ENTRY_SCHEMA))
    if unknown:
        raise RequestError(unknown[0], f"{unknown[0]}: not a field of a queue entry (fields: {', '.join(ENTRY_SCHEMA)})")
    plan = inside_root(root, body.get("plan"), "plan")
    if not plan.is_file():
        raise RequestError("plan", f"plan: no plan file {body['plan']!r} under the server's root")
    try:
        inputs = load_inputs(rig_path, plan)
    except GoniofrostError as exc:
        raise RequestError("plan", f"plan: {exc}") from None
    entry = {key: _text(body, key, ENTRY_SCHEMA[key][1]) for key in ("sample_id", "operator", "note")}
    entry["material"] = check_material(rig, body.get("material"))
    target, confidence = body.get("target_error"), body.get("confidence", DEFAULT_CONFIDENCE)
    if target is not None and not (_number(target) and 0 < target < math.inf):
        raise RequestError("target_error", f"target_error: expected a log-relative MSE > 0 (or null), found {target!r}")
    if not (_number(confidence) and 0 < confidence < 1):
        raise RequestError("confidence", f"confidence: expected a number between 0 and 1, found {confidence!r}")
    try:
        check_target(inputs, target, confidence)
    except ConfigError as exc:  # the capture's words name its options; a client's request names fields
        field = OPTION_FIELDS.get(exc.keypath) if exc.source == "command line" else None
        if field is not None:
            raise RequestError(field, f"{field}: expected {exc.expected}, found {exc.found!r}") from None
        raise RequestError("target_error", f"target_error: {exc}") from None
    return entry | {"plan": str(plan.relative_to(root.resolve())), "target_error": target,
                    "confidence": float(confidence)}


def check_material(rig, material) -> str | None:
    """A simulated rig's material, resolved to check it; none on a real rig."""
    from goniofrost.datasets import shown_material

    if not rig.simulated:
        if material is not None:
            raise RequestError("material", "material: a real rig shows what is on its stage; name no material")
        return None
    if not isinstance(material, str):
        raise RequestError("material", f"material: expected SPEC:NAME (e.g. builtin:red-plastic), found {material!r}")
    try:
        shown_material(material, "material")
    except GoniofrostError as exc:
        raise RequestError("material", f"material: {exc}") from None
    return material


def check_move(body, rig) -> dict[str, float]:
    """{axis: degrees} of a move request ``{"targets": {...}}``, each within its limits."""
    from goniofrost.capture.console import check_targets

    targets = body.get("targets") if isinstance(body, dict) else None
    if not isinstance(targets, dict) or not targets:
        raise RequestError("targets", 'targets: expected {"AXIS": degrees, ...}')
    for name, deg in targets.items():
        if name not in rig.axes:
            raise RequestError(f"targets.{name}", f"targets.{name}: no such axis (axes: {', '.join(rig.axes)})")
        if not (_number(deg) and math.isfinite(deg)):
            raise RequestError(f"targets.{name}", f"targets.{name}: expected a number of degrees, found {deg!r}")
        try:
            check_targets(rig, {name: float(deg)})
        except GoniofrostError as exc:
            raise RequestError(f"targets.{name}", str(exc)) from None
    return {name: float(deg) for name, deg in targets.items()}


def check_lamp(body, rig) -> bool:
    if not (rig.lamp or {}).get("driver"):
        raise RequestError("on", "on: this rig has no lamp driver (lamp.driver)", 409)
    on = body.get("on") if isinstance(body, dict) else None
    if not isinstance(on, bool):
        raise RequestError("on", f"on: expected true or false, found {on!r}")
    return on


def check_snap(body, root: Path) -> tuple[Path, str, float | None]:
    """(the PNG under ROOT/snaps, the target, the exposure or None) of a snap request."""
    body = body if isinstance(body, dict) else {}
    name = body.get("name", "snap.png")
    if not isinstance(name, str) or not NAME.match(name) or not name.endswith(".png"):
        raise RequestError("name", f"name: expected a file name ending .png (letters, digits, . _ -), found {name!r}")
    target = body.get("target", "sample")
    if target not in ("sample", "white", "flat"):
        raise RequestError("target", f"target: expected sample, white or flat, found {target!r}")
    exposure = body.get("exposure_s")
    if exposure is not None and not (_number(exposure) and 0 < exposure < math.inf):
        raise RequestError("exposure_s", f"exposure_s: expected a positive number of seconds, found {exposure!r}")
    return root / "snaps" / name, target, exposure


def _number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)
