"""``goniofrost demo``: the whole chain on the simulated rig, needing nothing but the package."""
from __future__ import annotations

# plain text: cli.py escapes it for argparse's %-formatting of help lines (the arguments' own help
# below is %-formatted too: a literal percent sign there is written %%)
HELP = ("train on the built-in library, plan up to 40 samples (Bayesian design), capture a held-out material on "
        "the simulated rig until its error is at most 0.005 with 95 % confidence, reconstruct with its uncertainty, "
        "write the MERL file, a preview and a report")


def add_arguments(parser) -> None:
    from goniofrost.app.arg_types import seed

    from goniofrost.app.demo import (DEFAULT_CONFIDENCE, DEFAULT_MATERIAL, DEFAULT_SAMPLES, DEFAULT_SPEEDUP,
                                     DEFAULT_TARGET_ERROR)
    from goniofrost.app.monitoring import add_server_options

    parser.add_argument("--out", default="demo-out", metavar="DIR", help="output folder (default demo-out; "
                        "a previous demo's results there are replaced)")
    parser.add_argument("--material", default=DEFAULT_MATERIAL, metavar="NAME",
                        help=f"built-in material to capture, left out of training (default {DEFAULT_MATERIAL})")
    parser.add_argument("--samples", type=int, default=DEFAULT_SAMPLES, metavar="M",
                        help=f"samples in the plan, the most the capture takes (default {DEFAULT_SAMPLES})")
    parser.add_argument("--target-error", type=float, default=DEFAULT_TARGET_ERROR, metavar="E",
                        help=f"stop once the log-relative MSE is at most E with the --confidence (default "
                             f"{DEFAULT_TARGET_ERROR:g}: an RMS error of about 7 %% in the log of the cosine-weighted "
                             "BRDF; 0 captures the whole plan)")
    parser.add_argument("--confidence", type=float, default=DEFAULT_CONFIDENCE, metavar="P",
                        help=f"with --target-error: how sure the stop must be (default {DEFAULT_CONFIDENCE:g})")
    parser.add_argument("--seed", type=seed, default=0, help="sensor noise seed (default 0)")
    parser.add_argument("--speedup", type=float, default=DEFAULT_SPEEDUP,
                        help=f"simulated clock speed-up (default {DEFAULT_SPEEDUP:g})")
    parser.add_argument("--bsdf", action="store_true",
                        help="also write session/brdf.bsdf, the RGL tensor file Mitsuba 3's 'measured' BSDF renders")
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")
    add_server_options(parser, with_flag=True)


def run(args) -> int:
    import sys
    from contextlib import nullcontext
    from pathlib import Path

    from goniofrost.app.demo import DemoRequest, run_demo
    from goniofrost.capture.options import StopRule
    from goniofrost.app.monitoring import monitored
    from goniofrost.capture.signals import SessionInterrupted
    from goniofrost.core.errors import ConfigError

    if not 0 <= args.target_error < float("inf"):  # -1 or nan would silently capture the whole plan
        raise ConfigError("command line", "--target-error", "a log-relative MSE >= 0 (0 captures the whole plan)",
                          args.target_error)
    # the rest of the options are used minutes later (after training and planning): check them now,
    # so that a bad one writes nothing
    from goniofrost.capture.runner import check_confidence, check_speedup
    from goniofrost.core.atomic_file import check_output_dir
    from goniofrost.frost.bayes_selection import MAX_PICKS

    check_confidence(args.confidence)
    check_speedup(args.speedup)
    if not 1 <= args.samples <= MAX_PICKS:
        raise ConfigError("command line", "--samples", f"an integer in [1, {MAX_PICKS}]", args.samples)
    check_output_dir(args.out)
    session = Path(args.out) / "session"
    try:
        with monitored(session, args.host, args.port, "demo") if args.monitor else nullcontext():
            stop = StopRule(args.target_error if args.target_error > 0 else None, args.confidence)
            request = DemoRequest(material=args.material, samples=args.samples, seed=args.seed,
                                  speedup=args.speedup, bsdf=args.bsdf, stop=stop)
            result = run_demo(args.out, request, progress=not args.no_progress)
    except SessionInterrupted as exc:  # Ctrl-C in the capture: the engine's message says how the axes took it
        print(f"goniofrost demo: {exc}", file=sys.stderr)
        return 130
    report, out = result.report, result.out
    truth, times = report.get("ground_truth", {}), report["times_s"]
    stages = ", ".join(f"{k} {v:.1f} s" for k, v in result.stages_s.items())
    print(f"demo: builtin:{args.material}, m = {report['samples']} of {_planned(report['plan'])} samples on the "
          f"simulated rig")
    target = report.get("target_error")
    if target:
        from goniofrost.app.demo import rms_relative_error

        print(f"  target: log-relative MSE <= {target['target']:g} (an RMS error of about "
              f"{100 * rms_relative_error(target['target']):.0f} % in the log of the cosine-weighted BRDF) with "
              f"{100 * target['confidence']:g} % confidence: {target['stopped']} after {target['samples_used']} "
              f"samples: {target['statement']}")
        print("  bound (median estimate) after each batch: " + ", ".join(
            f"{b['samples']}: {b['bound']:.4g} ({b['predicted_error']:.4g})" if b["bound"] is not None
            else f"{b['samples']}: none ({b['predicted_error']:.4g})" for b in target["batches"]))
    print(f"  motion {times['motion']:.1f} s + capture {times['capture']:.1f} s (simulated rig); "
          f"median sample SNR {report['snr']['median']:.0f}")
    if truth:
        print(f"  log-relative MSE against the ground truth {truth['log_relative_mse']:.4g}, median estimate "
              f"{truth['median_estimate']:.4g} (exact values at the same cells "
              f"{truth['log_relative_mse_exact_samples']:.4g}, ratio {truth['ratio_to_exact']:.3f}); "
              f"rendering SNR {report['demo']['rendering_snr_db']:.2f} dB")
    print(f"  wrote {out / 'session' / 'brdf.binary'} (MERL), {out / 'session' / 'brdf.std.binary'} (its per-cell "
          f"standard deviation), {out / 'preview.png'}, {out / 'report.json'}, "
          f"{out / 'reference.binary'} (ground truth), {out / 'plan.json'}, journal in {out / 'session'}")
    if args.bsdf:
        print(f"  wrote {out / 'session' / 'brdf.bsdf'} (for Mitsuba 3)")
    print(f"  time {sum(result.stages_s.values()):.1f} s ({stages})")
    return 0


def _planned(plan_path) -> str:
    """How many samples the demo's plan holds: "46 planned (40 + 3 sentinels + 3 check cells)",
    "43 planned (40 + 3 sentinels)" or "40 planned"."""
    import json
    from pathlib import Path

    doc = json.loads(Path(plan_path).read_text())
    sentinels, checks = int(doc.get("sentinels", 0)), int(doc.get("checks", 0))
    if not sentinels:
        return f"{doc['m']} planned"
    return f"{doc['m']} planned ({doc['m'] - sentinels - checks} + {sentinels} sentinels" \
        + (f" + {checks} check cells)" if checks else ")")
