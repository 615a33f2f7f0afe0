"""Compare several BRDFs: spheres side by side under the same lights and the pairwise differences.

For every pair of inputs (keyed A, B, C, ...): the rendering SNR both ways
(``preview.rendering_snr_db``; not symmetric) and, on a common grid, the log-relative MSE
(``preview.log_error``). ``to_json`` writes an infinite SNR as null with ``"identical": true``; a
black reference gives -inf, null with ``"identical": false``.
"""
from __future__ import annotations

import dataclasses
import io
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from goniofrost.brdf import preview
from goniofrost.brdf.merl_file import read_merl_complete
from goniofrost.core.atomic_file import write_bytes_atomic
from goniofrost.core.grid import MerlGrid

KEYS = "ABCDEFGHIJKLMNOPQRSTUVWXYZ"


@dataclass(frozen=True)
class Comparison:
    """Renderings and pairwise numbers of n inputs.

    ``images`` (n, n_lights, size, size, 3) HDR; ``snr_db`` (n, n): [i, j] the SNR of input j's
    rendering against input i's as the reference (NaN on the diagonal, +inf when identical, -inf
    when input i renders black and j does not);
    ``log_mse`` (n, n) symmetric, NaN where the grids differ (0 on the diagonal);
    ``figures`` (n,) each input's error figure from the record beside it (``preview.record_figure``:
    a reconstruction's or a session's), None for an input without one.
    """

    keys: tuple[str, ...]
    labels: tuple[str, ...]
    paths: tuple[str, ...]
    light_names: tuple[str, ...]
    images: np.ndarray
    snr_db: np.ndarray
    log_mse: np.ndarray
    figures: tuple = ()

    def pairs(self):
        """(i, j) for every pair i < j, in input order."""
        n = len(self.keys)
        return [(i, j) for i in range(n) for j in range(i + 1, n)]

    def identical(self, i: int, j: int) -> bool:
        """Whether inputs i and j render the same: +inf SNR only (-inf is a black reference)."""
        return bool(self.snr_db[i, j] == np.inf)

    def to_json(self) -> dict:
        """The numbers as a JSON-ready document (no infinities: see the module docstring)."""
        def finite(value):
            return None if not math.isfinite(value) else round(float(value), 6)

        pairs = []
        for i, j in self.pairs():
            pairs.append({
                "a": self.keys[i], "b": self.keys[j],
                "rendering_snr_db": {"b_against_a": finite(self.snr_db[i, j]), "a_against_b": finite(self.snr_db[j, i])},
                "identical": self.identical(i, j),
                "log_relative_mse": finite(self.log_mse[i, j]),
            })
        said = self.figures or (None,) * len(self.keys)
        return {"inputs": [{"key": k, "label": label, "path": p, "error_figure": f}
                           for k, label, p, f in zip(self.keys, self.labels, self.paths, said)],
                "lights": list(self.light_names), "size_px": int(self.images.shape[2]), "pairs": pairs}

    def table(self) -> list[str]:
        """Text lines: each input's error figure (those that have one), then one per pair (the
        command prints them, the picture shows them)."""
        lines = [f"{k}: {label}: {f}" for k, label, f in zip(self.keys, self.labels, self.figures) if f]
        for i, j in self.pairs():
            a, b = self.keys[i], self.keys[j]
            log = "grids differ" if np.isnan(self.log_mse[i, j]) else f"{self.log_mse[i, j]:.4g}"
            if self.identical(i, j):
                lines.append(f"{a}-{b}: identical renderings; log-relative MSE {log}")
                continue
            lines.append(f"{a}-{b}: rendering SNR {self.snr_db[i, j]:.2f} dB ({b} against {a}), "
                         f"{self.snr_db[j, i]:.2f} dB ({a} against {b}); log-relative MSE {log}")
        return lines


def log_relative_mse(a: np.ndarray, b: np.ndarray, grid: MerlGrid) -> float:
    """Mean over valid cells and channels of (ln(w a + eps) - ln(w b + eps))^2; tables (grid.size, 3)."""
    error = preview.log_error(a, b, grid)
    return float(np.nanmean(error[grid.valid_mask] ** 2))


def compare_tables(tables, labels, paths=None, lights=preview.DEFAULT_LIGHTS, size: int = 128) -> Comparison:
    """Compare BRDF tables: ``tables`` a list of (brdf (grid.size, 3) in 1/sr, grid), at least two."""
    n = len(tables)
    if not 2 <= n <= len(KEYS):
        raise ValueError(f"compare: expected 2 to {len(KEYS)} BRDFs, found {n}")
    images = np.stack([preview.render_set(brdf, grid, lights, size) for brdf, grid in tables])
    snr = np.full((n, n), np.nan)
    log_mse = np.zeros((n, n))
    for i in range(n):
        for j in range(n):
            if i != j:
                snr[i, j] = preview.rendering_snr_db(images[i], images[j])
            if i < j:
                (a, grid_a), (b, grid_b) = tables[i], tables[j]
                log_mse[i, j] = log_mse[j, i] = log_relative_mse(a, b, grid_a) if grid_a == grid_b else np.nan
    return Comparison(tuple(KEYS[:n]), tuple(labels), tuple(str(p) for p in (paths or labels)),
                      tuple(name for name, _, _ in lights), images, snr, log_mse)


def compare_files(paths, labels=None, lights=preview.DEFAULT_LIGHTS, size: int = 128) -> Comparison:
    """Compare MERL .binary files (each on its own grid); ``labels`` default to the file names."""
    tables = [read_merl_complete(path) for path in paths]   # every input checked before any rendering
    out = compare_tables(tables, labels or [Path(p).name for p in paths], paths, lights, size)
    return dataclasses.replace(out, figures=tuple(preview.record_figure(p) for p in paths))


def compose(comparison: Comparison) -> np.ndarray:
    """Tone-mapped grid (rows = lights, columns = inputs), one exposure: input A's (float in [0, 1])."""
    exposure = preview.exposure_for(comparison.images[0])
    rows = [np.concatenate([preview.tone_map(images[k], exposure) for images in comparison.images], axis=1)
            for k in range(comparison.images.shape[1])]
    return np.concatenate(rows, axis=0)


def write_png(path, comparison: Comparison, title: str = "") -> None:
    """Write the spheres (column headers A: label, ...) and the pairwise table below as a PNG, atomically."""
    import matplotlib
    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    image = compose(comparison)
    lines = comparison.table()
    n = len(comparison.keys)
    width = max(2.0 * n, 6.0)
    image_height = width * image.shape[0] / image.shape[1]
    text_height = 0.15 * (len(lines) + 1) + 0.15
    fig = Figure(figsize=(width, image_height + text_height + 0.5), dpi=100)
    total = image_height + text_height + 0.5
    ax = fig.add_axes((0.0, (text_height + 0.05) / total, 1.0, image_height / total))
    ax.imshow(image, interpolation="nearest")
    ax.set_axis_off()
    header = "  |  ".join(f"{k}: {label}" for k, label in zip(comparison.keys, comparison.labels))
    fig.suptitle(f"{title}\n{header}" if title else header, fontsize=8)
    fig.text(0.01, text_height / total, "\n".join(
        [f"rows: lights {', '.join(comparison.light_names)}; one exposure (A's)"] + lines),
        fontsize=7, va="top", family="monospace")
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", facecolor="white")
    write_bytes_atomic(path, buffer.getvalue())
