"""The catalogue of a folder of sessions (``goniofrost sessions ROOT``, ``goniofrost monitor ROOT``).

One ``SessionEntry`` per session folder directly under ROOT (a folder holding a journal): its
name, when it started, who measured which sample, its state, samples, predicted error and
duration. Everything is read through the monitor's read-only session reader
(``session_view.read_session``); the state comes from the typed run-end record (``RunEnd.status``)
and, for a run without one, from the session lock (held: running; free: the process was killed).
The samples of a queue not yet measured follow, "pending", in the queue's order: the queue files
named by the sessions' labels (``SessionLabel.queue``) whose root is ROOT say which they are.
"""
from __future__ import annotations

import datetime as dt
import time
from dataclasses import asdict, dataclass
from pathlib import Path

from goniofrost.core.errors import ConfigError
from goniofrost.capture.records import RunStatus
from goniofrost.monitor.session_view import journal_path, read_session

STATE_OF_STATUS = {RunStatus.FINISHED: "finished", RunStatus.TARGET_REACHED: "target reached",
                   RunStatus.PLAN_USED_UP: "plan used up", RunStatus.STOPPED_BY_OPERATOR: "interrupted",
                   RunStatus.FAULT: "faulted", RunStatus.REFUSED: "faulted"}
PENDING = "pending"   # a queue's sample without a session yet
STATES = ("finished", "target reached", "plan used up", "nothing measured", "interrupted", "faulted", "running",
          "not started", "unreadable", PENDING)


@dataclass(frozen=True)
class SessionEntry:
    """One session of the catalogue. Times are Unix seconds (``started_utc``: the first run's
    start; ``duration_s``: the runs' time added up, a run under way until now, a killed one
    until its last sample); ``state`` one of STATES; ``samples`` the samples measured,
    ``not_measured`` those journaled as not measured (too dark or saturated; done, without a value);
    ``predicted_error`` the median estimate of the reconstruction's log-relative MSE (or of the
    last batch's; ``session_view``), None before one; ``error_figure`` the sentence every output
    states of it (``frost.confidence.figure``), None before one; ``extrapolation`` when its report
    flags the reconstruction as an extrapolation (samples unlike every training material: the estimate is
    not backed by the training set); ``problem`` why a session is "unreadable" (its journal's path
    and the error); ``queue`` the queue file that measures it. A "pending" entry is a queue's
    sample not started: ``path`` the session folder it will have, no start, rig or plan yet."""

    name: str
    path: str
    started_utc: float | None
    operator: str | None
    sample_id: str | None
    material: str | None
    notes: tuple
    lab: str | None
    rig: str | None
    state: str
    samples: int
    samples_planned: int | None
    predicted_error: float | None
    duration_s: float
    error_figure: str | None = None
    not_measured: int = 0
    problem: str | None = None
    extrapolation: bool = False
    queue: str | None = None

    def as_json(self) -> dict:
        out = asdict(self)
        out["notes"] = list(self.notes)
        out["started"] = None if self.started_utc is None else iso_minutes(self.started_utc)
        return out


def session_state(view) -> str:
    """The state of a session (a SessionView) from its last run's RunEnd and the session lock;
    "nothing measured" when its runs completed with every plan sample journaled as not measured
    (too dark or saturated: there is no result, and running it again will not make one);
    "unreadable" when its journal is damaged (``view.unreadable``)."""
    if view.unreadable:
        return "unreadable"
    if view.run_end is not None:
        if view.run_end.status.completed and view.nothing_measured:
            return "nothing measured"
        return STATE_OF_STATUS[view.run_end.status]
    if view.capture_alive:
        return "running"
    return "interrupted" if view.run_spans else "not started"


def read_entry(session_dir: Path) -> SessionEntry:
    """The catalogue entry of the session in ``session_dir`` (read-only)."""
    view = read_session(session_dir)
    label, state = view.label or {}, session_state(view)
    commits = [d.committed_utc for d in (*view.done, *view.not_measured)]
    duration = 0.0
    for k, (start, end) in enumerate(view.run_spans):
        if end is None:  # under way (now), or killed: until its own last sample, if it took one
            live = state == "running" and k == len(view.run_spans) - 1
            end = time.time() if live else _last_commit_of_run(commits, view.run_spans, k)
        duration += max(0.0, end - start)
    return SessionEntry(name=Path(session_dir).name, path=str(session_dir), started_utc=view.first_started_utc,
                        operator=label.get("operator"), sample_id=label.get("sample_id"), material=view.material,
                        notes=tuple(label.get("notes") or ()), lab=label.get("lab"), rig=view.rig_name, state=state,
                        samples=len(view.done), samples_planned=len(view.plan),
                        predicted_error=view.predicted_error, error_figure=view.error_figure, duration_s=duration,
                        not_measured=len(view.not_measured),
                        problem=view.unreadable or None,
                        extrapolation=bool(((view.report or {}).get("prediction") or {}).get("extrapolation")),
                        queue=label.get("queue"))


def pending_entries(root: Path, entries) -> list[SessionEntry]:
    """The samples not started of every queue that measures into ``root`` (named by a session of
    ``entries``), in each queue's order, queues in the order of their first session. A queue file
    that is gone or no longer reads, or now measures elsewhere, has none."""
    from goniofrost.core.errors import GoniofrostError
    from goniofrost.capture.queue_file import read_queue

    started = {Path(e.path).resolve() for e in entries}
    out = []
    for path in dict.fromkeys(e.queue for e in entries if e.queue):
        try:
            queue = read_queue(path)
        except (GoniofrostError, OSError):
            continue
        if queue.root.resolve() != root.resolve():
            continue
        out += [SessionEntry(name=s.sample_id, path=str(root / s.sample_id), started_utc=None, operator=s.operator,
                             sample_id=s.sample_id, material=s.material, notes=s.notes, lab=None, rig=None,
                             state=PENDING, samples=0, samples_planned=None, predicted_error=None, duration_s=0.0,
                             queue=str(queue.path))
                for s in queue.samples if queue.session_dir(s).resolve() not in started]
    return out


def _last_commit_of_run(commits: list, spans: tuple, k: int) -> float:
    """The last sample committed by run ``k`` of ``spans`` (its start when it committed none):
    commits at or after its start and before the next run's. The session's last commit counted a
    killed run until the end of the run that resumed it (a run killed before its first sample and
    resumed at once made a 20 s session read 48 s)."""
    start = spans[k][0]
    until = spans[k + 1][0] if k + 1 < len(spans) else float("inf")
    return max((t for t in commits if start <= t < until), default=start)


def session_folders(root: Path) -> list[Path]:
    """The session folders directly under ``root`` (those holding a journal), by name; ``root``
    itself when it is one (``sessions s1`` lists s1, not an empty table)."""
    if journal_path(root).is_file():
        return [Path(root)]
    return sorted(p for p in Path(root).iterdir() if p.is_dir() and journal_path(p).is_file())


def parse_since(text: str | None) -> float | None:
    """``--since`` (an ISO date or date and time, UTC) as Unix seconds; ConfigError when it is none."""
    if text is None:
        return None
    try:
        when = dt.datetime.fromisoformat(text)
    except ValueError:
        raise ConfigError("command line", "--since", "a date YYYY-MM-DD or YYYY-MM-DDTHH:MM (UTC)", text) from None
    if when.tzinfo is None:
        when = when.replace(tzinfo=dt.timezone.utc)
    return when.timestamp()


def catalogue(root, sample: str | None = None, operator: str | None = None, since: float | None = None,
              missing_ok: bool = False) -> list:
    """Every session under ``root`` matching the filters (sample id and operator exactly, started at
    or after ``since``), oldest first (then by name), then its queues' pending samples in order.
    ``missing_ok``: a ``root`` that does not exist (yet) has none (else ConfigError)."""
    root = Path(root)
    if missing_ok and not root.exists():
        return []
    if not root.is_dir():
        raise ConfigError("command line", "ROOT", "a folder of session folders", str(root))
    entries = sorted((read_entry(p) for p in session_folders(root)),
                     key=lambda e: (e.started_utc if e.started_utc is not None else float("inf"), e.name))
    entries += pending_entries(root, entries)
    return [e for e in entries if (sample is None or e.sample_id == sample)
            and (operator is None or e.operator == operator)
            and (since is None or (e.started_utc is not None and e.started_utc >= since))]


def iso_minutes(t_utc: float) -> str:
    return dt.datetime.fromtimestamp(t_utc, dt.timezone.utc).strftime("%Y-%m-%d %H:%M")


COLUMNS = ("session", "started (UTC)", "operator", "sample", "state", "samples", "error (log-relative MSE)", "duration")


def table_rows(entries) -> list[tuple[str, ...]]:
    """The text cells of each entry, in COLUMNS order ("-" for what is not known: an unreadable
    journal's samples and duration are not 0)."""
    return [(e.name, "-" if e.started_utc is None else iso_minutes(e.started_utc), e.operator or "-",
             e.sample_id or "-", e.state, "-" if e.problem or e.state == PENDING else samples_text(e),
             "-" if e.error_figure is None else e.error_figure + (" (extrapolation)" if e.extrapolation else ""),
             "-" if e.problem or e.state == PENDING else duration_text(e.duration_s))
            for e in entries]


def samples_text(entry: SessionEntry) -> str:
    """'38/40', or '38/40 (2 not measured)' when some plan samples could not be measured."""
    text = f"{entry.samples}/{entry.samples_planned}"
    return text + (f" ({entry.not_measured} not measured)" if entry.not_measured else "")


def table_text(entries) -> str:
    """One line per session under a header, columns aligned; then one line per unreadable session
    saying why."""
    rows = [COLUMNS, *table_rows(entries)]
    widths = [max(len(r[i]) for r in rows) for i in range(len(COLUMNS))]
    table = "".join("  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() + "\n" for r in rows)
    return table + "".join(f"{e.name}: unreadable journal: {e.problem}\n" for e in entries if e.problem)


def duration_text(seconds: float) -> str:
    seconds = int(round(seconds))
    return f"{seconds // 3600}:{seconds // 60 % 60:02d}:{seconds % 60:02d}"


def catalogue_html(root) -> str:
    """The monitor's page of a folder of sessions: the catalogue as a table, each session's name a
    link to its own page (``/s/NAME/``; a pending sample has none yet); re-read every 5 s (a meta
    refresh: the page has no script). A ``root`` that does not exist yet is watched until it does."""
    from html import escape
    from urllib.parse import quote

    entries = catalogue(root, missing_ok=True)
    head = "".join(f"<th>{escape(c)}</th>" for c in COLUMNS)
    body = "".join(
        "<tr>" + (f"<td>{escape(e.name)}</td>" if e.state == PENDING
                  else f'<td><a href="/s/{quote(e.name)}/">{escape(e.name)}</a></td>')
        + "".join(f"<td>{escape(cell)}</td>" for cell in cells[1:]) + "</tr>"
        for e, cells in zip(entries, table_rows(entries)))
    missing = "" if Path(root).exists() else f'<p class="muted">{escape(str(root))} does not exist yet</p>'
    return ('<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8"><meta http-equiv="refresh" content="5">'
            '<title>goniofrost sessions</title><link rel="stylesheet" href="/static/monitor.css"></head><body>'
            f'<header><h1>goniofrost sessions</h1><span class="muted">{escape(str(root))}</span></header>'
            f'<section class="card"><table id="sessions"><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>'
            f'{missing}<p class="muted">{counts_text(entries)}</p></section></body></html>\n')


def counts_text(entries) -> str:
    """'3 session(s)', or '1 session(s), 2 pending'."""
    pending = sum(e.state == PENDING for e in entries)
    return f"{len(entries) - pending} session(s)" + (f", {pending} pending" if pending else "")


def is_catalogue(folder) -> bool:
    """True for a folder of sessions: no journal of its own, and a session folder in it."""
    folder = Path(folder)
    return not journal_path(folder).exists() and bool(session_folders(folder))
