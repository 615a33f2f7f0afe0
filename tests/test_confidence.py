"""The calibrated error bound and the out-of-model warning (frost.confidence): coverage on a
synthetic set whose truth is known, the conformal quantile, a material unlike the training set."""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from goniofrost.core.grid import MerlGrid
from goniofrost.frost import confidence, stopping
from goniofrost.frost.calibration import CvRecords, fit_calibration
from goniofrost.frost.prediction import Features, predict
from goniofrost.frost.reconstruction import error_bound

from conftest import trained_once
from test_frost import synthetic_tables

GRID = MerlGrid(10, 10, 20)
MS = (5, 10, 15, 20, 30, 40, 60)
BETA = np.array([0.3, 1.0, 0.5, 0.2, -0.1])  # the truth: log(actual) = x . BETA + material + noise


def synthetic_records(n_materials: int, seed: int, folds: int = 10, level_effect: float | None = None) -> CvRecords:
    """Records whose log error follows a known linear law in the features plus a per-material
    offset (a hard material is hard at every m) and per-(material, m) noise shrinking with m.
    level_effect: the records carry a level and spread, the material's level (the same at every m)
    adding level_effect * level to its log error (None: records without them)."""
    rng = np.random.default_rng(seed)
    m = np.tile(np.asarray(MS), n_materials)
    material = np.repeat(np.arange(n_materials), len(MS))
    design = np.exp(rng.normal(-4, 0.3, m.size)) * 20 / m
    z2, energy = np.exp(rng.normal(0, 0.5, m.size)), np.exp(rng.normal(0, 0.5, m.size))
    x = np.stack([np.ones(m.size), np.log(design), np.log(z2), np.log(energy), np.log(m)], axis=1)
    offset = rng.standard_t(5, n_materials)[material] * 0.3
    log_actual = x @ BETA + offset + rng.normal(0, 1, m.size) * 3.0 / np.sqrt(m)
    if level_effect is None:
        return CvRecords(fold=material % folds, material=material, m=m, actual=np.exp(log_actual),
                         design_error=design, z2=z2, energy=energy)
    level = rng.normal(0, 1, n_materials)[material]
    return CvRecords(fold=material % folds, material=material, m=m, actual=np.exp(log_actual + level_effect * level),
                     design_error=design, z2=z2, energy=energy, level=level, spread=np.exp(rng.normal(0, 0.3, m.size)))


def test_the_bound_covers_the_stated_fraction_of_new_materials_at_every_look_at_once():
    calibration = fit_calibration(synthetic_records(300, seed=1))
    fresh = synthetic_records(4000, seed=2)
    predicted = predict(calibration, Features(fresh.design_error, fresh.z2, fresh.energy, fresh.m))
    looks = fresh.m >= confidence.FIRST_LOOK
    for level in (0.8, 0.9, 0.95):
        b = confidence.error_bounds(calibration, predicted, fresh.z2, fresh.energy, fresh.m, level)
        covered = (fresh.actual <= b["upper"]).reshape(4000, len(MS))[:, looks[:len(MS)]]
        simultaneous = covered.all(axis=1).mean()  # every look of a material at once
        # conformal: at least the level (up to the calibration set's own sampling, 300 materials)
        assert level - 0.025 <= simultaneous <= level + 0.04, (level, simultaneous)
        assert covered.mean(axis=0).min() >= simultaneous  # one look alone is covered more often
    # the median estimate is the median: about half the errors above it at each m
    b = confidence.error_bounds(calibration, predicted, fresh.z2, fresh.energy, fresh.m, 0.95)
    for m in MS:
        assert 0.45 <= np.mean(fresh.actual[fresh.m == m] <= b["median"][fresh.m == m]) <= 0.55
    # in-range features are never out of the model
    assert not (b["out_of_model_z2"] | b["out_of_model_energy"]).any()


def test_a_material_feature_the_calibration_learns_narrows_the_bound_at_the_same_coverage():
    # the truth depends on the samples' level: fitted with it, the bound is as sure and tighter
    train, fresh = synthetic_records(300, seed=3, level_effect=0.8), synthetic_records(4000, seed=4, level_effect=0.8)
    blind = CvRecords(**{k: getattr(train, k) for k in ("fold", "material", "m", "actual", "design_error", "z2", "energy")})
    looks = np.isin(fresh.m, [m for m in MS if m >= confidence.FIRST_LOOK])
    widths = []
    for calibration, kwargs in ((fit_calibration(train), {"level": fresh.level, "spread": fresh.spread}),
                                (fit_calibration(blind), {})):
        predicted = predict(calibration, Features(fresh.design_error, fresh.z2, fresh.energy, fresh.m, **kwargs))
        b = confidence.error_bounds(calibration, predicted, fresh.z2, fresh.energy, fresh.m, 0.9)
        covered = (fresh.actual <= b["upper"])[looks].reshape(4000, -1).all(axis=1).mean()
        # conformal coverage given 300 calibration materials is Beta-distributed, sd 0.017: 2 sd
        assert 0.865 <= covered <= 0.935, covered
        widths.append(np.median(np.log(b["upper"] / fresh.actual)[looks]))
    assert widths[0] < widths[1] - 0.3, widths


def test_the_feature_distance_is_beyond_one_for_five_percent_of_typical_materials_and_for_an_unlike_one():
    calibration = fit_calibration(synthetic_records(300, seed=5, level_effect=0.5))
    fresh = synthetic_records(4000, seed=6, level_effect=0.5)
    for m in (15, 30, 60):
        at = fresh.m == m
        d = confidence.feature_distance(calibration, fresh.z2[at], fresh.energy[at], fresh.level[at],
                                        fresh.spread[at], m)
        assert 0.03 <= np.mean(d > 1) <= 0.08, (m, np.mean(d > 1))
    # typical z2 and energy, but a level 6 standard deviations off: far
    assert confidence.feature_distance(calibration, 1.0, 1.0, 6.0, 1.0, 20) > 3
    # a calibration without the samples' level and spread cannot say
    assert np.isnan(confidence.feature_distance(fit_calibration(synthetic_records(50, seed=7)), 1.0, 1.0, 0.0, 1.0, 20))


def test_the_conformal_quantile_and_what_too_few_materials_support():
    scores = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6]  # n = 6
    assert confidence.conformal_quantile(scores, 0.5) == 0.4  # ceil(7 * 0.5) = 4th smallest
    assert confidence.conformal_quantile(scores, 6 / 7) == 0.6
    assert confidence.conformal_quantile(scores, 0.9) == math.inf  # ceil(6.3) = 7 > 6
    calibration = {"bound": {"scores": scores}}
    assert confidence.max_confidence(calibration["bound"]) == pytest.approx(6 / 7)
    assert confidence.unavailability(calibration, 0.95) == ("the model's 6 held-out training materials support a "
                                                            "confidence of at most 0.857; 0.95 needs 19")
    assert confidence.unavailability({}, 0.95).startswith("the model has no calibrated error bound")


@pytest.fixture(scope="module")
def model(small_trained):
    """The model of 40 synthetic materials (seed 3) on GRID, trained once per test process."""
    return small_trained[0]


def test_a_trained_model_holds_its_bound_and_flags_a_material_unlike_its_training_set(model):
    bound = model.noise["calibration"]["bound"]
    assert len(bound["scores"]) == 40 and bound["looks"][0] == confidence.FIRST_LOOK
    rng = np.random.default_rng(5)
    positions = rng.choice(GRID.n_valid, 20, replace=False)
    like = synthetic_tables(GRID, 1, seed=11)[0].astype(np.float64)  # the training set's kind
    usual = error_bound(model, positions, like[positions], confidence=0.95)
    assert usual.out_of_model == () and usual.median < usual.upper < math.inf
    # unlike every training material: a BRDF that jumps by a factor 100 from cell to cell
    unlike = like * np.where(rng.random((GRID.n_valid, 1)) < 0.5, 0.1, 10.0)
    odd = error_bound(model, positions, unlike[positions], confidence=0.95)
    assert "z2" in odd.out_of_model
    assert stopping.stop_reason(odd, target=1e9, done=20, total=40) is None  # measures on
    assert stopping.why_not_reached(odd, 1e9).startswith("the samples are unlike every training material")


def test_the_report_flags_an_out_of_model_reconstruction_as_an_extrapolation(model):
    from goniofrost.capture.report import extrapolation_section

    rng = np.random.default_rng(5)
    positions = rng.choice(GRID.n_valid, 20, replace=False)
    like = synthetic_tables(GRID, 1, seed=11)[0].astype(np.float64)
    unlike = like * np.where(rng.random((GRID.n_valid, 1)) < 0.5, 0.1, 10.0)
    inputs = SimpleNamespace(model=model, positions=positions)

    def records(table):
        return [SimpleNamespace(plan_index=i, rgb=tuple(table[p]), sigma=tuple(0.001 * table[p]))
                for i, p in enumerate(positions)]

    assert extrapolation_section(inputs, records(like)) == {"extrapolation": False, "out_of_model": [],
                                                            "out_of_model_features": []}
    flagged = extrapolation_section(inputs, records(unlike))
    assert flagged["extrapolation"] and "z2" in flagged["out_of_model"]
    assert "leave-one-out residuals" in flagged["out_of_model_features"]


@pytest.fixture
def fit_once(monkeypatch):
    """goniofrost's fit_model made once per test run for each set of inputs (``trained_once``, keyed
    by a hash of them): the benchmark's plain and rig runs below both fit the same model of the
    builtin fold's 64 materials first (7-9 s of CPU)."""
    import hashlib
    import pickle

    from goniofrost.frost import training

    fit = training.fit_model

    def once(tables, names, *args, **options):
        key = hashlib.sha256(np.ascontiguousarray(tables).tobytes() + pickle.dumps((list(names), args, options)))
        return trained_once(f"fit-{key.hexdigest()[:16]}", lambda: fit(tables, names, *args, **options))

    monkeypatch.setattr(training, "fit_model", once)


def test_the_benchmark_runs_at_its_smallest_setting(tmp_path, fit_once):
    """benchmarks/target_error.py on one builtin fold of a small grid: every target's row, the
    per-m rows, and what it promised held for the materials it stopped on."""
    import importlib.util
    import json
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "benchmarks" / "target_error.py"
    spec = importlib.util.spec_from_file_location("target_error_bench", path)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    assert bench.main(["--grid", "10,10,20", "--folds", "1", "--settings", "builtin", "--m-max", "20",
                       "--out", str(tmp_path)]) == 0
    doc = json.loads((tmp_path / "target_error.json").read_text())
    stats = doc["summary"]["builtin"]
    # every target without and with the sentinels (3 more samples, measured with the first batch), and
    # without them with every other kind of bound
    assert sorted((r["target"], r["sentinels"], r["bound"]) for r in stats["targets"].values()) == [
        (t, s, k) for t in (0.01, 0.02, 0.05) for s, k in ((False, "normalised"), (False, "per-look"),
                                                            (False, "per-look-tuned"), (False, "split"),
                                                            (True, "split"))]
    for row in stats["targets"].values():  # the efficiency beside the coverage
        assert 0 <= row["clearly_could_stopped"] <= row["clearly_could"] <= row["materials"]
        assert row["oracle_materials"] <= row["materials"] and set(row["bound_over_actual"]) == {"20", "40"}
        assert row["over_oracle"] is None or row["over_oracle"] * row["oracle_samples"] == \
            pytest.approx(row["samples_used"])
        assert row["oracle_samples"] is None or 15 <= row["oracle_samples"] <= 20
    assert sorted(int(m) for m in stats["by_m"]) == [15, 20]
    for row in stats["targets"].values():
        extra = 3 if row["sentinels"] else 0
        assert row["materials"] == 10 and 15 + extra <= row["mean_samples"] <= 20 + extra
        assert row["within_when_stopped"] is None or row["within_when_stopped"] >= 0.9
        assert row["sentinel_flagged"] == 0 or row["sentinels"]
    stops = doc["results"]["builtin"][0]["stops"]
    assert all(s["upper"] <= s["target"] for s in stops if s["reached"])  # stopped on the bound only
    assert "| builtin | 0.05 | no | 10 |" in (tmp_path / "target_error.md").read_text()
    for row in stats["by_m"].values():  # every material is a miss of the bound or not, near or far
        assert row["missed_far"] <= row["missed"] and row["covered_far"] <= row["materials"] - row["missed"]
        assert row["missed_prequential"] <= row["missed"] and row["covered_prequential"] <= row["materials"] - row["missed"]
        assert row["missed_sentinel"] <= row["missed"] and row["covered_sentinel"] <= row["materials"] - row["missed"]
    assert all(np.isfinite(r["feature_distance"]) for r in doc["results"]["builtin"][0]["per_m"])


def test_the_benchmark_on_a_rig_measures_its_sentinels_where_the_rig_reaches(tmp_path, fit_once):
    """target_error.py --rig: the design and the sentinels among the rig's cells, three variants;
    the rig-calibrated model's sentinels are the cells the plan measures."""
    import importlib.util
    import json
    from pathlib import Path

    from goniofrost.rig.file import load_checked_rig
    from goniofrost.core.grid import MerlGrid
    from planner.reach import reachability

    repo = Path(__file__).resolve().parents[1]
    spec = importlib.util.spec_from_file_location("target_error_bench", repo / "benchmarks" / "target_error.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    rig = repo / "goniofrost" / "rigs" / "sim.yaml"
    assert bench.main(["--grid", "10,10,20", "--folds", "1", "--settings", "builtin", "--m-max", "20",
                       "--rig", str(rig), "--out", str(tmp_path)]) == 0
    doc = json.loads((tmp_path / "target_error.json").read_text())
    assert sorted({(r["target"], r["sentinels"]) for r in doc["summary"]["builtin"]["targets"].values()}) == [
        (t, v) for t in (0.01, 0.02, 0.05) for v in ("approx", "no", "rig")]
    cells = doc["results"]["builtin"][0]["sentinel_cells"]
    mask = reachability(load_checked_rig(rig), MerlGrid(10, 10, 20)).mask
    assert cells["rig_placed"] == cells["rig_calibrated"] and mask[cells["rig_placed"]].all()
    assert not mask[cells["whole_grid"]].all()  # the whole grid's sentinels are beyond this rig
    assert "| builtin | 0.05 | rig | 10 |" in (tmp_path / "target_error.md").read_text()
    # the test materials simulated 3 at a time: the same rows in the same order, the same summary;
    # the floats within float32 products blocked differently (the reconstruction's float32 values
    # differ by ~6e-8, a log error of ~0.02 rms by ~3e-6 of itself)
    bench.CHUNK = 3
    assert bench.main(["--grid", "10,10,20", "--folds", "1", "--settings", "builtin", "--m-max", "20",
                       "--rig", str(rig), "--out", str(tmp_path / "chunks")]) == 0
    chunked = json.loads((tmp_path / "chunks" / "target_error.json").read_text())
    assert chunked["summary"] == doc["summary"]
    for part in ("stops", "per_m"):
        whole, parts = doc["results"]["builtin"][0][part], chunked["results"]["builtin"][0][part]
        assert [(r["material"], r.get("target"), r.get("sentinels"), r.get("m")) for r in parts] == [
            (r["material"], r.get("target"), r.get("sentinels"), r.get("m")) for r in whole]
        for a, b in zip(whole, parts):
            assert {k: v if isinstance(v, str) else pytest.approx(v, rel=1e-5, nan_ok=True) for k, v in a.items()} == b


def test_the_prequential_errors_are_the_batch_posteriors_predictions_of_each_next_sample():
    from goniofrost.frost import posterior

    rng = np.random.default_rng(8)
    rows, noise = rng.normal(size=(12, 6)), np.exp(rng.normal(-2, 0.5, 12))
    prior, b = np.full(6, 0.3), rng.normal(size=(12, 4))
    one_step = posterior.prequential_errors(rows, noise, prior, b)
    assert one_step[0] == pytest.approx(b[0] ** 2 / (noise[0] + rows[0] ** 2 @ prior), rel=1e-12)  # the prior's
    for k in (1, 5, 11):  # the posterior of the first k samples (``fit``) predicting sample k
        post = posterior.fit(rows[:k], noise[:k], prior, b[:k], np.ones(6), 1.0, 1)
        mean, var = rows[k] @ post.coefficients, noise[k] + rows[k] @ post.covariances[0] @ rows[k]
        np.testing.assert_allclose(one_step[k], (b[k] - mean) ** 2 / var, rtol=1e-9)
    # samples drawn from the model itself: the standardized errors average 1 (chi-square, 1 dof)
    big = rng.normal(size=(40, 6))
    truth = rng.normal(size=(6, 2000)) * np.sqrt(prior)[:, None]
    draws = big @ truth + rng.normal(size=(40, 2000)) * 0.2
    mean = posterior.prequential_errors(big, np.full(40, 0.04), prior, draws).mean()
    assert abs(mean - 1.0) < 0.02, mean


def test_the_prequential_score_skips_the_priors_prediction_and_reads_the_materials_columns():
    from goniofrost.frost.prediction import prequential_score

    one_step = np.array([[100.0, 0.0, 0.0, 7.0], [1.0, 2.0, 3.0, 7.0], [3.0, 4.0, 5.0, 7.0]])
    assert prequential_score(one_step, [0, 1, 2]) == 3.0
    assert prequential_score(one_step[:1], [0, 1, 2]) == 1.0  # one sample: nothing predicted yet


def test_a_trained_model_records_its_held_out_materials_prequential_scores(model):
    bound = model.noise["calibration"]["bound"]
    assert len(bound["log_prequential_q95"]) == len(bound["m"])
    calibration = model.noise["calibration"]
    # at the 95th percentile: exactly 1; a score 3 x as large: 3 (interpolated between the m)
    q = math.exp(bound["log_prequential_q95"][2])
    assert confidence.prequential_excess(calibration, [q, 3 * q], bound["m"][2]) == pytest.approx([1.0, 3.0])
    assert np.isnan(confidence.prequential_excess({"bound": {"scores": [1.0]}}, 1.0, 20))


def test_plan_max_error_chooses_its_length_on_the_bound_a_capture_stops_on(model, tmp_path, capsys):
    """plan --max-error E (bayes) ends at the first pick whose typical material's bound at the plan's
    confidence is <= E: a capture of that material (the assessor's ``error_bound``: the same
    features, its samples along that plan) stops there with --target-error E, not one batch before;
    the command prints that bound and the training materials' spread. The model's 40 synthetic
    materials and a test material of the same kind have known truths."""
    from goniofrost.app.cli import main
    from goniofrost.bench.bayes_eval import target_outcomes
    from goniofrost.frost.bayes_selection import select_bayes, typical_bound
    from goniofrost.frost.prediction import calibration_of

    calibration = calibration_of(model)
    full = select_bayes(model, 40, confidence=0.95)  # a design of m picks: its first m are the m-pick design
    assert full.bounds.shape == (40,)
    target = float(full.bounds[19])  # the typical material's bound after 20 picks
    plan = select_bayes(model, max_error=target, confidence=0.95)
    first = int(np.argmax(full.bounds <= target)) + 1
    assert plan.m == first and plan.bounds[-1] <= target < plan.bounds[-2]
    assert list(plan.positions) == list(full.positions[:first])
    # the bound is the capture's: confidence.error_bounds of a typical material's prediction at m
    for m in (first - 1, first):
        said = typical_bound(calibration, plan.residuals[m - 1], m, 0.95)
        assert said == pytest.approx(plan.bounds[m - 1], rel=1e-12)
        bound = confidence.ErrorBound(float(plan.residuals[m - 1]), float(said), 0.95)
        stopped = stopping.stop_reason(bound, target, m, first) == stopping.REASON_TARGET
        assert stopped == (m == first)  # plan and capture agree on where the target is reached
    # a point prediction alone would have chosen a shorter plan (the 25 samples for 0.02)
    assert int(np.argmax(full.residuals <= target)) + 1 < first
    # materials of the training set's kind, truth known: captured along the plan at --target-error
    truth = synthetic_tables(GRID, 6, seed=11).astype(np.float64)
    out = target_outcomes(model, np.asarray(plan.positions), truth, model.to_log(truth), target, 0.95)
    assert out["samples"].max() <= first and all(out["mse"][out["reached"] == 1] <= target)
    # the command: the same length, the bound it chose on and the training materials' spread
    model.save(tmp_path / "model")
    assert main(["plan", "--model", str(tmp_path / "model"), "--max-error", f"{target!r}", "--no-sentinels",
                 "--out", str(tmp_path / "plan.json")]) == 0
    lines = capsys.readouterr().out.splitlines()
    spread = confidence.training_spread(calibration, first, 0.95)
    assert lines[-1] == (f"a typical material at {first} samples: "
                         f"{confidence.figure(plan.bounds[-1], 0.95, plan.residuals[-1])}; the training materials' "
                         f"bounds at {first} samples: 10 % {spread[0]:.3g}, median {spread[1]:.3g}, 90 % {spread[2]:.3g}")
    assert spread[0] <= spread[1] <= spread[2]
    assert main(["plan", "--model", str(tmp_path / "model"), "--samples", "5", "--confidence", "0.9",
                 "--out", str(tmp_path / "p2.json")]) == 2
    assert capsys.readouterr().err.strip().endswith("--confidence applies to --max-error with --selector bayes "
                                                    "without --usage (the confidence of the bound the plan's length "
                                                    "is chosen on)")


@pytest.mark.parametrize("confidence", [0.5, 0.8, 0.9, 0.95, 0.99, 0.9999])
def test_the_scores_a_confidence_needs_are_the_fewest_whose_quantile_is_finite(confidence):
    from goniofrost.frost.confidence import conformal_quantile, scores_needed

    n = scores_needed(confidence)
    assert n == round(confidence / (1 - confidence))   # 0.9999 needs 9999, not the float's 10000
    assert conformal_quantile(list(range(n)), confidence) == n - 1
    assert n == 1 or conformal_quantile(list(range(n - 1)), confidence) == math.inf
