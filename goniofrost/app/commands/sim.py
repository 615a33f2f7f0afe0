"""``goniofrost sim --rig RIG.yaml``: start the rig's simulated devices and serve until SIGINT/SIGTERM.

Prints one JSON line on stdout mapping each axis (and "lamp") to its endpoint entry
``{"protocol", "endpoint", "id" or "address", "baud"}``, so that any client (dynamixel-sdk, a
pymodbus client, a serial terminal) can talk to the devices.
"""
from __future__ import annotations

HELP = "start the simulated devices of a rig, print their endpoints as one JSON line, serve until stopped"


def add_arguments(parser) -> None:
    parser.add_argument("--rig", required=True, metavar="RIG.yaml", help="rig file (its devices are simulated)")
    parser.add_argument("--speedup", type=float, default=None,
                        help="simulated seconds per real second (default: the rig's sim.clock_speedup)")
    parser.add_argument("--seed", type=int, default=None, help="seed of the simulation (default: the rig's sim.seed)")


def run(args) -> int:
    import json
    import signal
    import sys
    import threading

    from goniofrost.core.errors import ConfigError
    from goniofrost.capture.rig_file import load_checked_rig
    from sim.rig import SimulatedRig

    if args.speedup is not None and not args.speedup > 0:
        raise ConfigError("command line", "--speedup", "a number > 0", args.speedup)
    rig = load_checked_rig(args.rig)
    seed = args.seed if args.seed is not None else int((rig.sim or {}).get("seed", 0))
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    with SimulatedRig(rig, speedup=args.speedup, seed=seed) as simulation:
        print(json.dumps(simulation.endpoints), flush=True)
        print(f"goniofrost sim: serving the {len(rig.axes)} axes (and lamp) of {rig.name} "
              f"(speed-up {simulation.clock.speedup:g}); stop with Ctrl-C", file=sys.stderr, flush=True)
        while not stop.wait(0.2):
            pass
    return 0
