"""Start every simulated device of a rig on one SimClock and report their endpoints.

``SimulatedRig(rig).start()`` opens a pty per serial device and a loopback port per Modbus TCP
device; ``resolved_rig()`` is the rig spec with those endpoints, ready for ``RigDevices.from_rig``.
"""
from __future__ import annotations

import copy
import os

from goniofrost.core.rig_spec import AxisSpec, RigSpec

from .clock import SimClock
from .config import check_fault_axes, validate_sim_section
from .faults import LAMP_KINDS, SILENT_KINDS, TIMED_KINDS
from .lamp_model import LampModel

# A twin answers from a thread of this process: on a busy computer (a test suite beside other
# work, a laptop rehearsing) its reply can take longer than a real bus's 100 ms, the Dynamixel
# driver's default, kept for real servos (measured: the full suite at load 5 to 9 failed 1 to 5
# tests per run on "no status packet" at 100 ms; at 300 ms it passed). A rig file's own
# reply_timeout_ms wins.
TWIN_REPLY_TIMEOUT_MS = {"dynamixel": 300.0}
# A host slower still (a test suite at load 8-11 on 2 cores) sets this to give every twin's driver
# that reply timeout (ms), whatever its protocol. An axis drilled to fall silent keeps the timeout
# it would have without it: a drilled silence must time out as promptly as a real device's would.
SLOW_HOST_ENV = "GONIOFROST_TWIN_REPLY_TIMEOUT_MS"


def _dynamixel(clock, axis: AxisSpec, section, lamp_model, lamp_section):
    from .dynamixel_servo import SimulatedDynamixel
    cpd = float(section["counts_per_deg"])
    return SimulatedDynamixel(clock, id=section["id"], baud=section.get("baud", 57600),
                              model=section.get("model", "XM430-W350"), counts_per_deg=cpd,
                              position=round(axis.home_deg * cpd))


def _smc100(clock, axis: AxisSpec, section, lamp_model, lamp_section):
    from .smc100 import SimulatedSMC100
    upd = float(section.get("units_per_deg", 1.0))
    lo, hi = axis.limits_deg
    return SimulatedSMC100(clock, address=section.get("address", 1), baud=section.get("baud", 57600),
                           units_per_deg=upd, position=axis.home_deg * upd,
                           velocity=axis.speed_deg_s * upd, acceleration=axis.accel_deg_s2 * upd,
                           limits=(lo * upd - 1.0, hi * upd + 1.0))  # SL/SR just outside the axis limits


def _modbus(clock, axis: AxisSpec, section, lamp_model, lamp_section, interlock_input: int = 0):
    from .modbus_drive import SimulatedModbusDrive
    rtu = section["protocol"] == "modbus-rtu"
    lamp = dict(coil=lamp_section["coil"], photodiode_register=lamp_section["photodiode_register"]) \
        if lamp_section else {}
    extra = dict(transport="rtu", baud=section.get("baud", 115200)) if rtu else dict(transport="tcp", port=0)
    return SimulatedModbusDrive(clock, device_id=section.get("device_id", 1),
                                steps_per_deg=section["steps_per_deg"],
                                word_order=section.get("word_order", "big"),
                                register_map=section.get("register_map", "oriental-az"),
                                position_deg=axis.home_deg, lamp=lamp_model,
                                interlock_input=interlock_input, **lamp, **extra)


DEVICE_FACTORIES = {"dynamixel": _dynamixel, "smc100": _smc100, "modbus-tcp": _modbus, "modbus-rtu": _modbus}


class SimulatedRig:
    """Every simulated device of one rig, sharing one SimClock and one LampModel.

    ``speedup``: simulated seconds per real second (default: the rig's ``sim.clock_speedup``, else 1).
    ``seed``: seeds the lamp's wobble. Attributes: ``clock``, ``lamp_model``, ``endpoints`` (after start),
    ``sim`` (the rig's ``sim`` section, checked, defaults filled in), ``faults`` (the fault drills
    of ``sim.faults``; see ``arm_faults``). As a capture session's ``Hardware.simulation``
    (``goniofrost.rig.contract.Simulation``) it arms the drills before each plan sample and
    journals and restores its state (``checkpoint``, ``restore``).
    """

    def __init__(self, rig: RigSpec, speedup: float | None = None, seed: int = 0) -> None:
        self.rig = rig
        self.axes = dict(rig.axes)
        self.lamp_section = dict(rig.lamp_driver) if rig.lamp_driver else None
        self.sim = validate_sim_section(rig.sim or {}, rig.source, "sim")
        self.clock = SimClock(float(speedup if speedup is not None else self.sim["clock_speedup"]))
        self.lamp_model = LampModel(self.clock, drift_per_hour=self.sim["lamp"]["drift_per_hour"], seed=seed)
        self.faults = [dict(fault) for fault in self.sim["faults"]]
        check_fault_axes(self.faults, self.axes, rig.source)
        self._armed: list[int] = []     # positions in self.faults, in the order armed
        self._retired: set[int] = set()  # drills that struck in an earlier run: never armed again
        self._devices: dict = {}
        self.endpoints: dict = {}

    def _lamp_host(self) -> str | None:
        return self.lamp_section.get("device") if self.lamp_section else None

    def start(self) -> dict:
        """Start every device; return axis name (and "lamp") -> endpoint entry. Idempotent."""
        if self._devices:
            return dict(self.endpoints)
        try:
            for name, axis in self.axes.items():
                section = axis.driver
                lamp = self.lamp_section if self._lamp_host() == name else None
                extra = self._interlock_of(name)
                device = DEVICE_FACTORIES[section["protocol"]](self.clock, axis, section, self.lamp_model, lamp, **extra)
                self.endpoints[name] = device.start()
                self._devices[name] = device
        except BaseException:
            self.stop()
            raise
        host = self._lamp_host()
        if host is not None:
            self.endpoints["lamp"] = self._devices[host].lamp_entry()
        return dict(self.endpoints)

    def _interlock_of(self, name: str) -> dict:
        """{"interlock_input": address} for the drive the rig's suspenders.interlock names, else {}."""
        interlock = (getattr(self.rig, "suspenders", None) or {}).get("interlock")
        return {"interlock_input": interlock["input"]} if interlock and interlock["device"] == name else {}

    def stop(self) -> None:
        """Stop every device and release its pty or port (idempotent)."""
        for device in self._devices.values():
            device.stop()
        self._devices.clear()

    def device(self, name: str):
        """The simulated device of axis ``name`` (for fault injection and ground truth)."""
        return self._devices[name]

    def arm_faults(self, sample_index: int) -> list[dict]:
        """Arm every fault drill whose ``at_sample`` <= ``sample_index`` and that was neither armed
        nor retired yet: it strikes when its axis next starts a move, once. Call before each plan
        sample (after start()); returns the drills armed by this call, in rig-file order, each as
        ``{"drill": position in sim.faults, "axis", "kind", "at_sample"}``."""
        armed = []
        for i, fault in enumerate(self.faults):
            if i not in self._armed and i not in self._retired and fault["at_sample"] <= sample_index:
                self._arm(fault)
                self._armed.append(i)
                armed.append(self._drill(i))
        return armed

    def _arm(self, fault: dict) -> None:
        """A device fault waits for its axis's next move; a timed one (sim.faults.TIMED_KINDS) starts now."""
        kind = fault["kind"]
        if kind in LAMP_KINDS:
            self.lamp_model.interrupt(fault.get("level", 0.0), fault["duration_s"])
        elif kind == "interlock_open":
            self._devices[fault["axis"]].open_interlock(fault["duration_s"])
        elif kind == "silent":
            self._devices[fault["axis"]].go_silent(fault["duration_s"])
        else:
            self._devices[fault["axis"]].arm_fault(kind)

    def struck_faults(self) -> list[dict]:
        """The drills armed by ``arm_faults`` that have struck so far, in rig-file order."""
        struck = [i for i in self._armed if self.faults[i]["kind"] in TIMED_KINDS]  # strike when armed
        waiting = [i for i in self._armed if self.faults[i]["kind"] not in TIMED_KINDS]
        for axis in {self.faults[i]["axis"] for i in waiting}:
            on_axis = [i for i in waiting if self.faults[i]["axis"] == axis]  # in the order armed
            struck += on_axis[:len(self._devices[axis].struck)]
        return [self._drill(i) for i in sorted(struck)]

    def retire_faults(self, drills) -> None:
        """Never arm these drills (``{"drill", "axis", "kind", "at_sample"}`` as returned above): they
        struck in an earlier run of the session, and a drill rehearses once. A drill whose entry in
        the rig file changed since is not retired."""
        for drill in drills:
            i = drill.get("drill")
            if isinstance(i, int) and 0 <= i < len(self.faults) and self._drill(i) == drill:
                self._retired.add(i)

    def _drill(self, i: int) -> dict:
        return {"drill": i, **self.faults[i]}

    def checkpoint(self) -> dict:
        """The simulated state that decides what comes next: the clock's nominal time (s) and where
        each axis is (device units). Journaled with each sample, so that a resumed run can
        ``restore`` it and measure what an uninterrupted run would have."""
        return {"nominal_time": self.clock.nominal_time(),
                "positions": {name: float(device.motion.position()) for name, device in self._devices.items()}}

    def restore(self, state: dict) -> None:
        """Put the simulation back into a ``checkpoint``: axes at rest where they were, nominal time
        as it was (the lamp's drift and the frames' noise follow it)."""
        for name, position in state["positions"].items():
            self._devices[name].place(position)
        self.clock.restore_nominal_time(state["nominal_time"])

    def true_joints_deg(self) -> dict[str, float]:
        """Where every simulated axis really is (degrees), by axis name."""
        return {name: dev.true_position_deg() for name, dev in self._devices.items()}

    def resolved_rig(self) -> RigSpec:
        """The rig spec given, with the driver endpoints made at ``start()`` in its driver sections."""
        if not self._devices:
            raise RuntimeError("SimulatedRig.start() first: the endpoints are made at start")
        drivers = {}
        for name, axis in self.axes.items():
            entry, section = self.endpoints[name], copy.deepcopy(dict(axis.driver))
            if section["protocol"] == "modbus-tcp":
                host, port = entry["endpoint"].rsplit(":", 1)
                section["host"], section["port"] = host, int(port)
            else:
                section["port"] = entry["endpoint"]
            if section["protocol"] == "modbus-rtu":
                section["parity"] = "N"  # Linux ptys refuse parity; the simulated drive serves 8N1
            timeout_ms = self._twin_reply_timeout_ms(name, section["protocol"])
            if timeout_ms is not None:  # None: the driver's own default
                section.setdefault("reply_timeout_ms", timeout_ms)
            drivers[name] = section
        return self.rig.with_drivers(drivers)

    def _twin_reply_timeout_ms(self, name: str, protocol: str) -> float | None:
        """The reply timeout (ms) a driver of this twin gets unless the rig file gives one (None:
        the driver's default): ``SLOW_HOST_ENV``'s when set and no drill silences the axis, else
        ``TWIN_REPLY_TIMEOUT_MS``'s."""
        slow = os.environ.get(SLOW_HOST_ENV)
        if slow and not any(fault.get("axis") == name and fault.get("kind") in SILENT_KINDS for fault in self.faults):
            return float(slow)
        return TWIN_REPLY_TIMEOUT_MS.get(protocol)

    def __enter__(self) -> "SimulatedRig":
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()
