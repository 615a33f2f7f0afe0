"""Render spheres of a tabulated BRDF and compare them with a reference (the paper's figures).

Orthographic unit spheres under a few directional lights, radiance L = sum_k E_k f cos theta_i, f
looked up in the MERL cell of each pixel. With a predictive std (``OUT.std.binary``) an uncertainty
panel shows it beside the actual log error. ``rendering_snr_db`` = 10 log10(sum ref^2 / sum
(ref - est)^2) on the HDR images; tone mapping: a common exposure, gamma 2.0.
"""
from __future__ import annotations

import io
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from goniofrost.core.grid import MerlGrid, dirs_to_half_diff
from goniofrost.core.atomic_file import write_bytes_atomic
from goniofrost.brdf.merl_file import read_merl_complete

GAMMA = 2.0
ERROR_GAIN = 10.0  # the paper multiplies error images by 10
EPS = 0.001  # the log-relative map's offset (frost training.EPS)
STD_COLOURMAP = "magma"
ERROR_COLOURMAP = "viridis"  # perceptually uniform: equal steps of error look like equal steps
# The colour bars' labels (with units), what the PNG's Description says too
ERROR_BAR = f"|ref - est| x{ERROR_GAIN:g} (display units, 1 = white)"
STD_BAR = "std of ln(wx+eps), |log error| (natural-log units)"

# (name, unit direction towards the light in the world frame, irradiance RGB at normal incidence)
# A key light from the upper front, a side light and a grazing back light that shows the
# Fresnel rise and retro-reflection, the three regimes a sparse reconstruction can get wrong.
DEFAULT_LIGHTS: tuple[tuple[str, tuple[float, float, float], float], ...] = (
    ("front", (-0.35, 0.45, 0.82), 1.0),
    ("side", (-0.94, 0.20, 0.28), 1.0),
    ("back", (0.55, 0.30, -0.78), 1.0),
)


@dataclass(frozen=True)
class Preview:
    """A rendered comparison: HDR images (n_lights, size, size, 3) and the rendering SNR in dB.

    ``reference`` is None when no reference was given; ``snr_db`` is then None too.
    ``std``: (n_lights, size, size) the predictive std of each lit pixel's cell (channel mean),
    or None; ``log_error``: the same for the actual |log error| (std and reference given);
    ``errors``: {"predicted": mean std^2, "actual": log-relative MSE or None} over valid cells.
    """

    estimate: np.ndarray
    reference: np.ndarray | None
    snr_db: float | None
    light_names: tuple[str, ...]
    std: np.ndarray | None = None
    log_error: np.ndarray | None = None
    errors: dict | None = None


def sphere_normals(size: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (size, size, 3) of an orthographic unit sphere and its (size, size) mask.

    Row 0 is the top of the image (+y); pixels outside the disc get the normal (0, 0, 1).
    """
    centres = (np.arange(size) + 0.5) / size * 2.0 - 1.0
    x, y = np.meshgrid(centres, -centres)
    r2 = x * x + y * y
    mask = r2 < 1.0
    z = np.sqrt(np.clip(1.0 - r2, 0.0, None))
    normals = np.stack([np.where(mask, x, 0.0), np.where(mask, y, 0.0), np.where(mask, z, 1.0)], -1)
    return normals, mask


def tangent_frame(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit tangent and bitangent (..., 3) completing each normal to an orthonormal frame.

    Branchless construction of Duff et al. 2017 ("Building an orthonormal basis, revisited"),
    stable for every normal; the azimuth of the frame does not matter for an isotropic BRDF.
    """
    nx, ny, nz = normals[..., 0], normals[..., 1], normals[..., 2]
    sign = np.where(nz >= 0, 1.0, -1.0)
    a = -1.0 / (sign + nz)
    b = nx * ny * a
    tangent = np.stack([1.0 + sign * nx * nx * a, sign * b, -sign * nx], -1)
    bitangent = np.stack([b, sign + ny * ny * a, -ny], -1)
    return tangent, bitangent


def lookup(brdf: np.ndarray, grid: MerlGrid, w_i: np.ndarray, w_o: np.ndarray) -> np.ndarray:
    """BRDF (..., 3) in 1/sr at local directions (..., 3) by MERL cell lookup; missing -> 0."""
    flat = grid.angles_to_flat(*dirs_to_half_diff(w_i, w_o))
    values = brdf[flat]
    return np.where(np.isfinite(values), values, 0.0)


@lru_cache(maxsize=16)
def sphere_view(grid: MerlGrid, direction: tuple, size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What a sphere under the light from ``direction`` (3,) shows, whatever its BRDF: each
    pixel's grid cell (int64 (size, size)), whether it is lit and seen (bool), and cos theta_i
    (clipped at 0). Read-only and cached: every capture's preview on a grid asks the same."""
    to_light = np.asarray(direction, dtype=np.float64)
    to_light = to_light / np.linalg.norm(to_light)
    normals, mask = sphere_normals(size)
    tangent, bitangent = tangent_frame(normals)
    frame = np.stack([tangent, bitangent, normals], -2)          # (size, size, 3 axes, 3)
    w_i = frame @ to_light                                       # light in each pixel's local frame
    w_o = frame @ np.array([0.0, 0.0, 1.0])                      # the camera looks along -z
    lit = mask & (w_i[..., 2] > 0) & (w_o[..., 2] > 0)
    view = (grid.angles_to_flat(*dirs_to_half_diff(w_i, w_o)), lit, np.clip(w_i[..., 2], 0, None))
    for array in view:
        array.flags.writeable = False
    return view


def _cell_values(values: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """``values`` (grid.size, 3) at ``cells``; missing (NaN) -> 0."""
    found = values[cells]
    return np.where(np.isfinite(found), found, 0.0)


def render_sphere(brdf: np.ndarray, grid: MerlGrid, light, size: int = 192) -> np.ndarray:
    """HDR radiance image (size, size, 3) of a sphere lit by one directional light.

    ``brdf`` is (grid.size, 3) in 1/sr (NaN = missing); ``light`` is (direction, irradiance).
    Pixels off the sphere or facing away from the light are 0.
    """
    direction, irradiance = light
    cells, lit, cos_i = sphere_view(grid, tuple(np.asarray(direction, dtype=np.float64).tolist()), size)
    radiance = _cell_values(brdf, cells) * (irradiance * cos_i)[..., None]
    return np.where(lit[..., None], radiance, 0.0)


def render_values(values: np.ndarray, grid: MerlGrid, light, size: int = 192) -> np.ndarray:
    """Per-pixel cell values (size, size) of a sphere under one light: the channel mean of
    ``values`` (grid.size, 3) at each lit pixel's cell (NaN -> 0), 0 elsewhere. No shading."""
    cells, lit, _ = sphere_view(grid, tuple(np.asarray(light[0], dtype=np.float64).tolist()), size)
    return np.where(lit, _cell_values(values, cells).mean(axis=-1), 0.0)


def log_error(estimate: np.ndarray, reference: np.ndarray, grid: MerlGrid) -> np.ndarray:
    """|ln(w x_ref + eps) - ln(w x_est + eps)| per cell and channel (grid.size, 3); NaN where
    either is missing (w = clip(cos theta_i cos theta_o, 0.01, 1), eps = 0.001, as training)."""
    from goniofrost.core.grid import cosine_weight

    cells = grid.valid_cells   # the others stay NaN: only valid cells are weighed
    w = cosine_weight(grid)[:, None]
    error = np.full((grid.size, 3), np.nan)
    with np.errstate(invalid="ignore"):
        error[cells] = np.abs(np.log(w * np.maximum(reference[cells], 0) + EPS)
                              - np.log(w * np.maximum(estimate[cells], 0) + EPS))
    return error


def render_set(brdf: np.ndarray, grid: MerlGrid, lights=DEFAULT_LIGHTS, size: int = 192) -> np.ndarray:
    """HDR images (n_lights, size, size, 3), one sphere per light of ``lights``."""
    return np.stack([render_sphere(brdf, grid, (d, e), size) for _, d, e in lights])


def rendering_snr_db(reference: np.ndarray, estimate: np.ndarray) -> float:
    """10 log10(sum ref^2 / sum (ref - est)^2) over HDR images of equal shape; inf if identical."""
    reference, estimate = np.asarray(reference, np.float64), np.asarray(estimate, np.float64)
    if reference.shape != estimate.shape:
        raise ValueError(f"rendering_snr_db: shapes differ: {reference.shape} vs {estimate.shape}")
    noise = float(np.sum((reference - estimate) ** 2))
    signal = float(np.sum(reference ** 2))
    if noise == 0.0:
        return float("inf")
    return 10.0 * np.log10(signal / noise) if signal > 0 else float("-inf")


def exposure_for(hdr: np.ndarray, percentile: float = 97.0) -> float:
    """A scale that maps the ``percentile`` of the lit HDR values to display white."""
    lit = hdr[hdr > 0]
    level = float(np.percentile(lit, percentile)) if lit.size else 1.0
    return 1.0 / level if level > 0 else 1.0


def tone_map(hdr: np.ndarray, exposure: float) -> np.ndarray:
    """Display values in [0, 1]: scale by ``exposure``, clip, then gamma 2.0 (as the paper)."""
    return np.clip(hdr * exposure, 0.0, 1.0) ** (1.0 / GAMMA)


def make_preview(estimate_path, reference_path=None, lights=DEFAULT_LIGHTS, size: int = 192,
                 std_path=None) -> Preview:
    """Render a MERL file (and optionally a reference MERL file and a std file) under ``lights``.

    The std file (OUT.std.binary of ``reconstruct``) must be on the estimate's grid.
    """
    estimate, grid = read_merl_complete(estimate_path)  # the file's own grid: a small-grid file renders as well
    reference, ref_grid = (None, None) if reference_path is None else read_merl_complete(reference_path)
    std = None if std_path is None else read_merl_complete(std_path, grid)[0]
    if reference is not None and ref_grid != grid:
        return _preview(render_set(estimate, grid, lights, size), render_set(reference, ref_grid, lights, size), lights)
    return preview_of(estimate, grid, reference, lights, size, std=std)


def preview_of(estimate: np.ndarray, grid: MerlGrid, reference: np.ndarray | None = None,
               lights=DEFAULT_LIGHTS, size: int = 192, std: np.ndarray | None = None) -> Preview:
    """Render BRDF arrays (grid.size, 3) in 1/sr (NaN = missing), as ``make_preview`` does files;
    ``std``: the predictive std (grid.size, 3) for the uncertainty panel."""
    hdr = render_set(estimate, grid, lights, size)
    ref = None if reference is None else render_set(reference, grid, lights, size)
    out = _preview(hdr, ref, lights)
    if std is None:
        return out
    valid = grid.valid_mask
    errors = {"predicted": float(np.nanmean(std[valid] ** 2)), "actual": None}
    panels = {"std": np.stack([render_values(std, grid, (d, e), size) for _, d, e in lights])}
    if reference is not None:
        err = log_error(estimate, reference, grid)
        errors["actual"] = float(np.nanmean(err[valid] ** 2))
        panels["log_error"] = np.stack([render_values(err, grid, (d, e), size) for _, d, e in lights])
    return Preview(out.estimate, out.reference, out.snr_db, out.light_names, errors=errors, **panels)


def _preview(estimate: np.ndarray, reference: np.ndarray | None, lights) -> Preview:
    snr = None if reference is None else rendering_snr_db(reference, estimate)
    return Preview(estimate, reference, snr, tuple(name for name, _, _ in lights))


def compose(preview: Preview) -> np.ndarray:
    """Tone-mapped image grid (rows = lights; columns = estimate | reference | error x10, then
    predicted std | actual |log error| when given).

    Returns float (n_lights * size, n_columns * size, 3) in [0, 1]; every rendered column shares
    the reference's exposure so that brightness differences are real; the std and log-error
    columns share one colour scale (0 to the 99th percentile of both).
    """
    exposure = exposure_for(preview.reference if preview.reference is not None else preview.estimate)
    columns = [preview.estimate] + ([preview.reference] if preview.reference is not None else [])
    maps = [m for m in (preview.std, preview.log_error) if m is not None]
    top = _map_scale(maps)
    rows = []
    for k in range(preview.estimate.shape[0]):
        tiles = [tone_map(col[k], exposure) for col in columns]
        if preview.reference is not None:
            tiles.append(_colour(error_display(preview, k, exposure), 1.0, ERROR_COLOURMAP, lit=preview.reference[k]))
        tiles += [_colour(m[k], top) for m in maps]
        rows.append(np.concatenate(tiles, axis=1))
    return np.concatenate(rows, axis=0)


def error_display(preview: Preview, k: int, exposure: float) -> np.ndarray:
    """(size, size) the |error| x ERROR_GAIN panel's value under light k: the channel mean of
    |reference - estimate| x gain in display units (the reference's exposure: 1 = white), before
    the colour map (ERROR_COLOURMAP on [0, 1])."""
    return ERROR_GAIN * exposure * np.abs(preview.reference[k] - preview.estimate[k]).mean(axis=-1)


def _map_scale(maps) -> float:
    values = np.concatenate([m[m > 0] for m in maps]) if maps else np.empty(0)
    return float(np.percentile(values, 99)) if values.size else 1.0


def _colour(values: np.ndarray, top: float, colourmap: str = STD_COLOURMAP, lit=None) -> np.ndarray:
    """(size, size) values -> RGB in [0, 1] with ``colourmap`` on [0, top]; unlit pixels (values 0,
    or ``lit`` (size, size, 3) all 0 when given) are black."""
    from matplotlib import colormaps

    rgb = colormaps[colourmap](np.clip(values / top, 0, 1))[..., :3]
    shown = (values > 0) if lit is None else (np.asarray(lit).max(axis=-1) > 0)
    return np.where(shown[..., None], rgb, 0.0)


def write_png(path, preview: Preview, title: str = "") -> None:
    """Write the composed preview with column labels, the SNR and a colour bar (with units) under
    every false-colour panel as a PNG (atomically); its Title is the title drawn, its Description
    names the colour bars."""
    fig = preview_figure(preview, title)
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", facecolor="white",
                metadata={"Title": fig._suptitle.get_text(), "Description": "; ".join(colour_bars(fig))})
    write_bytes_atomic(path, buffer.getvalue())


def colour_bars(fig) -> list[str]:
    """The labels of a figure's colour bars (``preview_figure``), in order."""
    return [ax.get_xlabel() for ax in fig.axes if ax.get_label() == "colour bar"]


def preview_figure(preview: Preview, title: str = ""):
    """The preview's matplotlib Figure: the composed image, a title (``title``, the SNR, the
    actual error), the columns' names, and a horizontal colour bar under the |error| column
    (ERROR_BAR, 0 to 1) and under the std and |log error| columns (STD_BAR, their shared scale)."""
    import matplotlib
    matplotlib.use("Agg")
    from matplotlib import colormaps
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize
    from matplotlib.figure import Figure

    image = compose(preview)
    labels = ["estimate"] + (["reference", f"|error| x{ERROR_GAIN:g}"] if preview.reference is not None else [])
    labels += ["predicted std of ln(wx+eps)"] if preview.std is not None else []
    labels += ["actual |log error|"] if preview.log_error is not None else []
    lines = title.count("\n") + 3 + (preview.errors is not None and preview.errors.get("actual") is not None)
    height = 2.2 * len(preview.light_names) + 0.25 * lines + 0.7
    fig = Figure(figsize=(2.2 * len(labels), height), dpi=100)
    bottom, top = 0.7 / height, 1 - (0.25 * lines + 0.05) / height
    ax = fig.add_axes((0.0, bottom, 1.0, top - bottom))
    ax.imshow(image, interpolation="nearest", aspect="auto")
    ax.set_axis_off()
    snr = "" if preview.snr_db is None else ("\n" if "\n" in title else "   ") + f"rendering SNR {preview.snr_db:.2f} dB"
    fig.suptitle(f"{title}{snr}{_errors_text(preview.errors)}\n" + "  |  ".join(labels), fontsize=9)
    width = 1 / len(labels)
    bars = []
    if preview.reference is not None:
        bars.append((2, 1, Normalize(0, 1), ERROR_COLOURMAP, ERROR_BAR))
    maps = [m for m in (preview.std, preview.log_error) if m is not None]
    if maps:
        first = 3 if preview.reference is not None else 1
        bars.append((first, len(maps), Normalize(0, _map_scale(maps)), STD_COLOURMAP, STD_BAR))
    for column, span, norm, cmap, label in bars:
        cax = fig.add_axes((column * width + 0.1 * width, 0.42 / height, span * width * 0.8, 0.1 / height),
                           label="colour bar")
        bar = fig.colorbar(ScalarMappable(norm, colormaps[cmap]), cax=cax, orientation="horizontal")
        bar.set_label(label, fontsize=6)
        cax.tick_params(labelsize=6)
    return fig


def _errors_text(errors) -> str:
    """The actual log-relative MSE against the reference for the title, or "". The predicted one is
    the caller's error figure (``confidence.figure``, in ``title``): the mean predicted variance
    this preview knows is not centred on the calibration, and a second number confuses."""
    if not errors or errors.get("actual") is None:
        return ""
    return f"\nactual log-relative MSE against the reference {errors['actual']:.4g}"


def record_figure(binary) -> str | None:
    """The error figure (``error_figure``) of the record ``reconstruct`` or a capture wrote beside
    a MERL file (FILE.json beside FILE.binary, a session's brdf.json), None when there is none."""
    import json
    from pathlib import Path

    path = Path(binary)
    stem = path.with_suffix("") if path.suffix.lower() == ".binary" else path
    try:
        record = json.loads(stem.with_name(stem.name + ".json").read_text())
    except (OSError, ValueError):
        return None
    figure = record.get("error_figure") if isinstance(record, dict) else None
    return figure if isinstance(figure, str) else None
