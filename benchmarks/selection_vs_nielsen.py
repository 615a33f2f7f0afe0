"""Selection time of FROST (both Y forms) against Nielsen et al. 2015 on one fold, any grid.

    .venv/bin/python benchmarks/selection_vs_nielsen.py [--grid 90,90,180] [--m 5,10,20,40,60]
        [--nielsen-max-iter 5] [--repeat 1]

Trains on fold 0 of the default benchmark split (131 of the 151 materials in ../shared/data),
then times select_cells for each m and one incremental Nielsen run (time to reach each m), in
this process. Prints one JSON object. The machine is shared: quote medians and the load.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def main() -> None:
    from goniofrost.bench.baselines import nielsen_path
    from goniofrost.bench.config import BenchConfig, fold_split, method_rng
    from goniofrost.bench.data import open_tables, tables_path
    from goniofrost.app.commands.bench import DEFAULT_DATASETS
    from goniofrost.core.grid import MerlGrid
    from goniofrost.frost.selection import select_cells
    from goniofrost.frost.training import TrainingOptions, fit_model

    parser = argparse.ArgumentParser()
    parser.add_argument("--grid", default="90,90,180")
    parser.add_argument("--m", default="5,10,20,40,60")
    parser.add_argument("--nielsen-max-iter", type=int, default=5)
    parser.add_argument("--repeat", type=int, default=1)
    args = parser.parse_args()
    ms = [int(v) for v in args.m.split(",")]
    config = BenchConfig(tuple(DEFAULT_DATASETS), grid=MerlGrid(*(int(v) for v in args.grid.split(","))),
                         m_values=tuple(ms), nielsen_max_iter=args.nielsen_max_iter)
    names, path = tables_path(config.datasets, config.grid)
    train, _ = fold_split(len(names), config, 0)
    start = time.perf_counter()
    model = fit_model(np.asarray(open_tables(path)[train]), [names[i] for i in train], config.grid,
                      TrainingOptions(k_max=max(ms)))
    out = {"grid": config.grid.as_dict(), "train_s": time.perf_counter() - start, "load": os.getloadavg(),
           "frost": {}, "frost-firstm": {}}
    for form, key in (("all", "frost"), ("firstm", "frost-firstm")):
        for m in ms:
            times = []
            for _ in range(args.repeat):
                t = time.perf_counter()
                select_cells(model, m, y_form=form)
                times.append(time.perf_counter() - t)
            out[key][m] = float(np.median(times))
    steps = nielsen_path(model.dictionary, ms, config.grid, method_rng(config, "nielsen", 0, 0),
                         config.nielsen_subset, config.nielsen_max_iter)
    out["nielsen"] = {s.m: s.seconds for s in steps}
    out["load_after"] = os.getloadavg()
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
