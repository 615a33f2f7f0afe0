"""What each ``goniofrost rig`` sub-command does and prints (the computations live in goniofrost.capture)."""
from __future__ import annotations

import json
import math
import sys
import time

from goniofrost.core.errors import GoniofrostError


class RigProblems(GoniofrostError):
    """``rig check`` found something wrong (the table was printed; exit 2)."""


def _load(args):
    from goniofrost.rig.file import load_checked_rig

    return load_checked_rig(args.rig, args.alignment)


def _connected(rig, **options):
    """``connected_rig`` on the rig's devices: a simulated rig file's twins are started for the
    command (``goniofrost.rig.simulated.device_sections``)."""
    from goniofrost.capture.console import connected_rig
    from goniofrost.rig.simulated import device_sections

    return connected_rig(rig, sections=device_sections, **options)


def _server(rig):
    """The client of a ``goniofrost serve`` holding ``rig`` (the command then asks it instead of
    opening the devices), or None."""
    from goniofrost.server.client import server_for

    return server_for(rig)


def _reached(joints) -> str:
    return ", ".join(f"{n} {float(d):.3f} deg" for n, d in joints.items())


def _say(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


# ----- check -----------------------------------------------------------------------------------
def run_check(args) -> int:
    from goniofrost.rig.check import RigCheckError, rig_file_problems

    problems = rig_file_problems(args.rig, args.alignment)
    if problems:
        if args.json:
            print(json.dumps({"rig": args.rig, "problems": [p.message for p in problems], "devices": []}, indent=1))
        raise RigCheckError(problems, args.rig)
    rig = _load(args)
    reports = [] if args.offline else _probe(rig)
    if args.json:
        print(json.dumps({"rig": args.rig, "problems": [], "devices": [r.as_dict() for r in reports]}, indent=1))
    else:
        print(f"{args.rig}: the rig file is sound ({len(rig.axes)} axes"
              f"{', a lamp' if rig.lamp.get('driver') else ''}, camera {rig.camera.get('kind', 'none')})")
        if reports:
            print(device_table(reports))
    silent = [r for r in reports if not r.answers or r.error or r.alarm]
    if silent:
        raise RigProblems(f"{len(silent)} of {len(reports)} devices did not answer cleanly: "
                          + ", ".join(r.device for r in silent))
    return 0


def _probe(rig):
    from drivers.rig_devices import RigDevices
    from goniofrost.rig.check import probe_camera, probe_rig
    from goniofrost.rig.simulated import connected_camera, device_sections

    with device_sections(rig) as (resolved, simulation):
        devices = RigDevices.from_rig(resolved)
        reports = probe_rig(rig, devices.axes, devices.lamp, {n: a.driver for n, a in resolved.axes.items()})
        if rig.camera:
            reports.append(probe_camera(rig, lambda: connected_camera(rig, simulation)))
        return reports


def device_table(reports) -> str:
    """The probe's findings as a fixed-width table, causes under each silent device."""
    head = ("device", "link", "answers", "identity", "position", "limits", "state")
    rows = [head]
    for r in reports:
        state = ("lamp on" if r.lamp_on else "lamp off") if r.device == "lamp" and r.answers else (
            "-" if not r.answers else (f"ALARM {r.alarm}" if r.alarm else ("enabled" if r.enabled else "disabled")))
        limits = "-" if r.limits_deg is None else f"[{r.limits_deg[0]:g}, {r.limits_deg[1]:g}]"
        if r.device == "camera":  # its limits are the exposure range, its state the frame grabbed
            limits = "-" if r.exposure_range_s is None else f"[{r.exposure_range_s[0]:g}, {r.exposure_range_s[1]:g}] s"
            state = _frame_text(r.frame) if r.frame else "-"
        rows.append((r.device, r.link, "yes" if r.answers else "NO", r.identity or "-",
                     "-" if r.position_deg is None else f"{r.position_deg:.3f} deg", limits, state))
    widths = [max(len(str(row[i])) for row in rows) for i in range(len(head))]
    lines = []
    for k, row in enumerate(rows):
        lines.append("  ".join(str(v).ljust(w) for v, w in zip(row, widths)).rstrip())
        report = reports[k - 1] if k else None
        if report is not None and (report.error or report.causes):
            if report.error:
                lines.append(f"    error: {report.error}")
            lines += [f"    likely cause: {c}" for c in report.causes]
    return "\n".join(lines)


def _frame_text(frame: dict) -> str:
    """'frame 0.002 s: median R 0.0102 G 0.0201 B 0.0150, 0 % saturated' (or why none was taken)."""
    if "skipped" in frame:
        return f"no frame: {frame['skipped']}"
    median = " ".join(f"{c} {v:.4f}" for c, v in zip("RGB", frame["median"]))
    return f"frame {frame['exposure_s']:g} s: median {median}, {100 * frame['saturated_fraction']:.2g} % saturated"


# ----- status ----------------------------------------------------------------------------------
def run_status(args) -> int:
    from goniofrost.capture.console import read_status

    interval = _watch_interval(args)
    rig = _load(args)  # the options first: a bad one connects nothing
    server = _server(rig)
    if server is not None:
        return _served_status(args, rig, server, interval)
    in_place = args.watch and not args.json and sys.stdout.isatty()  # a log or a pipe keeps every reading
    with _connected(rig, enable=False, program="rig status") as hardware:
        n, shown = 0, 0
        while True:
            readings, lamp = read_status(rig, hardware)
            text = _status_text(readings, lamp, args.json, stamp=_utc_now() if args.watch else None)
            # on a terminal the cursor goes back up over the last reading: one table, redrawn
            print((f"\x1b[{shown}F\x1b[J" if in_place and shown else "") + text, flush=True)
            n, shown = n + 1, text.count("\n") + 1
            if not args.watch or (args.count is not None and n >= args.count):
                return 0
            time.sleep(max(interval, 0.05))  # the operator's refresh rate, not a synchronisation


def _served_status(args, rig, server, interval: float) -> int:
    """``rig status`` of a rig a server holds: what the server last read (its ``/api/status``)."""
    offsets = rig.alignment.offsets_deg if rig.alignment is not None else {}
    n = 0
    while True:
        status = server.call("GET", "/api/status")
        axes = [{"axis": name, "position_deg": deg, "aligned_deg": None if deg is None else deg + offsets.get(name, 0.0),
                 "limits_deg": list(rig.axes[name].limits_deg)} for name, deg in status["pose"].items()]
        said = {k: status[k] for k in ("state", "reason", "current")}
        if args.json:
            print(json.dumps({"server": {"url": server.url, **said}, "axes": axes, "lamp": status["lamp"]}), flush=True)
        else:
            print(_served_text(server, status, axes), flush=True)
        n += 1
        if not args.watch or (args.count is not None and n >= args.count):
            return 0
        time.sleep(max(interval, 0.05))  # the operator's refresh rate, not a synchronisation


def _served_text(server, status: dict, axes: list) -> str:
    state = status["state"] + (f" ({status['reason']})" if status["reason"] else "")
    lines = [f"{status['rig']} is held by {server.holder.who()} at {server.url}: {state}; as it last read them:"]
    for a in axes:
        where = "not answering" if a["position_deg"] is None else \
            f"{a['position_deg']:10.3f} deg (aligned {a['aligned_deg']:10.3f})"
        lines.append(f"{a['axis']:<14} {where}  limits [{a['limits_deg'][0]:g}, {a['limits_deg'][1]:g}]")
    lamp = status["lamp"]
    if lamp.get("photodiode") is not None:
        on = {True: "on", False: "off", None: "on or off"}[lamp.get("on")]
        lines.append(f"{'lamp':<14} {on}, photodiode {lamp['photodiode']:.4f} of nominal")
    return "\n".join(lines)


def _utc_now():
    """The time of a reading (UTC, whole seconds)."""
    from datetime import datetime, timezone

    return datetime.now(timezone.utc).replace(microsecond=0)


def _watch_interval(args) -> float:
    """The seconds between ``--watch`` readings (default 1), after checking ``--interval`` and
    ``--count``: ``--interval nan`` read once and then ended in time.sleep's ValueError traceback,
    ``--count 0`` still read once, and either without ``--watch`` changed nothing, silently."""
    if not args.watch and (args.interval is not None or args.count is not None):
        raise GoniofrostError("--interval and --count apply to --watch only")
    if args.interval is not None and not (math.isfinite(args.interval) and args.interval > 0):
        raise GoniofrostError(f"--interval: expected a positive number of seconds, found {args.interval:g}")
    if args.count is not None and args.count < 1:
        raise GoniofrostError(f"--count: expected a number of readings >= 1, found {args.count}")
    return 1.0 if args.interval is None else args.interval


def _status_text(readings, lamp, as_json: bool, stamp=None) -> str:
    """The readings as a table (or one JSON line), headed by ``stamp`` (a UTC datetime) when given."""
    if as_json:
        doc = {"axes": [r.as_dict() for r in readings], "lamp": lamp}
        if stamp is not None:
            doc = {"time_utc": stamp.strftime("%Y-%m-%dT%H:%M:%SZ"), **doc}
        return json.dumps(doc)
    lines = [] if stamp is None else [f"reading at {stamp:%Y-%m-%d %H:%M:%S} UTC"]
    limits = [f"[{r.limits_deg[0]:g}, {r.limits_deg[1]:g}]" for r in readings]
    width = max(map(len, limits), default=0)  # the state column lines up under every axis's
    for r, span in zip(readings, limits):
        state = f"ALARM {r.alarm}" if r.alarm else ("moving" if r.moving else "at rest")
        lines.append(f"{r.axis:<14} {r.position_deg:10.3f} deg (aligned {r.aligned_deg:10.3f})  "
                     f"limits {span:<{width}}  {state}, {'enabled' if r.enabled else 'disabled'}")
    if lamp is not None:
        lines.append(f"{'lamp':<14} {'on' if lamp['on'] else 'off'}, photodiode {lamp['photodiode']:.4f} of nominal")
    return "\n".join(lines)


# ----- move, home, lamp ----------------------------------------------------------------------------
def run_move(args) -> int:
    from goniofrost.capture.console import (check_referenced, check_targets, move_plan, parse_targets,
                                            run_plan)

    rig = _load(args)
    requested = parse_targets(args.targets, rig)
    if not args.by:
        check_targets(rig, requested)  # before anything is connected: a refused move sends no byte
    server = _server(rig)
    if server is not None:
        targets = requested
        if args.by:
            pose = server.call("GET", "/api/status")["pose"]
            targets = {name: pose[name] + by for name, by in requested.items()}
            check_targets(rig, targets)
        _say(f"asking the server at {server.url} to move " + _reached(targets))
        reached = server.call("POST", "/api/move", {"targets": targets, "operator": server.who()})["reached"]
        _say("reached " + _reached(reached))
        return 0
    with _connected(rig, enable=True, program="rig move") as hardware:
        check_referenced(rig, hardware.axes, requested)
        targets = requested
        if args.by:
            targets = {name: hardware.axes[name].position() + by for name, by in requested.items()}
            check_targets(rig, targets)
        for name, deg in targets.items():  # the driver sends nothing to an axis within its tolerance
            axis = hardware.axes[name]
            here = axis.position()
            _say(f"{name} already at {here:.3f} deg" if abs(here - deg) <= axis.config.tolerance_deg
                 else f"moving {name} to {deg:.3f} deg")
        reached = run_plan(hardware, move_plan(rig, targets), "rig move")
    _say("reached " + ", ".join(f"{n} {d:.3f} deg" for n, d in reached.joints.items()))
    return 0


def run_home(args) -> int:
    from goniofrost.capture.console import ConsoleError, home_plan, run_plan

    rig = _load(args)
    axes = args.axes or list(rig.joint_names)
    unknown = [a for a in axes if a not in rig.axes]
    if unknown:
        raise ConsoleError(f"no axis {unknown[0]!r} in {rig.source} (axes: {', '.join(rig.axes)})")
    twice = next((a for k, a in enumerate(axes) if a in axes[:k]), None)
    if twice is not None:  # as rig move refuses it; home read "homing sample_tilt, sample_tilt"
        raise ConsoleError(f"{twice!r}: axis {twice} is given twice")
    if not args.yes and not _confirm(f"home {', '.join(axes)}: is the rig clear (nothing in the arms' or stage's way)? [y/N] "):
        raise ConsoleError("not homed: the rig was not confirmed clear (answer y, or pass --yes)")
    server = _server(rig)
    if server is not None:
        _say(f"asking the server at {server.url} to home {', '.join(axes)}")
        reached = server.call("POST", "/api/home", {"axes": axes, "operator": server.who()})["reached"]
        _say("homed " + ", ".join(f"{n} at {float(d):.3f} deg" for n, d in reached.items()))
        return 0
    with _connected(rig, enable=True, program="rig home") as hardware:
        _say(f"homing {', '.join(axes)}")
        reached = run_plan(hardware, home_plan(axes), "rig home")
    _say("homed " + ", ".join(f"{n} at {d:.3f} deg" for n, d in reached.joints.items()))
    return 0


def _confirm(question: str) -> bool:
    if not sys.stdin or not sys.stdin.isatty():
        line = sys.stdin.readline() if sys.stdin else ""
    else:
        line = input(question)
    return line.strip().lower() in ("y", "yes")


def run_lamp(args) -> int:
    from goniofrost.capture.console import ConsoleError, lamp_plan, run_plan

    rig = _load(args)
    if not rig.lamp.get("driver"):
        raise ConsoleError(f"{rig.source}: this rig has no lamp driver (lamp.driver)")
    on = args.state == "on"
    server = _server(rig)
    if server is not None:
        reading = server.call("POST", "/api/lamp", {"on": on, "operator": server.who()})["photodiode"]
    else:
        with _connected(rig, enable=False, program="rig lamp") as hardware:
            reading = run_plan(hardware, lamp_plan(on), "rig lamp")
    _say(f"lamp on, photodiode {reading:.4f} of nominal" if on else "lamp off")
    return 0


# ----- stop -------------------------------------------------------------------------------------
def run_stop(args) -> int:
    from goniofrost.capture.executor import StepExecutor
    from goniofrost.rig.stop import stop_text

    from goniofrost.rig.lock import request_stop

    rig = _load(args)
    server = _server(rig)
    if server is not None:  # a server is stopped through its API: it goes on serving, its queue held
        state = server.call("POST", "/api/stop", {"operator": server.who()})["state"]
        _say(f"asked {server.holder.who()} at {server.url} to stop {rig.name}: it is {state}; its queue waits "
             f"for POST /api/resume")
        return 0
    holder = request_stop(rig)
    if holder is not None:
        _say(f"asked {holder.who()} to stop {rig.name}: it stops and confirms every axis and "
             f"switches the lamp off; its own report follows in its terminal and journal")
        if rig.simulated:  # the devices of a simulated rig file end with their holder
            return 0
        _wait_for_release(rig, holder)
    # no holder, or one that let go: confirm it here (a holder killed by the SIGTERM left the lamp on)
    with _connected(rig, enable=False, program="rig stop") as hardware:
        executor = StepExecutor(hardware, ".")
        stops = executor.stop()
        lamp_error = executor.switch_lamp_off() if hardware.lamp is not None else None
    _say(stop_text(stops) + ("; lamp off" if hardware.lamp is not None and lamp_error is None
                             else f"; lamp NOT confirmed off: {lamp_error}" if lamp_error else ""))
    return 0 if all(s.confirmed for s in stops) and lamp_error is None else 2


RELEASE_S = 30.0   # how long rig stop waits for the holder to let go of the rig (s)


def _wait_for_release(rig, holder) -> None:
    """Return once no program holds ``rig``'s devices; ConsoleError naming the holder after RELEASE_S."""
    from goniofrost.capture.console import ConsoleError
    from goniofrost.rig.lock import rig_holder

    t_end = time.monotonic() + RELEASE_S
    while rig_holder(rig) is not None:
        if time.monotonic() > t_end:
            raise ConsoleError(f"{holder.who()} still holds {rig.name} {RELEASE_S:g} s after the stop request: it "
                               "may hang; end it (kill PID), then run goniofrost rig stop again")
        time.sleep(0.05)  # polls the lock's holder, a state: no synchronisation


# ----- snap -------------------------------------------------------------------------------------
def run_snap(args) -> int:
    from goniofrost.capture.console import check_targets, parse_targets
    from goniofrost.app.png_out import check_png_name
    from goniofrost.capture.runner import check_material
    from goniofrost.capture.snap import DEFAULT_MATERIAL, snap, snap_text
    from goniofrost.rig.simulated import rig_devices

    check_png_name(args.out)
    if args.exposure is not None and not (math.isfinite(args.exposure) and args.exposure > 0):
        raise GoniofrostError(f"--exposure: expected a positive number of seconds, found {args.exposure:g}")
    rig = _load(args)  # the options first: a bad one connects nothing
    move_to = parse_targets(args.move, rig) if args.move else None
    if move_to:
        check_targets(rig, move_to)
    server = _server(rig)
    if server is not None:
        return _served_snap(args, server, move_to)
    # as capture: none on a real rig (it shows what is on the stage), a known one on a simulated
    # rig, checked before anything is made or moved
    material = check_material(rig, args.material if args.material is not None or not rig.simulated else DEFAULT_MATERIAL)
    if material is not None:
        from goniofrost.datasets import shown_material
        material = shown_material(material)
    result = snap(rig, target=args.target, exposure_s=args.exposure, out=args.out, material=material,
                  move_to=move_to, devices=rig_devices)  # open_hardware takes the rig lock
    print(json.dumps(result.as_dict(), indent=1) if args.json else snap_text(result))
    # as rig check: a check that found a problem (a capture could not measure here) exits 2, so
    # `rig snap ... && goniofrost capture ...` does not go on past it
    return 2 if result.problem else 0


def _served_snap(args, server, move_to) -> int:
    """``rig snap`` of a rig a server holds: it moves (``--move``) and snaps; the PNG it writes under
    its root is copied to ``--out``."""
    import dataclasses
    import shutil
    from pathlib import Path

    from goniofrost.capture.snap import SnapResult, snap_text
    from goniofrost.server.entries import NAME

    if args.material is not None:
        raise GoniofrostError(f"--material: the server at {server.url} shows its own material; leave --material out "
                              f"(or stop the server)")
    if move_to:
        server.call("POST", "/api/move", {"targets": move_to, "operator": server.who()})
    out = Path(args.out)
    name = out.name if NAME.match(out.name) else "snap.png"   # a name the server takes, else its own
    body = {"name": name, "target": args.target, "exposure_s": args.exposure, "operator": server.who()}
    found = server.call("POST", "/api/snap", body)
    shutil.copyfile(server.root / found.pop("file"), out)
    result = SnapResult(**{f.name: found[f.name] for f in dataclasses.fields(SnapResult)})
    result.png = str(out)
    print(json.dumps(result.as_dict(), indent=1) if args.json else snap_text(result))
    return 2 if result.problem else 0


# ----- capture --dry-run -----------------------------------------------------------------------------
def run_dry_run(args) -> int:
    """``capture --dry-run``: the plan's moves timed on the rig, against the plan's times."""
    from goniofrost.capture.console import dry_run, twins_speedup
    from goniofrost.capture.inputs import check_alignment, check_joints, check_rig
    from goniofrost.plan.file import read_plan
    from goniofrost.capture.runner import check_sim_options

    rig = _load(args)
    check_sim_options(rig, None, args.speedup)  # as a capture's: a speed-up > 0, and only on a simulated rig
    plan = read_plan(args.plan)
    for check in (check_rig, check_alignment, check_joints):  # before anything is connected
        check(plan, args.plan, rig)
    n, done = len(plan["samples"]), []

    def progress(move):
        if move.index is not None and move.planned_s is not None:
            done.append(move)
            if not args.no_progress:
                _say(f"move {len(done)}/{n} (sample {move.index}): planned {move.planned_s:.2f} s, "
                     f"measured {move.measured_s:.2f} s{'  DIFFERS' if move.differs else ''}")

    with _connected(rig, enable=True, program="capture --dry-run", speedup=args.speedup) as hardware:
        timed = dry_run(rig, plan, hardware, on_move=progress)
    print(dry_run_text(timed[1:], twins_speedup(rig)))
    return 0


def dry_run_text(timed, speedup: float = 1.0) -> str:
    """The planned and measured times in total, and every move where they differ; ``speedup``
    other than 1: the times are on the twins' clock, which runs that much faster (said so)."""
    planned = sum(m.planned_s for m in timed)
    measured = sum(m.measured_s for m in timed)
    differ = [m for m in timed if m.differs]
    allowance = f"{timed[0].allowance_s:g} s" if timed else "0.5 s"
    lines = [f"{len(timed) - 1} moves and the return home: planned {planned:.1f} s, measured {measured:.1f} s "
             f"({100 * (measured / planned - 1) if planned > 0 else 0.0:+.1f} %)"
             + ("" if speedup == 1.0 else f" on the twins' clock (speed-up {speedup:g})")]
    if differ:
        lines.append(f"{len(differ)} moves differ from the plan by more than 20 % and {allowance}:")
        lines += [f"  {'return home' if m.index is None else f'sample {m.index}'}: planned {m.planned_s:.2f} s, "
                  f"measured {m.measured_s:.2f} s" for m in differ]
    else:
        lines.append(f"every move within 20 % or {allowance} of the plan")
    return "\n".join(lines)
