"""``goniofrost preview``: render spheres of a MERL file beside a reference; print the rendering SNR."""
from __future__ import annotations

HELP = "render spheres of a MERL .binary (beside a reference and an error image) into a PNG"


def add_arguments(parser) -> None:
    parser.add_argument("binary", metavar="FILE.binary", help="the BRDF to render (MERL .binary)")
    parser.add_argument("--reference", metavar="FILE.binary", help="ground truth to compare against")
    parser.add_argument("--out", required=True, metavar="FILE.png", help="the PNG to write")
    parser.add_argument("--std", metavar="FILE.std.binary",
                        help="predictive standard deviation from goniofrost reconstruct: adds an uncertainty "
                             "panel (and, with --reference, the actual log error beside it)")
    parser.add_argument("--size", type=int, default=192, help="sphere diameter in pixels, 16 to 2048 (default 192)")
    parser.add_argument("--renderer", choices=["goniofrost", "mitsuba"], default="goniofrost",
                        help="goniofrost: MERL cell lookup per pixel (default); mitsuba: export each file "
                             "(goniofrost export) and render it with Mitsuba 3's 'measured' BSDF (needs mitsuba)")


def run(args) -> int:
    from pathlib import Path

    from goniofrost.core.errors import GoniofrostError
    from goniofrost.app.png_out import check_png_name, check_sphere_size
    from goniofrost.brdf.preview import make_preview, record_figure, write_png

    check_png_name(args.out)
    check_sphere_size(args.size)
    if args.renderer == "mitsuba":
        if args.std is not None:
            raise GoniofrostError("--std: the uncertainty panel is drawn by the goniofrost renderer; "
                                  "leave out --renderer mitsuba")
        from goniofrost.brdf.mitsuba_render import make_preview_mitsuba
        preview = make_preview_mitsuba(args.binary, args.reference, size=args.size)
    else:
        preview = make_preview(args.binary, args.reference, size=args.size, std_path=args.std)
    figure = record_figure(args.binary)
    write_png(args.out, preview, title=Path(args.binary).name + (" (Mitsuba 3)" if args.renderer == "mitsuba" else "")
              + ("" if figure is None else f"\n{figure}"))
    print(f"wrote {args.out}")
    if preview.snr_db is not None:
        print(f"rendering SNR: {preview.snr_db:.2f} dB against {args.reference}")
    if preview.errors is not None:
        actual = preview.errors["actual"]
        print(f"predicted log-relative MSE {preview.errors['predicted']:.4g}"
              + (f", actual {actual:.4g} against {args.reference}" if actual is not None else ""))
    return 0
