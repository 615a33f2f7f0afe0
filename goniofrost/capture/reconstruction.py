"""The end of a session: reconstruct the full BRDF from the measured samples, write it, report.

``write_outputs`` writes ``DIR/brdf.binary`` (the Bayesian posterior mean on the model's grid, the
samples' uncertainties used), ``DIR/brdf.std.binary`` (its per-cell predictive standard deviation,
MERL layout, see ``goniofrost reconstruct``) and ``DIR/brdf.json`` (its predicted error), then the
reports (``capture.report``) and, when the caller hands one in, the comparison with a ground
truth (the demo's: ``goniofrost.app.ground_truth``). With fewer than MIN_MEASURED_SAMPLES measured samples there is nothing
to reconstruct: ``TooFewSamplesError``.
"""
from __future__ import annotations

import json
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from calib.measurement import remedy
from goniofrost.brdf.merl_file import valid_to_full
from goniofrost.capture.journal import by_reason
from goniofrost.capture.report import (bound_section, build_report, error_figure, extend_record,
                                       extrapolation_section, measurement_section, preview_title,
                                       read_earlier_record, scene_prediction, session_bound, summary_text,
                                       suspensions_section, target_section, whole_brdf_calibration,
                                       write_preview)
from goniofrost.core.atomic_file import write_text_atomic
from goniofrost.core.errors import GoniofrostError

# the posterior needs one measured sample (not a sentinel: those only check it) to say anything
MIN_MEASURED_SAMPLES = 1


class TooFewSamplesError(GoniofrostError):
    """Too few samples of a session were measured to reconstruct its BRDF (the others were not
    measured: too dark or saturated). ``measured``: the usable measured samples; ``needed``: the minimum;
    ``not_measured``: the journal's NotMeasuredRecords; ``plan_samples``: the plan's count."""

    def __init__(self, journal_path, measured: int, needed: int, not_measured: list, plan_samples: int) -> None:
        self.measured, self.needed, self.not_measured, self.plan_samples = measured, needed, not_measured, plan_samples
        grouped = by_reason(not_measured)
        why = "; ".join(f"{reason}: samples {' '.join(map(str, indices))}" for reason, indices in grouped.items())
        fixes = "; ".join(f"{reason}: {remedy(reason)}" for reason in grouped)
        super().__init__(
            f"{journal_path}: {measured} of {plan_samples} samples measured, {len(not_measured)} not measured ({why}): "
            f"a reconstruction needs at least {needed} measured sample(s); to measure them ({fixes}) capture "
            f"again in a new --session")


def check_enough_measured(inputs, records, not_measured, journal_path) -> None:
    """TooFewSamplesError when fewer than MIN_MEASURED_SAMPLES measured samples (sentinels not
    counted) are left to reconstruct from."""
    sentinel = getattr(inputs, "sentinel", None)
    usable = sum(1 for r in records if sentinel is None or not sentinel[r.plan_index])
    if usable < MIN_MEASURED_SAMPLES:
        raise TooFewSamplesError(journal_path, usable, MIN_MEASURED_SAMPLES, list(not_measured), len(inputs.samples))


def reconstruct_session(inputs, records):
    """The Bayesian reconstruction (frost.reconstruction.BayesReconstruction, on the valid cells)
    of the journaled samples, their measured standard deviations included."""
    from goniofrost.frost.reconstruction import reconstruct_bayes

    order = np.array([r.plan_index for r in records], dtype=np.int64)
    values = np.array([r.rgb for r in records], dtype=np.float64)
    sigmas = np.array([r.sigma for r in records], dtype=np.float64)
    return reconstruct_bayes(inputs.model, inputs.positions[order], values, sigmas=sigmas)


def write_outputs(inputs, journal, stats, session_dir, material=None, spec=None, compare=None) -> dict:
    """Reconstruct into brdf.binary (+ brdf.std.binary, brdf.json), write report.json and
    summary.txt; return the report. ``spec``: the SessionSpec (its target error, if any);
    ``material``: the ``SPEC:NAME`` a simulated rig showed; ``compare``: what the session is
    compared with (``reference(grid)``, the valid cells' table (n_valid, 3), and
    ``section(inputs, records, estimate, predicted, median)``, report.json's ``ground_truth``;
    ``goniofrost.app.ground_truth.GroundTruth``), None: nothing."""
    from goniofrost.capture.engine import SessionStats
    from goniofrost.frost.outputs import write_bayes_outputs

    records, dark = journal.samples(), journal.not_measured()
    check_enough_measured(inputs, records, dark, journal.path)
    session_dir = Path(session_dir)
    stats = stats or SessionStats(skipped=len(records) + len(dark))  # None: nothing was left to capture
    rec = reconstruct_session(inputs, records)   # the measured samples only
    grid = inputs.model.grid
    estimate, std = valid_to_full(rec.brdf, grid), valid_to_full(rec.std, grid)
    # tabulated once, here: the preview and the truth section both read it
    reference = valid_to_full(compare.reference(grid), grid) if compare is not None else None
    # The preview (rendering and PNG: about a second) needs only the estimate: drawn on a thread
    # beside the files and the report's other sections, which mostly run in numpy (GIL released).
    bound = session_bound(inputs, records, getattr(spec, "confidence", None))
    said = error_figure(inputs, bound, rec.predicted_error)
    label = journal.label().to_dict()
    title = preview_title(session_dir, label, material, said, bound)
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="preview") as pool:
        preview = pool.submit(write_preview, session_dir / "preview.png", estimate, grid, reference, std, title)
        earlier = read_earlier_record(session_dir / "brdf.json")  # its fields are kept, ours updated
        write_bayes_outputs(session_dir / "brdf.binary", inputs.model, rec, "samples.csv",
                            None if inputs.scene is not None else bound)
        runs = journal.runs()
        report = build_report(inputs, records, stats, session_dir, material, runs, dark)
        report["label"] = label
        report["suspensions"] = suspensions_section(journal.suspensions())
        report["prediction"] = {"estimator": "Bayesian posterior mean (all atoms, the samples' sigmas used)",
                                "error_figure": said,
                                "point_prediction_before_centring": rec.predicted_error, "cells": rec.samples,
                                "samples_used": len(records), "not_measured_left_out": len(dark),
                                **whole_brdf_calibration(inputs)}
        report["prediction"] |= extrapolation_section(inputs, records, bound) | bound_section(inputs, bound)
        if inputs.scene is not None:
            report["prediction"]["scene"] = scene_prediction(inputs, records)
        report["outputs"] |= {"std": "brdf.std.binary", "record": "brdf.json"}
        if spec is not None and spec.target is not None:
            report["target_error"] = target_section(spec, records, dark)
        if compare is not None:
            report["ground_truth"] = compare.section(inputs, records, estimate, rec.predicted_error,
                                                     report["prediction"].get("median_estimate"))
        report["rendering_snr_db"] = preview.result()
    report["outputs"]["preview"] = "preview.png"
    extend_record(session_dir / "brdf.json", earlier, measurement_section(inputs, report, [*records, *dark], runs))
    write_text_atomic(session_dir / "report.json", json.dumps(report, indent=1))
    write_text_atomic(session_dir / "summary.txt", summary_text(report))
    return report
