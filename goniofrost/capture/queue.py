"""A queue of samples measured in one run (``goniofrost queue QUEUE.yaml``), one session each.

Each sample is a capture session (``goniofrost.capture.runner.capture``) in ``ROOT/SAMPLE_ID``.
The first calibrates in full; each later one reuses the calibration of the one before and measures
only the white reference, calibrating in full when its scale moved by more than ``drift_limit``
(``calibration_steps.white_check_steps``). The journals are the queue's only state: running the
command again skips the completed sessions and resumes the one under way. A sample with a target
error is captured as ``capture --target-error E --confidence C``.
"""
from __future__ import annotations

import sys
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

from goniofrost.core.errors import ConfigError, GoniofrostError
from goniofrost.capture.queue_file import Queue, QueueSample
from goniofrost.capture.runner import JOURNAL_FILE
from goniofrost.rig.hardware import NO_SIM, SimOptions

REPORT_FILE = "report.json"


NOTHING_MEASURED = "nothing measured"   # a QueueItem's action: the rig measured none of the sample's plan
RERUN_QUEUE = "the same queue command"  # it resumes the session under way: a queue has no --resume


@dataclass(frozen=True)
class QueueItem:
    """What the queue did with one sample: ``action`` "measured", "skipped" (measured before) or
    "nothing measured" (every plan sample too dark or saturated for the rig: no result; ``summary``
    says which and what to change; the queue goes on with the next sample)."""

    sample_id: str
    session_dir: Path
    action: str
    summary: str = ""


def check_queue(queue: Queue, inputs, *, seed=None, speedup=None, materials=None) -> list:
    """Every sample's material and target, and the simulation options, before anything moves
    (ConfigError naming the queue file and the sample's key); return each sample's material
    resolved by ``materials(SPEC:NAME, None)`` (``goniofrost.datasets.shown_material``; None on a
    real rig)."""
    from goniofrost.capture.runner import check_material, check_sim_options

    check_sim_options(inputs.rig, seed, speedup)
    shown = []
    for i, sample in enumerate(queue.samples):
        check_sample_target(queue, i, inputs)
        try:
            check_material(inputs.rig, sample.material)
            shown.append(None if sample.material is None else materials(sample.material, None))
        except ConfigError as exc:
            raise ConfigError(queue.path, f"samples[{i}].material", exc.expected, sample.material) from None
        except GoniofrostError as exc:  # an unknown dataset or material name: its own words, under the queue's key
            raise GoniofrostError(f"{queue.path}: samples[{i}].material: {exc}") from None
    return shown


def check_sample_target(queue: Queue, index: int, inputs) -> None:
    """``capture``'s own check of sample ``index``'s target error and confidence (a Bayesian plan
    in batches, a confidence the model's calibrated bound can give), its ConfigError naming the
    queue file and the key that set the value instead of the command line's option."""
    from goniofrost.capture.runner import check_target

    sample = queue.samples[index]
    try:
        check_target(inputs, sample.target_error, sample.confidence)
    except ConfigError as exc:
        option = {"--target-error": "target_error", "--confidence": "confidence"}.get(exc.keypath)
        if exc.source != "command line" or option is None:  # the plan's or the model's own problem
            raise
        raise ConfigError(queue.path, queue.key_of(index, option), exc.expected, exc.found) from None


def completed(session_dir: Path) -> bool:
    """True when the session wrote its results: a capture writes report.json last, and only once
    nothing is left to capture (a stopped or failed run writes none)."""
    return (Path(session_dir) / JOURNAL_FILE).is_file() and (Path(session_dir) / REPORT_FILE).is_file()


def calibration_of(session_dir: Path) -> dict | None:
    """The calibration record journaled by the session in ``session_dir`` (None: none yet)."""
    from goniofrost.capture.journal import Journal

    path = Path(session_dir) / JOURNAL_FILE
    if not path.is_file():
        return None
    with Journal.open_read_only(path) as journal:
        return journal.calibration()


def ask_to_mount(sample: QueueSample, position: str) -> None:
    """Ask the operator to mount ``sample`` (Enter goes on; Ctrl-C stops the queue, resumable).

    The end of standard input is no answer (a queue started without a terminal, ``< /dev/null``,
    from cron): GoniofrostError before this sample is measured. It was read as Enter, and every
    sample of the queue was measured with whatever stood on the stage, under its sample id."""
    what = f" ({sample.material})" if sample.material else ""
    print(f"queue {position}: mount sample {sample.sample_id}{what} on the stage, then press Enter "
          f"(Ctrl-C stops the queue; the same command resumes it)", file=sys.stderr, flush=True)
    if not sys.stdin.readline():
        raise GoniofrostError(f"queue {position}: no one answered (standard input ended) to mount sample "
                              f"{sample.sample_id}: it was not measured; run the queue where an operator can press "
                              f"Enter, or pass --yes (a sample changer, the simulated rig)")


def run_queue(queue: Queue, *, confirm: Callable[[QueueSample, str], None] | None = ask_to_mount,
              sim: SimOptions = NO_SIM, progress: bool = True, out=print, devices=None, materials=None,
              compare=None) -> list[QueueItem]:
    """Measure every sample of ``queue`` not yet measured, in order; return what was done.

    ``devices``: the opener of the rig's devices and ``materials(SPEC:NAME, option)`` the resolver
    of a simulated rig's materials (see ``goniofrost.capture.runner.capture``), both the caller's;
    ``sim``: a ``rig.hardware.SimOptions`` for every sample's simulated rig (its seed, speedup and
    on_ready; its material is each sample's own; NO_SIM: the rig file's);
    ``compare(material)``: what a sample's report compares it with (``SessionOptions.compare``).

    ``confirm(sample, "k/n")`` is called before a sample is measured (None: a sample changer,
    ``--yes``). A fault or an interruption propagates (the capture's own exception and message);
    the sessions already completed stay, and the same call resumes. A sample the rig could measure
    none of (``TooFewSamplesError``: a property of the sample and the rig's exposures, which running
    again will not change) does not stop the queue: its item says so and the next sample follows;
    the same call takes it again without moving the rig (its journal has every sample done).
    """
    from goniofrost.capture.inputs import load_inputs
    from goniofrost.capture.lab import session_label
    from goniofrost.capture.reconstruction import TooFewSamplesError
    from goniofrost.capture.options import ReusedCalibration, SessionOptions, StopRule
    from goniofrost.capture.runner import capture

    inputs = load_inputs(queue.rig, queue.plan, queue.alignment)
    shown = check_queue(queue, inputs, seed=sim.seed, speedup=sim.speedup, materials=materials)
    items, previous, n = [], None, len(queue.samples)
    for k, sample in enumerate(queue.samples, start=1):
        session, position = queue.session_dir(sample), f"{k}/{n}"
        if completed(session):
            out(f"queue {position}: {sample.sample_id} already measured in {session}; skipped")
            items.append(QueueItem(sample.sample_id, session, "skipped"))
            previous = session
            continue
        label = session_label(inputs.rig, sample.operator, sample.sample_id, sample.notes, queue=str(queue.path),
                              source=queue.path)
        if confirm is not None:
            confirm(sample, position)
        reuse = calibration_of(previous) if previous is not None else None
        out(f"queue {position}: measuring {sample.sample_id} into {session}"
            + ("; white reference re-measured, dark frames and flat field reused" if reuse else "; full calibration"))
        try:
            options = SessionOptions(resume=(session / JOURNAL_FILE).exists(), progress=progress,
                                     progress_desc=f"queue {position} {sample.sample_id}", label=label,
                                     reuse=None if reuse is None else ReusedCalibration(reuse, queue.drift_limit),
                                     rerun=RERUN_QUEUE,
                                     compare=compare(shown[k - 1]) if compare and shown[k - 1] else None)
            outcome = capture(inputs, session, devices=devices,
                              sim=replace(sim, material=shown[k - 1]),
                              stop=StopRule(sample.target_error, sample.confidence), options=options)
        except TooFewSamplesError as exc:
            out(f"queue {position}: {sample.sample_id}: NOTHING MEASURED: {exc}; the queue goes on")
            items.append(QueueItem(sample.sample_id, session, NOTHING_MEASURED, str(exc)))
        else:
            out(outcome.summary.rstrip("\n"))
            items.append(QueueItem(sample.sample_id, session, "measured", outcome.summary))
        previous = session   # its calibration serves the next sample either way
    return items
