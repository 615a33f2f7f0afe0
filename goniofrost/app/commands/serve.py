"""``goniofrost serve``: one process holds the rig and runs its queue behind an HTTP JSON API."""
from __future__ import annotations

HELP = ("hold a rig's devices and run one plan at a time from a queue kept under ROOT, behind an HTTP "
        "JSON API (/openapi.json) with the monitor's pages beside it; control needs the printed token")


def add_arguments(parser) -> None:
    parser.add_argument("--rig", required=True, metavar="RIG.yaml", help="the rig file")
    parser.add_argument("--root", default=".", metavar="DIR",
                        help="folder of the queue (serve.sqlite), plan files, sessions/ and snaps/ (default: .)")
    parser.add_argument("--host", default="127.0.0.1",
                        help="address to listen on (default 127.0.0.1: this computer only). RISK: another address "
                             "lets anyone on that network who has the token move the rig")
    parser.add_argument("--port", type=int, default=8765, help="TCP port (default 8765; 0 picks a free one)")
    parser.add_argument("--speedup", type=float, default=None,
                        help="a simulated rig's clock speed-up (default: its sim.clock_speedup)")


def run(args) -> int:
    from goniofrost.app.ground_truth import GroundTruth
    from goniofrost.app.monitoring import check_port
    from goniofrost.server.serve import serve

    check_port(args.port)
    return serve(args.rig, args.root, host=args.host, port=args.port, speedup=args.speedup, compare=GroundTruth)
