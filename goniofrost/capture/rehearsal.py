"""A simulated rig in a session: fault drills rehearsed once, and a resume that measures what one
run would have.

``Rehearsal`` (a no-op on a real rig) arms the due drills of the rig file's ``sim: faults:``
before each plan sample and journals each as ``armed`` and ``struck``; a later run retires the
struck ones. The engine core journals the simulation's ``checkpoint`` with each committed sample; a
resumed run restores the last one, so its frames, samples.csv and brdf.binary are those of an
uninterrupted run.
"""
from __future__ import annotations

from goniofrost.capture.records import EventKind


class Rehearsal:
    """Drills and simulated state of one engine run: ``executor`` a StepExecutor (the device calls),
    ``journal`` the session's Journal."""

    def __init__(self, executor, journal) -> None:
        self.devices, self.journal = executor, journal
        self._resume_state: dict | None = None  # to restore before the run's first sample
        self._struck: set[int] = set()          # drills journaled as struck in this run

    @property
    def simulated(self) -> bool:
        return self.devices.hw.simulation is not None

    def prepare(self, n_samples: int, done: set, calibration_kept: bool) -> None:
        """At the start of a run: retire the drills that struck in earlier runs, and find the state
        to restore (the one journaled with the sample before the first to capture, or with the kept
        calibration when that is sample 0; none for a fresh session or an older journal)."""
        if not self.simulated:
            return
        self.devices.retire_drills(self._struck_before())
        todo = [i for i in range(n_samples) if i not in done]
        if not todo:
            return
        first = todo[0]
        if first == 0:
            result = self.journal.step_result("SaveCalibration") if calibration_kept else None
        else:
            result = self.journal.step_result("Commit", first - 1) if first - 1 in done else None
        self._resume_state = None if result is None else result.get("sim_state")

    def before_sample(self, index: int) -> None:
        """Before plan sample ``index``'s move: the run's first one restores the journaled state;
        then the drills due are armed."""
        if self._resume_state is not None:
            state, self._resume_state = self._resume_state, None
            self.devices.restore(state)
            self.journal.add_event(EventKind.SIMULATION, f"simulated rig restored as journaled before plan sample {index}",
                                   data=state)
        for drill in self.devices.arm_drills(index):
            self.journal.add_event(EventKind.DRILL, f"drill armed: {_armed_text(drill)} (sim.faults[{drill['drill']}], "
                                   f"at_sample {drill['at_sample']})", axis=drill.get("axis"),
                                   data={**drill, "state": "armed"})

    def journal_struck(self) -> None:
        """Journal each drill the moment it is seen to have struck (a resume never arms it again)."""
        for drill in self.devices.struck_drills():
            if drill["drill"] not in self._struck:
                self._struck.add(drill["drill"])
                self.journal.add_event(EventKind.DRILL, f"drill struck: {drill['kind']} on {drill.get('axis', 'the lamp')}",
                                       axis=drill.get("axis"), data={**drill, "state": "struck"})

    def _struck_before(self) -> list[dict]:
        """The drills earlier runs of the session journaled as struck."""
        return [{k: v for k, v in e["data"].items() if k != "state"} for e in self.journal.events()
                if e["kind"] is EventKind.DRILL and e["data"].get("state") == "struck"]


def _armed_text(drill: dict) -> str:
    """'stall on theta_o when it next moves'; a timed drill (the lamp's, an interlock's) starts at once."""
    where = drill.get("axis", "the lamp")
    if "duration_s" in drill:
        return f"{drill['kind']} on {where} for {drill['duration_s']:g} s"
    return f"{drill['kind']} on {where} when it next moves"
