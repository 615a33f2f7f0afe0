"""``goniofrost align``: measure the zero offset of every axis from images of the white card."""
from __future__ import annotations

HELP = "measure the axes' zero offsets from marker poses and the white tile (write ALIGNMENT.json)"


def add_arguments(parser) -> None:
    from goniofrost.app.arg_types import seed

    parser.description = (
        "Image the white reference card at poses spread over every axis (about 30: yaw -30..55 deg, tilt "
        "-35..35 deg, two arm angles each), read its markers (camera pose by solvePnP) and the white tile's "
        "brightness, and fit each axis's zero offset by least squares. Writes ALIGNMENT.json "
        "(offsets_deg: an axis reading q stands at q + offset), which plan and capture take with "
        "--alignment or through the rig file's alignment key. Run it first on a new rig, and after "
        "anything on the rig was moved.")
    parser.add_argument("--rig", required=True, metavar="RIG.yaml", help="rig file with the camera model")
    parser.add_argument("--out", required=True, metavar="ALIGNMENT.json", help="alignment file to write")
    parser.add_argument("--frames", metavar="DIR", help="keep the frames in DIR (default: not kept)")
    parser.add_argument("--seed", type=seed, default=None, help="simulated rig: noise seed (default: the rig's sim.seed)")
    parser.add_argument("--speedup", type=float, default=None,
                        help="simulated rig: clock speed-up (default: the rig's sim.clock_speedup)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args) -> int:
    from goniofrost.capture.align import align
    from goniofrost.rig.hardware import SimOptions
    from goniofrost.rig.simulated import rig_devices

    doc = align(args.rig, args.out, devices=rig_devices, sim=SimOptions(seed=args.seed, speedup=args.speedup),
                progress=not args.no_progress, frames=args.frames)
    offsets, stderr, lamp = doc["offsets_deg"], doc["stderr_deg"], doc["lamp"]
    print(f"{args.out}: zero offsets of rig {doc['rig']['name']!r} (an axis reading q stands at q + offset):")
    for name, value in offsets.items():
        print(f"  {name:>14} {value:+8.4f} deg  +- {stderr[name]:.4f}")
    print(f"  lamp elevation {lamp['elevation_deg']:+.4f} deg +- {lamp['elevation_stderr_deg']:.4f} (measured, not applied)")
    images = doc["images"]
    print(f"  from {images['used']} of {images['poses']} poses ({images['corners']} marker corners, residual "
          f"{doc['residual_px']['rms']:.3f} px RMS; tile brightness residual {100 * doc['photometric_residual_rms']:.3f} %)")
    print(f"  use it: goniofrost plan ... --rig {args.rig} --alignment {args.out}, and capture with the same "
          f"--alignment (or name it in the rig file: alignment: {args.out})")
    return 0
