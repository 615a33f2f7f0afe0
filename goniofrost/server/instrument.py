"""The held rig as an instrument: one thread drives the devices, one plan at a time.

The instrument's thread (``_work``) runs queued captures and the API's direct commands (``command``)
one at a time; ``status()`` is what it last published. Pause and stop reach a running capture
through ``ServerGate`` (the hardware's ``pause_gate`` and ``rig_lock``): the engine blocks at a
safe point while paused (``goniofrost.rig.pause``) and asks for a stop between steps; a suspender
tells the gate, which shows ``SUSPENDED`` until it ends (``resume()`` for ``resume: operator``).
Between runs the thread reads the devices; a silent one puts it in ``FAULT`` while
``hardware.reconnect`` retries after ``backoff()``. docs/explanations/serve.md says why.
"""
from __future__ import annotations

import concurrent.futures
import enum
import logging
import threading
import time
import traceback

from goniofrost.core.errors import GoniofrostError
from goniofrost.rig.pause import PauseHold, PauseLamp

log = logging.getLogger(__name__)
MAX_EVENTS = 2000   # typed records kept for the event stream (older ones are dropped)
IDLE_READ_S = 2.0   # real seconds between two status reads of an idle instrument
BACKOFF_S = (0.5, 30.0)   # session-clock seconds before the first reopening of a silent device, and the cap


def backoff(first: float = BACKOFF_S[0], cap: float = BACKOFF_S[1]):
    """The waits before each reopening of a device: first, 2 first, 4 first ... up to cap (seconds)."""
    delay = first
    while True:
        yield delay
        delay = min(2.0 * delay, cap)


class State(str, enum.Enum):
    """What the instrument is doing (``GET /api/status``'s ``state``)."""

    IDLE = "idle"
    RUNNING = "running"
    PAUSED = "paused"
    SUSPENDED = "suspended"
    STOPPING = "stopping"
    FAULT = "fault"


class Busy(GoniofrostError):
    """A direct command while a plan runs (the API answers 409)."""


class ServerGate:
    """What the engine asks between steps (module doc): the server's pause and stop, and the held
    device lock's own stop requests (``goniofrost rig stop`` of another process)."""

    def __init__(self, instrument: "Instrument", lock) -> None:
        self.instrument, self.lock, self.holder = instrument, lock, lock.holder

    def stop_request(self) -> str | None:
        return self.instrument.stop_asked or self.lock.stop_request()

    def __call__(self, where: str) -> None:
        """The pause gate: block while paused; raise SessionInterrupted on a stop."""
        self.instrument.safe_point(where)

    def suspended(self, watch, reason, text: str) -> None:
        """The engine's SuspendWatch suspended the run (``reason``: a SuspendReason)."""
        self.instrument.suspend(str(reason), text, watch)

    def resumed(self, watch, end, text: str) -> None:
        self.instrument.unsuspend(text)


class HeldDevices:
    """The opener (``open_hardware``'s ``devices``) of the hardware a server holds: it shows
    ``material`` on a simulated rig's camera, opens nothing, and carries the held lock
    (``rig_lock``: ``open_hardware`` then takes none)."""

    def __init__(self, hardware, gate) -> None:
        self.hw, self.rig_lock = hardware, gate

    def __call__(self, rig, *, material=None, seed=None, speedup=None):
        from contextlib import nullcontext

        camera = self.hw.camera
        if material is not None and hasattr(camera, "brdf"):  # the simulated camera
            camera.material, camera.brdf = material.spec, material.brdf
        return nullcontext(self.hw)


class Instrument:
    """The held ``hardware`` of ``rig`` (``goniofrost.rig.hardware.RigHardware``, already open and
    its lock held as ``lock``), its queue in ``store``; ``run_entry(entry, devices)`` runs one queue
    entry (``goniofrost.server.serve.run_entry``) with ``devices`` the opener of the held hardware."""

    def __init__(self, rig, hardware, lock, store, run_entry, idle_read_s: float = IDLE_READ_S) -> None:
        self.rig, self.hw, self.store, self.run_entry = rig, hardware, store, run_entry
        self.idle_read_s = idle_read_s
        self.pause_hold = PauseHold.of_rig(rig)  # the lamp while paused
        self.gate = ServerGate(self, lock)
        self.held_devices = HeldDevices(hardware, self.gate)
        hardware.rig_lock, hardware.pause_gate = self.gate, self.gate
        self._cond = threading.Condition()
        self.state, self.reason = State.IDLE, None
        self.current: dict | None = None
        self.held = False            # the queue waits for resume (after a stop or a fault)
        self.stop_asked: str | None = None
        self._pause_asked = False
        self._watch = None           # the SuspendWatch of a suspended run (its operator's resume)
        self.suspension: str | None = None   # the SuspendReason of a suspended run
        self._commands: list = []
        self._closing = False
        self.pose: dict = {}
        self.lamp: dict = {"on": None, "photodiode": None}
        self.events: list[dict] = []
        self.first_event = 0         # the sequence number of events[0]
        self._thread = threading.Thread(target=self._work, name="instrument", daemon=True)

    # ----- asked by the API ------------------------------------------------------------------------
    def start(self) -> "Instrument":
        self._thread.start()
        return self

    def close(self) -> None:
        """Stop what runs (as an operator's stop, at once if paused) and end the thread; a queue
        entry stopped so is left running in the store: the next start resumes it."""
        with self._cond:
            self._closing = True
            if self.state in (State.RUNNING, State.PAUSED, State.SUSPENDED):
                self.stop_asked = "the server shutting down"
            self._cond.notify_all()
        self._thread.join(timeout=60)

    def status(self) -> dict:
        with self._cond:
            return {"state": self.state.value, "reason": self.reason, "suspension": self.suspension,
                    "held": self.held, "current": self.current, "pose": dict(self.pose), "lamp": dict(self.lamp),
                    "rig": self.rig.name, "events": self.first_event + len(self.events)}

    def pause(self) -> State:
        """Ask a running capture to pause at its next safe point (the state turns paused there)."""
        with self._cond:
            if self.state is State.RUNNING:
                self._pause_asked = True
                self._publish("pause_asked")
            return self.state

    def resume(self) -> State:
        """Continue a paused run, resume a suspended one (once its conditions held clear), or release
        a queue held after a stop or a fault."""
        with self._cond:
            self._pause_asked, self.held = False, False
            if self._watch is not None:
                self._watch.resume()
            if self.state is State.FAULT:
                self._set(State.IDLE, None)
            self._cond.notify_all()
            return self.state

    def stop(self, who: str) -> State:
        """Stop the run under way (between two steps: a move under way finishes) and hold the queue."""
        with self._cond:
            self.held = True
            if self.state in (State.RUNNING, State.PAUSED, State.SUSPENDED):  # a capture or a command
                self.stop_asked = f"a stop request from {who}"
                self._set(State.STOPPING, self.stop_asked)
            self._cond.notify_all()
            return self.state

    def suspend(self, reason: str, text: str, watch) -> None:
        """A suspender holds the run (``watch``: its SuspendWatch, ``reason`` a SuspendReason's value)."""
        with self._cond:
            self._watch, self.suspension = watch, reason
            if not self.stop_asked:
                self._set(State.SUSPENDED, text)

    def unsuspend(self, text: str) -> None:
        """The suspension ended (``text``: how); a run not being stopped is running again."""
        with self._cond:
            self._watch, self.suspension = None, None
            self._publish("suspension_ended", text=text)
            if self.state is State.SUSPENDED:
                self._set(State.RUNNING, None)

    def lamp_switched(self, on: bool) -> None:
        with self._cond:
            self.lamp["on"] = on
            self._publish("lamp", on=on)

    def queue_changed(self) -> None:
        with self._cond:
            self._publish("queue")
            self._cond.notify_all()

    def command(self, what: str, job) -> concurrent.futures.Future:
        """Run ``job(hardware)`` on the instrument's thread when it is idle; Busy at once otherwise."""
        future: concurrent.futures.Future = concurrent.futures.Future()
        with self._cond:
            if self.state is not State.IDLE or self._commands:
                raise Busy(f"the rig is {self.state.value}: {what} waits until it is idle (stop or wait)")
            self._commands.append((what, job, future))
            self._cond.notify_all()
        return future

    # ----- asked by the engine, on the instrument's thread --------------------------------------------
    def safe_point(self, where: str) -> None:
        from goniofrost.capture.signals import SessionInterrupted

        with self._cond:
            paused = self._pause_asked and not self.stop_asked
        if paused:
            self._hold(where)
        with self._cond:
            if self.stop_asked:
                raise SessionInterrupted(self.stop_asked)
            if self.state is not State.RUNNING:
                self._set(State.RUNNING, None)
        self._read_pose()

    def _hold(self, where: str) -> None:
        """Paused: the axes at rest where they are, the lamp as the rig file's ``pause:`` says
        (``goniofrost.rig.pause``); wait for a resume or a stop, then light the lamp again."""
        before = None
        if self.pause_hold.lamp is PauseLamp.OFF and self.hw.lamp is not None and self.hw.lamp.is_on():
            before = self.hw.lamp.photodiode()
            self.hw.lamp.off()
            self.lamp_switched(False)
            self._read_pose()
        with self._cond:
            while self._pause_asked and not self.stop_asked:
                if self.state is not State.PAUSED:
                    self._set(State.PAUSED, f"paused{where}")
                self._cond.wait()
            stopped = self.stop_asked
        if before is not None and not stopped:
            self._relight(before)

    def _relight(self, before: float) -> None:
        """Switch the lamp on after a pause and wait, on the session clock, until its photodiode reads
        within ``lamp_tolerance`` of ``before`` (GoniofrostError after ``warmup_s``: the run faults;
        a lamp that read nothing before the pause is only switched on)."""
        hold, waited = self.pause_hold, 0.0
        self.hw.lamp.on()
        self.lamp_switched(True)
        reading = self.hw.lamp.photodiode() if before > 0 else None
        while reading is not None and abs(reading / before - 1.0) > hold.lamp_tolerance:
            if waited >= hold.warmup_s:
                raise GoniofrostError(f"lamp: after the pause it reads {reading:.3f} of nominal, not within "
                                      f"{100 * hold.lamp_tolerance:g} % of {before:.3f} before it, after "
                                      f"{waited:g} s (pause.warmup_s)")
            self.hw.clock.sleep(hold.poll_s)
            waited += hold.poll_s
            reading = self.hw.lamp.photodiode()
        with self._cond:
            self._publish("relit", photodiode=None if reading is None else round(reading, 4),
                          before=round(before, 4), waited_s=waited)

    # ----- the thread ---------------------------------------------------------------------------------
    def _work(self) -> None:
        self._check_devices()
        while True:
            with self._cond:
                if not self._has_work():
                    self._cond.wait(self.idle_read_s)
                if self._closing:
                    return
                command = self._commands.pop(0) if self._commands else None
                entry = None if command or self.held else self.store.next_entry()
            if command:
                self._run_command(*command)
            elif entry:
                self._run_queued(entry)
            self._check_devices()

    def _has_work(self) -> bool:
        return self._closing or bool(self._commands) or (not self.held and self.store.next_entry() is not None)

    def _check_devices(self) -> None:
        """Read the devices between runs; reopen the ones that do not answer (module doc)."""
        failed = self._read_pose()
        if failed:
            self._reconnect(failed)

    def _reconnect(self, failed: dict) -> None:
        """``failed``: device name -> its error. FAULT while reopening them with back-off; the state
        before comes back once every device answers (or the server closes)."""
        with self._cond:
            before = (self.state, self.reason)
        for attempt, delay in enumerate(backoff(), 1):
            with self._cond:
                if self._closing:
                    return
                why = "; ".join(f"{name} does not answer ({error})" for name, error in failed.items())
                self._set(State.FAULT, f"{why}: reopening in {delay:g} s (attempt {attempt})")
            self._sleep(delay)
            refused = {}
            for name in failed:
                try:
                    if self.hw.reconnect is not None:
                        self.hw.reconnect(name)
                except Exception as exc:  # noqa: BLE001 - say it, read again below, try again later
                    refused[name] = str(exc)
                    log.warning("reopening %s: %s", name, exc)
            failed = self._read_pose()
            failed.update((name, error) for name, error in refused.items() if name in failed)
            if not failed:
                with self._cond:
                    self._publish("reconnected", attempts=attempt)
                    self._set(*before)
                return

    def _sleep(self, seconds: float) -> None:
        """Wait ``seconds`` of the session clock in short steps, ending early when the server closes."""
        while seconds > 0 and not self._closing:
            self.hw.clock.sleep(min(0.5, seconds))
            seconds -= 0.5

    def _run_command(self, what, job, future) -> None:
        with self._cond:
            self._set(State.RUNNING, what)
        try:
            future.set_result(job(self.hw))
        except BaseException as exc:  # noqa: BLE001 - the API says what went wrong
            future.set_exception(exc)
        with self._cond:
            self.stop_asked = None  # a stop of this command is spent: the next one starts afresh
            self._set(State.IDLE, None)

    def _run_queued(self, entry: dict) -> None:
        from goniofrost.capture.plan_runner import SessionFault
        from goniofrost.capture.signals import SessionInterrupted

        with self._cond:
            self.current, self.stop_asked = entry, None
            self._set(State.RUNNING, None)
        try:
            result = self.run_entry(entry, self.held_devices)
            ended, state = ("done", result), State.IDLE
        except SessionInterrupted as exc:
            ended, state = ("stopped", {"reason": str(exc)}), State.IDLE
            if self._closing:  # the server is shutting down: the entry stays running, resumed on the next start
                ended = None
        except (SessionFault, GoniofrostError) as exc:
            ended, state = ("failed", {"reason": str(exc)}), State.FAULT
        except Exception as exc:  # noqa: BLE001 - a bug must not end the server: say it, hold the queue
            log.error("queue entry %s: %s", entry["id"], traceback.format_exc())
            ended, state = ("failed", {"reason": f"{type(exc).__name__}: {exc}"}), State.FAULT
        if ended is None:
            return
        self.store.ended(entry["id"], *ended)
        with self._cond:
            self.current, self._pause_asked = None, False
            if state is State.FAULT or ended[0] == "stopped":
                self.held = True
            self.stop_asked = None
            self._publish("entry_ended", id=entry["id"], state=ended[0], result=ended[1])
            self._set(state, ended[1].get("reason") if state is State.FAULT else None)

    def _read_pose(self) -> dict:
        """Read the axes and the photodiode (on the instrument's thread only); return the devices that
        did not answer (name -> the error)."""
        pose, reading, failed = {}, None, {}
        for name, axis in self.hw.axes.items():
            try:
                pose[name] = round(float(axis.position()), 4)
            except Exception as exc:  # noqa: BLE001 - a status shows what it can
                pose[name], failed[name] = None, str(exc)
                log.warning("reading %s: %s", name, exc)
        if self.hw.lamp is not None:
            try:
                reading = round(float(self.hw.lamp.photodiode()), 4)
            except Exception as exc:  # noqa: BLE001
                failed["lamp"] = str(exc)
        with self._cond:
            if (pose, reading) != (self.pose, self.lamp["photodiode"]):
                self.pose = pose
                self.lamp["photodiode"] = reading
                self._publish("pose", pose=pose, lamp=dict(self.lamp))
        return failed

    # ----- records -------------------------------------------------------------------------------------
    def _set(self, state: State, reason) -> None:
        self.state, self.reason = state, reason
        self._publish("state", state=state.value, reason=reason,
                      current=None if self.current is None else self.current["id"])
        self._cond.notify_all()

    def _publish(self, kind: str, **data) -> None:
        self.events.append({"type": kind, "seq": self.first_event + len(self.events), "t_utc": time.time(), **data})
        if len(self.events) > MAX_EVENTS:
            drop = len(self.events) - MAX_EVENTS
            del self.events[:drop]
            self.first_event += drop

    def events_since(self, seq: int) -> list[dict]:
        with self._cond:
            return self.events[max(0, seq - self.first_event):]
