"""A MERL file rendered by goniofrost's preview and by Mitsuba 3 from its export, with the difference.

    .venv/bin/python benchmarks/mitsuba_sphere.py [FILE.binary] [--label TEXT] [--out docs/mitsuba_sphere.png] [--size 128]

Without FILE.binary the demo material (builtin:red-plastic) is tabulated on the full grid.
Exports the file with ``goniofrost.brdf.mitsuba_export`` (timed), renders the preview spheres
(three lights, rows) with goniofrost's own lookup renderer and with Mitsuba's ``measured``
BSDF (columns: goniofrost | Mitsuba | |difference| x10, one exposure, gamma 2 as the preview),
prints the rendering SNR of Mitsuba's image against goniofrost's and writes a small PNG.
"""
from __future__ import annotations

import argparse
import io
import tempfile
import time
from pathlib import Path

import numpy as np

from goniofrost.brdf.merl_file import _read_header, read_merl, valid_to_full
from goniofrost.brdf.mitsuba_export import export_mitsuba
from goniofrost.brdf.mitsuba_render import render_set_mitsuba
from goniofrost.brdf.preview import DEFAULT_LIGHTS, ERROR_GAIN, exposure_for, render_set, rendering_snr_db, tone_map
from goniofrost.core.atomic_file import write_bytes_atomic
from goniofrost.core.grid import FULL_GRID

REPO = Path(__file__).resolve().parents[1]
DEMO_MATERIAL = "builtin:red-plastic"


def load(binary: str | None):
    """(brdf (grid.size, 3), grid, label) of a MERL file, or of the demo material tabulated."""
    if binary:
        grid = _read_header(Path(binary))
        return read_merl(binary, grid), grid, Path(binary).name
    from goniofrost.datasets import parse_material_spec
    from goniofrost.datasets.tabulate import tabulate_cached

    dataset, name = parse_material_spec(DEMO_MATERIAL)
    values = tabulate_cached(dataset, [name], FULL_GRID)[0].astype(np.float64)
    return valid_to_full(values, FULL_GRID), FULL_GRID, DEMO_MATERIAL


def compose(ours: np.ndarray, theirs: np.ndarray) -> np.ndarray:
    """Rows = lights; columns = goniofrost | Mitsuba | |difference| x ERROR_GAIN; one exposure."""
    exposure = exposure_for(ours)
    rows = [np.concatenate([tone_map(a, exposure), tone_map(b, exposure),
                            tone_map(ERROR_GAIN * np.abs(a - b), exposure)], axis=1)
            for a, b in zip(ours, theirs)]
    return np.concatenate(rows, axis=0)


def write_png(path: Path, image: np.ndarray, title: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    fig = Figure(figsize=(image.shape[1] / 100, image.shape[0] / 100 + 0.5), dpi=100)
    ax = fig.add_axes((0.0, 0.0, 1.0, image.shape[0] / (image.shape[0] + 50)))
    ax.imshow(np.round(image * 255).astype(np.uint8), interpolation="nearest")
    ax.set_axis_off()
    fig.suptitle(title, fontsize=7, y=0.995, va="top")
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", facecolor="white")
    write_bytes_atomic(path, buffer.getvalue())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("binary", nargs="?", help="MERL .binary (default: the demo material, tabulated)")
    parser.add_argument("--out", default=str(REPO / "docs" / "mitsuba_sphere.png"))
    parser.add_argument("--label", help="what the file is, for the title (default: its name)")
    parser.add_argument("--size", type=int, default=128, help="sphere diameter in pixels")
    args = parser.parse_args()

    brdf, grid, label = load(args.binary)
    label = args.label or label
    with tempfile.TemporaryDirectory() as folder:
        bsdf = Path(folder) / "export.bsdf"
        start = time.perf_counter()
        export_mitsuba(bsdf, brdf, grid, source=label)
        export_s = time.perf_counter() - start
        theirs = render_set_mitsuba(bsdf, DEFAULT_LIGHTS, args.size)
    ours = render_set(brdf, grid, DEFAULT_LIGHTS, args.size)
    snr = rendering_snr_db(ours, theirs)
    per_light = ", ".join(f"{name} {rendering_snr_db(a, b):.1f} dB"
                          for (name, _, _), a, b in zip(DEFAULT_LIGHTS, ours, theirs))
    print(f"{label}: export {export_s:.2f} s; rendering SNR of Mitsuba against goniofrost's preview "
          f"{snr:.2f} dB ({per_light})")
    title = (f"{label}\ngoniofrost preview | Mitsuba 3 from the .bsdf | |difference| x{ERROR_GAIN:g}\n"
             f"rendering SNR {snr:.1f} dB; rows: lights " + ", ".join(n for n, _, _ in DEFAULT_LIGHTS))
    write_png(Path(args.out), compose(ours, theirs), title)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
