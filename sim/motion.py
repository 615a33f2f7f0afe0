"""Trapezoidal motion of one simulated axis on a (possibly sped-up) SimClock.

Position in the device's units, speed in units/s, acceleration in units/s^2, times in simulated
seconds. Thread-safe.
"""
from __future__ import annotations

import math
import threading
from dataclasses import dataclass

from drivers.axis import trapezoid_time  # the same formula the drivers use for move timeouts

from .clock import SimClock

__all__ = ["TrapezoidMotion", "trapezoid_time"]


@dataclass(frozen=True)
class _Phase:
    """Constant acceleration for ``duration`` s from distance ``x0`` and speed ``v0`` (along the move)."""

    duration: float
    x0: float
    v0: float
    a: float

    def at(self, tau: float) -> tuple[float, float]:
        return self.x0 + self.v0 * tau + 0.5 * self.a * tau * tau, self.v0 + self.a * tau


def _plan(distance: float, u0: float, vmax: float, accel: float) -> list[_Phase]:
    """Phases of a move over ``distance`` >= 0 starting at speed ``u0`` >= 0 along the move, ending at rest.

    Accelerate (or brake) to the peak speed, cruise, brake. When the move is too short to brake
    from ``u0`` at ``accel``, brake harder (a simulator may; the real device would overshoot).
    """
    if distance <= 0.0:
        return []
    d_brake = u0 * u0 / (2 * accel)
    vp = min(vmax, math.sqrt(accel * distance + 0.5 * u0 * u0))
    d1 = abs(vp * vp - u0 * u0) / (2 * accel)
    d3 = vp * vp / (2 * accel)
    if d_brake >= distance or d1 + d3 > distance * (1 + 1e-12):
        a = u0 * u0 / (2 * distance) if u0 > 0 else accel
        return [_Phase(u0 / a, 0.0, u0, -a)] if u0 > 0 else _plan(distance, 0.0, vmax, accel)
    a1 = accel if vp >= u0 else -accel
    t1, t3 = abs(vp - u0) / accel, vp / accel
    t2 = max(0.0, (distance - d1 - d3) / vp)
    return [_Phase(t1, 0.0, u0, a1), _Phase(t2, d1, vp, 0.0), _Phase(t3, distance - d3, vp, -accel)]


class TrapezoidMotion:
    """An axis that moves with trapezoidal velocity profiles in simulated time.

    ``clock`` is a SimClock (``now()`` for the motion, ``start_activity(seconds)`` told of every
    planned move). ``start_move(target)`` starts from the present position and velocity; ``stop()`` brakes at
    ``accel``; ``stall()`` freezes the axis where it is while it still reports moving (a blocked
    motor). The profile (``set_profile``) applies to the next move, as on real drives.
    """

    def __init__(self, clock: SimClock, position: float = 0.0, speed: float = 1.0, accel: float = 1.0) -> None:
        self.clock = clock
        self._lock = threading.Lock()
        self.speed, self.accel = float(speed), float(accel)
        self._set_segment(clock.now(), float(position), 1.0, [])
        self._stalled = False
        self.target = float(position)

    def set_profile(self, speed: float, accel: float) -> None:
        """Speed (units/s) and acceleration (units/s^2) for the following moves; both > 0."""
        if not (speed > 0 and accel > 0):
            raise ValueError(f"speed and accel must be > 0, got {speed!r}, {accel!r}")
        with self._lock:
            self.speed, self.accel = float(speed), float(accel)

    def start_move(self, target: float) -> float:
        """Start moving to ``target`` now; returns the planned duration in simulated seconds."""
        with self._lock:
            t = self.clock.now()
            p, v = self._state(t)
            dist = float(target) - p
            direction = 1.0 if dist >= 0 else -1.0
            u0 = max(0.0, v * direction)  # moving the other way: reverse at once (simulator licence)
            self._set_segment(t, p, direction, _plan(abs(dist), u0, self.speed, self.accel))
            self._p_end = float(target)  # exact, free of rounding in the phase sums
            self.target, self._stalled = float(target), False
            duration = sum(ph.duration for ph in self._phases)
        self.clock.start_activity(duration)  # the planned duration, not the wall clock's
        return duration

    def stop(self) -> None:
        """Brake at ``accel`` from the present velocity; a stalled axis simply stops."""
        with self._lock:
            t = self.clock.now()
            p, v = self._state(t)
            direction = 1.0 if v >= 0 else -1.0
            speed = abs(v)
            phases = [_Phase(speed / self.accel, 0.0, speed, -self.accel)] if speed > 0 else []
            self._set_segment(t, p, direction, phases)
            self.target = p + direction * speed * speed / (2 * self.accel)
            self._stalled = False

    def stall(self) -> None:
        """Freeze where the axis is now; it keeps reporting motion until stop() or a new move."""
        with self._lock:
            t = self.clock.now()
            p, _ = self._state(t)
            self._set_segment(t, p, 1.0, [])
            self._stalled = True

    def set_position(self, position: float) -> None:
        """Teleport at rest (power-up, homing offset); cancels any move."""
        with self._lock:
            self._set_segment(self.clock.now(), float(position), 1.0, [])
            self.target, self._stalled = float(position), False

    def position(self, t: float | None = None) -> float:
        """Position (units) at simulated time t (default now)."""
        with self._lock:
            return self._state(self.clock.now() if t is None else t)[0]

    def velocity(self, t: float | None = None) -> float:
        """Signed velocity (units/s) at simulated time t (default now); 0 while stalled."""
        with self._lock:
            return self._state(self.clock.now() if t is None else t)[1]

    def is_moving(self, t: float | None = None) -> bool:
        """True during a profile (and while stalled)."""
        with self._lock:
            t = self.clock.now() if t is None else t
            return self._stalled or t < self._t_end

    @property
    def stalled(self) -> bool:
        return self._stalled

    # ----- internals (call with the lock held) -------------------------------------------------
    def _set_segment(self, t0: float, p0: float, direction: float, phases: list[_Phase]) -> None:
        self._t0, self._p0, self._dir, self._phases = t0, p0, direction, phases
        self._t_end = t0 + sum(ph.duration for ph in phases)
        self._p_end = p0 + direction * (phases[-1].at(phases[-1].duration)[0] if phases else 0.0)

    def _state(self, t: float) -> tuple[float, float]:
        """(position, signed velocity) at simulated time t."""
        if t >= self._t_end:
            return self._p_end, 0.0
        tau = max(0.0, t - self._t0)
        x, v = 0.0, 0.0
        for ph in self._phases:
            if tau < ph.duration:
                x, v = ph.at(tau)
                break
            x, v = ph.at(ph.duration)[0], 0.0
            tau -= ph.duration
        return self._p0 + self._dir * x, self._dir * v
