"""A read-only view of a session folder: the one module that knows how a session is stored.

``read_session(DIR)`` reads the journal (``DIR/session.sqlite``), ``report.json`` and the list of
the folder's files into a ``SessionView`` of plain values. It reads only through the journal's
read-only API (``Journal.open_read_only``, one ``Journal.snapshot`` per read on a fresh
connection), and how the last run ended by its typed ``RunEnd``'s fields, never its words. A
``-wal`` file without a live writer is read from a copy in a temporary folder.
docs/explanations/monitor.md says why.
"""
from __future__ import annotations

import json
import sqlite3
from dataclasses import dataclass, field
from pathlib import Path

from goniofrost.capture.journal import Journal
from goniofrost.capture.records import RunEnd, RunStatus
from goniofrost.capture.runner import JOURNAL_FILE
from goniofrost.capture.session_lock import LOCK_FILE
from goniofrost.rig.lock import flock_held

REPORT_FILE = "report.json"
SUMMARY_FILE = "summary.txt"
_SQLITE_SIDE_FILES = ("-wal", "-shm", "-journal")


@dataclass(frozen=True)
class PlanSample:
    """One plan sample in capture order: its grid cell (i_th, i_td, i_pd), angles (deg), joint
    targets {axis: deg}, planned move from the previous pose (s)."""

    index: int
    cell: tuple
    theta_i_deg: float
    theta_o_deg: float
    joints: dict
    planned_move_s: float


@dataclass(frozen=True)
class DoneSample:
    """One journaled sample: SNR (min over channels), exposures (s), BRDF and its standard deviation
    (1/sr), joints reached (deg), rig seconds moving and capturing (simulated seconds on a
    simulated rig), Unix times of the start of its move and of its commit, its RAW frames in the
    order taken."""

    plan_index: int
    snr: float
    exposures_s: tuple
    rgb: tuple
    sigma: tuple
    status: str
    joints: dict
    move_s: float
    capture_s: float
    started_utc: float
    committed_utc: float
    raw_paths: tuple


@dataclass(frozen=True)
class NotMeasuredSample:
    """One plan sample journaled as not measured (too dark or saturated): its ``reason`` (the value
    of a ``calib.NotMeasuredReason``), the SNR reached per channel and the rig's minimum, the longest
    exposure (s), the upper and lower limits of its BRDF per channel (1/sr), rig seconds moving and
    capturing, Unix times of the start of its move and of its commit, its RAW frames."""

    plan_index: int
    reason: str
    snr: tuple
    min_snr: float
    longest_exposure_s: float
    upper_limit: tuple
    lower_limit: tuple
    exposures_s: tuple
    move_s: float
    capture_s: float
    started_utc: float
    committed_utc: float
    raw_paths: tuple

    @property
    def best_snr(self) -> float:
        return max(self.snr)


@dataclass(frozen=True)
class Stop:
    """Why the last run ended early: ``status`` its RunStatus (fault, refused, stopped_by_operator),
    ``message`` the terminal's words (what went wrong and what to do next), ``detail`` the device's
    or library's message."""

    status: RunStatus
    message: str
    detail: str
    axis: str | None
    plan_index: int | None
    t_utc: float


@dataclass(frozen=True)
class SessionView:
    """Everything the monitor knows about a session folder at one moment (see module doc).

    ``journal_found`` is False before the capture created its journal (``note`` says why), and
    when the journal is damaged (``unreadable``: its path and the error, e.g. "file is not a
    database"; empty otherwise);
    ``done`` the measured samples (DoneSample), ``not_measured`` the samples journaled as not
    measured (NotMeasuredSample): both are done; ``events`` are dicts (t_utc, kind, axis, message); ``run_started_utc`` is the start of the
    last run (a resume starts a new run); ``run_end`` how it ended (None while it runs or when its
    process was killed); ``stop`` the same when it ended early; ``white_rates`` the calibration's
    white signal per channel (None before it); ``step`` the
    journal's latest plan step (kind, plan_index, detail, status, started_utc); ``reached`` the
    joints {axis: deg}, plan index and kind (Move or Home) of the last completed move (None before one);
    ``capture_alive`` whether a capture process holds the session's lock (None: cannot tell);
    ``summary`` the text of summary.txt (empty before the end);
    ``predicted_error`` is the latest predicted reconstruction error when the session
    records one; ``error_figure`` the one sentence of it every output states
    (``frost.confidence.figure``: report.json's, else the latest batch assessment's), None before one; ``assessment`` the latest batch assessment of a capture with a target error (the
    typed fields of its Assess step: batch, samples, predicted_error = the median estimate, bound,
    confidence, target, decision, out_of_model, scope: "brdf" or "scene", the error assessed), None
    before one; ``files`` are the names of the folder's own files (journal side files excluded);
    ``label`` who measured what (``SessionLabel.to_dict``: operator, sample_id, notes, lab, lens,
    lamp, queue); ``first_started_utc`` the first run's start; ``run_spans`` (started, ended or
    None) Unix times of every run.
    """

    session_dir: Path
    journal_found: bool = False
    note: str = ""
    unreadable: str = ""
    plan_key: str = ""
    plan_doc: dict = field(default_factory=dict)
    plan_file: str = ""
    rig_name: str = ""
    rig_text: str = ""
    material: str | None = None
    model_path: str = ""
    model_hash: str = ""
    plan: tuple = ()
    done: tuple = ()
    not_measured: tuple = ()
    events: tuple = ()
    run_started_utc: float | None = None
    run_end: RunEnd | None = None
    stop: Stop | None = None
    calibrated: bool = False
    white_rates: tuple | None = None
    step: dict | None = None
    reached: dict | None = None
    capture_alive: bool | None = None
    report: dict | None = None
    summary: str = ""
    predicted_error: float | None = None
    error_figure: str | None = None
    assessment: dict | None = None
    files: tuple = field(default_factory=tuple)
    label: dict = field(default_factory=dict)
    first_started_utc: float | None = None
    run_spans: tuple = ()

    @property
    def nothing_measured(self) -> bool:
        """Whether plan samples were journaled as not measured and none but sentinels (which only
        check a reconstruction) was measured: too dark or saturated for the rig's exposures, nothing
        to reconstruct (the capture's TooFewSamplesError)."""
        from goniofrost.plan.file import sentinel_flags  # here: plan_file's imports (numba) cost 0.4 s

        flags = sentinel_flags(self.plan_doc.get("samples") or [])
        return bool(self.not_measured) and all(d.plan_index < len(flags) and flags[d.plan_index] for d in self.done)


def journal_path(session_dir) -> Path:
    return Path(session_dir) / JOURNAL_FILE


def read_session(session_dir) -> SessionView:
    """Read the session in ``session_dir`` (read-only; see module doc)."""
    session_dir = Path(session_dir)
    path = journal_path(session_dir)
    files = _own_files(session_dir)
    if not path.is_file():
        return SessionView(session_dir, note=f"no {JOURNAL_FILE} in {session_dir} yet", files=files)
    try:
        meta, records, dark, events, calibration, steps, runs, label = _read_journal(path)
    except (sqlite3.Error, ValueError, TypeError, KeyError) as exc:   # a damaged file can fail anywhere
        return _unreadable_view(session_dir, path, exc, files)
    report = _read_report(session_dir / REPORT_FILE)
    start, end = runs[-1] if runs else (None, None)
    return SessionView(
        session_dir, journal_found=True, plan_key=str(meta.get("plan_sha256", "")),
        rig_name=str(meta.get("rig_name", "")), rig_text=str(meta.get("rig_text", "")),
        material=meta.get("material"), model_path=str(meta.get("model_path", "")),
        model_hash=str(meta.get("model_hash", "")), plan_doc=meta.get("plan") or {},
        plan_file=str(meta.get("plan_file", "")), plan=_plan_samples(meta.get("plan") or {}),
        done=tuple(_done_sample(r) for r in records), not_measured=tuple(_not_measured_sample(r) for r in dark),
        events=tuple({k: e[k] for k in ("t_utc", "kind", "axis", "message")} for e in events),
        run_started_utc=None if start is None else start.started_utc, run_end=end,
        stop=_stop(end), calibrated=calibration is not None, white_rates=_white_rates(calibration), report=report,
        summary=_read_text(session_dir / SUMMARY_FILE), step=_last_step(steps), reached=_reached(steps),
        capture_alive=flock_held(session_dir / LOCK_FILE),
        predicted_error=_predicted_error(events, report), error_figure=_error_figure(events, report),
        assessment=_assessment(events), files=files,
        label=label.to_dict(), first_started_utc=runs[0][0].started_utc if runs else None,
        run_spans=tuple((s.started_utc, None if e is None else e.ended_utc) for s, e in runs))


# SQLite primary result codes of a file that is not (or no longer) a database
_DAMAGED = {11: "SQLITE_CORRUPT", 26: "SQLITE_NOTADB"}


def _unreadable_view(session_dir: Path, path: Path, exc: Exception, files: tuple) -> SessionView:
    """The view of a journal that could not be read. Damaged (a corrupt or foreign file, a record
    that does not decode) with no capture holding the session: ``unreadable``, for good. Being
    created (no table yet), or read while a capture writes it (an immutable read can race a
    checkpoint): "not readable yet", read again next time."""
    sqlite = isinstance(exc, sqlite3.Error)
    damaged = (getattr(exc, "sqlite_errorcode", 0) & 0xFF) in _DAMAGED if sqlite else True
    if not damaged or flock_held(session_dir / LOCK_FILE) is True:
        return SessionView(session_dir, note=f"{path}: not readable yet ({exc})", files=files)
    what = f"{exc}" if sqlite else f"a record does not decode: {type(exc).__name__}: {exc}"
    return SessionView(session_dir, unreadable=f"{path}: {what}", note=f"{path}: unreadable ({what})", files=files)


def _read_journal(path: Path):
    """(meta, sample records, not-measured records, events, calibration, recent steps, runs, label)
    at one moment."""
    wal = path.with_name(path.name + "-wal")
    if wal.exists() and flock_held(path.with_name(LOCK_FILE)) is not True:
        return _read_journal_copy(path, wal)
    return _read_journal_at(path)


def _read_journal_at(path: Path):
    with Journal.open_read_only(path) as journal, journal.snapshot():
        return (journal.meta(), journal.samples(), journal.not_measured(), journal.events(), journal.calibration(),
                journal.recent_steps(), journal.runs(), journal.label())


def _read_journal_copy(path: Path, wal: Path):
    """``_read_journal`` on a copy of a journal left with its WAL by a writer that died (its
    ``-shm`` is not copied: SQLite rebuilds it from the WAL, in the copy's folder)."""
    import shutil
    import tempfile

    with tempfile.TemporaryDirectory(prefix="goniofrost-monitor-") as tmp:
        copy = Path(tmp) / path.name
        shutil.copyfile(path, copy)
        try:
            shutil.copyfile(wal, copy.with_name(copy.name + "-wal"))
        except FileNotFoundError:   # checkpointed and removed meanwhile: the main file has it all
            pass
        return _read_journal_at(copy)


def _read_report(path: Path) -> dict | None:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):  # not written yet (it is replaced atomically, never torn)
        return None


def _read_text(path: Path) -> str:
    try:
        return path.read_text(errors="replace")
    except OSError:
        return ""


def _own_files(session_dir: Path) -> tuple:
    """Names of the regular files directly in the session folder (not the journal's side files)."""
    try:
        entries = sorted(p for p in session_dir.iterdir() if p.is_file() and not p.is_symlink())
    except OSError:
        return ()
    return tuple(p.name for p in entries if not p.name.endswith(_SQLITE_SIDE_FILES))


def _plan_samples(plan: dict) -> tuple:
    out = []
    for i, s in enumerate(plan.get("samples", [])):
        out.append(PlanSample(i, tuple(s.get("cell", ())), float(s.get("theta_i_deg", float("nan"))),
                              float(s.get("theta_o_deg", float("nan"))), dict(s.get("joints", {})),
                              float(s.get("move_s", 0.0))))
    return tuple(out)


def _done_sample(r) -> DoneSample:
    return DoneSample(r.plan_index, float(r.snr), tuple(r.exposures_s), tuple(r.rgb), tuple(r.sigma), r.status,
                      dict(r.joints),
                      float(r.move_s), float(r.capture_s), float(r.started_utc), float(r.committed_utc),
                      tuple(r.raw_paths))


def _not_measured_sample(r) -> NotMeasuredSample:
    return NotMeasuredSample(r.plan_index, str(r.reason), tuple(r.snr), float(r.min_snr), float(r.longest_exposure_s),
                             tuple(r.upper_limit), tuple(r.lower_limit), tuple(r.exposures_s), float(r.move_s), float(r.capture_s),
                             float(r.started_utc), float(r.committed_utc), tuple(r.raw_paths))


def _stop(end: RunEnd | None) -> Stop | None:
    """The fault, refusal or operator's stop that ended the last run, if it ended early."""
    if end is None or not end.stopped_early:
        return None
    return Stop(end.status, end.reason, end.detail, end.axis, end.plan_index, end.ended_utc)


def _last_step(steps: list) -> dict | None:
    if not steps:
        return None
    last = steps[-1]
    return {k: last[k] for k in ("kind", "plan_index", "detail", "status", "started_utc")}


def _reached(steps: list) -> dict | None:
    """Joints, plan index and kind of the last Move or Home step that completed (its result: the
    joints reached): the rig's last confirmed pose (a capture ends with a Home)."""
    for step in reversed(steps):
        joints = step["result"].get("joints") if isinstance(step["result"], dict) else None
        if step["kind"] in ("Move", "Home") and step["status"] == "done" and isinstance(joints, dict):
            return {"joints": joints, "plan_index": step["plan_index"], "kind": step["kind"]}
    return None


def _white_rates(calibration: dict | None) -> tuple | None:
    """The white reference's signal rate per channel (R, G, B) from the calibration record: what a
    white surface gives, so dividing by it white-balances a frame."""
    scale = (calibration or {}).get("scale")
    ok = isinstance(scale, list) and len(scale) == 3 and all(isinstance(v, (int, float)) and v > 0 for v in scale)
    return tuple(float(v) for v in scale) if ok else None


def _predicted_error(events: list, report: dict | None) -> float | None:
    """The latest predicted reconstruction error the session records, else None.

    Looked for: report.json's ``prediction.median_estimate`` (the final reconstruction's, the same
    estimate as a batch's), else its ``prediction.predicted_log_relative_mse`` (a report from
    before that, or of a plan for a scene), else the ``predicted_error`` (the median estimate) of
    the latest event that has one (a capture with a target error journals one per batch, kind
    "batch").
    """
    prediction = (report or {}).get("prediction") or {}
    for key in ("median_estimate", "predicted_log_relative_mse"):
        if isinstance(prediction.get(key), (int, float)):
            return float(prediction[key])
    for e in reversed(events):
        value = (e.get("data") or {}).get("predicted_error")
        if isinstance(value, (int, float)):
            return float(value)
    return None


def _error_figure(events: list, report: dict | None) -> str | None:
    """report.json's ``prediction.error_figure``, else the figure of the latest batch assessment
    (its bound, confidence and median estimate), else None."""
    from goniofrost.frost.confidence import figure

    said = ((report or {}).get("prediction") or {}).get("error_figure")
    if isinstance(said, str):
        return said
    latest = _assessment(events)
    if latest is None:
        return None
    error = "error in the scene's use" if latest.get("scope") == "scene" else "error"
    return figure(latest["bound"], latest["confidence"], latest["predicted_error"], error)


ASSESSMENT_FIELDS = ("batch", "samples", "predicted_error", "bound", "confidence", "target", "decision",
                     "out_of_model")


def _assessment(events: list) -> dict | None:
    """The fields of the latest "batch" event (the engine journals an Assess step's fields), or None."""
    for e in reversed(events):
        data = e.get("data") or {}
        if e.get("kind") == "batch" and all(k in data for k in ASSESSMENT_FIELDS):
            # scope (the error assessed, frost.scene_error) came later: older journals assessed the BRDF's
            return {k: data[k] for k in ASSESSMENT_FIELDS} | {"scope": data.get("scope", "brdf")}
    return None


def camera_settings(view: SessionView) -> dict:
    """The rig file's ``camera`` section as journaled (empty if it cannot be read)."""
    import yaml

    try:
        rig = yaml.safe_load(view.rig_text) or {}
    except yaml.YAMLError:
        return {}
    section = rig.get("camera") if isinstance(rig, dict) else None
    return section if isinstance(section, dict) else {}
