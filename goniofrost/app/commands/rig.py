"""``goniofrost rig SUBCOMMAND --rig RIG.yaml``: the operator's console for a real (or simulated) rig.

check   every problem of the rig file, then every device probed (nothing enabled or moved)
status  positions (read and aligned), limits, motion, alarms, lamp; --json, --watch
move    AXIS=DEG ... (absolute, or relative with --by), checked before a byte is sent
home    home the axes (asks whether the rig is clear unless --yes)
lamp    on | off
stop    stop the program that drives the rig, or stop every axis and the lamp
snap    one frame (or the capture's bracket) at the current pose: levels, markers, ROI, SNR

When `goniofrost serve` holds the rig, these ask the server instead of opening the devices.
"""
from __future__ import annotations

import sys

HELP = "the operator's console: check, read, move, home, stop the rig, switch its lamp, snap a frame"

SUBCOMMANDS = {
    "check": "check the rig file (every problem in one run), then connect to every device without enabling "
             "or moving it and print one table: link, answers, identity, position, limits, state, likely causes",
    "status": "read every axis (position as read and aligned, limits, moving, enabled, alarm) and the lamp",
    "move": "move axes: AXIS=DEG ... absolute, or relative with --by; soft limits and the rig's geometry are "
            "checked before anything is sent; Ctrl-C stops and confirms every axis",
    "home": "home the named axes (default: all); asks whether the rig is clear unless --yes",
    "lamp": "switch the lamp on or off",
    "stop": "stop the rig from any terminal: a program driving it is told to stop (its own report follows); "
            "once it lets go (on a real rig), or when none drives it, connect, stop and confirm every axis and "
            "switch the lamp off",
    "snap": "take one frame (or the bracket the capture would take) at the current pose and report levels, "
            "saturation, markers, region-of-interest pixels and SNR; writes a PNG with the region and markers; "
            "exits 2 when it finds a problem: markers or region not found, a bracket that cannot expose the "
            "card, or an --exposure whose frame or region is more than a quarter saturated or too dark to read",
}


def add_arguments(parser) -> None:
    import argparse

    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.description = __doc__.split("\n", 1)[1]
    sub = parser.add_subparsers(dest="rig_command", metavar="SUBCOMMAND", required=True)
    for name, text in SUBCOMMANDS.items():
        p = sub.add_parser(name, help=text.split(";")[0], description=text)
        p.add_argument("--rig", required=True, metavar="RIG.yaml", help="the rig file")
        p.add_argument("--alignment", metavar="ALIGNMENT.json", default=None,
                       help="zero offsets of the axes (goniofrost align); default: the rig file's own")
        getattr(sys.modules[__name__], f"_args_{name}")(p)


def _args_check(p) -> None:
    p.add_argument("--offline", action="store_true", help="only check the rig file; connect to nothing")
    p.add_argument("--json", action="store_true", help="print the findings as JSON")


def _args_status(p) -> None:
    p.add_argument("--json", action="store_true", help="print one JSON document (per reading with --watch)")
    p.add_argument("--watch", action="store_true", help="read again every --interval seconds until Ctrl-C")
    p.add_argument("--interval", type=float, default=None, metavar="S",
                   help="seconds between readings (--watch; default 1)")
    p.add_argument("--count", type=int, default=None, metavar="N", help="stop after N readings (--watch)")


def _args_move(p) -> None:
    p.add_argument("targets", nargs="+", metavar="AXIS=DEG", help="an axis of the rig file and its target in degrees")
    p.add_argument("--by", action="store_true", help="relative moves: AXIS=DEG moves by DEG from where it is")


def _args_home(p) -> None:
    p.add_argument("axes", nargs="*", metavar="AXIS", help="axes to home (default: every axis)")
    p.add_argument("--yes", action="store_true", help="do not ask whether the rig is clear")


def _args_lamp(p) -> None:
    p.add_argument("state", choices=["on", "off"], help="switch the lamp on or off")


def _args_stop(p) -> None:
    pass


def _args_snap(p) -> None:
    p.add_argument("--target", choices=["white", "sample"], default="white",
                   help="what is in front of the camera (default: the white reference card)")
    p.add_argument("--exposure", type=float, default=None, metavar="S",
                   help="one frame of S seconds, on a camera with shutter_speeds the nearest of them "
                        "(default: the bracket the capture would take)")
    p.add_argument("--out", required=True, metavar="FRAME.png", help="the picture, with the region and markers drawn")
    p.add_argument("--json", action="store_true", help="print the findings as JSON")
    p.add_argument("--move", nargs="+", default=None, metavar="AXIS=DEG",
                   help="move these axes first (limits checked as for rig move), then snap")
    p.add_argument("--material", default=None, metavar="SPEC:NAME",
                   help="simulated rig only: the material on the sample card (default: builtin:red-plastic)")


def run(args) -> int:
    from goniofrost.app import rig_console
    from goniofrost.capture.signals import SessionInterrupted

    try:
        return getattr(rig_console, f"run_{args.rig_command}")(args)
    except SessionInterrupted as exc:  # Ctrl-C or a stop request: the message says how each axis took it
        print(f"goniofrost rig {args.rig_command}: {exc}", file=sys.stderr)
        return 130
