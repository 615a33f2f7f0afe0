"""The two benchmark entry points behind ``goniofrost bench``: the cross-validation and the
stress cases. Each tabulates the materials once (cached), runs, then writes its files."""
from __future__ import annotations

import json
import sys
from pathlib import Path

from goniofrost.bench.config import BenchConfig, BenchError
from goniofrost.bench.data import tables_path
from goniofrost.bench.executors import run_folds
from goniofrost.bench.plots import write_plots
from goniofrost.bench.results import check_rows, json_text, machine_info, summary_markdown, write_atomic, write_results


def run_benchmark(config: BenchConfig, out: Path, command: str, jobs: int = 1,
                  dask_address: str | None = None, progress: bool = True, resume: bool = False) -> list[Path]:
    """Run every fold and write results.json, results.csv, summary.md and the PNG plots.

    Each finished fold is checkpointed as ``out/folds/fold-NN.json``; with ``resume`` the
    checkpoints of the same configuration are reused. results.json and the rest are written
    only when every fold has finished and every number is finite.
    """
    out = Path(out)
    done = load_checkpoints(out, config) if resume else {}  # a damaged checkpoint fails before the tabulation
    if resume:
        print(resume_line(out, config, done), file=sys.stderr)
    names, path = tables_path(config.datasets, config.grid, progress=progress)
    rows = run_folds(config, path, names, jobs=jobs, dask_address=dask_address, progress=progress,
                     done=done, on_fold=lambda fold, fold_rows: write_checkpoint(out, config, fold, fold_rows))
    paths = write_results(out, rows, command, config.as_dict(), machine_info())
    write_atomic(out / "summary.md", summary_markdown(rows, config=config.as_dict()))
    return paths + [out / "summary.md"] + write_plots(out, rows)


def write_checkpoint(out: Path, config: BenchConfig, fold: int, rows: list[dict]) -> Path:
    """Write one finished fold's rows (checked finite) to ``out/folds/fold-NN.json``."""
    check_rows(rows)
    folder = Path(out) / "folds"
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"fold-{fold:02d}.json"
    write_atomic(path, json_text({"config": config.as_dict(), "fold": fold, "rows": rows}))
    return path


def load_checkpoints(out: Path, config: BenchConfig) -> dict:
    """{fold: rows} of the checkpoints in ``out/folds`` made with exactly this configuration.

    A checkpoint that cannot be read (cut short, edited by hand) raises BenchError naming it and
    what to do (it was a JSON traceback, exit 1)."""
    done = {}
    wanted = json.loads(json_text(config.as_dict()))
    for path in sorted((Path(out) / "folds").glob("fold-*.json")):
        try:
            payload = json.loads(path.read_text())
            if payload.get("config") == wanted and payload["fold"] < config.folds:
                check_rows(payload["rows"])
                done[int(payload["fold"])] = payload["rows"]
        except (ValueError, KeyError, TypeError, AttributeError) as exc:  # BenchError is a ValueError
            raise BenchError(f"{path}: expected a fold checkpoint of goniofrost bench ({{\"config\", \"fold\", "
                             f"\"rows\"}}), found {type(exc).__name__}: {exc}; delete it to run that fold again")
    return done


def resume_line(out: Path, config: BenchConfig, done: dict) -> str:
    """What --resume takes over: how many of the folds, or why none (checkpoints of other options
    are not this run's: every fold runs again, which a researcher who changed an option must know)."""
    folder = Path(out) / "folds"
    found = len(list(folder.glob("fold-*.json")))
    if done:
        return f"resume: {len(done)} of {config.folds} folds from {folder}, {config.folds - len(done)} to run"
    why = "none there" if not found else f"{found} there, of other options"
    return f"resume: no fold checkpoint of these options in {folder} ({why}): every fold runs"


def run_stress(config: BenchConfig, out: Path, command: str, m: int = 20, progress: bool = True) -> list[Path]:
    """Run the numerical stress cases on fold 0 and write stress.json and stress.md."""
    from goniofrost.bench.stress import run_cases, write_stress

    names, path = tables_path(config.datasets, config.grid, progress=progress)
    records = run_cases(config, path, names, m=m, progress=progress)
    return write_stress(Path(out), records, command, config.as_dict(), machine_info())
