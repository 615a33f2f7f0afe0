"""``goniofrost sim --rig RIG.yaml``: start the rig's simulated devices and serve until SIGINT/SIGTERM.

Prints one JSON line on stdout mapping each axis (and "lamp") to its endpoint entry
``{"protocol", "endpoint", "id" or "address", "baud"}``, so that any client can talk to the
devices. With ``--write-rig OUT.yaml`` it first writes a rig file (``simulated: false``) whose
drivers point at the running twins and whose camera is a ``rawfile`` camera served by the
simulation (``sim.camera_service``, hot folder ``OUT.frames/``), so every command runs on it as on a
real rig; the file is removed when the twins stop, unless another ``sim --write-rig`` replaced it.
"""
from __future__ import annotations

from contextlib import contextmanager

HELP = "start the simulated devices of a rig, print their endpoints as one JSON line, serve until stopped"
DEFAULT_MATERIAL = "builtin:white-diffuse"  # what the simulated camera sees through --write-rig's rig file


def add_arguments(parser) -> None:
    from goniofrost.app.arg_types import seed

    parser.add_argument("--rig", required=True, metavar="RIG.yaml", help="rig file (its devices are simulated)")
    parser.add_argument("--speedup", type=float, default=None,
                        help="simulated seconds per real second (default: the rig's sim.clock_speedup)")
    parser.add_argument("--seed", type=seed, default=None, help="seed of the simulation (default: the rig's sim.seed)")
    parser.add_argument("--write-rig", metavar="OUT.yaml", default=None,
                        help="also write a rig file (simulated: false) whose drivers and camera are the running "
                             "twins, to rehearse a capture or the console exactly as on a real rig; removed when "
                             "the twins stop (Ctrl-C or SIGTERM), as its endpoints stop with them")
    parser.add_argument("--material", default=None,
                        help=f"what the simulated camera sees with --write-rig when a capture names none "
                             f"(default {DEFAULT_MATERIAL}; capture --material picks another per run)")


def run(args) -> int:
    import json
    import sys
    from contextlib import ExitStack

    from goniofrost.core.errors import ConfigError
    from goniofrost.rig.file import load_checked_rig
    from goniofrost.rig.simulated import twins

    if args.speedup is not None and not args.speedup > 0:
        raise ConfigError("command line", "--speedup", "a number > 0", args.speedup)
    rig = load_checked_rig(args.rig)
    seed = args.seed if args.seed is not None else int((rig.sim or {}).get("seed", 0))
    if args.material is not None and args.write_rig is None:  # it would change nothing, silently
        raise ConfigError("command line", "--material", "--write-rig OUT.yaml as well (the material is what the "
                          "simulated camera of that rig file sees)", args.material)
    if args.write_rig is not None:
        from goniofrost.core.atomic_file import check_not_an_input, check_output_file, check_output_suffix
        from goniofrost.datasets import shown_material
        # a rig file is YAML: --write-rig x.json held YAML under a name that says JSON
        check_output_suffix(args.write_rig, (".yaml", ".yml"), "a rig file is written as YAML", "--write-rig")
        check_not_an_input(args.write_rig, {"--rig": args.rig}, "--write-rig")  # it replaced the rig file
        check_output_file(args.write_rig)
        material = shown_material(args.material or DEFAULT_MATERIAL, None)  # a bad name fails before anything starts
    with _stop_signals() as wait_for_stop, ExitStack() as stack:
        simulation = stack.enter_context(twins(rig, speedup=args.speedup, seed=seed))
        if args.write_rig is not None:
            stack.enter_context(_served_rig_file(rig, simulation, material, seed, args.write_rig))
        print(json.dumps(simulation.endpoints), flush=True)
        print(f"goniofrost sim: serving the {len(rig.axes)} axes (and lamp) of {rig.name} "
              f"(speed-up {simulation.clock.speedup:g}); stop with Ctrl-C", file=sys.stderr, flush=True)
        wait_for_stop()
    return 0


@contextmanager
def _stop_signals():
    """A context yielding ``wait()``, which returns once SIGINT or SIGTERM has come (at once if one
    came after entering: during start-up the devices are started, then stopped).

    The signals' C-level handler writes their number to a pipe (``signal.set_wakeup_fd``) that
    ``wait()`` reads: no polling (a wait of 0.2 s at a time kept the stop waiting up to that long),
    and no lock taken in a Python signal handler (``Event.set()`` there deadlocks when the signal
    interrupts the same thread inside ``Event.wait()``, which holds that lock). A second signal
    while the devices stop is absorbed, so the stop is never cut short.
    """
    import os
    import signal

    wanted = (signal.SIGINT, signal.SIGTERM)
    read_fd, write_fd = os.pipe()
    os.set_blocking(write_fd, False)  # set_wakeup_fd's requirement
    previous = {sig: signal.signal(sig, lambda *_: None) for sig in wanted}
    before = signal.set_wakeup_fd(write_fd, warn_on_full_buffer=False)

    def wait() -> None:
        while os.read(read_fd, 1)[0] not in wanted:  # any other signal with a handler writes too
            pass

    try:
        yield wait
    finally:
        signal.set_wakeup_fd(before)
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        os.close(read_fd)
        os.close(write_fd)


@contextmanager
def _served_rig_file(rig, simulation, material, seed: int, out_path):
    """Start the simulated camera's service and write the rig file; stop the service on exit."""
    import os
    from pathlib import Path

    import yaml

    from goniofrost.core.atomic_file import write_text_atomic
    from goniofrost.rig.simulated import simulated_camera
    from sim.camera_service import CameraService
    from sim.rig_file import real_rig_document

    camera = simulated_camera(rig, simulation, material, seed)
    camera.connect()
    out = Path(out_path).resolve()  # the rig file names its frames folder absolutely: usable from anywhere
    from goniofrost.datasets import material_brdf

    service = CameraService(camera, out.with_name(out.name + ".frames"), materials=material_brdf)
    service.start()
    written = None
    try:
        document = real_rig_document(rig.source, simulation.resolved_rig(), service, simulation.clock.speedup)
        write_text_atomic(out, f"# written by goniofrost sim --write-rig (process {os.getpid()}) from "
                               f"{rig.source}: the running simulation's twins, as a real rig; removed when they "
                               f"stop\n" + yaml.safe_dump(document, sort_keys=False))
        written = _identity(out)
        yield out
    finally:
        if written is not None:  # first, so that no new client reads endpoints about to go
            _withdraw_rig_file(out, written, service.folder)
        service.stop()
        camera.close()


def _identity(path) -> tuple[int, int]:
    """(device, inode) of ``path``: an atomic write of the same name (a rename over it) changes it."""
    st = path.stat()
    return st.st_dev, st.st_ino


def _withdraw_rig_file(out, written, frames) -> None:
    """Remove the rig file ``out`` if it is still the one written (identity ``written``), and the
    frames folder ``frames`` if empty; say what was done on stderr (one line)."""
    import sys

    try:
        mine = _identity(out) == written
    except FileNotFoundError:  # removed by hand: nothing points at the twins any more
        return
    if mine:
        out.unlink(missing_ok=True)
        said = f"removed {out}: its twins have stopped, so its endpoints are gone"
    else:
        said = f"left {out}: it is not the file this sim wrote (replaced since)"
    try:
        frames.rmdir()
    except OSError:  # frames taken (kept: they are the operator's), or already gone
        if frames.is_dir():
            said += f"; the frames in {frames} are kept"
    print(f"goniofrost sim: {said}", file=sys.stderr, flush=True)
