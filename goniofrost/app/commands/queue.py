"""``goniofrost queue``: measure several samples in one run, one session folder each."""
from __future__ import annotations

HELP = ("measure the samples of QUEUE.yaml one after another (one session each, the calibration shot once "
        "and the white reference re-measured between samples); the same command resumes")


def add_arguments(parser) -> None:
    from goniofrost.app.arg_types import seed

    parser.add_argument("queue", metavar="QUEUE.yaml", help="rig, plan, root, operator and the samples "
                                                            "(paths relative to the queue file)")
    parser.add_argument("--yes", action="store_true",
                        help="do not ask to mount each sample (a rig with a sample changer, or the simulated rig)")
    parser.add_argument("--seed", type=seed, default=None, help="simulated rig: noise seed (default: the rig's sim.seed)")
    parser.add_argument("--speedup", type=float, default=None,
                        help="simulated rig: clock speed-up (default: the rig's sim.clock_speedup)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args) -> int:
    import sys

    from goniofrost.app.ground_truth import GroundTruth
    from goniofrost.capture.engine import SessionInterrupted
    from goniofrost.capture.queue import NOTHING_MEASURED, ask_to_mount, run_queue
    from goniofrost.capture.queue_file import read_queue
    from goniofrost.datasets import shown_material
    from goniofrost.datasets.specs import spec_read_from
    from goniofrost.rig.simulated import rig_devices

    queue = read_queue(args.queue)

    def materials(text: str, option):   # a material's file, like every path of the queue, beside the queue file
        return shown_material(spec_read_from(text, str(queue.folder)), option)
    try:
        items = run_queue(queue, confirm=None if args.yes else ask_to_mount, seed=args.seed, speedup=args.speedup,
                          progress=not args.no_progress, devices=rig_devices, materials=materials,
                          compare=GroundTruth)
    except SessionInterrupted as exc:
        print(f"goniofrost queue: {exc}", file=sys.stderr)  # it says to run the same queue command
        return 130
    except KeyboardInterrupt:
        print(f"goniofrost queue: interrupted; every session under {queue.root} keeps what it captured: run the "
              f"same command to continue the queue", file=sys.stderr)
        return 130
    measured = sum(item.action == "measured" for item in items)
    empty = [item.sample_id for item in items if item.action == NOTHING_MEASURED]
    before = len(items) - measured - len(empty)
    print(f"queue {queue.path.name}: {len(items)} samples, {measured} measured this run, {before} from before"
          + (f", {len(empty)} with nothing measured ({' '.join(empty)}: see above)" if empty else "")
          + f"; sessions in {queue.root} (goniofrost sessions {queue.root})")
    if empty:
        print(f"goniofrost queue: nothing measured for {' '.join(empty)}: the rig's exposures cannot measure "
              f"these samples (see their lines above); the others are done", file=sys.stderr)
        return 2
    return 0
