"""Summary statistics and Markdown of the Bayesian rows of a benchmark: fold wins, interval
coverage and predicted against true error, the target-error captures, and selection times beside
the paper's Table II.
"""
from __future__ import annotations

from collections import defaultdict

import numpy as np

BAYES_RECON = ("bayes", "frost-bayesrec")
TOO_HIGH = 1.5  # a stop "with an actual error above 1.5 E" (the criterion)


def fold_means(rows: list[dict]) -> dict:
    """{(method, m): {fold: test-set mean error (mean over trials)}}."""
    acc = defaultdict(lambda: defaultdict(list))
    for r in rows:
        acc[(r["method"], r["m"])][r["fold"]].append(r["mse"])
    return {k: {f: float(np.mean(v)) for f, v in folds.items()} for k, folds in acc.items()}


def fold_wins(rows: list[dict], method: str, other: str) -> dict:
    """{m: (folds where ``method``'s mean < ``other``'s, folds compared)}."""
    means = fold_means(rows)
    out = {}
    for (meth, m), folds in means.items():
        theirs = means.get((other, m))
        if meth != method or not theirs:
            continue
        common = sorted(set(folds) & set(theirs))
        out[m] = (sum(folds[f] < theirs[f] for f in common), len(common))
    return dict(sorted(out.items()))


def uncertainty_stats(rows: list[dict]) -> dict:
    """{(method, m): coverage and predicted-against-true statistics} for BAYES_RECON rows."""
    from scipy.stats import spearmanr

    groups = defaultdict(list)
    for r in rows:
        if r["method"] in BAYES_RECON and r.get("pred_mse") is not None:
            groups[(r["method"], r["m"])].append(r)
    out = {}
    for key, group in sorted(groups.items()):
        actual = np.array([r["mse"] for r in group])
        predicted = np.array([r["pred_mse"] for r in group])
        ratio = predicted / actual
        rho = spearmanr(predicted, actual)[0] if len(group) > 2 else float("nan")
        out[key] = {"cover50": float(np.mean([r["cover50"] for r in group])),
                    "cover90": float(np.mean([r["cover90"] for r in group])),
                    "spearman": float(rho), "within_factor_2": float(np.mean((ratio >= 0.5) & (ratio <= 2))),
                    "ratio_geomean": float(np.exp(np.mean(np.log(ratio)))), "materials": len(group)}
    return out


def target_stats(rows: list[dict], m_max: int) -> dict:
    """{target: statistics of the simulated captures that stop at that target error}."""
    groups = defaultdict(list)
    for r in rows:
        if r["method"] == "bayes-target":
            groups[r["target"]].append(r)
    out = {}
    for target, group in sorted(groups.items()):
        samples = np.array([r["m"] for r in group], dtype=np.float64)
        actual = np.array([r["mse"] for r in group])
        out[target] = {"materials": len(group), "m_max": m_max, "mean_samples": float(samples.mean()),
                       "median_samples": float(np.median(samples)),
                       "saving": float(1.0 - samples.mean() / m_max),
                       "within_target": float(np.mean(actual <= target)),
                       "above_1_5": float(np.mean(actual > TOO_HIGH * target)),
                       "mean_actual": float(actual.mean()), "median_actual": float(np.median(actual))}
    return out


def markdown(rows: list[dict], stats: dict, m_values, paper_table: dict) -> list[str]:
    """The Markdown lines of the Bayesian sections (empty without Bayesian rows)."""
    lines = []
    methods = {r["method"] for r in rows}
    if "bayes" in methods:
        lines += _wins_lines(rows, [o for o in ("frost-firstm", "frost", "frost-bayesrec", "nielsen") if o in methods])
    unc = uncertainty_stats(rows)
    if unc:
        lines += ["", "Uncertainty (Bayesian reconstruction): interval coverage over test cells; "
                  "predicted against true error per material:", "",
                  "| method | m | cover 50 % | cover 90 % | Spearman | within x2 | predicted / true (geo. mean) |",
                  "|---|---|---|---|---|---|---|"]
        for (method, m), s in unc.items():
            lines.append(f"| {method} | {m} | {s['cover50']:.3f} | {s['cover90']:.3f} | {s['spearman']:.3f} | "
                         f"{s['within_factor_2']:.3f} | {s['ratio_geomean']:.3f} |")
    m_max = max(m_values) if m_values else 0
    targets = target_stats(rows, m_max)
    if targets:
        # the column is the saving of the mean sample count, 1 - mean / m_max, headed so that it
        # does not read as the share of captures that stopped early
        lines += ["", f"Simulated capture --target-error E --confidence 0.95 (batches of {_batches_text()}, up to "
                      f"m_max = {m_max} samples):", "",
                  "| E | materials | mean samples | median samples | mean samples below m_max | true error <= E | "
                  "true error > 1.5 E | mean true error |", "|---|---|---|---|---|---|---|---|"]
        for target, s in targets.items():
            lines.append(f"| {target:g} | {s['materials']} | {s['mean_samples']:.1f} | {s['median_samples']:.0f} | "
                         f"{100 * s['saving']:.1f} % | {100 * s['within_target']:.1f} % | {100 * s['above_1_5']:.1f} % | "
                         f"{s['mean_actual']:.4f} |")
    if any(("bayes", m) in stats or ("frost-firstm", m) in stats for m in paper_table):
        lines += _paper_lines(stats, paper_table)
    return lines


def _batches_text() -> str:
    from goniofrost.frost.stopping import BATCH, FIRST_BATCH
    return f"{FIRST_BATCH} then {BATCH}"


def _wins_lines(rows, others) -> list[str]:
    wins = {o: fold_wins(rows, "bayes", o) for o in others}
    ms = sorted({m for w in wins.values() for m in w})
    lines = ["", "Folds in which bayes's test-set mean is below the other method's:", "",
             "| m | " + " | ".join(f"vs {o}" for o in others) + " |", "|" + "---|" * (len(others) + 1)]
    for m in ms:
        cells = [f"{wins[o][m][0]} / {wins[o][m][1]}" if m in wins[o] else "-" for o in others]
        lines.append(f"| {m} | " + " | ".join(cells) + " |")
    return lines


def _paper_lines(stats: dict, paper_table: dict) -> list[str]:
    methods = [m for m in ("bayes", "frost-firstm", "frost", "nielsen") if any((m, k) in stats for k in paper_table)]
    lines = ["", "Selection time against the paper's Table II (median seconds; the paper: MATLAB FROST and "
             "the authors' Python Nielsen on a 4-core Xeon W-2123):", "",
             "| m | paper FROST | paper Nielsen | " + " | ".join(f"here {m}" for m in methods) + " |",
             "|" + "---|" * (len(methods) + 3)]
    for m, (frost, nielsen) in sorted(paper_table.items()):
        here = [f"{stats[(meth, m)]['select_s']:.3g}" if (meth, m) in stats else "-" for meth in methods]
        lines.append(f"| {m} | {frost:g} | {nielsen:g} | " + " | ".join(here) + " |")
    return lines
