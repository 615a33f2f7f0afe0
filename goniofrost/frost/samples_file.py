"""SAMPLES.csv: one module for its writer (a session's ``samples.csv``) and its readers
(``goniofrost reconstruct``, the report).

Required columns ``theta_h_deg,theta_d_deg,phi_d_deg,r,g,b`` (cell lower-edge angles in degrees,
BRDF in 1/sr); optional ``sigma_r,sigma_g,sigma_b`` (all or none); other columns are handed back as
text. A session writes ``SESSION_COLUMNS`` (plus ``batch``), floats in repr form to read back
exactly.
"""
from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from goniofrost.core.grid import MerlGrid
from goniofrost.frost.reconstruction import ReconstructionError, check_values

CSV_COLUMNS = ("theta_h_deg", "theta_d_deg", "phi_d_deg", "r", "g", "b")
SIGMA_COLUMNS = ("sigma_r", "sigma_g", "sigma_b")
PLAN_INDEX = "plan_index"
SESSION_COLUMNS = CSV_COLUMNS + SIGMA_COLUMNS + ("snr", PLAN_INDEX)
BATCH_COLUMN = "batch"


def header(batched: bool = False) -> str:
    """The header line of a session's samples.csv (no newline)."""
    return ",".join(SESSION_COLUMNS + ((BATCH_COLUMN,) if batched else ()))


def session_row(angles_deg, rgb, sigma, snr: float, plan_index: int, batch: int | None = None) -> str:
    """One line of a session's samples.csv (no newline): ``angles_deg`` (theta_h, theta_d, phi_d),
    ``rgb`` and ``sigma`` (3,) in 1/sr, the SNR, the plan index and (batched) the 1-based batch."""
    values = (*angles_deg, *rgb, *sigma, snr)
    fields = [*(repr(float(v)) for v in values), str(int(plan_index))]
    return ",".join(fields + ([str(int(batch))] if batch is not None else []))


def sample_sigmas(path, extra: dict) -> np.ndarray | None:
    """The samples' standard deviations (l, 3) in 1/sr from the sigma_r,sigma_g,sigma_b columns of
    ``read_samples_csv``'s extra columns, or None without them. All three or none; each a
    finite number >= 0 (the error names the file, the row and the column)."""
    present = [c for c in SIGMA_COLUMNS if c in extra]
    if not present:
        return None
    if len(present) != len(SIGMA_COLUMNS):
        raise ReconstructionError(f"{path}: columns {present} without {[c for c in SIGMA_COLUMNS if c not in present]}; "
                                  f"expected all of {','.join(SIGMA_COLUMNS)} or none")
    out = np.empty((len(extra[present[0]]), 3))
    for j, name in enumerate(SIGMA_COLUMNS):
        for i, text in enumerate(extra[name]):
            try:
                out[i, j] = float(text)
            except ValueError:
                raise ReconstructionError(f"{path}: data row {i + 1}: column {name}: expected a number, found {text!r}") from None
    check_values(out, lambda i: f"{path}: data row {i + 1}", tuple(f"column {name}" for name in SIGMA_COLUMNS),
                 "a finite standard deviation >= 0 (1/sr)")
    return out


def read_samples_csv(path, grid: MerlGrid):
    """Read SAMPLES.csv (header theta_h_deg,theta_d_deg,phi_d_deg,r,g,b; extra columns allowed).

    Returns (cells int64 (l,) flat indices, values float64 (l, 3) in 1/sr, extra: dict of
    column name -> list of strings). Raises ReconstructionError naming the file, line and column
    for an empty file, a missing column, a non-number, NaN/inf/negative values or a cell that is
    not valid on the grid.
    """
    path = Path(path)
    header, rows = _read_csv_rows(path)
    index = {name: header.index(name) for name in CSV_COLUMNS}
    numbers = np.array([[_number(path, line, row, name, index[name]) for name in CSV_COLUMNS]
                        for line, row in rows], dtype=np.float64)
    lines = [line for line, _ in rows]
    check_values(numbers[:, 3:], lambda i: f"{path}: line {lines[i]}")
    angles = numbers[:, :3]
    if not np.isfinite(angles).all():
        i = int(np.argwhere(~np.isfinite(angles))[0][0])
        raise ReconstructionError(f"{path}: line {lines[i]}: angles must be finite numbers of degrees")
    _check_angle_ranges(path, lines, angles)
    cells = grid.angles_to_flat(*np.radians(angles).T)
    invalid = grid.valid_position(cells) < 0
    if invalid.any():
        i = int(np.flatnonzero(invalid)[0])
        named = ", ".join(f"{n}={float(v):g}" for n, v in zip(CSV_COLUMNS[:3], angles[i]))
        raise ReconstructionError(
            f"{path}: line {lines[i]}: angles {named} fall in cell {tuple(int(v) for v in grid.unravel(cells[i]))}, "
            f"which is not a valid cell (light or view below the surface)")
    extra = {name: [row[col] for _, row in rows] for col, name in enumerate(header) if name not in CSV_COLUMNS}
    return cells.astype(np.int64), numbers[:, 3:], extra


ANGLE_RANGES = ((0.0, 90.0), (0.0, 90.0), (-360.0, 360.0))   # theta_h, theta_d, phi_d in degrees


def _check_angle_ranges(path: Path, lines: list, angles: np.ndarray) -> None:
    """Each angle within its range (degrees), or the first one outside named in plain numbers."""
    for col, (name, (lo, hi)) in enumerate(zip(CSV_COLUMNS[:3], ANGLE_RANGES)):
        bad = np.flatnonzero((angles[:, col] < lo) | (angles[:, col] > hi))
        if bad.size:
            i = int(bad[0])
            raise ReconstructionError(f"{path}: line {lines[i]}: {name}={float(angles[i, col]):g} is out of range: "
                                      f"expected {lo:g} to {hi:g} degrees")


def _read_csv_rows(path: Path):
    try:
        with path.open(newline="") as handle:
            table = [(i + 1, row) for i, row in enumerate(csv.reader(handle)) if any(c.strip() for c in row)]
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise ReconstructionError(f"{path}: cannot read samples CSV ({exc})") from exc
    if not table:
        raise ReconstructionError(f"{path}: empty file; expected the header {','.join(CSV_COLUMNS)} and one row per sample")
    header = [c.strip() for c in table[0][1]]
    missing = [c for c in CSV_COLUMNS if c not in header]
    if missing:
        raise ReconstructionError(f"{path}: missing column(s) {missing}; expected header {','.join(CSV_COLUMNS)} (extra columns allowed), found {header}")
    _check_unique_columns(path, table[0][0], header)
    rows = table[1:]
    if not rows:
        raise ReconstructionError(f"{path}: no samples after the header")
    for line, row in rows:
        if len(row) != len(header):
            raise ReconstructionError(f"{path}: line {line}: {len(row)} fields, expected {len(header)} as in the header")
    _check_unique_rows(path, header, rows)
    return header, rows


def _check_unique_columns(path: Path, line: int, header: list) -> None:
    """Each column named once: a second ``r`` was ignored, silently."""
    for col, name in enumerate(header):
        if name in header[:col]:
            raise ReconstructionError(f"{path}: line {line}: column {name!r} appears twice (columns "
                                      f"{header.index(name) + 1} and {col + 1}); expected each column once")


def _check_unique_rows(path: Path, header: list, rows: list) -> None:
    """No sample twice: a repeated plan_index (a session measures each plan sample once), nor a
    row repeated field for field (a copy: it weighed its cell twice in the fit)."""
    col = header.index(PLAN_INDEX) if PLAN_INDEX in header else None
    indices: dict = {}
    copies: dict = {}
    for line, row in rows:
        fields = tuple(c.strip() for c in row)
        if col is not None and fields[col] in indices:
            raise ReconstructionError(f"{path}: line {line}: {PLAN_INDEX} {fields[col]} again (line "
                                      f"{indices[fields[col]]}); expected each plan sample once")
        if fields in copies:
            raise ReconstructionError(f"{path}: line {line}: the same sample as line {copies[fields]}; "
                                      f"expected each sample once")
        if col is not None:
            indices[fields[col]] = line
        copies[fields] = line


def _number(path, line, row, name, col) -> float:
    text = row[col].strip()
    try:
        return float(text)
    except ValueError:
        raise ReconstructionError(f"{path}: line {line}: column {name}: expected a number, found {text!r}") from None
