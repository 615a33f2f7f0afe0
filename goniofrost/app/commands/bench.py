"""``goniofrost bench``: cross-validated run time against error of FROST and the baselines."""
from __future__ import annotations

import os
import shlex
from pathlib import Path

HELP = ("benchmark the Bayesian pipeline and FROST against Nielsen et al. 2015, random and uniform sampling "
        "(error, uncertainty, time, stress)")
SHARED_DATA = Path(os.environ.get("GONIOFROST_SHARED_DATA",
                                  Path(__file__).resolve().parents[4] / "shared" / "data"))
DEFAULT_DATASETS = [f"nbrdf:{SHARED_DATA / 'nbrdf_merl.npz'}", f"nbrdf:{SHARED_DATA / 'nbrdf_rgl.npz'}"]


def add_arguments(parser) -> None:
    """Options of ``goniofrost bench`` (defaults: the paper's 10 folds of 131 / 20 materials)."""
    from goniofrost.app.arg_types import grid_bins, seed

    parser.add_argument("--out", required=True, type=Path, help="output folder (results.json, results.csv, PNG plots)")
    parser.add_argument("--dataset", action="append", metavar="SPEC",
                        help="dataset spec, repeatable (default: the MERL and RGL networks in ../shared/data)")
    parser.add_argument("--quick", action="store_true",
                        help="reduced run: 2 folds, m in {10, 20, 40}, 2 Nielsen trials (max 10 descent iterations), grid 45,45,90")
    parser.add_argument("--stress", action="store_true",
                        help="run the numerical stress cases instead: every method, on fold 0 (stress.json, stress.md)")
    parser.add_argument("--folds", type=int, help="cross-validation folds (default 10; --quick 2)")
    parser.add_argument("--train", type=int, default=131, help="training materials per fold (default 131)")
    parser.add_argument("--test", type=int, default=20, help="test materials per fold (default 20)")
    parser.add_argument("--m", type=_int_list, metavar="LIST", help="sample counts, e.g. 5,10,20 or 5:60:5 (default 5:60:5; --quick 10,20,40)")
    parser.add_argument("--methods", type=_str_list, metavar="LIST",
                        help="comma-separated subset of bayes,frost-bayesrec,frost,frost-firstm,nielsen,random,uniform "
                             "(default all; bayes = Bayesian design and reconstruction, frost-bayesrec = FROST "
                             "first-m cells with the Bayesian reconstruction)")
    parser.add_argument("--target-error", type=_float_list, metavar="LIST",
                        help="targets E of the simulated capture --target-error, with bayes (default 0.05)")
    parser.add_argument("--nielsen-trials", type=int, help="Nielsen runs per fold (default 5; --quick 2)")
    parser.add_argument("--nielsen-subset", type=int, default=500, help="random candidates per greedy addition (default 500)")
    parser.add_argument("--nielsen-max-iter", type=int,
                        help="cap on descent iterations after each addition (default 100; --quick 10)")
    parser.add_argument("--random-trials", type=int, default=1, help="random selections per fold and m (default 1)")
    parser.add_argument("--eta", type=float, default=40.0, help="ridge parameter of the reconstruction (default 40)")
    parser.add_argument("--seed", type=seed, default=0, help="the one seed of the run (default 0)")
    parser.add_argument("--grid", type=grid_bins, default=None, metavar="NTH,NTD,NPD",
                        help="grid resolution (default 90,90,180, the MERL grid; --quick 45,45,90)")
    parser.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1),
                        help="local worker processes, one fold each (default: 2 or the core count if lower)")
    parser.add_argument("--dask", metavar="ADDRESS", help="run the folds on an existing dask.distributed scheduler")
    parser.add_argument("--stress-m", type=int, default=20, help="sample count of the stress cases (default 20)")
    parser.add_argument("--resume", action="store_true",
                        help="reuse the folds already checkpointed in OUT/folds by a run with the same options")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args) -> int:
    """Run the benchmark (or the stress cases) and write the results into ``--out``."""
    from goniofrost.bench.runner import run_benchmark, run_stress
    from goniofrost.core.atomic_file import check_output_dir

    from goniofrost.core.errors import ConfigError

    config = build_config(args)
    for option, value in (("--jobs", args.jobs), ("--stress-m", args.stress_m)):
        if value < 1:  # --jobs 0 ran with one worker silently; --stress-m 0 failed after the tabulation
            raise ConfigError("command line", option, "a positive integer", value)
    given = [option for option, value in (("--dask", args.dask), ("--resume", args.resume)) if value]
    if args.stress and given:  # the stress cases run here, in one pass: these would change nothing, silently
        raise ConfigError("command line", "--stress", "no --dask or --resume (the stress cases run in this "
                          "process, in one pass)", " ".join(given))
    _refuse_ignored(args)
    check_output_dir(args.out)   # a bad --out fails now, not after an hour of folds
    if args.dask:   # an unreachable scheduler too, not after the tabulation
        from goniofrost.bench.executors import check_dask_address
        check_dask_address(args.dask)
    if args.stress:
        paths = run_stress(config, args.out, command(config, args), m=args.stress_m, progress=not args.no_progress)
    else:
        paths = run_benchmark(config, args.out, command(config, args), jobs=args.jobs,
                              dask_address=args.dask, progress=not args.no_progress, resume=args.resume)
    for path in paths:
        print(path)
    return 0


def _refuse_ignored(args) -> None:
    """Raise ConfigError for options given that the run would ignore: --stress runs every method
    (STRESS_METHODS) on fold 0 with no simulated capture, and the simulated capture's targets are
    of the bayes method (bench --stress --methods frost listed six methods in stress.md; --methods
    frost --target-error 0.02 wrote no target row, both without a word)."""
    from goniofrost.core.errors import ConfigError

    if args.stress:
        given = [option for option, value in (("--methods", args.methods), ("--folds", args.folds),
                                              ("--target-error", args.target_error),
                                              ("--nielsen-trials", args.nielsen_trials)) if value is not None]
        if given:
            raise ConfigError("command line", "--stress", "no --methods, --folds, --target-error or --nielsen-trials "
                              "(the stress cases run every method once, on fold 0, without a simulated capture)",
                              " ".join(given))
    elif args.target_error is not None and args.methods is not None and "bayes" not in args.methods:
        raise ConfigError("command line", "--target-error", "--methods with bayes (the simulated capture "
                          "--target-error runs the Bayesian design)", ",".join(args.methods))


def build_config(args):
    """The BenchConfig of the parsed options (``--quick`` supplies defaults, options override)."""
    from goniofrost.bench.config import METHODS, BenchConfig
    from goniofrost.core.grid import MerlGrid

    fields = dict(n_train=args.train, n_test=args.test, nielsen_subset=args.nielsen_subset,
                  random_trials=args.random_trials,
                  eta=args.eta, seed=args.seed, methods=tuple(args.methods or METHODS))
    if args.grid:
        fields["grid"] = MerlGrid(*args.grid)
    if args.target_error is not None:
        fields["target_errors"] = tuple(args.target_error)
    for name, value in (("folds", args.folds), ("m_values", args.m), ("nielsen_trials", args.nielsen_trials),
                        ("nielsen_max_iter", args.nielsen_max_iter)):
        if value is not None:
            fields[name] = tuple(value) if name == "m_values" else value
    datasets = tuple(args.dataset or DEFAULT_DATASETS)
    return BenchConfig.quick(datasets, **fields) if args.quick else BenchConfig(datasets, **fields)


def command(config, args) -> str:
    """The exact command line that reproduces this run (every option spelled out)."""
    parts = ["goniofrost", "bench", "--out", str(args.out)]
    for spec in config.datasets:
        parts += ["--dataset", spec]
    g = config.grid
    parts += ["--grid", f"{g.n_th},{g.n_td},{g.n_pd}", "--folds", str(config.folds),
              "--train", str(config.n_train), "--test", str(config.n_test),
              "--m", ",".join(map(str, config.m_values)), "--methods", ",".join(config.methods),
              "--nielsen-trials", str(config.nielsen_trials), "--nielsen-subset", str(config.nielsen_subset),
              "--nielsen-max-iter", str(config.nielsen_max_iter), "--random-trials", str(config.random_trials),
              "--eta", repr(config.eta), "--seed", str(config.seed),
              "--target-error", ",".join(repr(e) for e in config.target_errors)]
    if args.stress:
        parts += ["--stress", "--stress-m", str(args.stress_m)]
    return shlex.join(parts)


def _int_list(text: str) -> list[int]:
    import argparse
    try:
        if ":" in text:
            start, stop, step = (int(v) for v in text.split(":"))
            return list(range(start, stop + 1, step))
        return [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected integers like 5,10,20 or 5:60:5, found {text!r}") from None


def _float_list(text: str) -> list[float]:
    import argparse
    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected numbers like 0.05 or 0.05,0.03, found {text!r}") from None


def _str_list(text: str) -> list[str]:
    return [v.strip() for v in text.split(",") if v.strip()]
