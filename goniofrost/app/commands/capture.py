"""``goniofrost capture``: run (or resume) a capture session of a plan on a rig."""
from __future__ import annotations

HELP = "capture a plan's samples on a rig (journaled, resumable), then reconstruct and report"
BSDF_FILE = "brdf.bsdf"  # --bsdf: what export_beside names the session's brdf.binary's export (checked first)


def add_arguments(parser) -> None:
    from goniofrost.app.arg_types import seed

    from goniofrost.app.monitoring import add_server_options

    parser.add_argument("--rig", required=True, metavar="RIG.yaml", help="rig file (simulated: true starts its own devices)")
    parser.add_argument("--plan", required=True, metavar="PLAN.json", help="plan from goniofrost plan --rig")
    parser.add_argument("--session", metavar="DIR", help="session folder (journal, RAW files, results); "
                        "required unless --dry-run")
    parser.add_argument("--material", metavar="SPEC:NAME",
                        help="simulated rig: the ground-truth material the simulated camera sees (e.g. builtin:NAME)")
    parser.add_argument("--alignment", metavar="ALIGNMENT.json",
                        help="the axes' zero offsets from goniofrost align (overrides the rig file's alignment key); "
                             "must be the one the plan was scheduled with")
    parser.add_argument("--resume", action="store_true", help="continue the session journaled in DIR")
    parser.add_argument("--operator", metavar="NAME", help="who measures (kept in the journal, report.json, brdf.json)")
    parser.add_argument("--sample-id", metavar="ID", help="the sample on the stage (a resume must name the same)")
    parser.add_argument("--note", action="append", default=[], metavar="TEXT",
                        help="a note on the session (repeatable; a resume may add notes)")
    parser.add_argument("--target-error", type=float, metavar="E",
                        help="measure a Bayesian plan batch by batch in design order and stop as soon as this "
                             "material's log-relative MSE is at most E (e.g. 0.05) with the --confidence, from an "
                             "upper bound calibrated on held-out training materials; or when the plan is used up. "
                             "Samples unlike every training material, or a design unlike every design the "
                             "calibration was fitted on, never stop it (an extrapolation)")
    parser.add_argument("--confidence", type=float, default=None, metavar="P",
                        help="with --target-error: the probability that the error is at most E when the capture "
                             "stops (default 0.95)")
    parser.add_argument("--seed", type=seed, default=None, help="simulated rig: noise seed (default: the rig's sim.seed)")
    parser.add_argument("--speedup", type=float, default=None,
                        help="simulated rig: clock speed-up (default: the rig's sim.clock_speedup)")
    parser.add_argument("--bsdf", action="store_true",
                        help="also write brdf.bsdf beside brdf.binary: the RGL tensor file Mitsuba 3's 'measured' "
                             "BSDF renders (as goniofrost export; about a second and 14 MB at full resolution)")
    from goniofrost.brdf.formats import FORMATS

    parser.add_argument("--bsdf-format", choices=tuple(FORMATS), default=None,
                        help="the format of brdf.bsdf (implies --bsdf): mitsuba (RGB, the default) or rgl-spectral / "
                             "pbrt (spectral, for pbrt-v4 and Mitsuba 3's spectral variants; about 100 MB)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--dry-run", action="store_true",
                        help="only the plan's motion on the rig (home, every pose in capture order, home), without "
                             "camera or lamp: each move's planned against measured time, and where they differ; "
                             "writes nothing")
    add_server_options(parser, with_flag=True)


def run(args) -> int:
    import sys
    from contextlib import nullcontext

    if args.dry_run:
        from goniofrost.app.rig_console import run_dry_run
        from goniofrost.core.errors import ConfigError

        given = [flag for flag, value in (
            ("--session", args.session), ("--material", args.material), ("--resume", args.resume),
            ("--operator", args.operator), ("--sample-id", args.sample_id), ("--note", args.note),
            ("--target-error", args.target_error), ("--confidence", args.confidence), ("--seed", args.seed),
            ("--bsdf", args.bsdf), ("--bsdf-format", args.bsdf_format), ("--monitor", args.monitor))
            if value is not None and value is not False and value != []]
        if given:  # a dry run moves the axes only and writes nothing: these would change nothing, silently
            raise ConfigError("command line", "--dry-run", "only --rig, --plan, --alignment, --speedup and "
                              "--no-progress (a dry run moves the axes and writes nothing)", " ".join(given))
        from goniofrost.capture.signals import SessionInterrupted

        try:
            return run_dry_run(args)
        except SessionInterrupted as exc:
            print(f"goniofrost capture: {exc}", file=sys.stderr)
            return 130
    from goniofrost.core.errors import ConfigError

    if args.session is None:
        raise ConfigError("command line", "--session", "a session folder (DIR)", "nothing")
    if args.confidence is not None and args.target_error is None:  # it would change nothing, silently
        raise ConfigError("command line", "--confidence", "--target-error E as well (the confidence is that of the "
                          "bound that stops the capture at E)", args.confidence)

    from goniofrost.app.monitoring import monitored
    from goniofrost.capture.runner import capture
    from goniofrost.app.ground_truth import GroundTruth
    from goniofrost.capture.options import DEFAULT_CONFIDENCE, SessionOptions, StopRule
    from goniofrost.capture.engine import SessionInterrupted

    from goniofrost.capture.inputs import load_inputs
    from goniofrost.capture.lab import session_label
    from goniofrost.capture.runner import check_material
    from goniofrost.rig.hardware import SimOptions
    from goniofrost.rig.simulated import rig_devices

    inputs = load_inputs(args.rig, args.plan, args.alignment)
    bsdf = bool(args.bsdf or args.bsdf_format)
    label = session_label(inputs.rig, args.operator, args.sample_id, args.note)
    material = check_material(inputs.rig, args.material)  # none on a real rig, one on a simulated rig
    if material is not None:
        from goniofrost.datasets import shown_material
        material = shown_material(material)
    confidence = DEFAULT_CONFIDENCE if args.confidence is None else args.confidence
    watch = monitored(args.session, args.host, args.port, "capture") if args.monitor else nullcontext()
    try:
        with watch:
            outcome = capture(inputs, args.session, devices=rig_devices,
                              sim=SimOptions(material=material, seed=args.seed, speedup=args.speedup),
                              stop=StopRule(args.target_error, confidence),
                              options=SessionOptions(resume=args.resume, progress=not args.no_progress, label=label,
                                                     extra_files=(BSDF_FILE,) if bsdf else (),
                                                     compare=None if material is None else GroundTruth(material)))
    except SessionInterrupted as exc:  # the engine's message says how the axes and the lamp took it
        text = str(exc) if str(exc).startswith("interrupted") else f"interrupted ({exc})"
        print(f"goniofrost capture: {text}", file=sys.stderr)
        return 130
    except KeyboardInterrupt:  # outside the engine: connecting, or writing the results
        print(f"goniofrost capture: interrupted; the journal in {args.session} keeps every captured sample: "
              f"run the same command with --resume", file=sys.stderr)
        return 130
    print(outcome.summary, end="")
    if bsdf:
        from goniofrost.brdf.formats import FORMATS, export_beside

        fmt = args.bsdf_format or "mitsuba"
        written = export_beside(outcome.session_dir / outcome.report['outputs']['brdf'], fmt)
        print(f"wrote {written} ({FORMATS[fmt].reader})")
    return 0
