"""One capture session from files to results: check, journal, drive the rig, reconstruct, report.

``capture`` is what ``goniofrost capture`` and ``goniofrost demo`` run. Everything that can be
checked is checked before a device is connected: the rig file, the plan, the model, that they
belong together, every joint target within its axis limits, the simulated material, and on
``--resume`` that the journal was started with the same plan, rig and model.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import math
from dataclasses import dataclass
from pathlib import Path

from goniofrost.core.errors import ConfigError, GoniofrostError, OutputError
from goniofrost.capture.journal import Journal, JournalError, SamplesCsv
from goniofrost.capture.session_steps import SessionSpec
from goniofrost.capture.options import DEFAULT_CONFIDENCE, SessionOptions, StopRule
from goniofrost.rig.hardware import NO_SIM, SimOptions

JOURNAL_FILE = "session.sqlite"
log = logging.getLogger(__name__)


@dataclass
class CaptureOutcome:
    """What a finished session produced: the report dict, its readable summary, the folder."""

    report: dict
    summary: str
    session_dir: Path


def capture(inputs, session_dir, *, devices=None, sim: SimOptions = NO_SIM, stop: StopRule = StopRule(),
            options: SessionOptions = SessionOptions()) -> CaptureOutcome:
    """Run (or resume) a session of ``inputs`` (``goniofrost.capture.inputs.load_inputs``: the
    rig, the plan and its model, checked together) into ``session_dir``; raise GoniofrostError
    subclasses on bad input or a device fault.

    ``devices``: the opener of the rig's devices (``goniofrost.rig.hardware.open_hardware``'s; None:
    the real ones; ``goniofrost.rig.simulated.rig_devices`` for a simulated rig file), chosen by the
    caller, with ``sim`` (``goniofrost.rig.hardware.SimOptions``: the material a simulated rig
    shows, which the report compares against, its seed and speed-up, ``on_ready``).
    ``stop``: measure the plan batch by batch and stop once the material's error is at most its
    target (``goniofrost.capture.target.StopRule``; default: the whole plan). ``options``: resume,
    progress, label, a reused calibration, what to type after a stop, the caller's extra files
    (``goniofrost.capture.options.SessionOptions``).
    """
    from goniofrost.capture.engine import SessionStats
    from goniofrost.capture.reconstruction import write_outputs
    from goniofrost.capture.report import preload_preview, summary_text
    from goniofrost.capture.lab import session_label
    from goniofrost.capture.session_lock import session_lock

    material = check_material(inputs.rig, sim.material)
    check_sim_options(inputs.rig, sim.seed, sim.speedup)
    check_target(inputs, stop.target_error, stop.confidence)
    session_dir, rerun = Path(session_dir), options.rerun
    meta = session_meta(inputs, material and material.spec, stop.target_error, stop.confidence,
                        sim_seed(inputs.rig, sim.seed)) | {
        "label": (options.label or session_label(inputs.rig)).to_dict()}
    spec = SessionSpec.from_inputs(inputs, stop.target_error, stop.confidence)
    if options.reuse is not None and options.reuse.drift_limit is not None:
        spec = dataclasses.replace(spec, drift_limit=float(options.reuse.drift_limit))
    existed = check_session_folder(session_dir)
    check_session_outputs(session_dir, options.extra_files)
    with session_lock(session_dir) as lock:
        try:
            journal = open_journal(session_dir, meta, options.resume)
        except GoniofrostError:   # refused: the folder is left as it was
            if not existed:  # made for this run (--resume of nothing): only its lock is in it
                remove_refused_session(session_dir, existed)
            elif lock.created:
                lock.path.unlink(missing_ok=True)
            raise
        fresh = not journal.done_indices() and not journal.steps()
        try:
            lock.claim()   # accepted: now this run may change the folder
            from goniofrost.core.atomic_file import remove_stale_temporaries
            for name in remove_stale_temporaries(session_dir):   # of a run killed while writing its results
                log.info("removed %s, left by an interrupted write", name)
            done = journal.done_indices()
            stats = SessionStats(skipped=len(done))  # what this run adds, if anything is left to capture
            if not session_finished(spec, journal):
                preload_preview()
                stats = run_engine(spec, journal, session_dir, rig=inputs.rig, devices=devices, sim=sim,
                                   options=options)
            else:  # nothing left to capture (a kill after the last sample): the journal is the truth
                SamplesCsv(session_dir / "samples.csv", csv_batches(spec)).rewrite(journal.samples())
            try:
                report = write_outputs(inputs, journal, stats, session_dir, material and material.spec, spec,
                                       options.compare)
            except OutputError as exc:
                raise OutputError(exc.path, f"{exc.reason}; every sample is safe in {journal.path}: fix this, "
                                  f"then run {rerun} to write the results") from exc
        except GoniofrostError:
            refused = fresh and not journal.done_indices() and not journal.steps()
            journal.close()
            if refused:   # nothing was done (e.g. a port that does not answer): leave nothing behind
                remove_refused_session(session_dir, existed)
            raise
        finally:
            journal.close()
    return CaptureOutcome(report, summary_text(report), session_dir)


# the files a capture writes into its session folder besides the journal (whose open refuses a
# folder in its place itself) and the frames (in the folder sample_steps.RAW_DIR)
SESSION_FILES = ("samples.csv", "brdf.binary", "brdf.std.binary", "brdf.json", "preview.png", "report.json",
                 "summary.txt")
# what a session folder holds besides its results (a folder holding anything else is not a session)
SESSION_OWN = ("session.lock", JOURNAL_FILE, JOURNAL_FILE + "-wal", JOURNAL_FILE + "-shm", "raw", "brdf.bsdf",
               *SESSION_FILES)


def check_session_outputs(session_dir: Path, extra_files=()) -> None:
    """OutputError now, before any device is connected, for anything in the way of what the
    capture writes into ``session_dir``: a folder where one of its files goes (``extra_files``: the
    names of those its caller writes there after it, ``capture --bsdf``'s brdf.bsdf), or a file
    where its frames folder goes. A folder named brdf.binary or brdf.bsdf was found at the end,
    after every sample had been measured. Creates nothing; a folder that does not exist yet holds
    nothing in the way (the session lock makes it)."""
    from goniofrost.capture.sample_steps import RAW_DIR
    from goniofrost.core.atomic_file import check_output_dir, check_output_file

    if not session_dir.is_dir():
        return
    for name in (*SESSION_FILES, *extra_files):
        check_output_file(session_dir / name, "it is a directory, where the capture writes a file: move it away "
                                              "or choose another --session")
    check_output_dir(session_dir / RAW_DIR)


def check_session_folder(session_dir: Path) -> bool:
    """Whether ``session_dir`` exists; OutputError for a non-empty folder that is not a session
    (no journal in it): a capture must not write into some other folder's files."""
    if not session_dir.is_dir():
        return session_dir.exists()
    if (session_dir / JOURNAL_FILE).exists():
        return True
    foreign = sorted(p.name for p in session_dir.iterdir() if p.name not in SESSION_OWN)
    if foreign:
        shown = ", ".join(foreign[:3]) + (f" and {len(foreign) - 3} more" if len(foreign) > 3 else "")
        raise OutputError(session_dir, f"it is not a session folder (no {JOURNAL_FILE}; it holds {shown}): "
                          f"choose a new or empty --session folder")
    return True


def remove_refused_session(session_dir: Path, existed: bool) -> None:
    """Remove what a run that did nothing created: the journal, its side files and the lock (the
    lock last, still held), and the folder if this run made it and it is empty."""
    for name in (JOURNAL_FILE + "-wal", JOURNAL_FILE + "-shm", JOURNAL_FILE, "samples.csv", "session.lock"):
        path = session_dir / name
        if path.is_file() and not path.is_symlink():   # never a directory or a link put there
            path.unlink(missing_ok=True)
    for folder in ((session_dir / "raw", session_dir) if not existed else (session_dir / "raw",)):
        try:
            folder.rmdir()
        except OSError:   # not empty or not there: kept
            pass


def run_engine(spec, journal, session_dir: Path, *, rig, devices, sim: SimOptions,
               options: SessionOptions = SessionOptions()):
    """Connect the rig (``devices``, ``sim``: the opener and its options, see ``capture``)
    and capture what is left of the session ``spec``; return the run's SessionStats. From connecting to releasing, the devices' log
    goes to the journal, not the terminal."""
    from goniofrost.rig.device_log import DeviceLog
    from goniofrost.capture.engine import SessionEngine
    from goniofrost.capture.holder import held_hardware

    with DeviceLog.capture() as device_log:
        try:
            with held_hardware(rig, devices, sim) as hardware:
                return SessionEngine(spec, hardware, journal, session_dir, options, device_log=device_log).run()
        finally:
            journal_device_log(journal, device_log)  # what connecting and releasing logged


def journal_device_log(journal, device_log) -> None:
    """Journal the device log's last records; on the way out of a failed session a journal that
    cannot take them (a full disk) must not hide the session's own error."""
    try:
        journal.add_device_log(device_log)
    except Exception as exc:  # noqa: BLE001
        log.error("could not journal the device log: %s", exc)


def check_target(inputs, target_error, confidence: float = DEFAULT_CONFIDENCE) -> None:
    """A target error must be a number > 0, the confidence in (0, 1) and one the model's calibrated
    bound can give, and the plan a Bayesian plan measured in batches."""
    from goniofrost.frost.confidence import max_confidence, scores_needed, unavailability
    from goniofrost.frost.prediction import calibration_of

    if target_error is None:
        return
    if not (isinstance(target_error, (int, float)) and 0 < target_error < float("inf")):
        raise ConfigError("command line", "--target-error", "a log-relative MSE > 0 (e.g. 0.05)", target_error)
    check_confidence(confidence)
    ends, n = inputs.plan.get("batch_ends"), len(inputs.samples)
    if not isinstance(ends, list) or not ends:
        raise ConfigError(inputs.plan_path, "batch_ends", "the batches of a Bayesian plan "
                          "(goniofrost plan --selector bayes --rig RIG.yaml)", ends)
    if (not all(isinstance(e, int) and not isinstance(e, bool) for e in ends) or ends[-1] != n
            or any(b <= a for a, b in zip([0] + ends[:-1], ends))):
        raise ConfigError(inputs.plan_path, "batch_ends", f"increasing sample counts ending at {n}", ends)
    calibration = calibration_of(inputs.model)
    if inputs.scene is not None:  # a plan made for a scene: its own error and calibration
        calibration = inputs.scene.calibration or {}
        if not calibration.get("bound"):
            raise ConfigError(inputs.plan_path, "usage.error.calibration", "the calibrated bound on the error in "
                              "the scene's use (plan --usage with the model's training materials at hand)",
                              inputs.scene.unavailable)
    if not calibration.get("bound"):
        raise ConfigError(inputs.model_path, "noise.calibration.bound", "the calibrated error bound --target-error "
                          "stops on (train the model again with this version of goniofrost)", None)
    if unavailability(calibration, confidence):
        n = len(calibration["bound"]["scores"])
        what = "this plan's scene" if inputs.scene is not None else "this model"
        raise ConfigError("command line", "--confidence", f"at most {max_confidence(calibration['bound']):.3f} with "
                          f"{what} (its bound is calibrated on {n} held-out training materials; "
                          f"{confidence:g} needs {scores_needed(confidence)})", confidence)


def csv_batches(spec) -> tuple:
    """The batch ends samples.csv records (a capture with a target error), else ()."""
    return spec.batch_ends if spec.target is not None else ()


def session_finished(spec, journal) -> bool:
    """True when nothing is left to capture: every plan sample journaled (measured or not
    measured), or (with a target error) the journaled batches already stopped the session."""
    if spec.target is not None:
        from goniofrost.capture.target import finished
        return finished(spec.assess, spec.batch_ends, spec.target, journal.samples(),
                        [r.plan_index for r in journal.not_measured()])
    return len(journal.done_indices()) >= len(spec.samples)


def check_material(rig, material):
    """The simulated camera's material as given (resolved by the caller: ``spec``, ``brdf``,
    ``table``; or its ``SPEC:NAME`` before that), or None on a real rig; ConfigError for one on a
    real rig or none on a simulated rig. A rig file of ``goniofrost sim --write-rig``
    (``rig.twins``) may name one: its camera service renders it (none: the one ``goniofrost sim``
    was started with)."""
    if not rig.simulated:
        if material is not None and rig.twins:
            return material
        if material is not None:
            raise ConfigError("command line", "--material", "no material on a real rig (it measures the sample "
                              "in front of it)", getattr(material, "spec", material))
        return None
    if material is None:
        raise ConfigError("command line", "--material", f"SPEC:NAME of the material the simulated rig {rig.name!r} shows "
                          "(e.g. builtin:NAME; see goniofrost materials --dataset builtin)", None)
    return material


def check_sim_options(rig, seed, speedup) -> None:
    """--seed and --speedup only make sense on a simulated rig; a speed-up must be > 0."""
    for option, value in (("--seed", seed), ("--speedup", speedup)):
        if value is not None and not rig.simulated:
            raise ConfigError("command line", option, f"no {option} for the real rig {rig.name!r} ({rig.source})",
                              value)
    if speedup is not None:
        check_speedup(speedup)


def check_speedup(speedup) -> None:
    """ConfigError unless the simulated clock's speed-up is a finite number > 0."""
    if not (speedup > 0 and speedup < float("inf")):
        raise ConfigError("command line", "--speedup", "a simulated clock speed-up > 0", speedup)


def check_confidence(confidence) -> None:
    """ConfigError unless --confidence is a probability strictly between 0 and 1."""
    if not (isinstance(confidence, (int, float)) and 0 < confidence < 1):
        raise ConfigError("command line", "--confidence", "a probability between 0 and 1 (e.g. 0.95)", confidence)


def sim_seed(rig, seed: int | None) -> int | None:
    """The seed of a simulated rig's noise (--seed, else the rig file's sim.seed, else 0); None on
    a real rig. Part of the resume check: one session's samples all come from one seed."""
    if not rig.simulated:
        return None
    return int((rig.sim or {}).get("seed", 0) if seed is None else seed)


def session_meta(inputs, material: str | None, target_error: float | None = None,
                 confidence: float = DEFAULT_CONFIDENCE, seed: int | None = None) -> dict:
    """What a journal records about its session (and what a resume must match); ``material``: the
    simulated material's ``SPEC:NAME``."""
    return {"sim_seed": seed, **{
        "plan": inputs.plan, "plan_file": str(inputs.plan_path), "plan_sha256": plan_sha256(inputs.plan),
        "rig_file": str(inputs.rig.source), "rig_text": Path(inputs.rig.source).read_text(),
        "rig_name": inputs.rig.name, "kinematic_hash": inputs.rig.kinematic_hash,
        "alignment": None if inputs.rig.alignment is None else inputs.rig.alignment.record(),
        "model_path": str(inputs.model_path), "model_hash": inputs.model.content_hash,
        "material": material, "target_error": None if target_error is None else float(target_error),
        "confidence": None if target_error is None else float(confidence),
    }}


# What a plan records of the run that made it, not of what it measures: the same plan command run
# again takes another time and writes the same plan (a resume after it must not be refused).
PLAN_RUN_RECORD = ("selection_seconds",)


def plan_sha256(plan: dict, with_run_record: bool = False) -> str:
    """SHA-256 of the plan's canonical JSON (key order and whitespace do not matter), without its
    PLAN_RUN_RECORD fields (with them: the identity journals recorded before they were left out)."""
    kept = plan if with_run_record else {key: value for key, value in plan.items() if key not in PLAN_RUN_RECORD}
    return hashlib.sha256(json.dumps(kept, sort_keys=True).encode()).hexdigest()


RESUME_KEYS = (("plan_sha256", "plan"), ("kinematic_hash", "rig kinematics"),
               ("model_hash", "model"), ("material", "simulated material"), ("target_error", "target error"),
               ("confidence", "confidence"), ("sim_seed", "simulated noise seed (--seed or sim.seed)"))
OPTIONAL_RESUME_KEYS = ("sim_seed",)   # journals written before it was recorded: not checked


def open_journal(session_dir: Path, meta: dict, resume: bool) -> Journal:
    """Create the session's journal, or on resume open it and check it is the same session.

    Without ``resume``, an existing journal that holds no sample yet (a run that failed before its
    first sample) is continued when it was started for the same session, so that the same command
    works again; one that holds samples needs ``--resume``. An existing journal is checked through
    a read-only connection first: a refused run writes nothing, not even SQLite's side files.
    """
    path = session_dir / JOURNAL_FILE
    if path.exists() and not path.is_file():
        raise OutputError(path, "it is a directory, where the session journal goes: move it away or choose "
                          "another --session")
    if not resume and not path.exists():
        return Journal.create(path, meta)
    with Journal.open(path, read_only=True) as journal:
        if not resume:
            _check_not_finished(journal, session_dir, resume)
            _check_nothing_captured(journal, meta)
        _check_same_session(journal, meta, resume)
        if resume:  # another plan or setting is the more telling refusal
            _check_not_finished(journal, session_dir, resume)
        label = _check_same_label(journal, meta)
    journal = Journal.open(path)
    try:
        if label != journal.label():  # new notes: the only change a resume may bring
            journal.set_label(label)
    except BaseException:
        journal.close()
        raise
    return journal


def _check_not_finished(journal: Journal, session_dir: Path, resume: bool) -> None:
    """JournalError for a session whose last run completed: nothing is left to capture or resume
    (``--resume`` only wrote the same results again). Its results missing (a kill while writing
    them), ``--resume`` writes them."""
    _, end = journal.last_run()
    reported = (session_dir / "report.json").is_file()  # a capture writes report.json last
    if end is None or not end.status.completed or (resume and not reported):
        return
    said = (f"{session_dir}: this session is finished ({end.samples_captured} of {end.samples_planned} samples, "
            f"{end.status}): nothing is left to capture; ")
    if reported:
        raise JournalError(said + f"its results are in {session_dir}; to measure again, choose a new --session folder")
    raise JournalError(said + "its results are not written yet: pass --resume to write them, or choose a new "
                              "--session folder to measure again")


def _check_nothing_captured(journal: Journal, meta: dict) -> None:
    n_done, n = len(journal.done_indices()), len(meta["plan"].get("samples", []))
    if n_done:
        raise JournalError(f"{journal.path}: a session journal already exists with {n_done} of {n} samples; "
                           f"pass --resume to continue it or choose a new --session folder")


def _check_same_session(journal: Journal, meta: dict, resume: bool) -> None:
    stored = journal.meta()
    for key, what in RESUME_KEYS:
        if key in OPTIONAL_RESUME_KEYS and key not in stored:
            continue
        if key == "plan_sha256" and stored.get(key) == plan_sha256(meta["plan"], with_run_record=True):
            continue  # a journal started before the plan's identity left its selection time out
        if stored.get(key) != meta[key]:
            remedy = ("resume with the same --rig, --plan, --material, --seed, --target-error and --confidence, or "
                      "start a new --session"
                      if resume else f"it holds no sample yet: to start this session there, delete it (rm "
                      f"{journal.path}), or choose a new --session")
            raise JournalError(f"{journal.path}: meta.{key}: this session was started with another {what}: "
                               f"expected {stored.get(key)!r}, found {meta[key]!r}; {remedy}")


LABEL_OPTIONS = {"operator": "--operator", "sample_id": "--sample-id", "queue": "the queue file",
                 "lab": "the rig file's lab.lab", "lens": "the rig file's lab.lens", "lamp": "the rig file's lab.lamp"}


def _check_same_label(journal: Journal, meta: dict):
    """The journaled label with the new notes of ``meta``'s added; JournalError when ``meta``
    gives a field another value (nothing is written then)."""
    from goniofrost.capture.records import SessionLabel

    stored, given = journal.label(), SessionLabel.from_dict(meta.get("label"))
    clash = stored.contradiction(given)
    if clash is not None:
        name, was, found = clash
        raise JournalError(f"{journal.path}: meta.label.{name}: this session was started with {name} {was!r}, "
                           f"found {found!r} ({LABEL_OPTIONS[name]}); resume with the same one, or start a new "
                           f"--session for another")
    return stored.merged(given)
