"""The Axis move logic (limits, timeout, waiting, arrival, retries, stop on error), the trapezoidal
sim motion, the driver-section validator and RigDevices' best-effort stop."""
from __future__ import annotations

import logging
import math

import pytest
import yaml

from drivers.axis import MOVE_TIMEOUT_MARGIN_S, Axis, AxisConfig, trapezoid_time
from drivers.config import validate_driver_section
from drivers.errors import (ArrivalError, AxisLimitError, DeviceFault, DeviceTimeout, ExceptionReply,
                            NotConnectedError)
from drivers.rig_devices import RigDevices
from goniofrost.core.errors import ConfigError
from goniofrost.core.rig_spec import AxisSpec, Role
from sim.clock import SimClock
from sim.motion import TrapezoidMotion


class ManualClock:
    """A clock that only moves when told (pure motion maths)."""

    def __init__(self):
        self.t = 0.0

    def now(self):
        return self.t

    def start_activity(self, sim_seconds):
        """TrapezoidMotion reports each planned move (nominal time is not what these tests check)."""


class MotionAxis(Axis):
    """An axis whose 'device' is a TrapezoidMotion in this process; counts every command and can
    fail its next N calls with a given error, or end moves short with a fault."""

    poll_s = 0.002

    def __init__(self, config, clock):
        super().__init__(config)
        self.motion = TrapezoidMotion(clock, 0.0, 1.0, 1.0)
        self.sent: list[str] = []
        self.fail_next, self.fail_with, self.fault = 0, DeviceTimeout, None
        self.lose_move_reply = 0  # moves carried out whose reply is then lost

    def _hook(self, what):
        if self.fail_next:
            self.fail_next -= 1
            raise self.fail_with(self.name, what)
        self.sent.append(what)

    def _attach(self, transport):
        self.transport = transport

    def _connect(self):
        self._hook("connect")

    def _close(self):
        pass

    def _read_identity(self):
        return {"protocol": "motion"}

    def _command_move(self, deg):
        self._hook(f"move {deg:g}")
        self.motion.start_move(deg)
        if self.lose_move_reply:
            self.lose_move_reply -= 1
            raise DeviceTimeout(self.name, f"move {deg:g}", None, "no reply")

    def _read_position(self):
        return self.motion.position()

    def _read_moving(self):
        self._hook("moving?")
        return self.motion.is_moving()

    def _command_stop(self):
        self._hook("stop")
        self.motion.stop()

    def _set_enabled(self, enabled):
        self._hook(f"enable {enabled}")

    def _read_fault(self):
        return self.fault

    def _apply_motion_profile(self, speed, accel):
        self._hook(f"profile {speed:g} {accel:g}")
        self.motion.set_profile(speed, accel)


def make_axis(speedup=50.0, **kw):
    cfg = AxisConfig("tilt", (-80.0, 80.0), kw.pop("speed", 20.0), 40.0, 0.0, 0.01, **kw)
    ax = MotionAxis(cfg, SimClock(speedup))
    ax.connect(None)  # its device lives in this process: no transport
    return ax


# ----- motion maths -------------------------------------------------------------------------------
def test_trapezoid_time_known_values():
    assert trapezoid_time(30.0, 10.0, 20.0) == pytest.approx(3.5)          # 0.5 + 2.5 + 0.5
    assert trapezoid_time(1.0, 10.0, 20.0) == pytest.approx(2 * math.sqrt(1 / 20))  # triangle
    assert trapezoid_time(-5.0, 10.0, 2.0) == trapezoid_time(5.0, 10.0, 2.0)
    assert trapezoid_time(0.0, 1.0, 1.0) == 0.0


def test_trapezoid_motion_profile_points():
    clock = ManualClock()
    m = TrapezoidMotion(clock, 0.0, speed=10.0, accel=20.0)
    assert m.start_move(30.0) == pytest.approx(3.5)
    expect = {0.25: (0.625, 5.0), 0.5: (2.5, 10.0), 1.0: (7.5, 10.0), 3.25: (29.375, 5.0), 3.5: (30.0, 0.0)}
    for t, (p, v) in expect.items():
        assert (m.position(t), m.velocity(t)) == (pytest.approx(p), pytest.approx(v))
    assert m.is_moving(3.49) and not m.is_moving(3.5)


def test_trapezoid_motion_backwards_and_triangle():
    m = TrapezoidMotion(ManualClock(), 10.0, speed=10.0, accel=20.0)
    m.start_move(9.0)  # 1 unit: never reaches 10 units/s
    half = math.sqrt(1 / 20)
    assert m.position(half) == pytest.approx(9.5) and m.velocity(half) == pytest.approx(-20 * half)
    assert m.position(2 * half) == 9.0


def test_stop_brakes_at_accel_and_stall_freezes():
    clock = ManualClock()
    m = TrapezoidMotion(clock, 0.0, speed=10.0, accel=20.0)
    m.start_move(100.0)
    clock.t = 1.0  # cruising at 10 from x = 7.5
    m.stop()
    assert m.target == pytest.approx(7.5 + 2.5) and m.position(1.5) == pytest.approx(10.0)
    assert not m.is_moving(1.5)
    m.start_move(50.0)
    clock.t = 2.0
    m.stall()
    frozen = m.position()
    assert m.is_moving(100.0) and m.position(100.0) == frozen and m.velocity(100.0) == 0.0
    m.stop()
    assert not m.is_moving() and m.position(100.0) == frozen


def test_retargeting_a_moving_axis_keeps_its_speed():
    clock = ManualClock()
    m = TrapezoidMotion(clock, 0.0, speed=10.0, accel=20.0)
    m.start_move(100.0)
    clock.t = 1.0
    m.start_move(50.0)
    assert m.velocity(1.0) == pytest.approx(10.0) and m.position(1.0) == pytest.approx(7.5)
    assert m.position(100.0) == 50.0


# ----- the move logic ----------------------------------------------------------------------------
def test_construction_connects_nothing():
    ax = MotionAxis(AxisConfig("tilt", (-80.0, 80.0), 20.0, 40.0), SimClock())
    assert ax.sent == []
    with pytest.raises(NotConnectedError, match="tilt: read position: not connected"):
        ax.move_to(1.0)
    with pytest.raises(NotConnectedError):
        ax.stop()


def test_connect_loads_the_profile():
    ax = make_axis()
    assert ax.sent == ["connect", "profile 20 40"]


def test_move_waits_and_arrives():
    ax = make_axis()
    status = ax.move_to(30.0)
    assert status.timeout_s == pytest.approx(1.5 * trapezoid_time(30.0, 20.0, 40.0) + MOVE_TIMEOUT_MARGIN_S)
    assert status.wait() == pytest.approx(30.0)
    assert status.done and ax.status().position_deg == pytest.approx(30.0)


def test_limit_error_names_everything_and_sends_nothing():
    ax = make_axis()
    ax.sent.clear()
    with pytest.raises(AxisLimitError) as info:
        ax.move_to(95.0)
    e = info.value
    assert (e.axis, e.start, e.target, e.limits, e.units) == ("tilt", 0.0, 95.0, (-80.0, 80.0), "deg")
    assert str(e) == ("tilt: move to 95 deg: target 95 deg outside limits [-80, 80] deg "
                      "(axis at 0 deg); nothing sent")
    assert ax.sent == []
    with pytest.raises(AxisLimitError):
        ax.move_to(float("nan"))


def test_move_within_tolerance_sends_nothing():
    ax = make_axis()
    ax.sent.clear()
    status = ax.move_to(0.005)
    assert status.done and status.wait() == 0.0 and ax.sent == []


def test_a_read_that_times_out_is_retried_a_bounded_number_of_times_each_retry_logged(caplog):
    ax = make_axis(retries=2)
    ax.sent.clear()
    ax.fail_next = 2
    with caplog.at_level(logging.INFO, logger="drivers.axis"):
        assert ax.is_moving() is False
    assert ax.sent == ["moving?"]
    assert [r.getMessage() for r in caplog.records] == [
        "tilt: read_moving: retry 1 of 2 after tilt: moving?: no reply",
        "tilt: read_moving: retry 2 of 2 after tilt: moving?: no reply"]
    ax.fail_next = 3
    with pytest.raises(DeviceTimeout, match="tilt: moving\\?: no reply"):
        ax.is_moving()  # 3 attempts, all lost: the axis is declared faulted


def test_a_move_the_device_took_is_not_sent_again_when_its_reply_is_lost(caplog):
    ax = make_axis(retries=2)
    ax.sent.clear()
    ax.lose_move_reply = 1
    with caplog.at_level(logging.INFO, logger="drivers.axis"):
        assert ax.move_to(5.0).wait() == pytest.approx(5.0)
    assert ax.sent.count("move 5") == 1  # read back (moving), never repeated
    assert "tilt: reply to the move to 5 deg lost (tilt: move 5: no reply); read back: the device took it" \
        in [r.getMessage() for r in caplog.records]


def test_a_move_the_device_never_took_is_sent_again_after_the_read_back():
    ax = make_axis(retries=2)
    ax.sent.clear()
    ax.fail_next = 1  # the move request itself is lost: nothing moves
    assert ax.move_to(5.0).wait() == pytest.approx(5.0)
    assert ax.sent[:2] == ["moving?", "move 5"]  # read back: at rest at 0, not 5; then sent once
    ax.sent.clear()
    ax.fail_next = 5  # move, read back (x3: retried reads) ... all lost
    with pytest.raises(DeviceTimeout):
        ax.move_to(10.0)
    assert ax.sent == ["stop"] and ax.fail_next == 0  # the stop after the error got through


def test_refusals_are_not_retried_and_stop_the_axis():
    ax = make_axis(retries=2)
    ax.sent.clear()
    ax.fail_next, ax.fail_with = 1, ExceptionReply
    with pytest.raises(ExceptionReply):
        ax.move_to(10.0)
    assert ax.sent == ["stop"]


def test_error_while_waiting_stops_the_axis():
    ax = make_axis(speedup=5.0)
    status = ax.move_to(60.0)
    ax.fail_next, ax.fail_with = 3, DeviceTimeout
    with pytest.raises(DeviceTimeout):
        status.wait()
    assert ax.sent[-1] == "stop"
    ax.motion.clock.sleep(2.0)
    assert not ax.motion.is_moving() and ax.motion.position() < 59.0


def test_stall_is_a_device_fault_and_stops():
    ax = make_axis(speedup=5.0, stall_s=0.2)
    status = ax.move_to(60.0)
    ax.motion.clock.sleep(0.5)
    ax.motion.stall()
    with pytest.raises(DeviceFault, match="stall: position frozen"):
        status.wait()
    assert ax.sent[-1] == "stop" and not ax.motion.is_moving()


def test_move_that_does_not_finish_in_time_is_a_timeout():
    ax = make_axis(speedup=1.0)
    status = ax.move_to(60.0)
    with pytest.raises(DeviceTimeout, match="move not finished within 0.1 s"):
        status.wait(timeout=0.1)
    assert ax.sent[-1] == "stop"


def test_short_arrival_reports_the_fault_or_an_arrival_error():
    ax = make_axis()
    status = ax.move_to(30.0)
    ax.motion.start_move(20.0)  # the device ends somewhere else
    with pytest.raises(ArrivalError, match="stopped at 20.0000 deg, not within 0.01 deg of the target 30 deg"):
        status.wait()
    status = ax.move_to(40.0)
    ax.motion.start_move(25.0)
    ax.fault = "following error"
    with pytest.raises(DeviceFault) as info:
        status.wait()
    assert info.value.causes == ["following error"]


def test_axis_config_from_a_typed_axis_spec():
    spec = AxisSpec("camera_arm", Role.CAMERA_ARM, (8, 172), 30, 60, 90, 0.02, driver={"retries": 1})
    assert AxisConfig.from_spec(spec) == AxisConfig("camera_arm", (8.0, 172.0), 30.0, 60.0, 90, 0.02, retries=1)
    assert AxisConfig.from_spec(spec, stall_s=0.3, retries=4) == \
        AxisConfig("camera_arm", (8.0, 172.0), 30.0, 60.0, 90, 0.02, retries=4, stall_s=0.3)


def test_the_one_stop_path_tries_every_axis_and_never_raises():
    from goniofrost.rig.stop import stop_axes

    axes = {n: make_axis() for n in ("a", "b", "c")}
    for ax in axes.values():
        ax.move_to(50.0)
    axes["a"].fail_next = 99
    stops = stop_axes(RigDevices(axes).axes)
    assert [s.confirmed for s in stops] == [False, True, True] and stops[0].error
    assert "stop" in axes["b"].sent and "stop" in axes["c"].sent  # then asked whether they still move


# ----- driver sections ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def sim_rig():
    with open("config/rigs/sim.yaml", encoding="utf-8") as f:
        return yaml.safe_load(f)


def test_sim_rig_driver_sections_are_valid(sim_rig):
    for name, axis in sim_rig["axes"].items():
        validate_driver_section(axis["driver"], "sim.yaml", f"axes.{name}.driver")
    validate_driver_section(sim_rig["lamp"]["driver"], "sim.yaml", "lamp.driver")


@pytest.mark.parametrize("change, message", [
    ({"speed": 3}, "sim.yaml: axes.sample_yaw.driver.speed: expected one of the keys protocol, port, id, "
                   "baud, model, counts_per_deg, reboot_after_fault, reply_timeout_ms, retries "
                   "(protocol dynamixel), found \"unknown key 'speed'\""),
    ({"id": 300}, "sim.yaml: axes.sample_yaw.driver.id: expected a Dynamixel ID 0-252, found 300"),
    ({"id": None}, "sim.yaml: axes.sample_yaw.driver.id: expected a Dynamixel ID 0-252, found None"),
    ({"counts_per_deg": -1.0}, "sim.yaml: axes.sample_yaw.driver.counts_per_deg: expected a positive number"),
    ({"baud": 12345}, "sim.yaml: axes.sample_yaw.driver.baud: expected a baud rate among"),
    ({"protocol": "canopen"}, "sim.yaml: axes.sample_yaw.driver.protocol: expected one of dynamixel, "
                              "modbus-tcp, modbus-rtu, smc100, found 'canopen'"),
])
def test_bad_driver_sections_name_the_key(sim_rig, change, message):
    section = {**sim_rig["axes"]["sample_yaw"]["driver"], **change}
    with pytest.raises(ConfigError) as info:
        validate_driver_section(section, "sim.yaml", "axes.sample_yaw.driver")
    assert str(info.value).startswith(message)


def test_missing_key_and_lamp_without_a_device(sim_rig):
    section = dict(sim_rig["axes"]["sample_yaw"]["driver"])
    del section["port"]
    with pytest.raises(ConfigError, match=r"driver.port: expected a serial device path .* found 'nothing'"):
        validate_driver_section(section, "sim.yaml", "axes.sample_yaw.driver")
    lamp = {k: v for k, v in sim_rig["lamp"]["driver"].items() if k != "device"}
    with pytest.raises(ConfigError, match="lamp.driver.device: expected either device"):
        validate_driver_section(lamp, "sim.yaml", "lamp.driver")
