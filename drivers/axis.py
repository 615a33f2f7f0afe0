"""The one Axis contract: move to an angle and get a status to wait on, with the move logic written once.

A driver subclasses ``Axis`` and supplies protocol hooks (``_command_move``, ``_read_position``,
...) in degrees and deg/s. The base class checks limits, times out, checks arrival, retries what is
safe to repeat and, on any error during a move, stops the axis before re-raising. Connecting is
``connect(transport)`` on a connection the rig layer opened.
"""
from __future__ import annotations

import logging
import math
import time
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass, field

from goniofrost.core.rig_spec import AxisSpec

from .errors import (ArrivalError, AxisLimitError, ChecksumError, DeviceError, DeviceFault,
                     DeviceTimeout, NotConnectedError, ProtocolError)

log = logging.getLogger(__name__)

MOVE_TIMEOUT_FACTOR = 1.5  # planned profile time x this ...
MOVE_TIMEOUT_MARGIN_S = 2.0  # ... + this (start-up latency, polling, settling), seconds
TRANSIENT_ERRORS = (DeviceTimeout, ChecksumError, ProtocolError)  # worth retrying once more


def trapezoid_time(distance: float, speed: float, accel: float) -> float:
    """Duration in s of a rest-to-rest trapezoidal move over ``distance`` (any unit) at ``speed``
    (unit/s) and ``accel`` (unit/s^2); a triangle when the cruise speed is never reached."""
    distance = abs(float(distance))
    if distance == 0.0:
        return 0.0
    if distance * accel <= speed * speed:  # triangle: accelerate half-way, then brake
        return 2.0 * math.sqrt(distance / accel)
    return distance / speed + speed / accel


@dataclass(frozen=True)
class AxisConfig:
    """What every axis needs besides its driver section (angles in degrees, speeds in deg/s).

    ``retries``: extra attempts of an idempotent read (or a repeatable write) after a reply timeout
    or a damaged reply (from the driver section). ``stall_s``: real seconds the position may stay frozen while the device reports motion
    before the move is declared stalled.
    """

    name: str
    limits_deg: tuple[float, float]
    speed_deg_s: float
    accel_deg_s2: float
    home_deg: float = 0.0
    tolerance_deg: float = 0.01
    retries: int = 2
    stall_s: float = 2.0

    @classmethod
    def from_spec(cls, spec: AxisSpec, **overrides) -> "AxisConfig":
        """Build from a rig's typed axis spec; its driver section's ``retries`` (when given) and
        then ``overrides`` (any field, e.g. ``stall_s``) replace the defaults."""
        extra = {"retries": int(spec.driver["retries"])} if spec.driver.get("retries") is not None else {}
        lo, hi = spec.limits_deg
        return cls(name=spec.name, limits_deg=(float(lo), float(hi)), speed_deg_s=float(spec.speed_deg_s),
                   accel_deg_s2=float(spec.accel_deg_s2), home_deg=float(spec.home_deg),
                   tolerance_deg=float(spec.tolerance_deg), **(extra | overrides))


@dataclass
class AxisStatus:
    """A snapshot of an axis: position (deg), moving, enabled, fault text (None when healthy), details."""

    position_deg: float
    moving: bool
    enabled: bool
    fault: str | None = None
    details: dict = field(default_factory=dict)


class MoveStatus:
    """A started move to wait on: ``wait()`` returns the final position in degrees or raises.

    ``timeout_s`` (real seconds) comes from the distance, speed and acceleration plus a margin.
    """

    def __init__(self, axis: "Axis", start: float, target: float, timeout_s: float,
                 done: bool = False) -> None:
        self.axis, self.start, self.target, self.timeout_s = axis, start, target, timeout_s
        self.done = done
        self.final_deg: float | None = start if done else None

    def __repr__(self) -> str:
        return (f"MoveStatus({self.axis.name}: {self.start:g} -> {self.target:g} deg, "
                f"done={self.done})")

    def wait(self, timeout: float | None = None) -> float:
        """Block until the move ends; return the final position (deg).

        Raises DeviceTimeout (not finished in time), DeviceFault (fault or stall), ArrivalError (stopped
        outside the tolerance) or any communication error; the axis is commanded to stop first.
        """
        if self.done:
            return self.final_deg
        try:
            self.final_deg = self.axis._wait_until_stopped(self, self.timeout_s if timeout is None else timeout)
        except BaseException:
            self.axis._stop_after_error(f"waiting for {self!r}")
            raise
        self.done = True
        return self.final_deg


class Axis(ABC):
    """One motorised rotation axis in physical units (degrees). Subclasses supply the protocol hooks."""

    units = "deg"
    poll_s = 0.01  # real seconds between two status polls while waiting

    def __init__(self, config: AxisConfig) -> None:
        self.config = config
        self.name = config.name
        self._connected = False
        self._enabled = False
        # A stop whose every attempt went unanswered (reply timeouts), nothing heard since: the
        # next stop is sent once, not retried (``_send_stop``).
        self._stop_unanswered = False
        self._rest_deg: float | None = None  # ``confirmed_at_rest_deg``

    # ----- public contract -------------------------------------------------------------------
    def connect(self, transport) -> None:
        """Take ``transport`` (a ``drivers.transport.ByteTransport`` the rig layer opened; the axis
        owns it from now on and closes it), check the device answers, then load the speed and
        acceleration of the configuration. On failure the transport is closed and the error re-raised.

        The handshake (``_connect``) only reads and sets, so it is retried like a read.
        """
        self._attach(transport)
        try:
            self._call(self._connect)
            self._connected = True
            self._call(self._apply_motion_profile, self.config.speed_deg_s, self.config.accel_deg_s2)
        except BaseException:
            self._connected = False
            self._close()
            raise

    def close(self) -> None:
        """Close the connection (idempotent). Does not stop or disable the axis."""
        if self._connected:
            self._connected = False
            self._close()

    def identity(self) -> dict:
        """What the device says it is (model, firmware, serial number, ... as its protocol gives;
        read-only: nothing is enabled or moved). Keys are the driver's; ``protocol`` always."""
        self._require_connected("read identity")
        return self._call(self._read_identity)

    @property
    def connected(self) -> bool:
        return self._connected

    @property
    def confirmed_at_rest_deg(self) -> float | None:
        """Where ``confirm_stopped`` last found the axis at rest (degrees), while no command that
        can move it (a move, a home) has gone out since and the connection stayed open; else None.
        The rig's release stops only the axes without one: one stop per axis per exit."""
        return self._rest_deg if self._connected else None

    def move_to(self, deg: float) -> MoveStatus:
        """Start a move to ``deg`` (within the limits) and return a MoveStatus to wait on.

        A target within the tolerance of the current position sends nothing. Raises AxisLimitError
        (nothing sent) or a DeviceError (after which the axis was commanded to stop).
        """
        deg = float(deg)
        start = self.position()
        self._check_limits(start, deg)
        if abs(deg - start) <= self.config.tolerance_deg:
            return MoveStatus(self, start, deg, 0.0, done=True)
        return self._start(start, deg)

    def home(self) -> MoveStatus:
        """Run the device's homing (or move to ``home_deg``); wait on the result like a move."""
        self._require_connected("home")
        try:
            start = self._call(self._read_position)
        except DeviceError:
            start = float("nan")  # some devices cannot report a position before homing
        lo, hi = self.config.limits_deg
        self._rest_deg = None  # from the command on, it may move
        try:  # a home search is not repeated: a lost reply fails the home (nothing to read back)
            self._command_home()
        except BaseException:
            self._stop_after_error(f"home to {self.config.home_deg:g} {self.units}")
            raise
        return MoveStatus(self, start, self.config.home_deg, self.move_timeout_s(hi - lo))

    def position(self) -> float:
        """Present position in degrees."""
        self._require_connected("read position")
        return self._call(self._read_position)

    def referenced(self) -> bool:
        """False when the device refuses moves until it is homed (an SMC100 after power-up, a
        disable or a failed home: NOT REFERENCED); True for devices that need no reference. A read."""
        self._require_connected("read the reference state")
        return bool(self._call(self._read_referenced))

    def is_moving(self) -> bool:
        """True while the device reports motion."""
        self._require_connected("read moving")
        return bool(self._call(self._read_moving))

    def stop(self) -> None:
        """Command the axis to stop (decelerate); returns without waiting."""
        self._require_connected("stop")
        self._send_stop()

    def confirm_stopped(self, timeout_s: float | None = None) -> float:
        """Wait until the device reports the axis at rest; return its position in degrees.

        A device in a fault state that no longer drives its motor counts as at rest. Raises a
        DeviceError when the device cannot tell (no reply, a damaged reply, ...) or still reports
        motion after ``timeout_s`` real seconds (default ``stop_timeout_s()``).
        """
        self._require_connected("confirm the stop")
        timeout_s = self.stop_timeout_s() if timeout_s is None else float(timeout_s)
        t_end = time.monotonic() + timeout_s
        while True:
            at_rest, pos = self._call(self._read_at_rest)
            if at_rest:
                self._rest_deg = pos
                return pos
            if time.monotonic() > t_end:
                raise DeviceTimeout(self.name, "stop", pos, f"still reports motion {timeout_s:.1f} s after the stop")
            time.sleep(self.poll_s)

    def stop_timeout_s(self) -> float:
        """Real seconds to allow a commanded stop: braking from full speed, with the margins of a move."""
        return MOVE_TIMEOUT_FACTOR * self.config.speed_deg_s / self.config.accel_deg_s2 + MOVE_TIMEOUT_MARGIN_S

    def enable(self) -> None:
        """Energise the motor (torque on / READY); required before moves on most devices."""
        self._require_connected("enable")
        self._call(self._set_enabled, True)
        self._enabled = True

    def disable(self) -> None:
        """De-energise the motor (torque off / DISABLE)."""
        self._require_connected("disable")
        self._call(self._set_enabled, False)
        self._enabled = False

    def status(self) -> AxisStatus:
        """Position, motion, enable state, fault text (None when healthy) and driver details."""
        self._require_connected("read status")
        return AxisStatus(position_deg=self._call(self._read_position), moving=bool(self._call(self._read_moving)),
                          enabled=self._enabled, fault=self._call(self._read_fault),
                          details=self._status_details())

    def move_timeout_s(self, distance_deg: float) -> float:
        """Real seconds to allow for a move over ``distance_deg`` before calling it a timeout."""
        t = trapezoid_time(distance_deg, self.config.speed_deg_s, self.config.accel_deg_s2)
        return MOVE_TIMEOUT_FACTOR * t + MOVE_TIMEOUT_MARGIN_S

    # ----- the move logic, written once -------------------------------------------------------
    def _check_limits(self, start: float, target: float) -> None:
        lo, hi = self.config.limits_deg
        if not (lo <= target <= hi) or math.isnan(target):
            raise AxisLimitError(self.name, start, target, (lo, hi), self.units)

    def _start(self, start: float, target: float) -> MoveStatus:
        """Send the move command; on failure stop and re-raise."""
        self._rest_deg = None  # from the command on, it may move
        try:
            self._send_move(target)
        except BaseException:
            self._stop_after_error(f"move to {target:g} {self.units}")
            raise
        return MoveStatus(self, start, target, self.move_timeout_s(abs(target - start)))

    def _send_move(self, target: float) -> None:
        """The move command, never blindly repeated: after a lost or damaged reply the device is
        asked whether it took the move (``_move_taken``, reads retried); a move it took is not
        sent again, one it shows it never took is sent again (up to ``config.retries`` times)."""
        for attempt in range(self.config.retries + 1):
            try:
                self._command_move(target)
                return
            except TRANSIENT_ERRORS as exc:
                if not getattr(exc, "transient", True):
                    raise
                taken = self._call(self._move_taken, target)
                log.info("%s: reply to the move to %g %s lost (%s); read back: %s", self.name, target,
                         self.units, exc, "the device took it" if taken else "not taken")
                if taken:
                    return
                if attempt == self.config.retries:
                    raise
                log.info("%s: sending the move to %g %s again (attempt %d of %d)", self.name, target,
                         self.units, attempt + 2, self.config.retries + 1)

    def _wait_until_stopped(self, status: MoveStatus, timeout_s: float) -> float:
        """Poll until the device stops; check for stalls, faults and arrival within tolerance."""
        t_end = time.monotonic() + timeout_s
        last_pos, last_change = None, time.monotonic()
        while True:
            moving = self._call(self._read_moving)
            pos = self._call(self._read_position)
            if not moving:
                return self._check_arrival(status, pos)
            now = time.monotonic()
            if last_pos is None or abs(pos - last_pos) > 1e-9:
                last_pos, last_change = pos, now
            elif now - last_change > self.config.stall_s:
                raise DeviceFault(self.name, f"move to {status.target:g} {self.units}", pos,
                                  [f"stall: position frozen at {pos:.4f} {self.units} for "
                                   f"{self.config.stall_s:g} s while the device reports motion"])
            if now > t_end:
                raise DeviceTimeout(self.name, f"move to {status.target:g} {self.units}", pos,
                                    f"move not finished within {timeout_s:.1f} s")
            time.sleep(self.poll_s)

    def _check_arrival(self, status: MoveStatus, pos: float) -> float:
        if abs(pos - status.target) <= self.config.tolerance_deg:
            return pos
        fault = self._call(self._read_fault)
        if fault:
            raise DeviceFault(self.name, f"move to {status.target:g} {self.units}", pos, [fault])
        raise ArrivalError(self.name, status.target, pos, self.config.tolerance_deg, self.units)

    def _stop_after_error(self, context: str) -> None:
        """Best-effort stop after an error; never raises (the original error matters more)."""
        if not self._connected:
            return
        try:
            self._send_stop()
        except Exception as exc:  # noqa: BLE001 - the caller re-raises the original error
            log.warning("%s: stop after error in %s failed: %s", self.name, context, exc)

    def _send_stop(self) -> None:
        """The stop command, retried like any repeatable command; but sent once only while an earlier
        stop of this axis went unanswered and nothing has been heard from the device since, so that a
        pulled cable does not cost every stopping layer its retries. Each stop still goes out.
        """
        try:
            if self._stop_unanswered:
                self._command_stop()
            else:
                self._call(self._command_stop)
        except DeviceTimeout:
            self._stop_unanswered = True
            raise
        except TRANSIENT_ERRORS:  # a damaged reply: the device was heard
            self._stop_unanswered = False
            raise
        self._stop_unanswered = False

    def _call(self, hook: Callable, *args):
        """Call a hook that is safe to repeat (a read, a stop, a set-point that repeats harmlessly),
        retrying reply timeouts and damaged replies up to ``config.retries`` more times, each retry
        logged (the device log of a session)."""
        for attempt in range(self.config.retries + 1):
            try:
                result = hook(*args)
                self._stop_unanswered = False  # the device answered
                return result
            except TRANSIENT_ERRORS as exc:
                if attempt == self.config.retries or not getattr(exc, "transient", True):
                    raise
                log.info("%s: %s: retry %d of %d after %s", self.name, hook.__name__.lstrip("_"),
                         attempt + 1, self.config.retries, exc)

    def _require_connected(self, command: str) -> None:
        if not self._connected:
            raise NotConnectedError(self.name, command)

    def _status_details(self) -> dict:
        """Extra driver-specific status (override to add e.g. temperature, raw state)."""
        return {}

    # ----- protocol hooks (degrees, deg/s, deg/s^2) -----------------------------------------
    @abstractmethod
    def _attach(self, transport) -> None:
        """Keep the connection the rig layer opened (nothing is sent yet)."""

    @abstractmethod
    def _connect(self) -> None:
        """Check the device answers on the attached transport (e.g. ping, model number)."""

    @abstractmethod
    def _close(self) -> None:
        """Close the transport (idempotent)."""

    @abstractmethod
    def _read_identity(self) -> dict:
        """The device's identity as its protocol gives it (read-only)."""

    def _move_taken(self, target: float) -> bool:
        """After a lost reply to the move to ``target``: did the device take it? By default: it
        reports motion, or stands at the target. Drivers that can read the set-point override."""
        if self._read_moving():
            return True
        return abs(self._read_position() - target) <= self.config.tolerance_deg

    @abstractmethod
    def _command_move(self, deg: float) -> None:
        """Send an absolute move to ``deg``; return without waiting."""

    @abstractmethod
    def _read_position(self) -> float:
        """Present position in degrees."""

    @abstractmethod
    def _read_moving(self) -> bool:
        """True while moving; raise DeviceFault if the reply shows a fault."""

    def _read_at_rest(self) -> tuple[bool, float]:
        """(at rest, position in degrees), without raising on a fault the device reports: used to
        confirm a stop, when the device may well be in a fault state. Drivers whose
        ``_read_moving`` raises on a fault override this."""
        return not self._read_moving(), self._read_position()

    def _read_referenced(self) -> bool:
        """Whether the device accepts moves without a home first; by default it does."""
        return True

    def _command_home(self) -> None:
        """Start homing; the default moves to ``config.home_deg`` (devices with a home search override)."""
        self._command_move(self.config.home_deg)

    @abstractmethod
    def _command_stop(self) -> None:
        """Decelerate to a stop now."""

    @abstractmethod
    def _set_enabled(self, enabled: bool) -> None:
        """Energise (True) or de-energise (False) the motor."""

    @abstractmethod
    def _read_fault(self) -> str | None:
        """Readable fault causes, or None when the device reports no fault."""

    @abstractmethod
    def _apply_motion_profile(self, speed_deg_s: float, accel_deg_s2: float) -> None:
        """Load the profile speed and acceleration used by the following moves."""
