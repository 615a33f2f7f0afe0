"""A clock that can run faster than real time, shared by every simulated device of a rig."""
from __future__ import annotations

import time


class SimClock:
    """Simulated seconds = speedup x real seconds since the clock was made.

    ``now()`` gives simulated seconds; ``sleep(sim_seconds)`` waits the matching real time.
    A speedup of 1 is real time. All devices of one simulated rig share one clock so that
    motion, lamp drift and exposures agree.
    """

    def __init__(self, speedup: float = 1.0) -> None:
        if not speedup > 0:
            raise ValueError(f"SimClock speedup must be > 0, got {speedup!r}")
        self.speedup = float(speedup)
        self._real0 = time.monotonic()

    def now(self) -> float:
        """Simulated seconds since the clock started."""
        return (time.monotonic() - self._real0) * self.speedup

    def sleep(self, sim_seconds: float) -> None:
        """Block for ``sim_seconds`` of simulated time."""
        if sim_seconds > 0:
            time.sleep(sim_seconds / self.speedup)
