"""Every problem of a rig file in one run, then every device probed without enabling or moving it.

``rig_file_problems(path)`` checks each part of a rig file on its own (top level, geometry, each
axis, lamp, camera, sim, alignment), so one run names every problem; the checks across parts
(``load_checked_rig``) run once each part is sound. ``probe_rig(rig)`` connects to each device with
the driver's bounded timeouts, reads identity, position, enabled and alarm state, and names a
silent device's likely causes; ``probe_camera`` reads the camera, its exposure range and one
frame's levels. Nothing here enables a motor, moves an axis or switches the lamp.
"""
from __future__ import annotations

import errno
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Mapping

from goniofrost.core.errors import ConfigError, GoniofrostError


@dataclass(frozen=True)
class Problem:
    """One problem of a rig file: the key path and the message (``SOURCE: KEY: expected ..., found ...``)."""

    keypath: str
    message: str


class RigCheckError(GoniofrostError):
    """A rig check found problems; the message lists them, one per line."""

    def __init__(self, problems: list[Problem], source: str) -> None:
        self.problems = problems
        lines = [f"{source}: {len(problems)} problem(s):"] + [f"  {p.message}" for p in problems]
        super().__init__("\n".join(lines))


def _collect(problems: list[Problem], check: Callable, *args):
    """Run ``check(*args)``; a ConfigError becomes a Problem. Returns the check's value or None."""
    try:
        return check(*args)
    except ConfigError as exc:
        if all(p.keypath != exc.keypath for p in problems):  # one per key: a missing geometry was listed twice
            problems.append(Problem(exc.keypath, str(exc)))
        return None


def rig_file_problems(path: str | Path, alignment: str | Path | None = None) -> list[Problem]:
    """Every problem of the rig file at ``path`` (an empty list when it is fit to drive a rig)."""
    from planner import schema as S

    source = str(path)
    problems: list[Problem] = []
    raw = _collect(problems, S.read_yaml, path)
    if raw is None:
        return problems or [Problem("", f"{source}: (top level): expected a rig file, found nothing")]
    if not isinstance(raw, Mapping):
        return [Problem("", str(ConfigError(source, "", "a mapping (a rig file)", raw)))]
    if _collect(problems, S.check_filled_in, raw, source) is None and problems:
        return problems  # a template not yet edited: its examples would only add problems of their own
    top = raw
    _check_parts(top, source, problems)
    if not problems:  # the checks across sections need every part sound
        from goniofrost.rig.file import load_checked_rig
        _collect(problems, load_checked_rig, path, alignment)
    return problems


def _check_parts(top: Mapping, source: str, problems: list[Problem]) -> None:
    """Check each part of the rig mapping on its own, collecting the problems."""
    from planner import rig as R

    from goniofrost.core.config_check import check_section
    from goniofrost.rig.file import section_validators

    validators = section_validators()
    _collect(problems, check_section, top, R.TOP_KEYS, source, "")
    geometry = _collect(problems, R.geometry_from_mapping, top.get("geometry"), source)
    axes_map = _collect(problems, lambda v: check_section(v, {}, source, "axes", open_keys=True), top.get("axes", {})) or {}
    axes = {}
    for name, spec in axes_map.items():
        axis = _collect(problems, R.axis_from_mapping, name, spec, source, validators["driver"])
        if axis is not None:
            axes[name] = axis
    if geometry is not None and len(axes) == len(axes_map):
        _collect(problems, R.check_roles, axes, geometry, source)
    lamp = _collect(problems, check_section, top.get("lamp", {}), R.LAMP_KEYS, source, "lamp") or {}
    if isinstance(lamp.get("driver"), Mapping):
        _collect(problems, validators["driver"], lamp["driver"], source, "lamp.driver")
    _check_lamp_device(top.get("lamp"), axes_map, source, problems)
    simulated = top.get("simulated", False) is True
    if "camera" in top:
        _collect(problems, validators["camera"], top["camera"], source, "camera")
    elif not simulated:
        problems.append(Problem("camera", f"{source}: camera: expected a camera section (kind, exposures_s, "
                                          f"intrinsics, mount: see config/rigs/template.yaml), found nothing"))
    if "sim" in top:
        _collect(problems, validators["sim"], top["sim"], source, "sim")
    if "twins" in top:
        _collect(problems, validators["twins"], top["twins"], source, "twins")


def _check_lamp_device(lamp, axes_map: Mapping, source: str, problems: list[Problem]) -> None:
    """A lamp ``device:`` must name a Modbus axis of this rig (drivers.config.check_lamp_host)."""
    from drivers.config import check_lamp_host

    driver = lamp.get("driver") if isinstance(lamp, Mapping) else None
    drivers = {name: spec.get("driver") for name, spec in axes_map.items() if isinstance(spec, Mapping)}
    _collect(problems, check_lamp_host, driver, drivers, source)


# ----- probing the devices -------------------------------------------------------------------------
@dataclass
class DeviceReport:
    """What one device answered: ``answers``; ``identity`` text where the protocol gives one;
    ``position_deg``, ``limits_deg``, ``enabled`` and ``alarm`` (None: healthy) for an axis;
    ``exposure_range_s`` and ``frame`` (exposure_s, per-channel median and 99th percentile of the
    linear values, saturated fraction) for the camera; ``error`` and ``causes`` (likely causes,
    most likely first) when it did not answer."""

    device: str
    link: str
    answers: bool
    identity: str | None = None
    position_deg: float | None = None
    limits_deg: tuple[float, float] | None = None
    enabled: bool | None = None
    alarm: str | None = None
    lamp_on: bool | None = None
    error: str | None = None
    causes: list[str] = field(default_factory=list)
    exposure_range_s: tuple[float, float] | None = None
    frame: dict | None = None

    def as_dict(self) -> dict:
        out = dict(self.__dict__)
        out["limits_deg"] = None if self.limits_deg is None else list(self.limits_deg)
        out["exposure_range_s"] = None if self.exposure_range_s is None else list(self.exposure_range_s)
        return out


def describe_link(section: Mapping) -> str:
    """The device's link in a few words, e.g. "modbus-tcp 127.0.0.1:502 id 1" or "smc100 /dev/ttyUSB1 57600 baud"."""
    protocol = section.get("protocol", "?")
    if "device" in section:
        return f"{protocol} on axis {section['device']}"
    if "host" in section:
        return f"{protocol} {section['host']}:{section.get('port')} id {section.get('device_id', 1)}"
    address = section.get("id", section.get("address", section.get("device_id")))
    return f"{protocol} {section.get('port')} {section.get('baud', '')} baud, address {address}".replace("  ", " ")


def likely_causes(section: Mapping, exc: BaseException) -> list[str]:
    """The likely causes of a device that did not answer, from the error and the link (most likely first)."""
    text = f"{type(exc).__name__}: {exc}".lower()
    os_errno = _errno(exc)
    tcp = "host" in section or section.get("protocol") == "modbus-tcp"
    if os_errno == errno.ENOENT or "no such file" in text or "could not open port" in text and "no such" in text:
        return [f"the port {section.get('port')} does not exist: the USB adapter is unplugged or has another name "
                f"(ls /dev/ttyUSB* /dev/serial/by-id/)"]
    if os_errno in (errno.EBUSY, errno.EAGAIN) or "busy" in text or "lock" in text:
        return [f"the port {section.get('port')} is busy: another program holds it (lsof {section.get('port')})"]
    if os_errno == errno.EACCES or "permission" in text:
        return [f"no permission to open {section.get('port')}: add the user to the dialout group"]
    if tcp and (os_errno == errno.ECONNREFUSED or "refused" in text):
        return [f"nothing listens on {section.get('host')}:{section.get('port')}: the drive is off, or the port is wrong",
                "the drive's Modbus TCP server is disabled"]
    if tcp:
        return [f"no answer from {section.get('host')}: power, network cable, or a wrong host address",
                f"wrong Modbus unit id (device_id {section.get('device_id', 1)})"]
    address = section.get("id", section.get("address"))
    return ["the controller is not powered", "the cable is loose or crossed (TX/RX)",
            f"wrong baud rate ({section.get('baud')}) or address/ID ({address})"]


def _errno(exc: BaseException) -> int | None:
    """The OS error number behind ``exc`` or one of its causes, if any."""
    while exc is not None:
        if isinstance(exc, OSError) and exc.errno is not None:
            return exc.errno
        exc = exc.__cause__ or exc.__context__
    return None


def probe_axis(name: str, spec, axis, section: Mapping | None = None) -> DeviceReport:
    """Connect ``axis`` (not enabled, not moved), read its identity and state, close it.

    ``section``: the driver section the axis was built from (default: the rig file's)."""
    from drivers.rig_devices import connect_axis

    section = dict(spec.driver if section is None else section)
    report = DeviceReport(name, describe_link(section), False, limits_deg=tuple(spec.limits_deg))
    try:
        connect_axis(axis, section)  # the rig layer opens the port or socket and hands it over
    except Exception as exc:  # noqa: BLE001 - a device that does not answer is a finding, not a crash
        report.error, report.causes = _short(exc), likely_causes(section, exc)
        return report
    try:
        report.answers = True
        identity = getattr(axis, "identity", None)
        report.identity = _read(identity) if callable(identity) else None
        status = axis.status()
        report.position_deg, report.enabled, report.alarm = status.position_deg, status.enabled, status.fault
    except Exception as exc:  # noqa: BLE001
        report.error = _short(exc)
    finally:
        axis.close()
    return report


_LINK_KEYS = {"protocol", "id", "address", "device_id", "register_map", "model_number_register", "firmware_register"}


def _read(call) -> str | None:
    try:
        value = call()
    except Exception as exc:  # noqa: BLE001 - an identity the device will not give is not a failure
        return f"(no identity: {_short(exc)})"
    if isinstance(value, Mapping):  # the link column already says protocol and address
        return ", ".join(f"{k} {v}" for k, v in value.items() if k not in _LINK_KEYS) or None
    return None if value is None else str(value)


def _short(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def probe_rig(rig, axes: Mapping, lamp=None, sections: Mapping | None = None) -> list[DeviceReport]:
    """Probe every axis of ``axes`` (name -> unconnected Axis) and the ``lamp`` (unconnected Lamp or None).

    ``sections``: {axis name: the driver section it was built from} when not the rig file's (the
    endpoints of a simulated rig's devices). The protocol libraries' log lines (pymodbus says
    "Connection refused" only there) are kept off the terminal and added to a silent device's error.
    """
    from goniofrost.rig.device_log import DeviceLog

    sections = sections or {}
    reports = []
    with DeviceLog.capture() as device_log:
        for name, axis in axes.items():
            reports.append(_with_log(probe_axis(name, rig.axes[name], axis, sections.get(name)), device_log,
                                     sections.get(name, rig.axes[name].driver)))
        if lamp is not None:
            owner = (rig.lamp.get("driver") or {}).get("device")
            silent_owner = next((r for r in reports if r.device == owner and not r.answers), None)
            if silent_owner is not None:  # its link is the axis's: probing it again would only wait again
                reports.append(DeviceReport("lamp", describe_link(rig.lamp["driver"]), False,
                                            error=f"not probed: its link is {owner}'s, which did not answer",
                                            causes=list(silent_owner.causes)))
            else:
                reports.append(_with_log(probe_lamp(rig, lamp, axes, sections or None), device_log,
                                         rig.lamp.get("driver", {})))
    return reports


def _with_log(report: DeviceReport, device_log, section: Mapping) -> DeviceReport:
    """Add what the protocol libraries logged while probing a silent device to its error and causes."""
    said = []
    for record in device_log.drain():
        message = " ".join(record.getMessage().split())
        if record.levelno >= 30 and message not in said and not message.startswith("Repeating"):
            said.append(message)
    if not report.answers and said:
        report.error = f"{report.error} ({'; '.join(said[-2:])})"
        report.causes = likely_causes(section, RuntimeError(report.error))
    return report


def probe_lamp(rig, lamp, axes: Mapping, sections: Mapping | None = None) -> DeviceReport:
    """Connect the lamp (through its own link or its axis's), read the coil, close. ``sections``:
    {axis name: driver section} when not the rig file's (a simulated rig's endpoints)."""
    section = dict(rig.lamp.get("driver", {}))
    link_owner = section.get("device")
    report = DeviceReport("lamp", describe_link(section), False)
    owner = axes.get(link_owner) if link_owner else None
    from drivers.rig_devices import connect_axis, open_transport

    try:
        if owner is not None:
            connect_axis(owner, dict(rig.axes[link_owner].driver) if sections is None else sections[link_owner])
        lamp.connect(None if owner is not None else open_transport("lamp", section))
        report.answers, report.lamp_on = True, lamp.is_on()
    except Exception as exc:  # noqa: BLE001
        source = dict(rig.axes[link_owner].driver) if link_owner in rig.axes else section
        report.error, report.causes = _short(exc), likely_causes(source, exc)
    finally:
        for device in (lamp, owner):
            if device is not None:
                try:
                    device.close()
                except Exception:  # noqa: BLE001 - closing a link that never opened
                    pass
    return report


# ----- probing the camera --------------------------------------------------------------------------
def camera_link(section: Mapping) -> str:
    """The camera's link in a few words: "pylon serial 40012345", "rawfile /data/raw (trigger command)"."""
    kind = section.get("kind", "?")
    if kind == "pylon":
        return f"pylon serial {section.get('serial')}" if section.get("serial") else "pylon (the first camera found)"
    if kind == "rawfile":
        how = "trigger command" if section.get("trigger_command") else "the operator triggers it"
        return f"rawfile {section.get('folder')} ({how})"
    return f"{kind} (the simulated camera)"


def camera_causes(section: Mapping, exc: BaseException) -> list[str]:
    """The likely causes of a camera that did not give a frame (most likely first)."""
    text = str(exc).lower()
    if section.get("kind") == "pylon":
        if "serial" in text:
            return ["camera.serial is not this camera's: the serials found are listed above",
                    "the camera with that serial is unplugged or not powered"]
        return ["the camera is unplugged or not powered (pylon Viewer lists what pylon sees)",
                "another program (pylon Viewer) holds the camera"]
    if section.get("kind") == "rawfile":
        return ["the trigger command failed: the camera is off, not connected, or the program or service it "
                "calls is not running", f"no RAW file arrived in {section.get('folder')} within camera.timeout_s "
                f"({section.get('timeout_s')} s): the tethering software writes elsewhere"]
    return []


def probe_camera(rig, connected) -> DeviceReport:
    """Connect the camera (``connected()``: a context manager yielding it connected), read what it
    is (vendor, model, serial) and its exposure range, grab one frame at the shortest exposure of
    the ladder and read its levels. A rawfile camera the operator triggers is not exposed."""
    import tempfile

    section = dict(rig.camera)
    report = DeviceReport("camera", camera_link(section), False)
    ladder = sorted(float(t) for t in section.get("exposures_s", ()))
    try:
        with connected() as camera, tempfile.TemporaryDirectory(prefix="goniofrost-check-") as folder:
            report.exposure_range_s = _exposure_range(camera, section, ladder)
            report.identity = _identity_text(getattr(camera, "info", None) or {})
            if section.get("kind") == "rawfile" and not section.get("trigger_command"):
                report.frame = {"skipped": "the operator triggers this camera (no camera.trigger_command)"}
            else:  # it answers once it gave a frame
                frame = camera.capture(ladder[0], Path(folder) / "probe.dng")
                report.frame, identity = _levels(frame)
                report.identity = report.identity or _identity_text(identity)
            report.answers = True
    except Exception as exc:  # noqa: BLE001 - a camera that gives no frame is a finding, not a crash
        report.error, report.causes = _short(exc), camera_causes(section, exc)
    return report


def _exposure_range(camera, section: Mapping, ladder: list) -> tuple[float, float]:
    """The camera's stated range (pylon), a folder camera's shutter speeds, else the ladder's."""
    stated = getattr(camera, "exposure_range_s", None)
    if callable(stated):
        return tuple(stated())
    if section.get("shutter_speeds"):
        from calib.config import shutter_seconds
        seconds = [shutter_seconds(label) for label in section["shutter_speeds"]]
        return min(seconds), max(seconds)
    return ladder[0], ladder[-1]


def _identity_text(identity: Mapping) -> str | None:
    return ", ".join(f"{k} {identity[k]}" for k in ("vendor", "model", "serial") if identity.get(k)) or None


def _levels(frame) -> tuple[dict, dict]:
    """(the frame's exposure and levels per channel, the camera the RAW file names)."""
    import numpy as np

    from drivers.rawfile import raw_identity, read_raw

    raw = read_raw(frame.path)
    by_channel = [raw.linear[raw.channels == c] for c in range(3)]
    levels = {"exposure_s": float(frame.exposure_s),
              "median": [round(float(np.median(v)), 6) for v in by_channel],
              "p99": [round(float(np.percentile(v, 99)), 6) for v in by_channel],
              "saturated_fraction": float(raw.saturated.mean())}
    return levels, raw_identity(frame.path)
