"""``goniofrost queue``: measure several samples in one run, one session folder each.

When a ``goniofrost serve`` holds the queue's rig, its samples are added to that server's queue
instead (the server measures them, its sessions under its root); else the command opens the rig.
``goniofrost queue add --rig RIG --plan PLAN --sample-id ID ...`` adds one sample to the queue of
the server holding RIG.
"""
from __future__ import annotations

HELP = ("measure the samples of QUEUE.yaml one after another (one session each, the calibration shot once "
        "and the white reference re-measured between samples); the same command resumes")


def add_arguments(parser) -> None:
    from goniofrost.app.arg_types import seed

    parser.add_argument("queue", metavar="QUEUE.yaml", help="rig, plan, root, operator and the samples "
                                                            "(paths relative to the queue file); or the word add: "
                                                            "one sample to a running goniofrost serve (below)")
    parser.add_argument("--yes", action="store_true",
                        help="do not ask to mount each sample (a rig with a sample changer, or the simulated rig)")
    parser.add_argument("--seed", type=seed, default=None, help="simulated rig: noise seed (default: the rig's sim.seed)")
    parser.add_argument("--speedup", type=float, default=None,
                        help="simulated rig: clock speed-up (default: the rig's sim.clock_speedup)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    add = parser.add_argument_group("goniofrost queue add: one sample, to the queue of the goniofrost serve "
                                    "holding --rig (its fields checked by the server)")
    for option, kind, text in ADD_OPTIONS:
        add.add_argument(option, type=kind, default=None, help=text)


ADD_OPTIONS = [  # (option, type, help) of ``queue add``; the entry's field is the option's name
    ("--rig", str, "the rig file whose devices the server holds"),
    ("--plan", str, "the plan file, under the server's root"),
    ("--sample-id", str, "the sample's name (its session folder is named after it)"),
    ("--material", str, "a simulated rig's material, e.g. builtin:gold"),
    ("--operator", str, "who measures (default: this user)"),
    ("--note", str, "a note kept with the session"),
    ("--target-error", float, "stop once the error is at most this (log-relative MSE)"),
    ("--confidence", float, "the bound's confidence, with --target-error"),
]


def run(args) -> int:
    import sys

    from goniofrost.app.ground_truth import GroundTruth
    from goniofrost.capture.engine import SessionInterrupted
    from goniofrost.capture.queue import NOTHING_MEASURED, ask_to_mount, run_queue
    from goniofrost.capture.queue_file import read_queue
    from goniofrost.datasets import shown_material
    from goniofrost.datasets.specs import spec_read_from
    from goniofrost.rig.hardware import SimOptions
    from goniofrost.rig.simulated import rig_devices

    if args.queue == "add":
        return _add_one(args)
    given = [option for option, _, _ in ADD_OPTIONS if getattr(args, _field(option)) is not None]
    if given:
        from goniofrost.core.errors import ConfigError
        raise ConfigError("command line", given[0], "only with goniofrost queue add (a queue file names its own)",
                          getattr(args, _field(given[0])))
    queue = read_queue(args.queue)
    server = _server_of(queue.rig)
    if server is not None:
        return _add_to_server(queue, server, args)

    def materials(text: str, option):   # a material's file, like every path of the queue, beside the queue file
        return shown_material(spec_read_from(text, str(queue.folder)), option)
    try:
        items = run_queue(queue, confirm=None if args.yes else ask_to_mount,
                          sim=SimOptions(seed=args.seed, speedup=args.speedup), progress=not args.no_progress,
                          devices=rig_devices, materials=materials, compare=GroundTruth)
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


def _server_of(rig_path):
    """The client of the ``goniofrost serve`` holding the rig of ``rig_path``, or None."""
    from goniofrost.rig.file import load_checked_rig
    from goniofrost.server.client import server_for

    return server_for(load_checked_rig(rig_path))


def _post_entry(server, plan: str, sample_id: str, material, operator, note, target_error, confidence) -> int:
    """Add one entry to the server's queue (``plan`` relative to its root; a confidence only when
    given); its id. The server checks every field."""
    body = {"plan": plan, "sample_id": sample_id, "material": material,
            "operator": operator or server.who("goniofrost queue"), "note": note, "target_error": target_error}
    if confidence is not None:
        body["confidence"] = confidence
    return server.call("POST", "/api/queue", body)["id"]


def _add_to_server(queue, server, args) -> int:
    """Add every sample of ``queue`` to the server's queue (its plan must lie under the server's root)."""
    from goniofrost.core.errors import GoniofrostError
    from goniofrost.datasets.specs import spec_read_from

    root = server.root.resolve()
    for option, value in (("--seed", args.seed), ("--speedup", args.speedup), ("alignment", queue.alignment)):
        if value is not None:
            raise GoniofrostError(f"{option}: the server at {server.url} holds the rig with its own; leave it out")
    if not queue.plan.resolve().is_relative_to(root):
        raise GoniofrostError(f"{queue.path}: plan: the server at {server.url} reads plans under its root {root}; "
                              f"put {queue.plan.name} there")
    added = []
    for s in queue.samples:
        material = None if s.material is None else spec_read_from(s.material, str(queue.folder))
        confidence = None if s.target_error is None else s.confidence  # meaningless without a target
        entry_id = _post_entry(server, str(queue.plan.resolve().relative_to(root)), s.sample_id, material,
                               s.operator, "; ".join(s.notes) or None, s.target_error, confidence)
        added.append(f"{s.sample_id} (id {entry_id})")
    print(f"queue {queue.path.name}: added {', '.join(added)} to the queue of the server at {server.url}; "
          f"sessions in {root / 'sessions'} (goniofrost sessions {root / 'sessions'})")
    return 0


def _field(option: str) -> str:
    return option[2:].replace("-", "_")


def _add_one(args) -> int:
    """``queue add``: one entry to the queue of the server holding ``--rig`` (the server checks it)."""
    from pathlib import Path

    from goniofrost.core.errors import ConfigError, GoniofrostError

    for option in ("--rig", "--plan", "--sample-id"):
        if getattr(args, _field(option)) is None:
            raise ConfigError("command line", option, "a value with goniofrost queue add", None)
    for option in ("--yes", "--seed", "--speedup", "--no-progress"):
        if getattr(args, _field(option)) not in (None, False):
            raise ConfigError("command line", option, "left out with queue add (the server runs the capture)",
                              getattr(args, _field(option)))
    server = _server_of(args.rig)
    if server is None:
        raise GoniofrostError(f"--rig: no goniofrost serve holds the devices of {args.rig}: start one "
                              f"(goniofrost serve --rig {args.rig} --root DIR), or list the sample in a queue file "
                              f"(goniofrost queue QUEUE.yaml)")
    root, plan = server.root.resolve(), Path(args.plan).resolve()
    if not plan.is_relative_to(root):
        raise ConfigError("command line", "--plan", f"a plan file under the server's root {root}", args.plan)
    entry_id = _post_entry(server, str(plan.relative_to(root)), args.sample_id, args.material, args.operator,
                           args.note, args.target_error, args.confidence)
    print(f"queue: added {args.sample_id} (id {entry_id}) to the queue of the server at {server.url}; "
          f"its session in {root / 'sessions'}")
    return 0
