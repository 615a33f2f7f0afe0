"""A rig file that treats the running twins as real hardware (``goniofrost sim --write-rig``).

``real_rig_document(source, resolved, service)`` returns the rig file ``source`` as a mapping with
``simulated: false``, no ``sim`` section, every driver section pointing at its running twin
(``SimulatedRig.resolved_rig()``: pty paths, loopback ports) and a ``rawfile`` camera
whose frames come from the simulated camera's service (``sim.camera_service``), keeping the
camera model, ladder and references of the original: the kinematics, and so a plan's
``rig.kinematic_hash``, stay those of the simulated rig. Its ``twins`` section (``sim.config``)
names the twins' clock speed-up (a dry run compares moves on their clock) and the service's port
(a capture names the material the simulated camera renders there).
"""
from __future__ import annotations

import shlex
import sys
from pathlib import Path

import yaml

from calib.config import KIND_ONLY_KEYS

# the source camera's keys a rawfile camera section does not have: its kind, and the keys only
# another kind reads (sim-pylon.yaml's pixel_format and gain_db), which a rawfile section refuses
_DROPPED_CAMERA_KEYS = ("kind",) + tuple(key for key, kinds in KIND_ONLY_KEYS.items() if "rawfile" not in kinds)


def real_rig_document(source, resolved, service, clock_speedup: float = 1.0) -> dict:
    """The rig file at ``source`` rewritten for the running simulation (see the module doc);
    ``resolved``: the running SimulatedRig's ``resolved_rig()``; ``clock_speedup``: its clock's."""
    doc = yaml.safe_load(Path(source).read_text())
    doc["simulated"] = False
    doc.pop("sim", None)
    for name, axis in resolved.axes.items():
        doc["axes"][name]["driver"] = dict(axis.driver)
    if resolved.lamp_driver:
        doc.setdefault("lamp", {})["driver"] = dict(resolved.lamp_driver)
    client = f"{shlex.quote(sys.executable)} -m sim.camera_service --port {service.port}"
    camera = {k: v for k, v in (doc.get("camera") or {}).items() if k not in _DROPPED_CAMERA_KEYS}
    doc["camera"] = {"kind": "rawfile", "folder": str(service.folder),
                     "trigger_command": f"{client} expose {{exposure_s}}",
                     "target_command": f"{client} target {{target}}", **camera}
    doc["twins"] = {"clock_speedup": float(clock_speedup), "camera_service_port": int(service.port)}
    return doc
