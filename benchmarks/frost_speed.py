"""FROST speed: selection, training (time + peak memory), reconstruction + .binary writing.

    .venv/bin/python benchmarks/frost_speed.py targets [--model MODEL] [--training] [--demo]
        every figure of the "first five minutes" (median of 5) beside its target, the machine's
        streaming bandwidth and the load: the one command to rerun on a quiet machine
    .venv/bin/python benchmarks/frost_speed.py kernels [--model MODEL] [--repeat 5]
        one pass of every selection kernel: time, the bytes it must move, GB/s against the stream
    .venv/bin/python benchmarks/frost_speed.py selection --model MODEL [--repeat 5]
    .venv/bin/python benchmarks/frost_speed.py bayes-selection --model MODEL [--repeat 7]
    .venv/bin/python benchmarks/frost_speed.py time-selection --model MODEL [--rig RIG] [--repeat 7]
        the sample-count and the time-aware designs among the rig's cells (the latter also with
        the reference full scan): greedy passes, and the one-off table of the cells' fixed costs
    .venv/bin/python benchmarks/frost_speed.py training [--seed 0]      # /usr/bin/time -v, fresh cache
    .venv/bin/python benchmarks/frost_speed.py reconstruction --model MODEL
    .venv/bin/python benchmarks/frost_speed.py bayes-reconstruction --model MODEL [--repeat 7]
    .venv/bin/python benchmarks/frost_speed.py pca [--rows N]           # Gram vs randomized SVD
    .venv/bin/python benchmarks/frost_speed.py floor [--model MODEL] [--results BENCH/results.json]
    .venv/bin/python benchmarks/frost_speed.py bounds --model MODEL [--m 20]
    .venv/bin/python benchmarks/frost_speed.py flatness [--model MODEL] [--m 20]
        the share of cells near the best Bayesian score per step (why every step reads all of D)

Timings are medians of repeated runs; the machine is shared, so say so when quoting them.
Targets (DESIGN.md): selection full grid m=20 <= 0.3 s, m=60 <= 2 s; Bayesian selection (K = 60)
m=20 <= 0.3 s, m=60 <= 1.0 s; training 131 materials <= 60 s (with the noise cross-validation of
a format-2 model: <= 120 s) and <= 6 GB peak; reconstruction + writing <= 0.5 s (Bayesian, with
the uncertainty file and record: <= 0.6 s).
"""
from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "benchmarks"))


def median_time(fn, repeat: int) -> tuple[float, list[float]]:
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return float(np.median(times)), times


def bench_selection(args) -> None:
    from goniofrost.frost.selection import select_cells

    model = _paged_model(args.model)
    for y_form in ("firstm", "all"):
        for m in (20, 60):
            # The all-columns form is ~20x slower: one run is enough to see it.
            repeat = args.repeat if y_form == "firstm" else 1
            cpu = []

            def run():
                start = time.process_time()
                select_cells(model, m, y_form=y_form)
                cpu.append(time.process_time() - start)

            med, times = median_time(run, repeat)
            # CPU time (both threads) tells how much of the wall time other users' load took.
            print(f"selection y_form={y_form:6s} m={m}: median {med:.3f} s  (runs {', '.join(f'{t:.3f}' for t in times)}; "
                  f"CPU median {float(np.median(cpu)):.3f} s, load {os.getloadavg()[0]:.1f})", flush=True)


def bench_bayes_selection(args) -> None:
    from goniofrost.frost.bayes_selection import select_bayes

    model = _paged_model(args.model)
    for m in (20, 60):
        cpu = []

        def run():
            start = time.process_time()
            select_bayes(model, m)
            cpu.append(time.process_time() - start)

        med, times = median_time(run, args.repeat)
        print(f"Bayesian selection K={model.n_components} m={m}: median {med:.3f} s  (runs "
              f"{', '.join(f'{t:.3f}' for t in times)}; CPU median {float(np.median(cpu)):.3f} s, "
              f"load {os.getloadavg()[0]:.1f})", flush=True)


def bench_time_selection(args) -> None:
    """Both designs among the rig's cells, m = 20 and 60: the greedy (``pick_seconds[-1]``, the
    passes over D) and the whole ``select_bayes``; the time-aware design's cost table apart."""
    sys.path[:] = [p for p in sys.path if p != str(REPO / "benchmarks")]  # its planner.py shadows ours
    from goniofrost.rig.file import load_checked_rig
    from goniofrost.frost.bayes_selection import _candidate_rows, greedy_design
    from goniofrost.frost.posterior import cell_noise, design_scale, prior_variance
    from goniofrost.frost.time_design import OVERHEAD_S, SHARE, RigTrack, cached_costs
    from planner.reach import reachability

    model = _paged_model(args.model)
    rig = load_checked_rig(args.rig or REPO / "config" / "rigs" / "sim.yaml")
    rows = _candidate_rows(reachability(rig, model.grid).mask, model.grid.n_valid)
    start = time.perf_counter()
    costs = cached_costs(model, rig, rows)
    print(f"cost table of {rows.size} cells: {time.perf_counter() - start:.2f} s (computed once per model and "
          "rig, then read from the cache)")
    s2 = np.asarray(model.singular_values, np.float64) ** 2
    noise = cell_noise(model) * design_scale(model)
    # "time, full scan": the qualifying cells found by a second sweep over the forms (the
    # reference; the same picks), against the cells collected in the pass over D
    variants = {"samples": None, "time": False, "time, full scan": True}
    for m in (20, 60):
        picks = {}
        for name, full in variants.items():
            def run():
                track = None if full is None else RigTrack(costs, rig, OVERHEAD_S, m, SHARE, full_scan=full)
                design = greedy_design(model.dictionary, s2, prior_variance(model), noise, m, rows=rows, track=track)
                picks[name] = design.rows.tolist()
            run()  # compiled and warm
            med, times = median_time(run, args.repeat)
            print(f"{name:>15} design m={m}: median {med:.3f} s (runs {', '.join(f'{t:.3f}' for t in times)}; "
                  f"load {os.getloadavg()[0]:.1f})", flush=True)
        print(f"m={m}: the time-aware picks with and without the full scan are "
              f"{'the same' if picks['time'] == picks['time, full scan'] else 'DIFFERENT'}", flush=True)


def bench_bayes_reconstruction(args) -> None:
    from goniofrost.frost.bayes_selection import select_bayes
    from goniofrost.frost.outputs import write_bayes_outputs
    from goniofrost.frost.reconstruction import reconstruct_bayes

    model = _paged_model(args.model)
    positions = select_bayes(model, 20).positions
    values = np.random.default_rng(0).uniform(0.05, 2.0, (positions.size, 3))
    with tempfile.TemporaryDirectory() as tmp:
        def run():
            rec = reconstruct_bayes(model, positions, values)
            write_bayes_outputs(Path(tmp) / "out.binary", model, rec)
        med, times = median_time(run, args.repeat)
    print(f"Bayesian reconstruction + write .binary, .std.binary, .json (m=20): median {med:.3f} s  "
          f"(runs {', '.join(f'{t:.3f}' for t in times)}; load {os.getloadavg()[0]:.1f})")


def bench_training(args) -> None:
    from frost_accuracy import SPECS, test_split

    excluded = test_split(args.seed)
    cmd = ["/usr/bin/time", "-v", str(REPO / ".venv/bin/goniofrost"), "train", "--no-cache"]
    for spec in SPECS:
        cmd += ["--dataset", spec]
    for name in excluded:
        cmd += ["--exclude", name]
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, GONIOFROST_CACHE=str(Path(tmp) / "cache"))
        result = subprocess.run(cmd + ["--out", str(Path(tmp) / "model")], env=env,
                                capture_output=True, text=True)
    report = result.stderr
    wall = re.search(r"Elapsed \(wall clock\) time.*: (.*)", report)
    rss = re.search(r"Maximum resident set size \(kbytes\): (\d+)", report)
    cpu = [re.search(rf"{what} time \(seconds\): ([\d.]+)", report) for what in ("User", "System")]
    if all(cpu):
        print(f"CPU time: user {cpu[0].group(1)} s, system {cpu[1].group(1)} s (2 cores shared with others)")
    print(result.stdout.strip())
    print(f"training (131 materials, full grid, tabulation included): wall {wall.group(1) if wall else '?'}, "
          f"peak RSS {int(rss.group(1)) / 1e6:.2f} GB" if rss else report[-2000:])


def bench_reconstruction(args) -> None:
    from goniofrost.brdf.merl_file import valid_to_full, write_merl
    from goniofrost.frost.reconstruction import reconstruct
    from goniofrost.frost.selection import select_cells

    model = _paged_model(args.model)
    positions = select_cells(model, 20, y_form="firstm").positions
    values = np.random.default_rng(0).uniform(0.05, 2.0, (positions.size, 3))
    with tempfile.TemporaryDirectory() as tmp:
        def run():
            brdf = reconstruct(model, positions, values)
            write_merl(Path(tmp) / "out.binary", valid_to_full(brdf, model.grid), model.grid)
        med, times = median_time(run, args.repeat)
    print(f"reconstruction + write .binary (m=20): median {med:.3f} s  (runs {', '.join(f'{t:.3f}' for t in times)})")


def bench_pca(args) -> None:
    """Gram matrix (float64, chunked dsyrk) against a randomized SVD on the same matrix."""
    from scipy.linalg import blas

    rng = np.random.default_rng(0)
    n, t, k = args.rows, 393, 60
    # A matrix with a decaying spectrum like the mapped training data (s_i ~ i^-1.5).
    x = ((rng.standard_normal((n, t)).astype(np.float32) * (np.arange(1, t + 1) ** -1.5).astype(np.float32))
         @ np.linalg.qr(rng.standard_normal((t, t)))[0].astype(np.float32))

    def gram():
        g = np.zeros((t, t))
        for a in range(0, n, 1 << 14):
            g = blas.dsyrk(1.0, x[a:a + (1 << 14)].astype(np.float64), trans=1, beta=1.0, c=g, overwrite_c=1)
        g = np.triu(g) + np.triu(g, 1).T
        return np.sqrt(np.maximum(np.linalg.eigvalsh(g)[::-1][:k], 0))

    def randomized(power=2, oversample=10):
        omega = rng.standard_normal((t, k + oversample)).astype(np.float32)
        y = x @ omega
        for _ in range(power):
            y = np.linalg.qr(x @ (x.T @ y))[0]
        q = np.linalg.qr(y)[0]
        return np.linalg.svd(q.T @ x, compute_uv=False)[:k]

    # Reference: a dense SVD when it fits (n <= 200k), else the Gram result itself.
    exact = np.linalg.svd(x, compute_uv=False)[:k] if n <= 200_000 else None
    for name, fn in (("gram", gram), ("randomized", randomized)):
        start = time.perf_counter()
        s = fn()
        took = time.perf_counter() - start
        ref = exact if exact is not None else gram()
        print(f"pca {name:10s}: {took:.2f} s for {n} x {t}; max rel. error of s_1..s_{k}: "
              f"{np.max(np.abs(s - ref) / ref):.2e}")


def bench_floor(args) -> None:
    """The least time an exact SOMP selection can take on the full grid, against Nielsen / 100.

    Every step changes every cell's score (C -= v u^T with v_j = q_j . b, nonzero in
    general), so each of the m - 1 steps after the first must at least read the n x m float32
    score matrix (or the n x m atoms) once. One such read is timed here with the scores kernel
    on the selection's threads; (m - 1) reads are a floor for any exact implementation on this
    machine. With --model, the actual select_cells time is printed beside it; with --results
    (a `goniofrost bench` results.json), the median Nielsen selection time of that run / 100.
    """
    from goniofrost.frost import selection, somp_kernels
    from goniofrost.core.grid import MerlGrid

    n, w = MerlGrid().n_valid, selection.BLOCK_CELLS
    model = _paged_model(args.model) if args.model else None
    nielsen = {}
    if args.results:
        from goniofrost.bench.results import load_rows, summary

        nielsen = {m: stats["select_s"] for (method, m), stats in summary(load_rows(args.results)).items()
                   if method == "nielsen"}
    for m in (5, 10, 20, 40, 60):
        cb = np.ones((-(-n // w), m, w), dtype=np.float32)
        scores = np.empty(cb.shape[0] * w, dtype=np.float32)
        one_read, _ = median_time(lambda: selection._in_threads(somp_kernels.block_scores, cb.shape[0], None, cb,
                                                                scores), args.repeat)
        line = (f"m={m:2d}: one read of C ({cb.nbytes / 1e6:.0f} MB) {one_read * 1e3:.1f} ms, "
                f"floor ({m - 1} reads) {(m - 1) * one_read:.3f} s")
        if model is not None:
            actual, _ = median_time(lambda: selection.select_cells(model, m), args.repeat)
            line += f"; select_cells {actual:.3f} s"
        if m in nielsen:
            line += f"; Nielsen (bench median) {nielsen[m]:.3f} s / 100 = {nielsen[m] / 100:.4f} s"
        print(line + f"  (load {os.getloadavg()[0]:.1f})", flush=True)


def bench_flatness(args) -> None:
    """Why a Bayesian step reads every row of D: how flat the score field is near its top.

    The exact greedy design (numpy, float64, the selection's prior, noise and design scale) on
    the demo's model (or --model); at each of the first --m steps it prints the best score and
    the share of the n cells whose exact score is within a factor 2 of it, and the share a
    per-row bound could rule out: score_c <= ||d_c||^2 lambda_max(Sigma S^2 Sigma) /
    (sigma_c^2 + lambda_min(Sigma) ||d_c||^2) (the Rayleigh quotients of both forms). A cell
    can be skipped only when its bound is below the best score; when most cells are near the
    top and no bound rules any out, the step must read every row (and a float16 shortlist
    must re-score most of them).
    """
    from goniofrost.core.grid import FULL_GRID, MerlGrid
    from goniofrost.frost.posterior import cell_noise, design_scale, prior_variance
    from goniofrost.frost.training import train

    grid = MerlGrid(*args.grid) if args.grid else FULL_GRID
    model = _paged_model(args.model) if args.model else train(["builtin"], exclude=["red-plastic"], grid=grid)
    d = np.asarray(model.dictionary, dtype=np.float64)
    s2 = np.asarray(model.singular_values, np.float64) ** 2
    noise = cell_noise(model) * design_scale(model)
    sigma = np.diag(prior_variance(model))
    norm2 = np.einsum("ij,ij->i", d, d)
    for step in range(args.m):
        u = d @ sigma
        q, p = np.einsum("ij,ij->i", u, d), np.einsum("ij,ij->i", u * s2, u)
        score = p / (noise + q)
        best = int(np.argmax(score))
        top = np.linalg.eigvalsh(sigma @ np.diag(s2) @ sigma)[-1]
        bound = top * norm2 / (noise + np.linalg.eigvalsh(sigma)[0] * norm2)
        print(f"step {step + 1:2d}: best score {score[best]:.4g}; cells within a factor 2 of it "
              f"{np.mean(score >= 0.5 * score[best]):.1%}; ruled out by the bound {np.mean(bound < score[best]):.1%}",
              flush=True)
        row = d[best]
        gain = sigma @ row
        sigma = sigma - np.outer(gain, gain) / (noise[best] + row @ gain)


def bench_bounds(args) -> None:
    """Could SOMP skip cells? Fractions of cells two upper bounds on the score fail to rule out.

    At each step of an exact (float64) first-m SOMP with k = m, for score_j = ||R^T q_j||_1:
    * cell bound: g ||(I - B B^T) q_j||_2 with g = min(sqrt(t) ||R||_2, sum of R's column
      norms) >= max_{||x||=1} ||R^T x||_1;
    * block bound (BLOCK_CELLS consecutive cells): ||R^T mu||_1 + g max_j ||(I - B B^T)(q_j - mu)||_2
      with mu the block's mean atom.
    A cell (block) must be scored when its bound reaches the step's best score; "exact >= 0.9"
    is the fraction within 10 % of the best, the least that even a tight bound must score.
    """
    from goniofrost.frost.selection import BLOCK_CELLS

    model = _paged_model(args.model)
    k = m = args.m
    q = np.asarray(model.dictionary[:, :k], dtype=np.float64) / np.asarray(model.singular_values[:k], dtype=np.float64) ** 2
    q /= np.maximum(np.linalg.norm(q, axis=1), 1e-300)[:, None]
    r = np.asarray(model.coefficients[:k, :m], dtype=np.float64).copy()
    blocks = np.vstack([q, np.zeros((-q.shape[0] % BLOCK_CELLS, k))]).reshape(-1, BLOCK_CELLS, k)
    mean = blocks.mean(axis=1)
    spread, z, basis = blocks - mean[:, None, :], q.copy(), np.zeros((k, 0))
    print("step  best score  g / best  cell bound  block bound  exact >= 0.9 best")
    for step in range(m):
        scores = np.abs(q @ r).sum(axis=1)
        j = int(np.argmax(scores))
        best = scores[j]
        g = min(np.sqrt(m) * np.linalg.norm(r, 2), np.linalg.norm(r, axis=0).sum())
        radius = np.linalg.norm(spread - (spread @ basis) @ basis.T, axis=2).max(axis=1)
        block_bound = np.abs(mean @ r).sum(axis=1) + g * radius
        print(f"{step:4d}  {best:10.4g}  {g / best:8.2f}  {np.mean(g * np.linalg.norm(z, axis=1) >= best):10.3f}  "
              f"{np.mean(block_bound >= best):11.3f}  {np.mean(scores >= 0.9 * best):17.4f}", flush=True)
        b = z[j] / np.linalg.norm(z[j])
        b -= basis @ (basis.T @ b)
        b /= np.linalg.norm(b)
        basis = np.column_stack([basis, b])
        r -= np.outer(b, b @ r)
        z -= np.outer(z @ b, b)


# Targets (issue 26, 2 cores, nothing else running): selection s, training s and GB, demo s.
TARGETS = {"bayes m=20": 0.25, "bayes m=60": 0.75, "somp m=20": 0.25, "training s": 45.0, "training GB": 3.0,
           "demo cold s": 35.0, "demo warm s": 15.0}


def stream_bandwidth(nbytes: int = 1 << 29, repeat: int = 5, threads: int | None = None) -> float:
    """GB/s of a read of a large float32 array on ``threads`` threads (default: the selection's),
    split as a selection pass is (``threads.run_ranges``), each piece summed by np.add.reduce
    (it releases the GIL and is vectorised well past the memory's speed); the median of
    ``repeat`` reads: the read limit such a pass can reach. One thread reads a fraction of what
    two do (``threads=1``), so a one-thread figure would put a two-thread pass's limit too low."""
    from concurrent.futures import ThreadPoolExecutor

    from goniofrost.frost.threads import resolve_threads, run_ranges

    x = np.ones(nbytes // 4, dtype=np.float32)
    threads = resolve_threads(threads)
    with ThreadPoolExecutor(max_workers=threads) as pool:
        def read():
            run_ranges(lambda lo, hi: np.add.reduce(x[lo:hi]), x.size, threads, pool=pool)
        read()
        med, _ = median_time(read, repeat)
    return nbytes / med / 1e9


def _load() -> str:
    return "load " + " ".join(f"{v:.1f}" for v in os.getloadavg())


def bench_targets(args) -> None:
    """Selection (Bayesian m = 20 and 60, SOMP m = 20), optionally training and the demo, each
    beside its target; the bandwidth limit of a selection is one read of D per greedy step."""
    from goniofrost.core.grid import FULL_GRID, MerlGrid
    from goniofrost.frost.bayes_selection import select_bayes
    from goniofrost.frost.selection import select_cells
    from goniofrost.frost.threads import resolve_threads
    from goniofrost.frost.training import train

    grid = MerlGrid(*args.grid) if args.grid else FULL_GRID
    print(f"machine: {os.cpu_count()} cores, {_load()}", flush=True)
    bandwidth = stream_bandwidth(min(1 << 29, 64 * grid.n_valid * 60 * 4))
    print(f"streaming read bandwidth (numpy sums of a large float32 array on {resolve_threads(None)} threads): "
          f"{bandwidth:.1f} GB/s  ({_load()})", flush=True)
    model = _paged_model(args.model) if args.model else train(["builtin"], exclude=["red-plastic"], grid=grid)
    d_bytes = model.grid.n_valid * model.n_components * 4
    print(f"model: K = {model.n_components}, n = {model.grid.n_valid} cells, D = {d_bytes / 1e6:.0f} MB", flush=True)
    select_bayes(model, 2), select_cells(model, 2)  # nothing compiles or pages in inside the timings
    # A Bayesian step reads D (n x K float32) once; a first-m SOMP step at least the n x m
    # float32 score matrix C (see ``floor``), m - 1 times.
    c_bytes = model.grid.n_valid * 20 * 4
    for name, fn, m, reads, nbytes, what in (("bayes m=20", select_bayes, 20, 20, d_bytes, "D"),
                                             ("bayes m=60", select_bayes, 60, 60, d_bytes, "D"),
                                             ("somp m=20", select_cells, 20, 19, c_bytes, "C")):
        med, times = median_time(lambda: fn(model, m), args.repeat)
        limit = reads * nbytes / (bandwidth * 1e9)
        print(f"{name}: median {med:.3f} s  target {TARGETS[name]:.2f} s  {'met' if med <= TARGETS[name] else 'MISSED'}; "
              f"bandwidth limit {limit:.4g} s ({reads} reads of {what}), ratio {med / limit:.2f}  "
              f"(runs {', '.join(f'{t:.3f}' for t in times)}; {_load()})", flush=True)
    if args.training:
        _target_training(args)
    if args.demo:
        _target_demo(args)


def bench_kernels(args) -> None:
    """One pass of each selection kernel on the model (median of --repeat), on the selection's
    threads: its time, the bytes it must move (reads + writes of its arrays) and the GB/s that
    makes, beside the machine's streaming read bandwidth. A Bayesian step of S designs reads D
    (n x K float32), the candidate rows (int64) and, per design, q, p (float64, read and
    written) and the noise; a SOMP step reads Q (n x k) and C (n x t) and writes C (Q pass),
    or reads and writes C alone (C pass)."""
    from goniofrost.core.grid import FULL_GRID, MerlGrid
    from goniofrost.frost import bayes_kernels, selection, somp_kernels
    from goniofrost.frost.threads import resolve_threads, run_ranges
    from goniofrost.frost.training import train

    grid = MerlGrid(*args.grid) if args.grid else FULL_GRID
    model = _paged_model(args.model) if args.model else train(["builtin"], exclude=["red-plastic"], grid=grid)
    d = np.ascontiguousarray(model.dictionary, dtype=np.float32)
    n, k_all = d.shape
    threads = resolve_threads(None)
    bandwidth = stream_bandwidth(min(1 << 29, max(d.nbytes, 1 << 20)))
    print(f"{os.cpu_count()} cores, {threads} threads; streaming read {bandwidth:.1f} GB/s; n = {n}, K = {k_all}  "
          f"({_load()})", flush=True)
    rng = np.random.default_rng(0)
    rows = np.arange(n, dtype=np.int64)

    def report(name, fn, nbytes, floor_bytes):
        med, _ = median_time(fn, args.repeat)
        print(f"{name}: {med * 1e3:.1f} ms, {nbytes / 1e6:.0f} MB moved, {nbytes / med / 1e9:.1f} GB/s; "
              f"one read of {floor_bytes / 1e6:.0f} MB at the stream: {floor_bytes / bandwidth / 1e6:.1f} ms, ratio "
              f"{med / (floor_bytes / bandwidth / 1e9):.2f}  ({_load()})", flush=True)

    for designs in (1, 3):
        q, p = np.ones((designs, n)), np.ones((designs, n))
        noise = rng.uniform(0.5, 1.0, (designs, n))
        u, v = rng.normal(size=(designs, k_all)) * 1e-3, rng.normal(size=(designs, k_all)) * 1e-3
        scalars = np.full(designs, 0.5), np.full(designs, 1e-3)

        def step():
            run_ranges(lambda lo, hi: bayes_kernels.update_forms(d, rows, u, v, *scalars, q, p, noise,
                                                                 np.empty(designs), np.empty(designs, np.int64),
                                                                 lo, hi), n, threads)
        report(f"bayes step, {designs} design{'s' * (designs > 1)}", step, d.nbytes + 8 * n + 40 * n * designs, d.nbytes)

    k = t = min(20, k_all)
    start = time.perf_counter()
    pos, qb, n_c = selection._atoms(model, k, None, k, threads)
    print(f"somp pack (k = {k}, one run): {(time.perf_counter() - start) * 1e3:.1f} ms", flush=True)
    state = selection._ScoreState(qb, n_c, np.asarray(model.coefficients[:k, :t], np.float64), threads)
    b, z, u = (rng.normal(size=x).astype(np.float32) * 1e-3 for x in (k, t, t))
    blocks = qb.shape[0]
    report(f"somp Q pass (k = t = {t})", lambda: run_ranges(somp_kernels.rank1_step, blocks, threads, qb, b,
                                                             state.cb, u, state.scores), qb.nbytes + 2 * state.cb.nbytes,
           state.cb.nbytes)
    report(f"somp C pass (t = {t})", lambda: run_ranges(somp_kernels.rank1_step, blocks, threads, state.cb, z,
                                                          state.cb, u, state.scores), 2 * state.cb.nbytes, state.cb.nbytes)


def _timed(cmd, env) -> tuple[float, float, str]:
    """(wall s, peak RSS GB, stdout) of a command under /usr/bin/time -v."""
    result = subprocess.run(["/usr/bin/time", "-v", *cmd], env=env, capture_output=True, text=True)
    if result.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{result.stderr[-3000:]}")
    wall = re.search(r"Elapsed \(wall clock\) time.*: (?:(\d+):)?(\d+):([\d.]+)", result.stderr)
    hours, minutes, secs = wall.groups()
    rss = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", result.stderr).group(1))
    return int(hours or 0) * 3600 + int(minutes) * 60 + float(secs), rss / 1e6, result.stdout


def _target_training(args) -> None:
    """Training on the 151 shared materials, --repeat times: the median wall and the largest
    peak RSS, beside their targets."""
    data = REPO.parent / "shared" / "data"
    specs = [f"nbrdf:{args.data or data}/{name}" for name in ("nbrdf_merl.npz", "nbrdf_rgl.npz")]
    cmd = [str(REPO / ".venv/bin/goniofrost"), "train", "--no-cache"]
    for spec in specs:
        cmd += ["--dataset", spec]
    tabulate = ("from goniofrost.datasets.tabulate import collect_materials, tabulate_cached\n"
                f"for m in collect_materials({specs!r}, None, None): tabulate_cached(m.dataset, [m.name])")
    walls, peaks = [], []
    with tempfile.TemporaryDirectory() as tmp:
        # The user's cache (GONIOFROST_CACHE or ~/.cache): the tabulations are made once and
        # kept, so the figure is the training itself; --no-cache retrains the model.
        env = dict(os.environ)
        subprocess.run([str(REPO / ".venv/bin/python"), "-c", tabulate], env=env, check=True)
        for _ in range(args.repeat):
            wall, gb, _ = _timed(cmd + ["--out", str(Path(tmp) / "model")], env)
            walls.append(wall)
            peaks.append(gb)
    for name, value, runs in (("training s", float(np.median(walls)), walls), ("training GB", max(peaks), peaks)):
        what = "wall, median" if name.endswith(" s") else "peak RSS, largest"
        print(f"training {what} (151 materials, tabulation cached): {value:.2f}  target {TARGETS[name]:g}  "
              f"{'met' if value <= TARGETS[name] else 'MISSED'}  (runs {', '.join(f'{r:.2f}' for r in runs)}; {_load()})",
              flush=True)


def _target_demo(args) -> None:
    """The demo cold (an empty cache: it trains its model) then warm (that cache), --repeat times
    each pair: the medians, beside their targets, with the stages of the median run."""
    runs = {"demo cold s": [], "demo warm s": []}
    for _ in range(args.repeat):
        with tempfile.TemporaryDirectory() as tmp:
            env = dict(os.environ, GONIOFROST_CACHE=str(Path(tmp) / "cache"))
            cmd = [str(REPO / ".venv/bin/goniofrost"), "demo", "--out", str(Path(tmp) / "demo"), "--no-progress"]
            for name in runs:
                wall, gb, out = _timed(cmd, env)
                runs[name].append((wall, gb, re.search(r"time .*", out).group(0)))
    for name, results in runs.items():
        walls = [r[0] for r in results]
        wall, gb, stages = sorted(results)[len(results) // 2]  # the median run (the upper one of an even count)
        print(f"{name[:-2]}: median {wall:.1f} s  target {TARGETS[name]:g} s  {'met' if wall <= TARGETS[name] else 'MISSED'}; "
              f"peak RSS {gb:.2f} GB; {stages}  (runs {', '.join(f'{w:.1f}' for w in walls)}; {_load()})", flush=True)


def _paged_model(path):
    from goniofrost.frost.model import FrostModel

    model = FrostModel.load(path)
    np.asarray(model.dictionary).sum()  # page the model in once: we time selection, not the disk
    return model


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("what", choices=("targets", "kernels", "selection", "bayes-selection", "time-selection",
                                         "training", "reconstruction",
                                         "bayes-reconstruction", "pca", "floor", "bounds", "flatness"))
    parser.add_argument("--model", help="model directory (selection, reconstruction, bounds; optional for floor)")
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--rows", type=int, default=1_111_432)
    parser.add_argument("--results", help="a goniofrost bench results.json (floor: Nielsen's times)")
    parser.add_argument("--rig", help="time-selection: the rig file (default config/rigs/sim.yaml)")
    parser.add_argument("--m", type=int, default=20, help="samples (bounds), steps (flatness)")
    parser.add_argument("--grid", type=int, nargs=3, metavar=("TH", "TD", "PD"),
                        help="targets, kernels, flatness: train the demo model on this grid instead of the full one (a quick check)")
    parser.add_argument("--training", action="store_true", help="targets: also time training 151 materials")
    parser.add_argument("--demo", action="store_true", help="targets: also time the demo, cold and warm")
    parser.add_argument("--data", help="targets --training: the folder of nbrdf_merl.npz and nbrdf_rgl.npz")
    args = parser.parse_args()
    {"targets": bench_targets, "kernels": bench_kernels, "selection": bench_selection, "bayes-selection": bench_bayes_selection,
     "time-selection": bench_time_selection, "training": bench_training,
     "reconstruction": bench_reconstruction, "bayes-reconstruction": bench_bayes_reconstruction,
     "pca": bench_pca, "floor": bench_floor, "bounds": bench_bounds, "flatness": bench_flatness}[args.what](args)


if __name__ == "__main__":
    main()
