"""Benchmark results: validation, the JSON/CSV files, and summary statistics.

``results.json`` is ``{"machine", "command", "config", "rows"}``, each row with exactly ROW_FIELDS
plus OPTIONAL_FIELDS (``pred_mse``, ``cover50``, ``cover90``, ``target``; null where they do not
apply). Files are written atomically, and not at all if a number is NaN or inf.
"""
from __future__ import annotations

import csv
import io
import json
import math
import os
import platform
from collections import defaultdict
from pathlib import Path

import numpy as np

from goniofrost.core.atomic_file import write_text_atomic
from goniofrost.bench.config import METHODS, ROW_KINDS, BenchError

BASE_FIELDS = ("method", "m", "fold", "trial", "material", "mse", "select_s", "recon_s")
OPTIONAL_FIELDS = ("pred_mse", "cover50", "cover90", "target")
ROW_FIELDS = BASE_FIELDS + OPTIONAL_FIELDS
FLOAT_FIELDS = ("mse", "select_s", "recon_s")
# The paper's Table II (MATLAB FROST and the authors' Python Nielsen, Xeon W-2123, 4 cores), s.
PAPER_TABLE_II = {5: (0.14, 76.01), 10: (0.47, 248.67), 20: (1.86, 772.74), 30: (4.21, 1600.46),
                  40: (7.49, 2772.74), 50: (12.05, 4357.08), 60: (17.67, 6366.88)}


def machine_info() -> dict:
    """Where the run happened: CPU model, core count, memory, Python and numpy versions."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        mem_gb = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    except (ValueError, OSError, AttributeError):
        mem_gb = float("nan")
    return {"cpu": cpu, "cores": os.cpu_count(), "memory_gb": round(mem_gb, 1) if math.isfinite(mem_gb) else None,
            "load_average": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
            "platform": platform.platform(), "python": platform.python_version(), "numpy": np.__version__,
            "code": _code_version()}


def _code_version() -> str | None:
    """``git describe --always --dirty`` of the checkout the code runs from, if it is one."""
    import subprocess

    try:
        done = subprocess.run(["git", "describe", "--always", "--dirty"], cwd=Path(__file__).parent,
                              capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return None
    return done.stdout.strip() or None if done.returncode == 0 else None


def check_rows(rows: list[dict]) -> None:
    """Raise BenchError unless every row has the BASE_FIELDS (and only ROW_FIELDS) with finite
    numbers (optional fields: finite or null)."""
    for i, row in enumerate(rows):
        if not set(BASE_FIELDS) <= set(row) <= set(ROW_FIELDS):
            raise BenchError(f"result row {i}: expected fields {ROW_FIELDS}, found {tuple(row)}")
        if row["method"] not in ROW_KINDS:
            raise BenchError(f"result row {i}: unknown method {row['method']!r}")
        for key in FLOAT_FIELDS + OPTIONAL_FIELDS:
            value = row.get(key)
            if key in OPTIONAL_FIELDS and value is None:
                continue
            if not (isinstance(value, float) and math.isfinite(value)):
                raise BenchError(f"result row {i} ({row['method']} m={row['m']} {row['material']}): "
                                 f"{key} must be a finite float, found {value!r}")


def write_atomic(path: Path, text: str) -> None:
    """Write text to ``path`` through a temporary sibling and a rename."""
    write_text_atomic(path, text)


def json_text(payload) -> str:
    """JSON that refuses NaN/inf (a strict reader could not load it)."""
    try:
        return json.dumps(payload, indent=1, allow_nan=False)
    except ValueError as exc:
        raise BenchError(f"refusing to write non-finite numbers to JSON ({exc})") from exc


def write_results(out: Path, rows: list[dict], command: str, config: dict, machine: dict | None = None) -> list[Path]:
    """Write ``results.json`` and ``results.csv`` into ``out``; returns their paths."""
    check_rows(rows)
    out.mkdir(parents=True, exist_ok=True)
    payload = {"machine": machine or machine_info(), "command": command, "config": config, "rows": rows}
    paths = [out / "results.json", out / "results.csv"]
    write_atomic(paths[0], json_text(payload))
    write_atomic(paths[1], rows_csv(rows))
    return paths


def rows_csv(rows: list[dict]) -> str:
    """The rows as CSV text with a ROW_FIELDS header (floats with full precision)."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=ROW_FIELDS, lineterminator="\n")
    writer.writeheader()
    writer.writerows({k: (repr(v) if isinstance(v, float) else "" if v is None else v) for k, v in row.items()}
                     for row in rows)
    return buf.getvalue()


def load_rows(path: Path) -> list[dict]:
    """The rows of a results.json (checked)."""
    rows = json.loads(Path(path).read_text())["rows"]
    check_rows(rows)
    return rows


# ----- statistics ---------------------------------------------------------------------------
def trial_means(rows: list[dict], field: str = "mse") -> dict:
    """{(method, m, fold, trial): mean of ``field`` over the test materials}."""
    acc = defaultdict(list)
    for r in rows:
        acc[(r["method"], r["m"], r["fold"], r["trial"])].append(r[field])
    return {k: float(np.mean(v)) for k, v in acc.items()}


def summary(rows: list[dict]) -> dict:
    """Per (method, m): error and time statistics over folds.

    ``mse``: mean over folds and trials of the test-set mean; ``best_trial_mse``: mean over folds
    of the best trial's test-set mean (the lowest; equals ``mse`` for one trial);
    ``worst_trial_mse`` likewise; ``select_s``: median over folds and trials of the selection
    time; ``recon_s``: median reconstruction time per material.
    """
    rows = [r for r in rows if r["method"] in METHODS]  # target rows have their own summary
    means, times = trial_means(rows), trial_means(rows, "select_s")
    recon = defaultdict(list)
    for r in rows:
        recon[(r["method"], r["m"])].append(r["recon_s"])
    by_fold = defaultdict(lambda: defaultdict(list))
    for (method, m, fold, _), value in means.items():
        by_fold[(method, m)][fold].append(value)
    out = {}
    for (method, m), folds in by_fold.items():
        fold_lists = list(folds.values())
        sel = [t for (me, mm, _, _), t in times.items() if me == method and mm == m]
        out[(method, m)] = {
            "mse": float(np.mean([v for vs in fold_lists for v in vs])),
            "best_trial_mse": float(np.mean([min(vs) for vs in fold_lists])),
            "worst_trial_mse": float(np.mean([max(vs) for vs in fold_lists])),
            "select_s": float(np.median(sel)),
            "recon_s": float(np.median(recon[(method, m)])),
            "folds": len(fold_lists),
        }
    return out


def methods_in(rows: list[dict]) -> list[str]:
    """Methods present in the rows, in METHODS order."""
    present = {r["method"] for r in rows}
    return [m for m in METHODS if m in present]


def summary_markdown(rows: list[dict], m_values=None, config: dict | None = None) -> str:
    """Markdown tables: mean log-relative MSE and median selection time per method and m.

    config: the run's ``BenchConfig.as_dict()``: a first line says what the numbers are of (folds,
    materials, the grid and its valid cells beside the MERL grid the paper's times are of)."""
    from goniofrost.bench.bayes_report import markdown as bayes_markdown

    stats = summary(rows)
    methods = methods_in(rows)
    ms = sorted({k[1] for k in stats}) if m_values is None else [m for m in m_values if any(k[1] == m for k in stats)]
    cols = []
    for method in methods:
        cols.append((method, "mse"))
        if method == "nielsen":
            cols.append(("nielsen best trial", "best_trial_mse"))
    head = "| m | " + " | ".join(c for c, _ in cols) + " |"
    lines = [] if config is None else [_run_line(config), ""]
    lines += ["Mean log-relative MSE over folds (lower is better):", "", head, "|" + "---|" * (len(cols) + 1)]
    for m in ms:
        cells = [_fmt(stats.get((c if c in METHODS else "nielsen", m), {}).get(key)) for c, key in cols]
        lines.append(f"| {m} | " + " | ".join(cells) + " |")
    lines += ["", "Median selection time in seconds:", "",
              "| m | " + " | ".join(methods) + " | nielsen / frost | nielsen / frost-firstm |",
              "|" + "---|" * (len(methods) + 3)]
    for m in ms:
        sel = [stats.get((meth, m), {}).get("select_s") for meth in methods]
        ratios = [_ratio(stats, m, frost) for frost in ("frost", "frost-firstm")]
        lines.append(f"| {m} | " + " | ".join(_fmt(s, 3) for s in sel) + f" | {ratios[0]} | {ratios[1]} |")
    lines += bayes_markdown(rows, stats, ms, PAPER_TABLE_II)
    return "\n".join(lines) + "\n"


def _run_line(config: dict) -> str:
    """What the tables are of: a reduced grid's selection times are not the paper's (its Table II
    is of the full MERL grid; the time of a pass over the cells scales with their number)."""
    from goniofrost.core.grid import FULL_GRID, MerlGrid

    grid = MerlGrid(**config["grid"])
    size = f"{grid.n_th} x {grid.n_td} x {grid.n_pd} grid, {grid.n_valid:,} valid cells"
    if grid != FULL_GRID:
        size += f" (the MERL grid of the paper's times: {FULL_GRID.n_valid:,})"
    folds = f"{config['folds']} fold" + ("s" if config["folds"] != 1 else "")
    return (f"Run: {folds} of {config['n_train']} training and {config['n_test']} test materials "
            f"on the {size}.")


def _ratio(stats, m, frost: str) -> str:
    """Nielsen's median selection time over the FROST form's, e.g. "0.39x" or "19x"."""
    a, b = stats.get(("nielsen", m)), stats.get((frost, m))
    if not a or not b or b["select_s"] <= 0:
        return "-"
    return f"{a['select_s'] / b['select_s']:.2g}x"


def _fmt(value, digits: int = 4) -> str:
    if value is None:
        return "-"
    return f"{value:.{digits}g}"
