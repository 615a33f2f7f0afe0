"""The reports of a session: its sections, the preview, summary.txt and brdf.json's ``measurement``.

This module only writes, each atomically: ``DIR/preview.png`` (spheres with the uncertainty panel,
beside the ground truth and the actual error on a simulated rig), ``DIR/report.json`` and
``DIR/summary.txt``. The reconstruction is ``capture.reconstruction``'s; a comparison with ground
truth is handed in by the caller. Times come from the journal, so a resumed session reports every
run. With a target error the report holds every batch's predicted error and decision. Samples not
measured (``NotMeasuredRecord``) are left out of the reconstruction and listed, with why.
"""
from __future__ import annotations

import json
import sys
import threading
from pathlib import Path

import numpy as np

from calib.measurement import remedy
from goniofrost.core.atomic_file import write_text_atomic
from goniofrost.capture.journal import by_reason, json_limits


def build_report(inputs, records, stats, session_dir: Path, material: str | None, runs, not_measured=()) -> dict:
    """The report.json content (see module doc); ``runs``: the journal's (RunStart, RunEnd) pairs;
    ``not_measured``: the journal's NotMeasuredRecords (their motion and capture time count)."""
    snr = np.array([r.snr for r in records], dtype=np.float64)
    motion = float(sum(r.move_s for r in (*records, *not_measured)))
    capture = float(sum(r.capture_s for r in (*records, *not_measured)))
    return {
        "session": str(session_dir), "rig": inputs.rig.name, "simulated": bool(inputs.rig.simulated),
        "rig_file": str(inputs.rig.source), "plan": str(inputs.plan_path),
        "model": {"path": str(inputs.model_path), "hash": inputs.model.content_hash},
        "grid": inputs.model.grid.as_dict(), "material": material,
        "samples": len(records), "plan_samples": len(inputs.samples), "not_measured": not_measured_section(not_measured),
        "captured_this_run": stats.captured, "already_done": stats.skipped,
        "runs": len(runs), "last_run": _last_run(runs),
        "times_s": {"motion": motion, "capture": capture, "calibration_wall_this_run": stats.calibration_s,
                    "motion_and_capture": motion + capture, "session_clock_this_run": stats.ended_clock - stats.started_clock,
                    "wall_this_run": stats.wall_s, "planned_motion": _planned_motion(inputs.plan)},
        "snr": {"min": float(snr.min()), "median": float(np.median(snr)), "max": float(snr.max())},
        "markers_off": [r.plan_index for r in records if "markers-off" in r.status.split(",")],
        "roi_mixed": [r.plan_index for r in records if "roi-mixed" in r.status.split(",")],
        "detection_limit": [r.plan_index for r in records if "detection-limit" in r.status.split(",")],
        "per_sample": [{"index": r.plan_index, "cell": r.cell, "theta_h_deg": r.theta_h_deg,
                        "theta_d_deg": r.theta_d_deg, "phi_d_deg": r.phi_d_deg, "rgb": list(r.rgb),
                        "sigma": list(r.sigma), "snr": r.snr, "move_s": r.move_s, "capture_s": r.capture_s}
                       for r in records],
        "outputs": {"brdf": "brdf.binary", "samples": "samples.csv", "journal": "session.sqlite"},
    }


def not_measured_section(not_measured) -> dict:
    """report.json's ``not_measured``: how many plan samples were not measured, which, why, and the
    limits of their BRDF (1/sr per channel; an upper limit of None: none); none of them is in the
    reconstruction."""
    reasons = {reason: len(indices) for reason, indices in by_reason(not_measured).items()}
    return {"count": len(not_measured), "indices": [d.plan_index for d in not_measured], "reasons": reasons,
            "samples": [{"index": d.plan_index, "cell": d.cell, "theta_h_deg": d.theta_h_deg,
                         "theta_d_deg": d.theta_d_deg, "phi_d_deg": d.phi_d_deg, "reason": str(d.reason),
                         "snr": list(d.snr), "min_snr": d.min_snr, "longest_exposure_s": d.longest_exposure_s,
                         "upper_limit": json_limits(d.upper_limit), "lower_limit": list(d.lower_limit),
                         "why": d.why(), "move_s": d.move_s, "capture_s": d.capture_s}
                        for d in not_measured]}


def _last_run(runs) -> dict | None:
    """The last run's end as report.json has it: status (a RunStatus value) and reason; None
    before any run ended."""
    ends = [end for _start, end in runs if end is not None]
    return None if not ends else {"status": ends[-1].status.value, "reason": ends[-1].reason}


def _planned_motion(plan: dict) -> float | None:
    """The plan's motion time from home through the last sample and back home."""
    total = plan.get("planned_motion_s")
    return None if total is None else float(total)


def error_figure(inputs, bound, point: float) -> str:
    """The session's one statement of its error (``confidence.figure``): the whole BRDF's bound and
    median estimate; for a plan for a scene, whose design the whole BRDF's calibration is not of,
    the words say there is no calibrated bound and give the point prediction."""
    from goniofrost.frost.confidence import figure, figure_of

    if inputs.scene is not None:
        return figure(None, bound.confidence, None) + f" (uncalibrated point prediction {point:.3g})"
    return figure_of(bound)


def preview_title(session_dir, label: dict, material: str | None, said: str, bound) -> str:
    """The preview's title: what was measured (the sample id, else the material), the session,
    the error figure and, when the bound is an extrapolation, a stamp that says so."""
    what = label.get("sample_id") or material or "unnamed sample"
    stamp = "\nEXTRAPOLATION: the samples or design are unlike the training set" if bound.out_of_model else ""
    return f"{what}, session {Path(session_dir).name}" + (f" vs {material}" if material and material != what else "") \
        + f"\n{said}{stamp}"


def suspensions_section(suspensions) -> dict:
    """report.json's ``suspensions``: how many times a suspender paused the session, by reason, the
    session-clock seconds suspended, and each (``goniofrost.capture.records.Suspension``)."""
    reasons: dict = {}
    for s in suspensions:
        reasons[s.reason] = reasons.get(s.reason, 0) + 1
    return {"count": len(suspensions), "reasons": reasons,
            "waited_s": float(sum(s.waited_s or 0.0 for s in suspensions)),
            "each": [{"run": s.run, "reason": s.reason, "plan_index": s.plan_index, "started_utc": s.started_utc,
                      "ended_utc": s.ended_utc, "waited_s": s.waited_s, "end": None if s.end is None else str(s.end)}
                     for s in suspensions]}


def session_bound(inputs, records, confidence: float | None = None):
    """The whole BRDF's calibrated ErrorBound of the session's measured samples at ``confidence``
    (the session's; None: 95 %), as a target-error capture's last batch makes it
    (``target.Assessor``: the sentinels and check cells used when the plan has them). The report
    computes it once: the extrapolation flags and the bound are two readings of it."""
    from goniofrost.capture.target import DEFAULT_CONFIDENCE, make_assessor

    confidence = DEFAULT_CONFIDENCE if confidence is None else confidence
    return make_assessor(inputs.model, inputs.positions, confidence, None,
                         getattr(inputs, "sentinel", None))(records)


def extrapolation_section(inputs, records, bound=None) -> dict:
    """Whether the samples are unlike every training material, or the design unlike every design
    the calibration was fitted on: the reconstruction's predicted error is then an extrapolation
    the model's training does not back (``frost.confidence.extrapolation_fields``). ``bound``: the
    session's ``session_bound`` (None: computed here; the flags do not depend on its confidence)."""
    from goniofrost.frost.confidence import extrapolation_fields

    return extrapolation_fields(session_bound(inputs, records) if bound is None else bound)


def read_earlier_record(path: Path) -> dict:
    """The fields of a brdf.json already in the session folder ({} when there is none or it is
    not a JSON object): a record someone extended is extended again, not replaced."""
    try:
        earlier = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return {}
    return earlier if isinstance(earlier, dict) else {}


# Fields an earlier version of the reconstruction wrote into brdf.json and this one does not: not
# kept from an earlier record (a second error figure beside the one stated would contradict it)
SUPERSEDED_FIELDS = ("predicted_log_relative_mse",)


def extend_record(path: Path, earlier: dict, measurement: dict) -> None:
    """brdf.json = the earlier fields (but SUPERSEDED_FIELDS), the reconstruction's (just written)
    and ``measurement``."""
    kept = {k: v for k, v in earlier.items() if k not in SUPERSEDED_FIELDS}
    record = {**kept, **json.loads(Path(path).read_text()), "measurement": measurement}
    write_text_atomic(path, json.dumps(record, indent=1, allow_nan=False) + "\n")


def measurement_section(inputs, report: dict, records, runs) -> dict:
    """What brdf.json says of the measurement: what was measured, by whom, when (Unix times: the
    first run's start, the last sample's commit, ``records`` measured or not), on which rig (its lab
    section), with which alignment and model, how many samples it used and how many were not
    measured, its predicted error (whether that is calibrated for the plan's design, and whether it
    is an extrapolation: ``extrapolation_section``) and the goniofrost version that made it."""
    label = report["label"]
    return {"sample_id": label["sample_id"], "material": report["material"], "operator": label["operator"],
            "notes": label["notes"], "lab": label["lab"], "lens": label["lens"], "lamp": label["lamp"],
            "queue": label["queue"], "started_utc": runs[0][0].started_utc if runs else None,
            "ended_utc": max((r.committed_utc for r in records), default=None),
            "rig": {"name": inputs.rig.name, "file": str(inputs.rig.source), "simulated": bool(inputs.rig.simulated),
                    "kinematic_hash": inputs.rig.kinematic_hash},
            "alignment": None if inputs.rig.alignment is None else inputs.rig.alignment.record(),
            "model": report["model"], "samples": report["samples"],
            "samples_not_measured": report["not_measured"]["count"],
            "error_figure": report["prediction"]["error_figure"],
            "predicted_calibrated": report["prediction"]["calibrated"],
            "extrapolation": report["prediction"]["extrapolation"],
            **{key: report["prediction"][key] for key in ("median_estimate", "bound", "confidence")
               if key in report["prediction"]},
            "last_run": report["last_run"], "goniofrost_version": _version()}


def _version() -> str | None:
    """The installed goniofrost's version (None when it runs from a folder without installing)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("goniofrost")
    except PackageNotFoundError:
        return None


def bound_section(inputs, bound) -> dict:
    """The calibrated statement of every capture from its ``session_bound``: the median estimate of
    the whole BRDF's error and its bound at the session's confidence. Not for a plan for a scene,
    whose design the whole BRDF's calibration is not of (``whole_brdf_calibration``)."""
    if inputs.scene is not None:
        return {}
    return {"median_estimate": float(bound.median), "confidence": float(bound.confidence),
            "bound": float(bound.upper) if np.isfinite(bound.upper) else None}


def whole_brdf_calibration(inputs) -> dict:
    """Whether the whole BRDF's predicted error is calibrated for this plan's design. Its
    calibration was fitted on the designs for the whole BRDF; a plan for a scene (a usage map)
    puts its samples where the scene looks, and there the prediction can be far below the truth
    (builtin gold, 20 samples for the retro sphere: predicted 0.0099, actual 0.069)."""
    if inputs.scene is None:
        return {"calibrated": True}
    return {"calibrated": False, "uncalibrated_because": "the plan's design is for a scene's use (its usage map); "
            "the whole BRDF's prediction is calibrated on designs for the whole BRDF and can be far below the truth"}


def scene_prediction(inputs, records) -> dict:
    """The predicted error in the scene's use of a plan made with a usage map (``frost.scene_error``):
    the usage-weighted log-relative MSE of this reconstruction, beside the whole BRDF's."""
    from goniofrost.frost.reconstruction import predicted_error
    from goniofrost.frost.scene_error import NAMES, SCOPE_SCENE

    order = np.array([r.plan_index for r in records], dtype=np.int64)
    value = predicted_error(inputs.model, inputs.positions[order], np.array([r.rgb for r in records], dtype=np.float64),
                            np.array([r.sigma for r in records], dtype=np.float64), scene=inputs.scene)
    return {"error": NAMES[SCOPE_SCENE], "predicted_log_relative_mse": value, "usage_hash": inputs.scene.usage_hash,
            "calibrated": bool(inputs.scene.calibration), "weighting": "log-relative squared error weighted by the "
            "scene's use of every cell (PLAN.json usage)"}


def target_section(spec, records, not_measured=()) -> dict:
    """The target-error part of report.json: every batch's predicted error and decision (of its
    measured samples only), and why the capture stopped ("target reached", "plan used up", or "not
    finished" if interrupted)."""
    from goniofrost.capture.target import CONTINUE, history, statement

    batches = history(spec.assess, spec.batch_ends, spec.target, records, [d.plan_index for d in not_measured])
    for batch in batches:
        batch["out_of_model"] = list(batch["out_of_model"])
    stopped = batches[-1]["decision"] if batches and batches[-1]["decision"] != CONTINUE else "not finished"
    last = batches[-1] if batches else None
    from goniofrost.frost.scene_error import NAMES, SCOPE_BRDF

    scope = getattr(spec.assess, "scope", SCOPE_BRDF)
    return {"target": spec.target, "error": NAMES[scope], "scope": scope, "confidence": spec.confidence,
            "plan_samples": len(spec.samples),
            "samples_used": len(records), "not_measured": len(not_measured), "batch_ends": list(spec.batch_ends),
            "batches": batches,
            "stopped": stopped, "statement": statement(last) if last else "no batch was completed",
            "bound": None if last is None else last["bound"],
            "median_estimate": None if last is None else last["predicted_error"],
            "extrapolation": bool(last and last["out_of_model"])}


_RENDERER_IMPORT: threading.Thread | None = None


def preload_preview() -> None:
    """Import the preview's renderer (matplotlib: 1 to 3 s) on a thread while the session runs, whose
    steps mostly wait on devices and on compiled code; ``write_preview`` waits for it."""
    global _RENDERER_IMPORT
    if _RENDERER_IMPORT is None and "matplotlib.figure" not in sys.modules:
        _RENDERER_IMPORT = threading.Thread(target=_import_renderer, name="preview-import", daemon=True)
        _RENDERER_IMPORT.start()


def _import_renderer() -> None:
    try:
        import matplotlib.backends.backend_agg  # noqa: F401
        import matplotlib.figure  # noqa: F401
    except ImportError:   # write_png's own import raises it where it can be reported
        pass


def write_preview(path: Path, estimate: np.ndarray, grid, reference=None, std=None,
                  title: str | None = None) -> float | None:
    """Write the sphere preview with the uncertainty panel (beside ``reference``, the ground truth
    on the full grid (n_cells, 3), and the actual error on a simulated rig); return its rendering
    SNR in dB (None without a reference). title: the preview's (``preview_title``)."""
    from goniofrost.brdf.preview import preview_of, write_png

    if _RENDERER_IMPORT is not None:
        _RENDERER_IMPORT.join()

    preview = preview_of(estimate, grid, reference, std=std)
    write_png(path, preview, title=title or "session estimate")
    return preview.snr_db


def _prediction_lines(prediction: dict, std_file: str) -> list[str]:
    """The summary's statement of the reconstruction's error: its ``error_figure``, marked when
    it is not calibrated for the plan's design."""
    lines = [f"reconstruction (log-relative MSE): {prediction['error_figure']}",
             f"  per-cell standard deviation in {std_file}"]
    if not prediction.get("calibrated", True):
        lines.append(f"  uncalibrated: {prediction['uncalibrated_because']}")
    return lines


def _estimates(truth: dict, prediction: dict) -> str:
    """What the capture said of its error, for the line beside the actual one."""
    return prediction["error_figure"] + ("" if prediction.get("calibrated", True) else ", uncalibrated")


def _pct(value) -> str:
    return "n/a" if value is None else f"{100 * value:.2f} %"


def _fmt(value, spec: str) -> str:
    return "n/a" if value is None else format(value, spec)


def snr_text(snr: float) -> str:
    """A sample's SNR (its worst channel's, dimensionless) for the summary's list: whole numbers from 10
    on, 2 significant digits below, where a channel at its detection limit sits (its patch mean can
    fall below the dark level: -0.039 printed as "-0")."""
    return f"{snr:.0f}" if abs(snr) >= 10 else f"{snr:.2g}"


def summary_text(report: dict) -> str:
    """A short readable summary of a report (a few lines)."""
    from goniofrost.frost.confidence import extrapolation_lines

    t = report["times_s"]
    label = report.get("label") or {}
    who = ", ".join(f"{k.replace('_', ' ')} {label[k]}" for k in ("sample_id", "operator") if label.get(k))
    lines = [
        f"session {report['session']}: {report['samples']} samples"
        + (f" measured and {report['not_measured']['count']} not measured" if report['not_measured']['count'] else "")
        + f" on rig {report['rig']!r}"
        f" ({report['captured_this_run']} this run, {report['already_done']} from before; {report['runs']} run(s))"
        + (f"; {who}" if who else ""),
        f"motion {t['motion']:.1f} s + capture {t['capture']:.1f} s = {t['motion_and_capture']:.1f} s"
        + (" (simulated rig: axis motion profiles and exposure time)" if report["simulated"] else "")
        + (f"; planned motion {t['planned_motion']:.1f} s" if t.get("planned_motion") is not None else ""),
        f"this run: calibration {t['calibration_wall_this_run']:.1f} s, whole run {t['wall_this_run']:.1f} s (wall clock)",
        f"SNR per sample: min {report['snr']['min']:.1f}, median {report['snr']['median']:.1f}, max {report['snr']['max']:.1f}",
        "  " + " ".join(f"{s['index']}:{snr_text(s['snr'])}" for s in report["per_sample"]),
    ]
    target = report.get("target_error")
    if target:
        lines.append(f"target {target.get('error', 'error')} {target['target']:g} at {100 * target['confidence']:g} % confidence: "
                     f"{target['stopped']} after {target['samples_used']} of {target['plan_samples']} samples: "
                     f"{target['statement']}")
        lines.append("  bound (median estimate) after each batch: " + ", ".join(
            f"{b['samples']}: {_fmt(b['bound'], '.3g')} ({b['predicted_error']:.3g})" for b in target["batches"]))
    lines += _prediction_lines(report["prediction"], report["outputs"]["std"])
    scene = report["prediction"].get("scene")
    if scene:
        lines.append(f"predicted {scene['error']} (the plan's usage map): log-relative MSE "
                     f"{scene['predicted_log_relative_mse']:.4g}" + ("" if scene["calibrated"] else " (uncalibrated)"))
    lines += extrapolation_lines(report["prediction"])
    off = report.get("markers_off", [])
    if off:
        lines.append(f"{len(off)} sample(s) saw the holder's markers away from where the camera model puts them "
                     f"(flag markers-off: {' '.join(map(str, off))}): the rig may be misaligned; run goniofrost align "
                     f"and capture with --alignment")
    mixed = report.get("roi_mixed", [])
    if mixed:
        lines.append(f"{len(mixed)} sample(s) had a region of interest that took in the card around the patch "
                     f"(flag roi-mixed: {' '.join(map(str, mixed))}): their values are not to be trusted; the rig may be "
                     f"misaligned")
    suspended = report.get("suspensions") or {}
    if suspended.get("count"):
        lines.append(f"suspended {suspended['count']} time(s) for {suspended['waited_s']:g} s of session clock ("
                     + ", ".join(f"{reason} {n}" for reason, n in suspended["reasons"].items()) + ")")
    dark = report["not_measured"]
    if dark["count"]:
        lines.append(f"{dark['count']} sample(s) NOT MEASURED, left out of the reconstruction and its predicted error, "
                     f"which use the {report['samples']} measured samples only:")
        lines += [f"  sample {d['index']}: {d['reason']}: {d['why']}" for d in dark["samples"]]
        lines += [f"  to measure the {reason} ones: {remedy(reason)} and capture them in a new session"
                  for reason in dark["reasons"]]
    limited = report.get("detection_limit", [])
    if limited:
        lines.append(f"{len(limited)} sample(s) have a channel at its detection limit (flag detection-limit: "
                     f"{' '.join(map(str, limited))}): below the minimum SNR with the longest exposure the channel "
                     f"allows, recorded with its uncertainty, which the reconstruction weighs")
    truth = report.get("ground_truth")
    if truth:
        lines.append(f"rendering SNR of the preview against the ground truth: {report['rendering_snr_db']:.2f} dB")
        lines.append(f"error against the ground truth {truth['material']}: log-relative MSE {truth['log_relative_mse']:.4g}"
                     f" ({_estimates(truth, report['prediction'])}; exact values at the same cells:"
                     f" {truth['log_relative_mse_exact_samples']:.4g}, ratio {_fmt(truth['ratio_to_exact'], '.3f')})")
        graz = truth["grazing"]
        lines.append(f"median sample error {_pct(truth['sample_relative_error_median'])} against the cells' values,"
                     f" {_pct(truth['sample_relative_error_median_at_measured_directions'])} at the directions measured;"
                     f" beyond {graz['beyond_deg']:g} deg ({graz['samples']} samples):"
                     f" {_pct(graz['sample_relative_error_median'])}, {_pct(graz['sample_relative_error_median_at_measured_directions'])}")
    outputs = report["outputs"]
    written = [outputs[key] for key in ("brdf", "std", "record", "samples", "preview") if key in outputs]
    lines.append(f"wrote {', '.join(written)}, report.json, summary.txt in {report['session']}")
    return "\n".join(lines) + "\n"
