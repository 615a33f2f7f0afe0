"""Faults of the simulated devices: the kinds every twin supports, and faults armed for the next move.

``inject_fault(kind)`` (each twin's method) strikes now; ``arm_fault(kind)`` strikes once when the
device next starts a move, after executing the command and before replying.
"""
from __future__ import annotations

# What each kind does is the twin's to say (see its inject_fault); all three twins support all.
# The faults that end a capture: a device that stays silent, damages replies, alarms, stalls or goes.
FAULT_KINDS = ("no_reply", "bad_checksum", "drop_byte", "alarm", "stall", "disconnect")
# A hiccup the drivers must ride out: one reply lost (a loaded host, a noisy line), then answers.
HICCUP_KINDS = ("miss_reply",)
DRILL_KINDS = FAULT_KINDS + HICCUP_KINDS  # what a rig file's sim.faults may rehearse
INJECTABLE_KINDS = DRILL_KINDS + ("clear",)  # "clear" undoes the injected faults
# Faults that last a while (``duration_s`` nominal seconds from the plan sample they are due at)
# and end by themselves: what the suspenders of goniofrost.rig.suspenders are drilled with.
LAMP_KINDS = ("lamp_dim", "lamp_cut")  # the lamp at ``level`` of its intensity, or off
# the interlock input of the Modbus drive ``axis`` reads 0; that drive answers nothing
TIMED_KINDS = LAMP_KINDS + ("interlock_open", "silent")
SIM_FAULT_KINDS = DRILL_KINDS + TIMED_KINDS  # every kind a rig file's sim.faults may name
# the kinds after which a driver waits out its reply timeout: a reply that does not (wholly) come,
# or a damaged one (pymodbus drops a Modbus TCP reply with a wrong header and waits on)
SILENT_KINDS = ("no_reply", "bad_checksum", "drop_byte", "disconnect", "miss_reply", "interlock_open", "silent")


def check_kind(kind: str, kinds: tuple[str, ...] = INJECTABLE_KINDS) -> None:
    """ValueError naming the allowed kinds when ``kind`` is not one of them."""
    if kind not in kinds:
        raise ValueError(f"unknown fault kind {kind!r}; expected one of {kinds}")


class ArmedFaults:
    """Mixin of the simulated devices: faults armed now strike when the device next starts a move.

    The device provides ``_lock`` (an RLock), ``faults`` (the set of active faults), ``motion``
    and ``inject_fault(kind)``; ``struck`` lists the armed faults that have struck; calls ``_init_armed()`` in its constructor, and calls
    ``_move_started()`` with its lock held right after it starts any move of non-zero length
    (before replying): holding still where the axis already is starts nothing.
    """

    def _init_armed(self) -> None:
        self.armed: list[str] = []
        self.struck: list[str] = []  # the armed faults that struck, in order

    def arm_fault(self, kind: str) -> None:
        """Strike ``kind`` (one of DRILL_KINDS) when the device next starts a move, once."""
        check_kind(kind, DRILL_KINDS)
        with self._lock:
            self.armed.append(kind)

    def _move_started(self) -> None:
        """A move just started: a stalled motor stalls again, and the armed faults strike."""
        if "stall" in self.faults:
            self.motion.stall()
        armed, self.armed = self.armed, []
        for kind in armed:
            self.struck.append(kind)
            self._strike(kind)

    def _strike(self, kind: str) -> None:
        """Inject an armed fault from inside the device's own request handling."""
        self.inject_fault(kind)
