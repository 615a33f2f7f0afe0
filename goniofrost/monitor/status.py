"""What the monitor page shows, computed from a ``SessionView``: one JSON-ready dict.

``page_state`` gives the session's state (waiting, unreadable, running, stopped, stalled,
reconstructing, nothing measured, finished, faulted, interrupted, failed), "N of M samples",
the ETA (wall seconds after the last journaled sample: k x the planned moves left + c x the
samples left, k and c fitted on this run's samples), the poses, every plan sample's state and the
latest pictures. What each state means: docs/explanations/monitor.md."""
from __future__ import annotations

import math
import statistics

import numpy as np

from goniofrost.capture.records import RunStatus
from goniofrost.frost.stopping import Decision

# The enums whose values the state carries, by member name: the one place the page's script reads
# them from (it compares ``a.decision === names.decision.TARGET_REACHED``, never a sentence of its own).
ENUMS = {"decision": {m.name: m.value for m in Decision}, "run_status": {m.name: m.value for m in RunStatus}}

MIN_FIT = 3              # samples of this run before the ETA's wall model is fitted
STALL_MIN_S = 300.0      # never call a capture stalled sooner than this
STALL_SAMPLES = 10.0     # ... or sooner than this many median sample times


def page_state(view, now_utc: float, *, attached: bool = False, ended_message: str | None = None,
               rig=None) -> dict:
    """The page's state dict for ``view`` at Unix time ``now_utc`` (see module doc).

    ``attached``: the monitor runs inside the capture's process; ``rig``: the session's
    ``planner.rig.Rig`` for the pose drawings (None: no drawings).
    """
    done = {d.plan_index: d for d in view.done}
    dark = {d.plan_index: d for d in view.not_measured}   # done too, without a value
    journaled, total = done | dark, len(view.plan)
    state, hint = _state(view, now_utc, attached, ended_message, journaled, total)
    pending = [s.index for s in view.plan if s.index not in journaled]
    failed = view.stop.plan_index if view.stop and view.stop.plan_index not in journaled else None
    next_index = pending[0] if pending else None  # after a stop: the sample a resume starts with
    eta = eta_seconds(view, done) if state in ("running", "waiting") else None
    latest = max(view.done, key=lambda d: d.committed_utc) if view.done else None
    return {
        "session": str(view.session_dir), "plan_key": view.plan_key, "rig": view.rig_name,
        "material": view.material, "journal_found": view.journal_found,
        "label": view.label, "label_text": label_text(view.label),
        "state": state, "hint": hint, "attached": attached,
        "done": len(done) + len(dark), "total": total, "count_text": count_text(len(done), len(dark), total),
        "not_measured": [_not_measured(d) for d in view.not_measured],
        "eta_s": eta, "eta_text": eta_text(eta, state), "eta_from_utc": latest.committed_utc if latest else None,
        "last_event": _last_event(view),
        "samples": _sample_columns(view, done, next_index, failed, dark),
        "latest": None if latest is None else _latest(latest),
        "poses": _poses(view, rig, latest, next_index if state in ("running", "stalled") else None),
        "stop": None if view.stop is None else {
            "status": view.stop.status.value, "message": view.stop.message, "detail": view.stop.detail,
            "axis": view.stop.axis, "plan_index": view.stop.plan_index},
        "run_end": None if view.run_end is None else {
            "status": view.run_end.status.value, "reason": view.run_end.reason,
            "samples_planned": view.run_end.samples_planned, "samples_captured": view.run_end.samples_captured},
        "ended_message": ended_message,
        "predicted_error": view.predicted_error,
        "error_figure": view.error_figure,
        "assessment": view.assessment,
        "calibrated": view.calibrated,
        "files": list(view.files),
        "summary": view.summary,
        "names": ENUMS,
    }


def count_text(measured: int, not_measured: int, total: int) -> str:
    """'5 of 40 samples' ('5 of 40 samples (1 not measured)' when some of them could not be measured)."""
    if not total:
        return "no plan yet"
    return f"{measured + not_measured} of {total} samples" + (f" ({not_measured} not measured)" if not_measured else "")


def _not_measured(d) -> dict:
    return {"plan_index": d.plan_index, "reason": d.reason, "snr": [_finite(v) for v in d.snr], "min_snr": d.min_snr,
            "longest_exposure_s": d.longest_exposure_s, "upper_limit": [_finite(v) for v in d.upper_limit],
            "lower_limit": [_finite(v) for v in d.lower_limit]}


def _state(view, now_utc, attached, ended_message, done, total) -> tuple[str, str]:
    """(state, a one-line hint) as the module doc defines them; ``done``: the plan samples
    journaled, measured or not."""
    if ended_message:
        return "failed", ended_message
    if view.unreadable:
        return "unreadable", (f"the session journal cannot be read ({view.unreadable}): it is damaged or not a "
                              f"journal; the files beside it are untouched")
    if not view.journal_found:
        return "waiting", f"waiting for the capture to start ({view.note})"
    if view.stop is not None:
        what = "interrupted" if view.stop.status is RunStatus.STOPPED_BY_OPERATOR else "faulted"
        return what, f"{what} with {len(done)} of {total} samples safe in the journal: what happened and what to do below"
    end = view.run_end
    complete = (end is not None and end.status.completed) or (bool(total) and len(done) >= total)
    if complete and view.nothing_measured:
        reasons = sorted({str(d.reason) for d in view.not_measured})
        return "nothing measured", (f"every sample journaled is not measured ({', '.join(reasons)}): there is no BRDF to "
                                    f"reconstruct; the summary of `goniofrost capture` says what to change in the rig file")
    if complete and view.report is not None:
        why = end.reason if end is not None else f"all {total} samples captured"
        return "finished", f"finished: {why}; results written to {view.session_dir}"
    if not attached and view.capture_alive is False:
        return "stopped", (f"the capture process is gone without journaling why (killed, or the computer stopped?) "
                           f"with {len(done)} of {total} samples safe: run the same capture command with --resume "
                           f"to {'write the results' if complete else 'continue'}")
    if complete:
        why = end.reason if end is not None else f"all {total} samples captured"
        return "reconstructing", f"{why}; reconstructing the BRDF and writing the report"
    idle = now_utc - last_activity_utc(view)
    if not attached and view.capture_alive is None and idle > stall_after_s(view):
        return "stalled", (f"no journal activity for {duration_text(idle)}: if the capture process is gone "
                           f"(killed?), run the same capture command with --resume to continue")
    doing = step_text(view.step)
    if not view.calibrated:
        return "running", f"homing and calibrating (dark frames, flat field, white reference){doing}"
    return "running", f"capturing: {len(done)} of {total} samples journaled{doing}"


def step_text(step: dict | None) -> str:
    """'; now: ...' for the journal's running step (empty when none is running)."""
    if not step or step["status"] != "running":
        return ""
    kind, detail, index = step["kind"], step["detail"] or {}, step["plan_index"]
    sample = f"sample {index}" if index is not None else "the calibration"
    text = {"Move": f"moving to {sample if index is not None else 'the white reference pose'}",
            "Expose": f"exposing {detail.get('exposure_s', '?')} s for {sample} ({detail.get('file', '')})",
            "Home": "homing every axis", "LampOn": "switching the lamp on", "LampOff": "switching the lamp off",
            "SetTarget": f"showing the camera the {detail.get('target', '?')} target",
            "Commit": f"journaling {sample}", "SaveCalibration": "saving the calibration"}.get(kind, kind)
    return f"; now: {text}"


def last_activity_utc(view) -> float:
    """Unix time of the latest event or sample commit (0 if none)."""
    times = [e["t_utc"] for e in view.events] + [d.committed_utc for d in (*view.done, *view.not_measured)]
    return max(times, default=0.0)


def stall_after_s(view) -> float:
    """Idle seconds after which a running capture counts as stalled (module doc)."""
    walls = [d.committed_utc - d.started_utc for d in view.done]
    typical = statistics.median(walls) if walls else 0.0
    return max(STALL_MIN_S, STALL_SAMPLES * typical)


def eta_seconds(view, done: dict) -> float | None:
    """Wall seconds left after the last journaled sample (module doc); None before this run's
    first sample."""
    this_run = [d for d in done.values()
                if view.run_started_utc is None or d.started_utc >= view.run_started_utc]
    if not this_run:
        return None
    k, c = wall_model([d.move_s for d in this_run], [d.capture_s for d in this_run],
                      [d.committed_utc - d.started_utc for d in this_run])
    left = [s for s in view.plan if s.index not in done and all(d.plan_index != s.index for d in view.not_measured)]
    return k * sum(s.planned_move_s for s in left) + c * len(left)


def wall_model(move_s, capture_s, wall_s) -> tuple[float, float]:
    """(k, c) of wall = k x move + c per sample (module doc): least squares with k, c >= 0 over
    at least MIN_FIT samples whose moves differ; else k = total wall / total rig time and
    c = k x the median capture time."""
    from scipy.optimize import nnls

    move, wall = np.asarray(move_s, dtype=np.float64), np.asarray(wall_s, dtype=np.float64)
    if move.size >= MIN_FIT and np.ptp(move) > 0:
        (k, c), _ = nnls(np.stack([move, np.ones_like(move)], axis=1), wall)
        return float(k), float(c)
    rig = float(np.sum(move) + np.sum(capture_s))
    k = float(np.sum(wall)) / rig if rig > 0 else 0.0
    return k, (k * float(np.median(capture_s)) if rig > 0 else float(np.median(wall)))


def duration_text(seconds: float) -> str:
    """'42 s', '3 min 20 s', '2 h 05 min'."""
    s = int(round(max(seconds, 0.0)))
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60:02d} s"
    return f"{s // 3600} h {(s % 3600) // 60:02d} min"


def eta_text(eta: float | None, state: str) -> str:
    if state not in ("running", "waiting"):
        return ""
    if eta is None:
        return "ETA after the first sample"
    return "less than 1 s left" if eta < 1 else f"about {duration_text(eta)} left"


def _last_event(view) -> dict | None:
    """The journal's latest event, or the latest sample commit when that came later."""
    latest = max(view.done, key=lambda d: d.committed_utc, default=None)
    e = view.events[-1] if view.events else None
    if latest is not None and (e is None or latest.committed_utc > e["t_utc"]):
        e = {"kind": "sample", "axis": None, "t_utc": latest.committed_utc,
             "message": f"sample {latest.plan_index} journaled (SNR {latest.snr:.0f}, {len(latest.raw_paths)} frames)"}
    if e is None:
        return None
    return {"kind": e["kind"], "message": e["message"], "axis": e["axis"], "t_utc": e["t_utc"]}


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def _sample_columns(view, done: dict, next_index, failed, dark: dict | None = None) -> dict:
    """Per plan sample (capture order): status done|not-measured|next|pending|failed, angles, SNR,
    exposure, flags (a sample not measured: its reason)."""
    status, snr, exposure, flags = [], [], [], []
    for s in view.plan:
        d = done.get(s.index)
        if d is None and dark and s.index in dark:
            n = dark[s.index]
            status.append("not-measured")
            snr.append(_finite(n.best_snr))
            exposure.append(_finite(sum(n.exposures_s)))
            flags.append(n.reason)
            continue
        status.append("done" if d else "failed" if s.index == failed else "next" if s.index == next_index
                      else "pending")
        snr.append(None if d is None else _finite(d.snr))
        exposure.append(None if d is None else _finite(sum(d.exposures_s)))
        flags.append("" if d is None or d.status == "ok" else d.status)
    return {"theta_i_deg": [_finite(s.theta_i_deg) for s in view.plan],
            "theta_o_deg": [_finite(s.theta_o_deg) for s in view.plan],
            "status": status, "snr": snr, "exposure_s": exposure, "flags": flags}


def _latest(d) -> dict:
    return {"plan_index": d.plan_index, "snr": _finite(d.snr), "exposures_s": list(d.exposures_s),
            "frames": len(d.raw_paths), "rgb": [_finite(v) for v in d.rgb], "status": d.status}


def _poses(view, rig, latest, next_index) -> dict:
    """Drawings of the last confirmed pose (where a stop confirmed the axes at rest; else the last
    completed move or homing; the last journaled sample's joints; the rig's home before any) and
    of the next plan sample's target pose (``next_index``: None once the run has ended). The
    sample the rig has reached and is measuring is never also the next."""
    if rig is None:
        return {"current": None, "next": None}
    from goniofrost.monitor.rig_pose import pose_drawing

    label, joints = _current_pose(view, rig, latest)
    current = {"label": label, **pose_drawing(rig, joints)}
    here = (view.reached or {}).get("plan_index")
    if next_index is not None and next_index == here:  # being measured: the next is the one after it
        next_index = next((s.index for s in view.plan[here + 1:] if s.index not in _journaled(view)), None)
    nxt = None
    if next_index is not None:
        s = view.plan[next_index]
        nxt = {"label": f"sample {s.index} (target)", "theta_i_deg": s.theta_i_deg, "theta_o_deg": s.theta_o_deg,
               **pose_drawing(rig, s.joints)}
    return {"current": current, "next": nxt}


def _current_pose(view, rig, latest) -> tuple[str, dict]:
    """(label, joints {axis: deg}) of the rig's last confirmed pose (see ``_poses``)."""
    if view.reached is not None:
        index, kind = view.reached["plan_index"], view.reached.get("kind", "Move")
        label = ("home (reached)" if kind == "Home" else f"sample {index} (reached)" if index is not None
                 else "white reference (reached)")
        joints = dict(view.reached["joints"])
    elif latest is not None:
        label, joints = f"sample {latest.plan_index} (reached)", dict(latest.joints)
    else:
        label, joints = "home", {a.name: a.home_deg for a in rig.ordered_axes}
    stops = view.run_end.stops if view.stop is not None and view.run_end is not None else ()
    if stops:  # the stop's own readings are the last confirmed pose; an unconfirmed axis keeps its last reached
        joints.update({s.axis: s.position_deg for s in stops if s.confirmed and s.position_deg is not None})
        unsure = [s.axis for s in stops if not s.confirmed or s.position_deg is None]
        label = ("where the stop left it (every axis confirmed at rest)" if not unsure else
                 f"where the stop left it ({', '.join(unsure)} not confirmed: the last pose it reached shown)")
    return label, joints


def _journaled(view) -> set:
    """Plan indices journaled, measured or not."""
    return {d.plan_index for d in (*view.done, *view.not_measured)}


def label_text(label: dict) -> str:
    """Who measured what, for the page's header ("sample S-001 · operator A. Operator · lab ..."); ''
    for a session without a label."""
    label = label or {}
    parts = [f"{name.replace('_id', '')} {label[name]}" for name in ("sample_id", "operator", "lab", "lens", "lamp")
             if label.get(name)]
    parts += [f"note: {note}" for note in label.get("notes") or ()]
    return "  ·  ".join(parts)
