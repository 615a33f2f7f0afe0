"""``goniofrost export FILE.binary --format mitsuba|rgl-spectral|pbrt --out FILE.bsdf``: a MERL file for renderers.

``mitsuba`` writes the RGB RGL tensor file (Dupuy and Jakob 2018) that Mitsuba 3's ``measured``
BSDF loads in its RGB variants (``goniofrost.brdf.mitsuba_export``); ``rgl-spectral`` (alias
``pbrt``) the spectral one, with ``spectra`` and ``wavelengths`` instead of ``rgb``, that pbrt-v4's
``measured`` material and Mitsuba 3's spectral variants load (``goniofrost.brdf.rgl_spectral``).
Nothing is written when the input is refused (truncated or oversized file, NaN or inf stored, a
missing value on a valid cell: ``merl_file.read_merl_complete``, as preview and compare; no valid
value, a bad option, options that would make a file of more than 1 GB of values).
"""
from __future__ import annotations

import argparse

HELP = ("export a MERL .binary to the RGL tensor format (.bsdf): RGB for Mitsuba 3, spectral for pbrt-v4 and "
        "Mitsuba 3's spectral variants")
MAX_TABLE_BYTES = 1_000_000_000  # 10 times the default spectral file; exporting takes a few times this in memory


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from goniofrost.brdf.formats import FORMATS
    from goniofrost.brdf.mitsuba_export import DEFAULT_OPTIONS
    from goniofrost.brdf.rgl_spectral import DEFAULT_WAVELENGTHS, WAVELENGTH_RANGE_NM

    parser.add_argument("binary", metavar="FILE.binary", help="the BRDF to export (MERL .binary, any grid)")
    parser.add_argument("--format", choices=tuple(FORMATS), default="mitsuba",
                        help="mitsuba: the RGB file for Mitsuba 3's 'measured' BSDF (RGB variants; the default); "
                             "rgl-spectral, or its alias pbrt: the spectral file for pbrt-v4's 'measured' material "
                             "and Mitsuba 3's spectral variants")
    parser.add_argument("--out", metavar="FILE.bsdf",
                        help="output file, ending in .bsdf (default: FILE.bsdf beside the input)")
    parser.add_argument("--theta-i", type=int, default=DEFAULT_OPTIONS.theta_i, metavar="N",
                        help=f"incident elevations tabulated (default {DEFAULT_OPTIONS.theta_i})")
    parser.add_argument("--sample", type=int, default=DEFAULT_OPTIONS.sample, metavar="N",
                        help=f"rgb/spectra and luminance nodes per side of each incident slice (default "
                             f"{DEFAULT_OPTIONS.sample}; the file grows with N^2; at most 1 GB of values in all)")
    lo, hi = WAVELENGTH_RANGE_NM
    parser.add_argument("--wavelengths", type=int, default=None, metavar="N",
                        help=f"spectral formats: wavelengths from {lo:g} to {hi:g} nm (default {DEFAULT_WAVELENGTHS}; "
                             f"the file grows with N)")


def run(args: argparse.Namespace) -> int:
    import time
    from dataclasses import replace
    from pathlib import Path

    from goniofrost.brdf.mitsuba_export import DEFAULT_OPTIONS
    from goniofrost.brdf import formats
    from goniofrost.brdf.rgl_spectral import DEFAULT_WAVELENGTHS
    from goniofrost.core.atomic_file import check_output_file, check_output_suffix
    from goniofrost.core.errors import GoniofrostError

    source = Path(args.binary)
    out = Path(args.out) if args.out else source.with_suffix(".bsdf")
    if out.resolve() == source.resolve():
        raise GoniofrostError(f"--out {out}: is the input file; expected another name such as {source.stem}.bsdf")
    # --out brdf.txt held an RGL tensor under a name that says text; the format is the file's
    # contents (RGB or spectral), never its name, so the name is checked and not read
    check_output_suffix(out, ".bsdf", "every --format writes an RGL tensor file")
    check_output_file(out)  # a folder named brdf.bsdf was found only when the file was written, after the export
    spectral = formats.FORMATS[args.format].spectral
    if args.wavelengths is not None and not spectral:  # it would change nothing, silently
        raise GoniofrostError("--wavelengths: applies to the spectral formats only (--format rgl-spectral or pbrt)")
    wavelengths = DEFAULT_WAVELENGTHS if args.wavelengths is None else args.wavelengths
    for flag, value in (("--theta-i", args.theta_i), ("--sample", args.sample), ("--wavelengths", wavelengths)):
        if value < 2:
            raise GoniofrostError(f"{flag}: expected an integer >= 2, found {value}")
    channels = wavelengths if spectral else 3
    size = 4 * args.theta_i * channels * args.sample ** 2  # the float32 rgb or spectra table, most of the file
    if size > MAX_TABLE_BYTES:  # --theta-i 100000 ran a minute, then the kernel killed it for memory
        # the same table at the default options, in this format: "the defaults write 9 MB" was the
        # rgb table alone, beside a default RGB file of 13.7 MB and a spectral one of 105 MB
        default_channels = 3 if channels == 3 else DEFAULT_WAVELENGTHS
        default = 4 * DEFAULT_OPTIONS.theta_i * default_channels * DEFAULT_OPTIONS.sample ** 2
        raise GoniofrostError(
            f"--theta-i {args.theta_i}, --sample {args.sample}"
            + ("" if channels == 3 else f", --wavelengths {wavelengths}")
            + f": the file would hold {size / 1e9:.1f} GB of values; expected at most {MAX_TABLE_BYTES / 1e9:g} GB "
              f"(the defaults hold {default / 1e6:.0f} MB of {'rgb values' if channels == 3 else 'spectra'})")
    options = replace(DEFAULT_OPTIONS, theta_i=args.theta_i, sample=args.sample)
    start = time.perf_counter()
    fields = formats.export_file(source, out, args.format, options, wavelengths)
    seconds, size = time.perf_counter() - start, out.stat().st_size / 1e6
    print(f"wrote {out}: {size:.1f} MB{_layout(fields)}, in {seconds:.1f} s ({formats.FORMATS[args.format].how_to_load})")
    return 0


def _layout(fields: dict) -> str:
    """What an RGL tensor file tabulates (its rgb or spectra nodes), or nothing for another layout."""
    if "rgb" in fields:
        rgb = fields["rgb"].shape
        return f", {rgb[1]} incident elevations x {rgb[3]}x{rgb[4]} rgb nodes"
    if "spectra" in fields:
        spectra, lam = fields["spectra"].shape, fields["wavelengths"]
        return (f", {spectra[1]} incident elevations x {spectra[3]}x{spectra[4]} nodes x {spectra[2]} wavelengths "
                f"({lam[0]:g}-{lam[-1]:g} nm)")
    return ""
