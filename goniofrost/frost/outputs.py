"""The output files of a Bayesian reconstruction: OUT (the BRDF, MERL .binary), OUT.std.binary
(the predictive standard deviation of every cell, MERL layout) and OUT.json (what was
reconstructed, how, and its predicted error). The estimators (``reconstruction``) write nothing.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from goniofrost.frost.model import FrostModel
from goniofrost.frost.reconstruction import BayesReconstruction, ReconstructionError


def bayes_output_paths(out) -> tuple[Path, Path]:
    """(OUT.std.binary, OUT.json) beside OUT (OUT's ``.binary`` suffix, in any case, replaced: the
    case ``check_output_suffix`` accepts)."""
    out = Path(out)
    stem = out.with_suffix("") if out.suffix.lower() == ".binary" else out
    return stem.with_name(stem.name + ".std.binary"), stem.with_name(stem.name + ".json")


def write_bayes_outputs(out, model: FrostModel, rec: BayesReconstruction, samples_source=None,
                        bound=None) -> tuple[Path, Path]:
    """Write OUT (the BRDF), OUT.std.binary (the predictive std, MERL layout) and OUT.json.

    See ``goniofrost/app/commands/reconstruct.py`` for the std file's format. Returns the paths
    of the two side files. Nothing is written if any value is not finite. ``bound``: the samples'
    ``confidence.ErrorBound``, whose flags OUT.json records (``confidence.extrapolation_fields``);
    None: none recorded (a capture's brdf.json records its session's in ``measurement``).
    """
    import json

    from goniofrost.brdf.merl_file import valid_to_full, write_merl
    from goniofrost.core.atomic_file import write_text_atomic

    std_path, record_path = bayes_output_paths(out)
    if rec.std is None or not np.all(np.isfinite(rec.std)):
        raise ReconstructionError(f"{std_path}: the predictive standard deviation is missing or not finite")
    record = reconstruction_record(model, rec, samples_source, Path(out).name, std_path.name, bound)
    text = json.dumps(record, indent=1, allow_nan=False)
    write_merl(out, valid_to_full(rec.brdf, model.grid), model.grid)
    write_merl(std_path, valid_to_full(rec.std, model.grid), model.grid)
    write_text_atomic(record_path, text + "\n")
    return std_path, record_path


def reconstruction_record(model: FrostModel, rec: BayesReconstruction, samples_source, brdf_name: str,
                          std_name: str, bound=None) -> dict:
    """The OUT.json content: what was reconstructed, how, and its error: with ``bound`` (a
    ``confidence.ErrorBound`` of the samples) the error figure, the bound and median estimate and
    whether that is an extrapolation, and why; without, the point prediction."""
    from goniofrost.frost.confidence import extrapolation_fields, figure_of

    flags = {} if bound is None else extrapolation_fields(bound)
    # with a bound: the one error figure (the point prediction before centring stays in report.json)
    error = {"predicted_log_relative_mse": rec.predicted_error} if bound is None else {
        "error_figure": figure_of(bound), "median_estimate": float(bound.median), "confidence": float(bound.confidence),
        "bound": float(bound.upper) if np.isfinite(bound.upper) else None}
    return {
        "brdf": brdf_name, "std": std_name,
        "std_meaning": "predictive standard deviation of ln(w x + eps) per cell and channel (MERL layout; "
                       "read it with any MERL reader that applies the channel scales)",
        "estimator": "bayes posterior mean, all atoms",
        "model": {"hash": model.content_hash, "noise": model.noise.get("kind", "scalar")},
        "samples_file": None if samples_source is None else str(samples_source),
        "cells": rec.samples, **error,
        "features": {"design_error": rec.design_error, "z2": rec.z2, "energy": rec.energy,
                     "level": rec.level, "spread": rec.spread},
        **flags,
        "interval_90": "((w x + eps) * exp(+-1.645 std) - eps) / w",
    }
