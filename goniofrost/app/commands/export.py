"""``goniofrost export FILE.binary --format mitsuba --out FILE.bsdf``: a MERL file for Mitsuba 3.

Writes the RGL tensor file (Dupuy and Jakob 2018) that Mitsuba 3's ``measured`` BSDF loads in
its RGB variants (pbrt-v4 reads only the spectral form, which is not written); see
``goniofrost.brdf.mitsuba_export``. Nothing is written when the input is refused (truncated or
oversized file, NaN or inf stored, no valid value).
"""
from __future__ import annotations

import argparse

HELP = "export a MERL .binary to the RGL tensor format (.bsdf) that Mitsuba 3's 'measured' BSDF renders"
FORMATS = ["mitsuba"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from goniofrost.brdf.mitsuba_export import DEFAULT_OPTIONS

    parser.add_argument("binary", metavar="FILE.binary", help="the BRDF to export (MERL .binary, any grid)")
    parser.add_argument("--format", choices=FORMATS, default="mitsuba",
                        help="mitsuba: RGL tensor file for Mitsuba 3's 'measured' BSDF (RGB variants); the default")
    parser.add_argument("--out", metavar="FILE.bsdf", help="output file (default: FILE.bsdf beside the input)")
    parser.add_argument("--theta-i", type=int, default=DEFAULT_OPTIONS.theta_i, metavar="N",
                        help=f"incident elevations tabulated (default {DEFAULT_OPTIONS.theta_i})")
    parser.add_argument("--sample", type=int, default=DEFAULT_OPTIONS.sample, metavar="N",
                        help=f"rgb/luminance nodes per side of each incident slice (default {DEFAULT_OPTIONS.sample}; "
                             f"the file grows with N^2)")


def run(args: argparse.Namespace) -> int:
    import time
    from dataclasses import replace
    from pathlib import Path

    from goniofrost.brdf.mitsuba_export import DEFAULT_OPTIONS, export_binary_file
    from goniofrost.core.errors import GoniofrostError

    source = Path(args.binary)
    out = Path(args.out) if args.out else source.with_suffix(".bsdf")
    if out.resolve() == source.resolve():
        raise GoniofrostError(f"--out {out}: is the input file; expected another name such as {source.stem}.bsdf")
    for flag, value in (("--theta-i", args.theta_i), ("--sample", args.sample)):
        if value < 2:
            raise GoniofrostError(f"{flag}: expected an integer >= 2, found {value}")
    options = replace(DEFAULT_OPTIONS, theta_i=args.theta_i, sample=args.sample)
    start = time.perf_counter()
    fields = export_binary_file(source, out, options)
    rgb = fields["rgb"].shape
    print(f"wrote {out}: {out.stat().st_size / 1e6:.1f} MB, {rgb[1]} incident elevations x {rgb[3]}x{rgb[4]} "
          f"rgb nodes, in {time.perf_counter() - start:.1f} s (load it with Mitsuba 3: type 'measured', an RGB variant)")
    return 0
