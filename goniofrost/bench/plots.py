"""Benchmark figures (matplotlib, Agg), written atomically: ``inverse_mse.png`` (paper Fig. 3),
``selection_time.png`` (Table II), ``frontier.png`` (error against time) and ``box_m40.png``
(per-material errors, Fig. 5).
"""
from __future__ import annotations

import os
from collections import defaultdict
from pathlib import Path

import numpy as np

from goniofrost.bench.results import methods_in, summary

COLOURS = {"frost": "tab:blue", "frost-firstm": "tab:cyan", "nielsen": "tab:orange",
           "random": "tab:gray", "uniform": "tab:green", "bayes": "tab:red", "frost-bayesrec": "tab:purple"}
FIGSIZE = (5.5, 3.6)
DPI = 90


def write_plots(out: Path, rows: list[dict], box_m: int = 40) -> list[Path]:
    """Write the four figures into ``out``; returns their paths."""
    import matplotlib
    matplotlib.use("Agg")
    rows = [r for r in rows if r["method"] != "bayes-target"]  # their m varies per material
    stats, methods = summary(rows), methods_in(rows)
    ms = sorted({r["m"] for r in rows})
    box = out / f"box_m{_closest(ms, box_m)}.png"
    for stale in out.glob("box_m*.png"):  # an earlier run's box plot of another m would pass for this run's
        if stale != box:
            stale.unlink()
    return [
        _save(out / "inverse_mse.png", _inverse_mse(stats, methods, ms)),
        _save(out / "selection_time.png", _selection_time(stats, methods, ms)),
        _save(out / "frontier.png", _frontier(stats, methods, ms)),
        _save(box, _boxes(rows, methods, _closest(ms, box_m))),
    ]


def _closest(ms, target: int) -> int:
    return min(ms, key=lambda m: (abs(m - target), m))


def _figure(title: str, xlabel: str, ylabel: str):
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=FIGSIZE, dpi=DPI)
    ax.set_title(title, fontsize=10)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(True, alpha=0.3)
    return fig, ax


def _inverse_mse(stats, methods, ms):
    fig, ax = _figure("Inverse MSE (mean over folds)", "samples m", "1 / log-relative MSE")
    for method in methods:
        ax.plot(ms, [1 / stats[(method, m)]["mse"] for m in ms], "o-", ms=3,
                color=COLOURS[method], label=method if method != "nielsen" else "nielsen (mean trial)")
        if method == "nielsen":
            ax.plot(ms, [1 / stats[(method, m)]["best_trial_mse"] for m in ms], "--",
                    color=COLOURS[method], label="nielsen (best trial)")
    ax.legend(fontsize=7)
    return fig


def _selection_time(stats, methods, ms):
    fig, ax = _figure("Selection time (median over folds, trials)", "samples m", "seconds")
    for method in methods:
        ax.plot(ms, [max(stats[(method, m)]["select_s"], 1e-6) for m in ms], "o-", ms=3,
                color=COLOURS[method], label=method)
    ax.set_yscale("log")
    ax.legend(fontsize=7)
    return fig


def _frontier(stats, methods, ms):
    fig, ax = _figure("Error against selection time", "selection seconds (median)", "mean log-relative MSE")
    for method in methods:
        x = [max(stats[(method, m)]["select_s"], 1e-6) for m in ms]
        y = [stats[(method, m)]["mse"] for m in ms]
        ax.plot(x, y, "o-", ms=3, color=COLOURS[method], label=method)
        for xi, yi, m in zip(x[::2], y[::2], ms[::2]):
            ax.annotate(str(m), (xi, yi), fontsize=6, xytext=(2, 2), textcoords="offset points")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.legend(fontsize=7)
    return fig


def _boxes(rows, methods, m: int):
    groups = defaultdict(list)
    for r in rows:
        if r["m"] == m:
            label = f"nielsen t{r['trial'] + 1}" if r["method"] == "nielsen" else r["method"]
            groups[(methods.index(r["method"]), r["trial"] if r["method"] == "nielsen" else 0, label)].append(r["mse"])
    keys = sorted(groups)
    fig, ax = _figure(f"Per-material error at m = {m} (all folds)", "", "log-relative MSE")
    box = ax.boxplot([groups[k] for k in keys], whis=(0, 100), patch_artist=True, widths=0.6)
    for patch, key in zip(box["boxes"], keys):
        patch.set_facecolor(COLOURS[methods[key[0]]])
        patch.set_alpha(0.5)
    ax.plot(range(1, len(keys) + 1), [np.mean(groups[k]) for k in keys], "*", color="k", ms=6, label="mean")
    ax.set_xticks(range(1, len(keys) + 1), [k[2] for k in keys], rotation=30, fontsize=7, ha="right")
    ax.set_yscale("log")
    ax.legend(fontsize=7)
    fig.tight_layout()
    return fig


def _save(path: Path, fig) -> Path:
    import matplotlib.pyplot as plt
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp.png")
    try:
        fig.tight_layout()
        fig.savefig(tmp, dpi=DPI)
        os.replace(tmp, path)
    finally:
        plt.close(fig)
        if tmp.exists():
            tmp.unlink()
    return path
