"""Numerical stress cases of selection and reconstruction (``goniofrost bench --stress``).

Each case runs on fold 0 and ends in a record whose ``status`` is "ok", "error" (a clear
GoniofrostError), "failure" or "non-finite" (findings to fix); stress.json is strict JSON. The
cases: docs/benchmarks/stress.md.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from goniofrost.bench.baselines import condition_numbers, nielsen_path, random_select, uniform_select
from goniofrost.core.errors import GoniofrostError
from goniofrost.core.grid import MerlGrid
from goniofrost.bench.config import BenchConfig, fold_split, method_rng
from goniofrost.bench.data import open_tables
from goniofrost.frost.metrics import batch_log_errors
from goniofrost.bench.results import json_text, write_atomic

NOISE_MULTIPLICATIVE = (0.001, 0.01, 0.05, 0.2)
ETAS = (0.0, 0.1, 1.0, 10.0, 40.0, 100.0, 1000.0)
GRAZING_DEG = 80.0
DYNAMIC_RANGE_WORDS = ("chrome", "black")
# bayes last: the noise case draws from one stream in this order, so the other methods keep their draws.
STRESS_METHODS = ("frost", "frost-firstm", "nielsen", "random", "uniform", "bayes")


def record(case: str, variant: str, method: str, m, outcome) -> dict:
    """One result line; ``outcome`` is a dict of numbers (ok) or an exception."""
    out = {"case": case, "variant": variant, "method": method, "m": None if m is None else int(m)}
    if isinstance(outcome, GoniofrostError):
        return out | {"status": "error", "message": str(outcome)}
    if isinstance(outcome, BaseException):
        return out | {"status": "failure", "message": f"{type(outcome).__name__}: {outcome}"}
    values = {k: (float(v) if isinstance(v, (float, np.floating, int, np.integer)) and not isinstance(v, bool) else v)
              for k, v in outcome.items()}
    bad = [k for k, v in values.items() if isinstance(v, float) and not math.isfinite(v)]
    if bad:
        return out | {"status": "non-finite", "message": f"non-finite {', '.join(bad)}",
                      "values": {k: v for k, v in values.items() if k not in bad}}
    return out | {"status": "ok", "values": values}


def attempt(fn, *args, **kwargs):
    """fn's result, or the exception it raised (reported as a record, never re-raised)."""
    try:
        return fn(*args, **kwargs)
    except Exception as exc:  # the case boundary: every outcome becomes a record
        return exc


class StressSetup:
    """Fold 0: the training model (dynamic-range materials left out) and the test materials."""

    def __init__(self, config: BenchConfig, path, names: list[str]) -> None:
        from goniofrost.frost.training import TrainingOptions, fit_model

        self.config, self.names = config, names
        self.tables = open_tables(path)
        train, test = fold_split(len(names), config, 0)
        self.dr = [i for i, n in enumerate(names) if any(w in n for w in DYNAMIC_RANGE_WORDS)]
        self.train = np.array([i for i in train if i not in self.dr])
        self.test = np.array([i for i in test if i not in self.dr])
        self.k_max = max(config.m_values)
        self.model = fit_model(np.asarray(self.tables[self.train]), self.train_names, config.grid,
                               TrainingOptions(k_max=self.k_max))

    @property
    def train_names(self) -> list[str]:
        return [self.names[i] for i in self.train]

    def truth(self, idx) -> np.ndarray:
        return np.asarray(self.tables[np.asarray(idx)])


# ----- selections and errors ------------------------------------------------------------
def select(model, method: str, m: int, config: BenchConfig, candidates=None) -> np.ndarray:
    """Positions of one method's design (Nielsen: one trial); ``candidates`` a bool mask."""
    from goniofrost.frost.selection import select_cells

    if method == "bayes":
        from goniofrost.frost.bayes_selection import select_bayes
        return np.asarray(select_bayes(model, m, candidates=candidates).positions)
    if method in ("frost", "frost-firstm"):
        form = "all" if method == "frost" else "firstm"
        return np.asarray(select_cells(model, m, y_form=form, candidates=candidates).positions)
    rng = method_rng(config, method, 0, 0)
    if method == "random":
        if candidates is None:
            return random_select(model.grid, m, rng)
        return np.sort(rng.choice(np.flatnonzero(candidates), size=m, replace=False))
    if candidates is not None:
        raise GoniofrostError(f"{method} selection has no candidate restriction")
    if method == "uniform":
        return uniform_select(model.grid, m)
    return nielsen_path(model.dictionary, [m], model.grid, rng, config.nielsen_subset,
                        config.nielsen_max_iter)[-1].positions


def errors_from_values(model, positions, values: np.ndarray, truth_log: np.ndarray, eta: float,
                       method: str = "frost") -> np.ndarray:
    """Per-material log-relative MSE of reconstructions from samples values (n_mat, m, 3).

    Each material goes through the public ``reconstruct`` (``reconstruct_bayes`` for method
    "bayes"; their checks refuse NaN, inf and negative samples with a clear error) and
    ``metrics.log_relative_mse``; ``truth_log`` is ``model.to_log(truth)`` (n_mat, n_valid, 3).
    """
    from goniofrost.frost.reconstruction import ReconstructionError, reconstruct, reconstruct_bayes

    out = np.empty(values.shape[0])
    for i in range(values.shape[0]):
        if method == "bayes":
            rec = reconstruct_bayes(model, positions, values[i])
            if not (np.all(np.isfinite(rec.std)) and np.isfinite(rec.predicted_error)):
                raise ReconstructionError("the predictive standard deviation or predicted error is not finite")
            estimate = rec.brdf
        else:
            estimate = reconstruct(model, positions, values[i], eta=eta)  # >= 0, so its map is finite
        # = log_relative_mse(model, truth_i, estimate), with the truth's map computed once
        out[i] = np.mean((model.to_log(estimate) - truth_log[i]) ** 2)
    return out


def _summary(errors: np.ndarray, baseline: float | None = None) -> dict:
    out = {"mse_mean": float(np.mean(errors)), "mse_max": float(np.max(errors))}
    if baseline is not None:
        out["ratio_to_noise_free"] = out["mse_mean"] / baseline
    return out


# ----- the cases --------------------------------------------------------------------------
def case_noise(setup: StressSetup, designs: dict, m: int) -> list[dict]:
    """Multiplicative noise 0.1 % to 20 % and additive noise at the darkest material's level."""
    model, truth = setup.model, setup.truth(setup.test)
    truth_log = model.to_log(truth)
    darkest = np.asarray(setup.tables[setup.train]).mean(axis=(1, 2)).argmin()
    level = float(np.median(np.asarray(setup.tables[setup.train[darkest]])))
    rng = np.random.default_rng([setup.config.seed, 7])
    out = []
    for method, pos in designs.items():
        clean = truth[:, pos, :]
        base = attempt(errors_from_values, model, pos, clean, truth_log, setup.config.eta, method)
        out.append(record("noise", "none", method, m, base if isinstance(base, Exception) else _summary(base)))
        ref = None if isinstance(base, Exception) else float(np.mean(base))
        for sigma in NOISE_MULTIPLICATIVE:
            noisy = np.maximum(clean * (1 + sigma * rng.standard_normal(clean.shape)), 0.0)
            res = attempt(errors_from_values, model, pos, noisy, truth_log, setup.config.eta, method)
            out.append(record("noise", f"multiplicative {sigma:g}", method, m,
                              res if isinstance(res, Exception) else _summary(res, ref)))
        additive = clean + level * rng.standard_normal(clean.shape)
        for variant, values in ((f"additive {level:.3g} 1/sr, raw", additive),
                                (f"additive {level:.3g} 1/sr, clamped at 0", np.maximum(additive, 0.0))):
            res = attempt(errors_from_values, model, pos, values, truth_log, setup.config.eta, method)
            out.append(record("noise", variant, method, m, res if isinstance(res, Exception) else _summary(res, ref)))
    return out


def case_eta(setup: StressSetup, designs: dict, m: int) -> list[dict]:
    """The ridge parameter from 0 (plain least squares) to 1000."""
    truth = setup.truth(setup.test)
    truth_log = setup.model.to_log(truth)
    out = []
    for method, pos in designs.items():
        if method == "bayes":  # no eta: its noise model was learned at training
            continue
        for eta in ETAS:
            res = attempt(errors_from_values, setup.model, pos, truth[:, pos, :], truth_log, eta)
            out.append(record("eta", f"eta {eta:g}", method, m, res if isinstance(res, Exception) else _summary(res)))
    return out


def case_precision(setup: StressSetup, designs: dict, m: int) -> list[dict]:
    """float32 against float64: the model's dictionary, and the training tables."""
    from goniofrost.frost.model import FrostModel
    from goniofrost.frost.reconstruction import reconstruct_log
    from goniofrost.frost.training import TrainingOptions, fit_model

    model, truth = setup.model, setup.truth(setup.test)
    truth_log = model.to_log(truth)
    wide = FrostModel(**{f: getattr(model, f) for f in ("grid", "names", "eps", "singular_values",
                                                         "coefficients", "mean", "reference", "weight",
                                                         "noise_variance", "noise")},
                      dictionary=np.asarray(model.dictionary, dtype=np.float64))
    out = []
    for method, pos in designs.items():
        values = truth[:, pos, :].transpose(1, 0, 2).reshape(pos.size, -1)
        for v_dtype in (np.float32, np.float64):
            if method == "bayes":
                from goniofrost.frost.reconstruction import reconstruct_bayes

                logs = [np.concatenate([reconstruct_bayes(mod, pos, truth[i, pos].astype(v_dtype), with_std=False).mapped
                                        for i in range(truth.shape[0])], axis=1) for mod in (model, wide)]
            else:
                logs = [reconstruct_log(mod, pos, mod.to_log(values.astype(v_dtype), pos), eta=setup.config.eta)
                        for mod in (model, wide)]
            e32, e64 = (batch_log_errors(model, lg, truth_log) for lg in logs)
            out.append(record("precision", f"dictionary float32 vs float64, samples {np.dtype(v_dtype).name}",
                              method, m, {"mse_float32": float(e32.mean()), "mse_float64": float(e64.mean()),
                                          "max_abs_log_difference": float(np.max(np.abs(logs[0] - logs[1])))}))
    # The PCA alone (noise=False): the record compares singular values and the uniform design's
    # eta reconstructions, neither of which reads the noise model its inner folds would learn.
    m64 = attempt(fit_model, np.asarray(setup.tables[setup.train], dtype=np.float64), setup.train_names,
                  setup.config.grid, TrainingOptions(k_max=setup.k_max, noise=False))
    if isinstance(m64, Exception):
        return out + [record("precision", "training tables float64", "-", None, m64)]
    k = min(model.n_components, m64.n_components)
    s32, s64 = model.singular_values[:k], m64.singular_values[:k]
    pos = designs.get("uniform", next(iter(designs.values())))
    e32 = errors_from_values(model, pos, truth[:, pos, :], truth_log, setup.config.eta)
    e64 = errors_from_values(m64, pos, truth[:, pos, :], m64.to_log(truth), setup.config.eta)
    out.append(record("precision", "training tables float32 vs float64", "uniform", m, {
        "max_rel_singular_value_difference": float(np.max(np.abs(s32 - s64) / s64)),
        "mse_float32_tables": float(e32.mean()), "mse_float64_tables": float(e64.mean())}))
    return out


def _small_training(setup: StressSetup, indices, label: str, m: int) -> list[dict]:
    """Train on the given material indices, then select and reconstruct at m and at K."""
    from goniofrost.frost.training import TrainingOptions, fit_model

    names = [setup.names[i] for i in indices]
    model = attempt(fit_model, np.asarray(setup.tables[np.asarray(indices)]), names, setup.config.grid,
                    TrainingOptions(k_max=setup.k_max))
    if isinstance(model, Exception):
        return [record(label, "training", "-", None, model)]
    out = [record(label, "training", "-", None, {"components": model.n_components,
                                                  "smallest_singular_value": float(model.singular_values[-1])})]
    truth = setup.truth(setup.test)
    truth_log = model.to_log(truth)
    for mm in sorted({m, model.n_components}):
        for method in STRESS_METHODS:
            pos = attempt(select, model, method, mm, setup.config)
            if isinstance(pos, Exception):
                out.append(record(label, f"m={mm} (K={model.n_components})", method, mm, pos))
                continue
            res = attempt(errors_from_values, model, pos, truth[:, pos, :], truth_log, setup.config.eta, method)
            out.append(record(label, f"m={mm} (K={model.n_components})", method, mm,
                              res if isinstance(res, Exception) else _summary(res)))
    return out


def case_rank(setup: StressSetup, m: int) -> list[dict]:
    """m above the rank of the training set: 3 materials (9 columns, rank <= 8 after centring)."""
    return _small_training(setup, setup.train[:3], "m above rank", m)


def case_duplicates(setup: StressSetup, m: int) -> list[dict]:
    """Training materials repeated: 5 materials, each three times (45 columns, rank <= 14)."""
    return _small_training(setup, np.repeat(setup.train[:5], 3), "duplicated materials", m)


def case_single(setup: StressSetup, m: int) -> list[dict]:
    """A single training material (3 columns, rank <= 2 after centring)."""
    return _small_training(setup, setup.train[:1], "single material", m)


def case_dynamic_range(setup: StressSetup, designs: dict, m: int) -> list[dict]:
    """Reconstruct the materials of the highest dynamic range (chrome, black ones)."""
    if not setup.dr:
        return [record("dynamic range", "no chrome or black materials in the datasets", "-", None, {})]
    truth = setup.truth(setup.dr)
    truth_log = setup.model.to_log(truth)
    positive = truth[truth > 0]
    out = [record("dynamic range", "materials", "-", None, {
        "names": ", ".join(setup.names[i] for i in setup.dr), "max_value": float(truth.max()),
        "min_positive_value": float(positive.min()) if positive.size else 0.0})]
    for method, pos in designs.items():
        res = attempt(errors_from_values, setup.model, pos, truth[:, pos, :], truth_log, setup.config.eta, method)
        out.append(record("dynamic range", f"{len(setup.dr)} materials", method, m,
                          res if isinstance(res, Exception) else _summary(res)))
    return out


def grazing_mask(grid: MerlGrid, min_deg: float = GRAZING_DEG) -> np.ndarray:
    """Bool (n_valid,): cells whose light or view is at least ``min_deg`` from the normal."""
    w_i, w_o = grid.cell_directions(grid.valid_cells)
    cos_limit = np.cos(np.radians(min_deg))
    return (w_i[:, 2] <= cos_limit) | (w_o[:, 2] <= cos_limit)


def case_grazing(setup: StressSetup, m: int) -> list[dict]:
    """Samples only at near-grazing cells (light or view >= 80 degrees from the normal)."""
    mask = grazing_mask(setup.config.grid)
    truth = setup.truth(setup.test)
    truth_log = setup.model.to_log(truth)
    out = []
    for method in ("bayes", "frost", "frost-firstm", "random"):
        pos = attempt(select, setup.model, method, m, setup.config, candidates=mask)
        if isinstance(pos, Exception):
            out.append(record("grazing", f">= {GRAZING_DEG:g} deg, {int(mask.sum())} cells", method, m, pos))
            continue
        res = attempt(errors_from_values, setup.model, pos, truth[:, pos, :], truth_log, setup.config.eta, method)
        out.append(record("grazing", f">= {GRAZING_DEG:g} deg, {int(mask.sum())} cells", method, m,
                          res if isinstance(res, Exception) else _summary(res)))
    return out


def case_condition(setup: StressSetup) -> list[dict]:
    """cond(D[positions, :m]) for every method and m of the configuration."""
    model, config = setup.model, setup.config
    ms = [m for m in config.m_values if m <= model.n_components]
    designs = {}
    for method in ("bayes", "frost", "frost-firstm", "random", "uniform"):
        for m in ms:
            designs[(method, m)] = attempt(select, model, method, m, config)
    steps = attempt(nielsen_path, model.dictionary, ms, model.grid, method_rng(config, "nielsen", 0, 0),
                    config.nielsen_subset, config.nielsen_max_iter)
    for m in ms:
        designs[("nielsen", m)] = steps if isinstance(steps, Exception) else next(s.positions for s in steps if s.m == m)
    out = []
    for (method, m), pos in sorted(designs.items(), key=lambda kv: (STRESS_METHODS.index(kv[0][0]), kv[0][1])):
        if isinstance(pos, Exception):
            out.append(record("condition", "cond(D[cells, :m])", method, m, pos))
            continue
        cond = condition_numbers(np.asarray(model.dictionary[pos, :m])[None])[0]
        # A singular sampled block is a finding, not a failure: say so in words (JSON has no inf).
        value = float(cond) if np.isfinite(cond) else "inf (singular to working precision)"
        out.append(record("condition", "cond(D[cells, :m])", method, m, {"cond": value}))
    return out


def run_cases(config: BenchConfig, path, names: list[str], m: int = 20, progress: bool = True) -> list[dict]:
    """Run every stress case; returns the records (see ``record``)."""
    from goniofrost.core.progress import progress_bar

    setup = StressSetup(config, path, names)
    m = min(m, setup.model.n_components)
    designs = {}
    for method in STRESS_METHODS:
        pos = attempt(select, setup.model, method, m, config)
        if not isinstance(pos, Exception):
            designs[method] = np.asarray(pos, dtype=np.int64)
    cases = [lambda: case_noise(setup, designs, m), lambda: case_eta(setup, designs, m),
             lambda: case_precision(setup, designs, m), lambda: case_rank(setup, m),
             lambda: case_duplicates(setup, m), lambda: case_single(setup, m),
             lambda: case_dynamic_range(setup, designs, m), lambda: case_grazing(setup, m),
             lambda: case_condition(setup)]
    records = []
    for case in progress_bar(cases, asked=progress, desc="stress", unit="case"):
        records += case()
    return records


def write_stress(out: Path, records: list[dict], command: str, config: dict, machine: dict) -> list[Path]:
    """Write stress.json (strict JSON: no NaN/inf) and a readable stress.md."""
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / "stress.json", out / "stress.md"]
    write_atomic(paths[0], json_text({"machine": machine, "command": command, "config": config, "records": records}))
    write_atomic(paths[1], stress_markdown(records))
    return paths


def stress_markdown(records: list[dict]) -> str:
    """One table per case: variant, method, m, status and the numbers (or the message)."""
    lines, current = [], None
    for r in records:
        if r["case"] != current:
            current = r["case"]
            lines += ["", f"### {current}", "", "| variant | method | m | status | result |", "|---|---|---|---|---|"]
        if r["status"] == "ok":
            result = ", ".join(f"{k}={_fmt(v)}" for k, v in r["values"].items())
        else:
            result = r["message"].replace("|", "/")
        lines.append(f"| {r['variant']} | {r['method']} | {r['m'] if r['m'] is not None else '-'} | {r['status']} | {result} |")
    return "\n".join(lines).lstrip() + "\n"


def _fmt(v) -> str:
    return f"{v:.4g}" if isinstance(v, float) else str(v)
