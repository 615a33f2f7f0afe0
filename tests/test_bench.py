"""goniofrost bench: schema, determinism, executors, error equivalence, stress, CLI (small grid)."""
from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest

from goniofrost.bench.config import BenchConfig, BenchError, fold_split
from goniofrost.bench.data import open_tables, tables_path
from goniofrost.bench.evaluate import designs_per_fold
from goniofrost.frost.metrics import batch_log_errors
from goniofrost.bench.executors import run_folds
from goniofrost.bench.results import ROW_FIELDS, write_results
from goniofrost.app.cli import main
from goniofrost.core.grid import MerlGrid

GRID = MerlGrid(12, 12, 24)
TIME_FIELDS = ("select_s", "recon_s")


@pytest.fixture(scope="module")
def config(merl_npz, rgl_npz) -> BenchConfig:
    return BenchConfig((f"nbrdf:{merl_npz}", f"nbrdf:{rgl_npz}"), grid=GRID, folds=2, n_train=10,
                       n_test=3, m_values=(4, 8), nielsen_trials=2, nielsen_subset=50, nielsen_max_iter=3)


@pytest.fixture(scope="module")
def tables(config):
    return tables_path(config.datasets, config.grid, progress=False)


@pytest.fixture(scope="module")
def local_rows(config, tables):
    """Rows of the two folds run in two local worker processes."""
    names, path = tables
    return run_folds(config, path, names, jobs=2, progress=False)


def without_times(rows):
    return [{k: v for k, v in r.items() if k not in TIME_FIELDS} for r in rows]


def test_rows_cover_every_method_m_fold_trial_material(config, tables, local_rows):
    targets = len(config.target_errors)
    assert len(local_rows) == config.folds * (designs_per_fold(config) + targets) * config.n_test
    keys = {(r["method"], r["m"], r["fold"], r["trial"]) for r in local_rows}
    assert {(k[0], k[3]) for k in keys} == {("frost", 0), ("frost-firstm", 0), ("nielsen", 0),
                                           ("nielsen", 1), ("random", 0), ("uniform", 0), ("bayes", 0),
                                           ("frost-bayesrec", 0), ("bayes-target", 0)}
    for r in local_rows:
        assert set(r) == set(ROW_FIELDS) and math.isfinite(r["mse"]) and r["mse"] > 0
        _, test = fold_split(len(tables[0]), config, r["fold"])
        assert r["material"] in [tables[0][i] for i in test]
        bayes = r["method"] in ("bayes", "frost-bayesrec")
        assert (r["pred_mse"] is not None) == (bayes or r["method"] == "bayes-target")
        assert (r["cover90"] is not None) == bayes and (r["target"] is not None) == (r["method"] == "bayes-target")
        if bayes:
            assert r["pred_mse"] > 0 and 0 <= r["cover50"] <= r["cover90"] <= 1
        if r["method"] == "bayes-target":  # stopped at a batch end, within the plan
            assert r["m"] in (8,) and r["target"] == 0.05
    # FROST beats random cells on average even on this tiny problem
    mean = lambda meth: np.mean([r["mse"] for r in local_rows if r["method"] == meth and r["m"] == 8])
    assert mean("frost") < mean("random")


def test_dask_gives_the_rows_of_local_processes(config, tables, local_rows):
    """Same seed, same rows (times aside), whoever runs the folds: bit for bit. The dask worker runs
    the second fold alone (the first is given as done, as a resumed run has it): one fold shows it
    and halves the test's time."""
    distributed = pytest.importorskip("distributed")
    names, path = tables
    first = [r for r in local_rows if r["fold"] == 0]
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=None) as cluster:
        on_dask = run_folds(config, path, names, dask_address=cluster.scheduler_address, progress=False,
                            done={0: first})
    assert config.folds == 2 and first and {r["fold"] for r in on_dask[len(first):]} == {1}
    assert without_times(on_dask) == without_times(local_rows)


def test_batched_errors_equal_reconstruct_then_log_relative_mse(config, tables):
    from goniofrost.frost.metrics import log_relative_mse
    from goniofrost.frost.reconstruction import reconstruct, reconstruct_log
    from goniofrost.frost.training import TrainingOptions, fit_model

    names, path = tables
    t = open_tables(path)
    model = fit_model(np.asarray(t[:10]), names[:10], GRID,
                      TrainingOptions(k_max=8, noise=False))  # reconstruction reads no noise
    truth = np.asarray(t[[20, 40, 140]])  # includes a dark and a glossy material
    pos = np.array([5, 90, 400, 777, 1200, 1500, 1800, 2100])
    values = truth[:, pos, :].transpose(1, 0, 2).reshape(pos.size, -1)
    est = reconstruct_log(model, pos, model.to_log(values, pos), eta=40.0)
    batched = batch_log_errors(model, est, model.to_log(truth))
    direct = [log_relative_mse(model, truth[i], reconstruct(model, pos, truth[i, pos], eta=40.0)) for i in range(3)]
    np.testing.assert_allclose(batched, direct, rtol=1e-9)


def test_non_finite_numbers_are_never_written(tmp_path):
    row = {"method": "frost", "m": 5, "fold": 0, "trial": 0, "material": "x",
           "mse": float("nan"), "select_s": 0.1, "recon_s": 0.1}
    with pytest.raises(BenchError, match=r"result row 0 \(frost m=5 x\): mse must be a finite float, found nan"):
        write_results(tmp_path / "out", [row], "cmd", {})
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_fold_splits_are_fixed_disjoint_and_checked(config):
    train, test = fold_split(151, config, 3)
    again = fold_split(151, config, 3)
    assert np.array_equal(train, again[0]) and np.array_equal(test, again[1])
    assert len(train) == 10 and len(test) == 3 and not set(train) & set(test)
    assert not np.array_equal(test, fold_split(151, config, 4)[1])
    with pytest.raises(BenchError, match="datasets hold only 12"):
        fold_split(12, config, 0)


def test_stress_cases_end_in_results_or_clear_errors(config, tables, tmp_path):
    from goniofrost.bench.stress import run_cases, write_stress

    names, path = tables
    cfg = config.with_(n_train=30, n_test=4, m_values=(4, 8, 12))
    records = run_cases(cfg, path, names, m=8, progress=False)
    assert {r["status"] for r in records} <= {"ok", "error"}, [r for r in records if r["status"] not in ("ok", "error")]
    by = {(r["case"], r["variant"], r["method"]): r for r in records}
    raw = [r for r in records if r["case"] == "noise" and r["variant"].endswith("raw")]
    # negative raw samples are refused by name (bayes's brighter cells drew none negative here)
    assert raw and all(r["status"] == "error" and "negative value" in r["message"] for r in raw if r["method"] != "bayes")
    assert by[("eta", "eta 0", "frost")]["status"] == "ok"
    assert by[("m above rank", "m=8 (K=8)", "frost")]["status"] == "ok"
    single = [r for r in records if r["case"] == "single material" and r["method"] == "frost" and r["m"] == 8]
    assert single[0]["status"] == "error" and "the model's components" in single[0]["message"]
    for method in ("bayes", "frost", "frost-firstm", "nielsen", "random", "uniform"):
        # 0.1 % multiplicative noise leaves the error as it was; the float64 dictionary changes
        # the mapped estimates only at float32 rounding level; chrome and black materials
        # reconstruct to finite errors.
        noise = by[("noise", "multiplicative 0.001", method)]["values"]["ratio_to_noise_free"]
        assert abs(noise - 1) < 0.01, (method, noise)
        precision = by[("precision", "dictionary float32 vs float64, samples float64", method)]["values"]
        assert precision["max_abs_log_difference"] < 1e-5, (method, precision)
        assert by[("dynamic range", "8 materials", method)]["status"] == "ok"
    assert by[("precision", "training tables float32 vs float64", "uniform")]["values"]["max_rel_singular_value_difference"] < 1e-9
    grazing = [r for r in records if r["case"] == "grazing"]
    assert {r["method"] for r in grazing} == {"bayes", "frost", "frost-firstm", "random"}
    assert all(r["status"] == "ok" and r["values"]["mse_mean"] > 0 for r in grazing)
    span = by[("dynamic range", "materials", "-")]["values"]
    assert span["max_value"] > 1e3 and span["min_positive_value"] < 1e-6  # the case spans >= 9 decades
    conds = [r for r in records if r["case"] == "condition"]
    assert {r["method"] for r in conds} == {"bayes", "frost", "frost-firstm", "nielsen", "random", "uniform"}
    assert not [r for r in records if r["case"] == "eta" and r["method"] == "bayes"]  # it has no eta
    for r in conds:  # a singular sampled block is reported in words, never as inf
        cond = r["values"]["cond"]
        assert cond == "inf (singular to working precision)" if isinstance(cond, str) else cond >= 1
    assert all(isinstance(r["values"]["cond"], float) for r in conds if r["method"] == "nielsen")
    write_stress(tmp_path, records, "cmd", {}, {})
    json.loads((tmp_path / "stress.json").read_text(), parse_constant=lambda c: pytest.fail(f"{c} in JSON"))


def test_cli_runs_and_rejects_bad_options(merl_npz, rgl_npz, tmp_path, capsys):
    base = ["bench", "--dataset", f"nbrdf:{merl_npz}", "--dataset", f"nbrdf:{rgl_npz}",
            "--grid", "12,12,24", "--jobs", "1", "--no-progress"]
    assert main(base + ["--train", "200", "--out", str(tmp_path / "a")]) == 2
    assert "200 training + 20 test materials requested but the datasets hold only 151" in capsys.readouterr().err
    assert main(base + ["--m", "8,4", "--out", str(tmp_path / "b")]) == 2
    assert "m_values: expected distinct positive sample counts in increasing order" in capsys.readouterr().err
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()
    out = tmp_path / "c"
    assert main(base + ["--folds", "1", "--train", "8", "--test", "2", "--m", "3,6", "--methods",
                        "frost,nielsen,random,uniform", "--nielsen-trials", "1", "--nielsen-max-iter", "2",
                        "--out", str(out)]) == 0
    payload = json.loads((out / "results.json").read_text())
    assert set(payload) == {"machine", "command", "config", "rows"} and payload["machine"]["cores"] >= 1
    assert "--m 3,6" in payload["command"] and "--grid 12,12,24" in payload["command"]
    rows = payload["rows"]
    assert len(rows) == 4 * 2 * 2
    for r in rows:
        assert list(r) == list(ROW_FIELDS)
        assert isinstance(r["m"], int) and isinstance(r["fold"], int) and isinstance(r["trial"], int)
        assert all(isinstance(r[k], float) for k in ("mse", "select_s", "recon_s"))
    with open(out / "results.csv", newline="") as f:
        csv_rows = list(csv.DictReader(f))
    assert [c["material"] for c in csv_rows] == [r["material"] for r in rows]
    assert [float(c["mse"]) for c in csv_rows] == [r["mse"] for r in rows]
    pngs = sorted(out.glob("*.png"))
    assert [p.name for p in pngs] == ["box_m6.png", "frontier.png", "inverse_mse.png", "selection_time.png"]
    assert all(0 < p.stat().st_size < 200_000 for p in pngs)
    assert (out / "folds" / "fold-00.json").is_file()


def test_summary_markdown_time_ratios_keep_two_digits():
    """Nielsen / FROST ratios below 1 must not round to "0x" (both FROST forms are given)."""
    from goniofrost.bench.results import summary_markdown

    rows = [dict(method=method, m=20, fold=0, trial=0, material="a", mse=0.1, select_s=select_s, recon_s=0.01)
            for method, select_s in (("frost", 7.3), ("frost-firstm", 0.54), ("nielsen", 2.86))]
    line = [l for l in summary_markdown(rows).splitlines() if l.startswith("| 20 |") and l.endswith("x |")][-1]
    assert line.endswith("| 0.39x | 5.3x |")


def test_bench_bars_are_drawn_on_a_terminal_only(config, tables, local_rows, tmp_path, capsys, monkeypatch):
    """A bar redrawn with carriage returns is noise in a log (core.progress): bench's own bars (the
    folds, the tabulation) asked for but with stderr not a terminal draw nothing."""
    import sys

    from goniofrost.bench.data import _tabulate_into
    from goniofrost.datasets import open_dataset

    names, path = tables
    done = {f: [r for r in local_rows if r["fold"] == f] for f in range(config.folds)}
    assert run_folds(config, path, names, progress=True, done=done) == local_rows
    _tabulate_into(tmp_path / "t.npy", [("builtin", "gold")], {"builtin": open_dataset("builtin")},
                   MerlGrid(4, 4, 8), progress=True)
    assert capsys.readouterr().err == ""
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True)
    run_folds(config, path, names, progress=True, done=done)
    assert capsys.readouterr().err.startswith("\rbench: ")


def test_resume_refuses_a_damaged_checkpoint_in_one_line(config, tmp_path, capsys):
    """bench --resume on a fold checkpoint cut short: one line naming the file, exit 2, before the
    tabulation and with nothing written (it was json's traceback, exit 1)."""
    folds = tmp_path / "out" / "folds"
    folds.mkdir(parents=True)
    (folds / "fold-00.json").write_text('{\n "config": {\n  "datasets": [\n   "nbrd')
    assert main(["bench", "--dataset", "nbrdf:/nonexistent.npz", "--grid", "12,12,24", "--folds", "1",
                 "--jobs", "1", "--no-progress", "--resume", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err == (f"goniofrost bench: error: {folds / 'fold-00.json'}: expected a fold checkpoint of goniofrost "
                   'bench ({"config", "fold", "rows"}), found JSONDecodeError: Unterminated string starting at: '
                   "line 4 column 4 (char 34); delete it to run that fold again\n")
    assert sorted(p.name for p in (tmp_path / "out").rglob("*")) == ["fold-00.json", "folds"]


def test_the_box_plot_of_an_earlier_run_of_another_m_is_not_left_beside_this_runs(tmp_path):
    """bench --out DIR again with other sample counts left the first run's box_m10.png beside
    the new box_m15.png, passing for this run's figure."""
    from goniofrost.bench.plots import write_plots

    def rows(m):
        return [dict(method="random", m=m, fold=0, trial=0, material=name, mse=mse, select_s=0.01, recon_s=0.01)
                for name, mse in (("a", 0.5), ("b", 0.7))]

    (tmp_path / "notes.png").write_bytes(b"")
    write_plots(tmp_path, rows(10))
    assert (tmp_path / "box_m10.png").is_file()
    write_plots(tmp_path, rows(15))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["box_m15.png", "frontier.png", "inverse_mse.png",
                                                         "notes.png", "selection_time.png"]


def test_the_summary_says_which_grid_its_times_are_of(config):
    """summary.md set selection times of a 15 x 15 x 30 run beside the paper's Table II (the full
    MERL grid) without saying either grid: the first line now says what the numbers are of."""
    from goniofrost.bench.results import summary_markdown

    rows = [dict(method="frost", m=4, fold=0, trial=0, material="a", mse=0.1, select_s=0.01, recon_s=0.01)]
    assert summary_markdown(rows, config=config.as_dict()).splitlines()[0] == (
        "Run: 2 folds of 10 training and 3 test materials on the 12 x 12 x 24 grid, 2,836 valid cells (the MERL "
        "grid of the paper's times: 1,111,432).")
    full = config.with_(grid=MerlGrid()).as_dict()
    assert summary_markdown(rows, config=full).splitlines()[0] == (
        "Run: 2 folds of 10 training and 3 test materials on the 90 x 90 x 180 grid, 1,111,432 valid cells.")


def test_resume_says_how_many_folds_it_takes_over_or_why_none(config, local_rows, tmp_path):
    """bench --resume after an option changed ran every fold again without a word, as it does when
    the checkpoints are of this run; now a line says which."""
    from goniofrost.bench.runner import load_checkpoints, resume_line, write_checkpoint

    folder = tmp_path / "folds"
    assert resume_line(tmp_path, config, {}) == f"resume: no fold checkpoint of these options in {folder} (none there): every fold runs"
    write_checkpoint(tmp_path, config, 0, [r for r in local_rows if r["fold"] == 0])
    done = load_checkpoints(tmp_path, config)
    assert resume_line(tmp_path, config, done) == f"resume: 1 of 2 folds from {folder}, 1 to run"
    other = config.with_(m_values=(4, 8, 12))
    assert resume_line(tmp_path, other, load_checkpoints(tmp_path, other)) == (
        f"resume: no fold checkpoint of these options in {folder} (1 there, of other options): every fold runs")


@pytest.mark.parametrize("grid, ms, found", [(MerlGrid(1, 1, 1), (1,), "1,1,1 with 1"),
                                             (MerlGrid(2, 2, 4), (5, 20), "2,2,4 with 16")])
def test_a_grid_too_small_for_the_sample_counts_is_refused_before_any_fold(config, grid, ms, found):
    """--grid 1,1,1 ended in a worker's traceback (max() of an empty sequence, exit 1) and --grid
    2,2,4 --m 5,20 in 'candidates: 16 allowed cells', both after a fold had trained."""
    need = max(max(ms), 5)
    with pytest.raises(BenchError) as refused:
        config.with_(grid=grid, m_values=ms)
    assert str(refused.value) == (f"benchmark option grid: expected at least {need} valid cells (the largest m, and "
                                  f"the 5 of training's smallest design), found {found!r}")


def test_the_target_table_names_m_max_and_says_its_saving_is_of_the_mean_sample_count():
    """Two captures of 15 and 60 samples of a plan of 60: the column headed "fewer than m_max"
    read 37.5 % (1 - 37.5 / 60), the saving of the mean sample count, where half the captures
    stopped early; m_max itself was named nowhere."""
    from goniofrost.bench.bayes_report import markdown

    rows = [dict(method="bayes-target", m=m, fold=0, trial=0, material=name, mse=0.04, select_s=0.01,
                 recon_s=0.01, target=0.05) for name, m in (("a", 15), ("b", 60))]
    lines = markdown(rows, {}, [20, 40, 60], {})
    at = lines.index("| E | materials | mean samples | median samples | mean samples below m_max | true error <= E | "
                     "true error > 1.5 E | mean true error |")
    assert lines[at - 2] == ("Simulated capture --target-error E --confidence 0.95 (batches of 15 then 5, up to "
                             "m_max = 60 samples):")
    assert lines[at + 2] == "| 0.05 | 2 | 37.5 | 38 | 37.5 % | 100.0 % | 0.0 % | 0.0400 |"
