"""A program that holds the rig stops it when it is stopped, also outside a run of the engine core.

A run (``plan_runner.PlanRunner``) stops the rig itself and raises ``RunStopped``. A holder can be
stopped with no run under way (``rig status --watch``, a program between runs): ``stopped_safely``
turns SIGINT and SIGTERM (``rig stop`` sends SIGTERM) into ``SessionInterrupted`` while the rig is
held, and when no run took care of it stops and confirms every axis, switches the lamp off and
raises ``RunStopped`` saying what each confirmed.
"""
from __future__ import annotations

from contextlib import contextmanager

from goniofrost.capture.executor import StepExecutor
from goniofrost.rig.stop import stop_text
from goniofrost.capture.signals import RunStopped, SessionInterrupted, signals_raise
from goniofrost.rig import hardware as rig_hardware


@contextmanager
def held_hardware(rig, devices=None, *args, **options):
    """``open_hardware(rig, devices, ...)``, stopped safely (``stopped_safely``) while held."""
    # looked up when called: a test that replaces the opener's module attribute reaches this too
    with rig_hardware.open_hardware(rig, devices, *args, **options) as hardware, stopped_safely(hardware):
        yield hardware


@contextmanager
def stopped_safely(hardware):
    """The block holding ``hardware`` (axes, lamp, ``rig_lock``), stopped as the module doc says."""
    with signals_raise() as deferral:
        try:
            yield
        except RunStopped:
            raise
        except SessionInterrupted as exc:
            with deferral.ignored():  # a second Ctrl-C cannot cut the stop short
                message = stop_everything(hardware, exc)
            raise RunStopped(message) from exc


def stop_everything(hardware, exc) -> str:
    """Stop and confirm every axis, switch the lamp off; the sentence saying who stopped the
    holder and what each device confirmed."""
    lock = getattr(hardware, "rig_lock", None)
    who = (lock.stop_request() if lock is not None else None) or str(exc) or "a signal"
    executor = StepExecutor(hardware, ".")
    stops = executor.stop()
    lamp_error = executor.switch_lamp_off() if hardware.lamp is not None else None
    text = stop_text(stops)
    lamp = ("the lamp is off" if lamp_error is None
            else f"the lamp did not confirm it is off ({lamp_error}): it may still be on")
    check = " Check the axes named above before anything else moves." if any(not s.confirmed for s in stops) else ""
    return f"interrupted by {who}. {text[0].upper()}{text[1:]}; {lamp}.{check}"
