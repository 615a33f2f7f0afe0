"""A clock that can run faster than real time, shared by every simulated device of a rig.

``now()`` follows the wall clock times the speed-up: motion runs on it. ``nominal_time()``
advances only by what the devices are told to do, so everything that ends up in a measured value
runs on it and a seeded session is reproducible however threads are scheduled.
"""
from __future__ import annotations

import threading
import time


class SimClock:
    """Simulated seconds = speedup x real seconds since the clock was made (``now``), and a
    nominal time driven by the devices' commands only (``nominal_time``).

    ``sleep(sim_seconds)`` waits the matching real time and advances the nominal time by it.
    A speedup of 1 is real time. All devices of one simulated rig share one clock so that
    motion, lamp drift and exposures agree.
    """

    def __init__(self, speedup: float = 1.0) -> None:
        if not speedup > 0:
            raise ValueError(f"SimClock speedup must be > 0, got {speedup!r}")
        self.speedup = float(speedup)
        self._real0 = time.monotonic()
        self._lock = threading.Lock()
        self._nominal = 0.0  # nominal seconds already spent
        self._horizon = 0.0  # end of the activities started since nominal time was last read

    def now(self) -> float:
        """Simulated seconds since the clock started (wall clock x speed-up)."""
        return (time.monotonic() - self._real0) * self.speedup

    def nominal_time(self) -> float:
        """Nominal simulated seconds: every activity started so far has ended by then.

        Activities started between two readings (the axes of one move, started together) run
        side by side; an activity started after a reading follows the ones before it.
        """
        with self._lock:
            self._nominal = max(self._nominal, self._horizon)
            return self._nominal

    def restore_nominal_time(self, t: float) -> None:
        """Continue from nominal time ``t`` (s), as journaled by an earlier run of the session: what
        the devices do next is timed as it would have been then."""
        with self._lock:
            self._nominal = self._horizon = float(t)

    def start_activity(self, sim_seconds: float) -> None:
        """A device starts something that takes ``sim_seconds`` (a planned move) from now, nominally."""
        with self._lock:
            self._horizon = max(self._horizon, self._nominal + max(0.0, float(sim_seconds)))

    def sleep(self, sim_seconds: float) -> None:
        """Block for ``sim_seconds`` of simulated time (and spend them on the nominal time)."""
        self.wait_until(self.start_sleep(sim_seconds))

    def start_sleep(self, sim_seconds: float) -> float:
        """Spend ``sim_seconds`` on the nominal time now and return the wall-clock instant
        (``time.monotonic``) the matching real wait ends: ``wait_until`` it. Between the two the
        caller computes what the wait stands for (a simulated frame while it is exposed), so the
        host's work hides in the wait instead of adding to it."""
        deadline = time.monotonic()
        if sim_seconds > 0:
            with self._lock:
                self._nominal = max(self._nominal, self._horizon) + float(sim_seconds)
            deadline += sim_seconds / self.speedup
        return deadline

    @staticmethod
    def wait_until(deadline: float) -> None:
        """Block until the wall-clock instant ``deadline`` (``time.monotonic``; past: at once)."""
        remaining = deadline - time.monotonic()
        if remaining > 0:
            time.sleep(remaining)
