"""A rig file that treats the running twins as real hardware (``goniofrost sim --write-rig``).

``real_rig_document`` returns the rig file with ``simulated: false``, drivers pointing at the
running twins, a ``rawfile`` camera served by ``sim.camera_service``, and a ``twins`` section; the
kinematics, hence the plan's ``rig.kinematic_hash``, stay those of the simulated rig.
"""
from __future__ import annotations

import shlex
import sys
from pathlib import Path

import yaml

from calib.config import kind_only_keys


def _dropped_camera_keys() -> tuple:
    """The source camera's keys a rawfile camera section does not have: its kind, and the keys only
    another kind reads (sim-pylon.yaml's pixel_format and gain_db), which a rawfile section refuses."""
    return ("kind",) + tuple(key for key, kinds in kind_only_keys()[1].items() if "rawfile" not in kinds)


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
    dropped = _dropped_camera_keys()
    camera = {k: v for k, v in (doc.get("camera") or {}).items() if k not in dropped}
    doc["camera"] = {"kind": "rawfile", "folder": str(service.folder),
                     "trigger_command": f"{client} expose {{exposure_s}}",
                     "target_command": f"{client} target {{target}}", **camera}
    doc["twins"] = {"clock_speedup": float(clock_speedup), "camera_service_port": int(service.port)}
    return doc
