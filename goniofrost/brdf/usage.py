"""A scene's use of a BRDF: one weight per valid MERL cell, from the (w_i, w_o) pairs a renderer visited.

A usage map is float32 (n_valid,) in ``grid.valid_cells`` order, non-negative, summing to 1; pairs
are folded by isotropy and reciprocity. The file is a plain ``.npy`` of that array.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from goniofrost.core.errors import GoniofrostError
from goniofrost.core.grid import MerlGrid, dirs_to_half_diff


class UsageError(GoniofrostError, ValueError):
    """A usage map that cannot be used: names the file, what was expected and what was found."""


def fold_pairs(grid: MerlGrid, w_i: np.ndarray, w_o: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """The usage map (n_valid,) float64 of direction pairs (m, 3) each in the local shading frame
    (z = normal); pairs with a direction at or below the surface are left out. ``weights`` (m,)
    default 1. Raises UsageError when no pair lies above the surface."""
    w_i, w_o = np.asarray(w_i, np.float64).reshape(-1, 3), np.asarray(w_o, np.float64).reshape(-1, 3)
    weights = np.ones(len(w_i)) if weights is None else np.asarray(weights, np.float64).reshape(-1)
    above = (w_i[:, 2] > 0) & (w_o[:, 2] > 0) & (weights > 0)
    theta_h, theta_d, phi_d = dirs_to_half_diff(w_i[above], w_o[above])
    ok = np.isfinite(theta_h) & np.isfinite(theta_d) & np.isfinite(phi_d)
    rows = grid.valid_position(grid.angles_to_flat(theta_h[ok], theta_d[ok], phi_d[ok]))
    kept = rows >= 0
    counts = np.bincount(rows[kept], weights=weights[above][ok][kept], minlength=grid.n_valid)
    total = counts.sum()
    if not total > 0:
        raise UsageError(f"no recorded light/view pair lies above the surface ({len(w_i)} recorded): "
                         f"the object is not seen, or not lit, in this scene")
    return counts / total


def save_usage(path, usage: np.ndarray) -> None:
    """Write a usage map as float32 .npy, atomically."""
    import io

    from goniofrost.core.atomic_file import write_bytes_atomic

    buffer = io.BytesIO()
    np.save(buffer, np.asarray(usage, dtype=np.float32))
    write_bytes_atomic(path, buffer.getvalue())


def load_usage(path, n_valid: int) -> np.ndarray:
    """Read a usage map for a model of ``n_valid`` valid cells: float64 (n_valid,), sum 1.

    UsageError (naming the file) for a missing or unreadable file, another shape, a non-finite
    or negative weight, or an all-zero map. A map summing to another positive total is
    renormalised (only relative weights matter).
    """
    path = Path(path)
    try:
        usage = np.load(path, allow_pickle=False)
    except FileNotFoundError:
        raise UsageError(f"{path}: usage map not found (goniofrost usage --scene SCENE.xml --object ID --out FILE.npy)") from None
    except ValueError:
        # numpy reads a file without the .npy header as a pickle and refuses it, with advice to
        # "load it unsafely" that a user must not follow: say what the file is not, instead
        raise UsageError(f"{path}: not a usage map (.npy of float32 weights): not in NumPy's .npy format") from None
    except OSError as exc:
        raise UsageError(f"{path}: not a usage map (.npy of float32 weights): {exc}") from None
    if usage.ndim != 1 or usage.shape[0] != n_valid or not np.issubdtype(usage.dtype, np.floating):
        raise UsageError(f"{path}: expected float weights of shape ({n_valid},) (one per valid cell of the model's "
                         f"grid), found {usage.dtype} {usage.shape}")
    usage = usage.astype(np.float64)
    if not np.all(np.isfinite(usage)):
        raise UsageError(f"{path}: {int(np.sum(~np.isfinite(usage)))} weights are not finite (NaN or inf)")
    if np.any(usage < 0):
        raise UsageError(f"{path}: {int(np.sum(usage < 0))} weights are negative (smallest {usage.min():g})")
    total = usage.sum()
    if not total > 0:
        raise UsageError(f"{path}: every weight is 0: the map says the scene uses no cell")
    return usage / total
