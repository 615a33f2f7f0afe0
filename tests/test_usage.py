"""Scene-aware design: a scene's usage map recorded by the real Mitsuba 3, and plan --usage."""
from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from goniofrost.app.cli import main
from goniofrost.core.grid import FULL_GRID, MerlGrid

from conftest import train_once

REPO = Path(__file__).resolve().parents[1]
SCENES = REPO / "config" / "scenes"
GRID = MerlGrid(30, 30, 60)
pytest.importorskip("mitsuba")


def _llvm_missing() -> str | None:
    """Why Mitsuba's LLVM variant (the tabulated BSDF's) cannot run here, or None."""
    from goniofrost.brdf.drjit_llvm import name_newest_llvm

    try:
        name_newest_llvm("llvm_ad_rgb", environ=dict(os.environ))
    except RuntimeError as exc:
        return str(exc)
    return None


# as the browser tests without Chromium: skipped, saying why (.ci/run installs Debian's libllvm19)
needs_llvm = pytest.mark.skipif(_llvm_missing() is not None, reason=str(_llvm_missing()))


@pytest.fixture(scope="module")
def model():
    """Five built-in materials on GRID, k <= 15: trained once per test run (test_usage's and
    test_sequential_design's)."""
    return train_once("five-materials", ["builtin"], only=["white-diffuse", "blue-plastic", "gold", "green-felt",
                                                            "red-plastic"], grid=GRID, k_max=15)


@pytest.fixture
def p1_up_to_14(monkeypatch):
    """Every scene's power 1 up to 14 samples (the first band's count of effective cells patched to
    0): the tests of the p = 1 design with its floor and of the phases of an error target. On this
    grid (42k valid cells) the shipped 3,300 cells, counted on the full grid's 1.1 million, leave a
    small map p = 0.5 (issue 29 round 11)."""
    from goniofrost.frost import usage_design

    monkeypatch.setitem(usage_design.BAND_POWERS, usage_design.FEW_SAMPLES, (usage_design.POWERS_FEW, 0.0))


@pytest.fixture(scope="module")
def model_dir(model):
    from goniofrost.core.cache import cache_path

    return cache_path("models", model.info["cache_key"], "")


def test_a_scene_lit_from_the_camera_uses_the_brdf_near_retro_reflection(tmp_path, capsys):
    out = tmp_path / "retro.npy"
    assert main(["usage", "--scene", str(SCENES / "retro-sphere.xml"), "--object", "sample", "--out", str(out),
                 "--spp", "4"]) == 0
    usage = np.load(out)
    assert usage.dtype == np.float32 and usage.shape == (FULL_GRID.n_valid,)
    assert usage.sum() == pytest.approx(1.0, abs=1e-5) and usage.min() >= 0
    _, theta_d, _ = FULL_GRID.flat_angles(FULL_GRID.valid_cells)
    assert usage[np.degrees(theta_d) < 5].sum() > 0.9  # the light sits 0.7 deg from the lens
    assert "light/view pairs of 'sample'" in capsys.readouterr().out


def test_a_grazing_view_puts_the_mass_at_grazing_angles():
    from goniofrost.brdf.mitsuba_usage import record_usage

    usage, _ = record_usage(SCENES / "grazing-plane.xml", "sample", spp=2, grid=GRID)
    w_i, w_o = GRID.cell_directions(GRID.valid_cells)
    grazing = np.minimum(w_i[:, 2], w_o[:, 2]) < np.cos(np.radians(65))
    assert usage[grazing].sum() > 0.6  # the camera looks 80 deg off the normal


AREA_LIGHT_SCENE = """<scene version="3.0.0">
    <integrator type="path"><integer name="max_depth" value="3"/></integrator>
    <sensor type="perspective">
        <float name="fov" value="20"/>
        <transform name="to_world"><lookat origin="0, -3, 3" target="0, 0, 0" up="0, 0, 1"/></transform>
        <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/></film>
    </sensor>
    <shape type="rectangle" id="sample"><bsdf type="diffuse"/></shape>
    <shape type="rectangle">
        <transform name="to_world"><scale value="0.5"/><rotate x="1" angle="180"/><translate z="4"/></transform>
        <emitter type="area"><rgb name="radiance" value="1"/></emitter>
    </shape>
</scene>"""


def test_a_bsdf_sample_counts_only_when_its_ray_reaches_the_light(tmp_path):
    """A flat sample under a small area light 4 above it (half-size 0.5): of the BSDF samples only
    those whose rays hit the light are kept, so every kept direction is within atan(2 sqrt(2) / 4)
    of the normal (the sample spans [-1, 1]^2), and most samples (cosine-distributed) are dropped."""
    import xml.etree.ElementTree as ET

    from goniofrost.brdf import mitsuba_usage as mu

    path = tmp_path / "area.xml"
    path.write_text(AREA_LIGHT_SCENE)
    mi = mu._mitsuba()
    scene = mu.load_scene(path, "sample", ET.Element("bsdf", {"type": mu.RECORDER}), keep_inner=True)
    recorder = mu._find_shape(scene, "sample").bsdf()
    mi.render(scene, spp=4)
    seen_without = len(recorder.sampled)  # no scene given: every sample counts
    recorder.scene, recorder.sampled = scene, []
    mi.render(scene, spp=4)
    kept = np.asarray(recorder.sampled).reshape(-1, 6)
    assert 0 < len(kept) < 0.2 * seen_without
    assert kept[:, 5].min() > np.cos(np.arctan(2 * np.sqrt(2) / 4))


@pytest.mark.parametrize("scene, obj, message", [
    ("retro-sphere.xml", "teapot", "no shape with id 'teapot' (shapes with an id: sample)"),
    ("missing.xml", "sample", "missing.xml: scene file not found"),
])
def test_a_scene_without_the_object_or_file_is_one_line_exit_2(tmp_path, capsys, scene, obj, message):
    out = tmp_path / "u.npy"
    assert main(["usage", "--scene", str(SCENES / scene), "--object", obj, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0] and not out.exists()


def test_a_scene_mitsuba_cannot_load_is_one_line_exit_2(tmp_path, capsys):
    scene = tmp_path / "bad.xml"
    scene.write_text('<scene version="3.0.0"><shape type="nosuchshape" id="sample"/></scene>')
    assert main(["usage", "--scene", str(scene), "--object", "sample", "--out", str(tmp_path / "u.npy")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Mitsuba cannot load the scene" in err[0]


def test_plan_with_a_uniform_usage_map_equals_the_plain_design(model, model_dir, tmp_path, capsys):
    uniform = tmp_path / "uniform.npy"
    np.save(uniform, np.full(GRID.n_valid, 1.0 / GRID.n_valid, dtype=np.float32))
    plain, scene = tmp_path / "plain.json", tmp_path / "scene.json"
    assert main(["plan", "--model", str(model_dir), "--samples", "12", "--out", str(plain)]) == 0
    assert main(["plan", "--model", str(model_dir), "--samples", "12", "--usage", str(uniform), "--out", str(scene)]) == 0
    cells = [[s["cell"] for s in json.loads(p.read_text())["samples"]] for p in (plain, scene)]
    assert cells[0] == cells[1]


def test_plan_times_the_selection_without_the_scenes_calibration(model_dir, tmp_path, capsys, monkeypatch):
    """The scene's calibration on the training materials (a minute on the full grid) ran inside the
    selection's clock: plan --usage printed "selection 57.513 s" where the plain plan's took 0.4 s.
    On a fake clock that only the calibration advances (60 s), the selection's own time is 0."""
    import time

    from goniofrost.plan import make

    now = [1000.0]
    real = make._scene_error

    def calibrating(*args, **kwargs):
        now[0] += 60.0
        return real(*args, **kwargs)

    monkeypatch.setattr(time, "perf_counter", lambda: now[0])
    monkeypatch.setattr(make, "_scene_error", calibrating)
    uniform, out = tmp_path / "uniform.npy", tmp_path / "scene.json"
    np.save(uniform, np.full(GRID.n_valid, 1.0 / GRID.n_valid, dtype=np.float32))
    assert main(["plan", "--model", str(model_dir), "--samples", "12", "--usage", str(uniform),
                 "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["selection_seconds"] == 0.0 and "calibration_seconds" not in doc["usage"]
    assert capsys.readouterr().out.splitlines()[-1].endswith(", selection 0.000 s (and 60.0 s calibrating the "
                                                             "scene's error)")


def test_the_rotated_basis_with_a_uniform_map_picks_as_the_plain_design(model):
    """The change of basis itself (not the shortcut) is exact: same picks, same predicted errors."""
    from goniofrost.frost.bayes_selection import select_bayes
    from goniofrost.frost.usage_design import SceneDesign

    uniform = np.full(GRID.n_valid, 1.0 / GRID.n_valid)
    plain = select_bayes(model, 10)
    rotated = select_bayes(model, 10, scene=SceneDesign(uniform, uniform_is_plain=False))
    assert plain.positions.tolist() == rotated.positions.tolist()
    np.testing.assert_allclose(rotated.residuals, plain.residuals, rtol=1e-4)


def test_a_scene_design_lowers_the_error_of_what_the_scene_sees(model):
    """On a map that uses only near-retro-reflection cells, the part of the expected weighted error
    a design can change, trace(M Sigma), is well below the scene-blind design's (the rest,
    sum u sigma^2, is the model's own floor)."""
    from goniofrost.frost.bayes_selection import select_bayes
    from goniofrost.frost.posterior import cell_noise, design_scale, prior_variance
    from goniofrost.frost.usage_design import SceneDesign, scene_matrix

    _, theta_d, _ = GRID.flat_angles(GRID.valid_cells)
    usage = np.where(np.degrees(theta_d) < 10, 1.0, 0.0)
    usage /= usage.sum()
    noise = cell_noise(model) * design_scale(model)  # the noise the design assumes

    def weighted_error(rows):
        d = np.asarray(model.dictionary[rows], np.float64)
        sigma = np.linalg.inv(np.diag(1 / prior_variance(model)) + d.T @ (d / noise[rows, None]))
        return float(np.trace(scene_matrix(model.dictionary, usage) @ sigma))

    # this 5-material model has about six effective atoms: both designs pin them down by m = 8,
    # so the scene's gain shows at few samples and the scene design is never worse after
    # (sensitivity_power=0: the design of this mapped error itself; the default weighs the image's
    # sensitivity too, tested below)
    ratios = {m: weighted_error(select_bayes(model, m, scene=SceneDesign(usage, sensitivity_power=0)).positions)
              / weighted_error(select_bayes(model, m).positions) for m in (4, 8, 15, 30)}
    assert ratios[4] < 0.8 and max(ratios.values()) <= 1.0, ratios


def test_the_scene_design_weighs_the_sensitivity_and_predicts_the_error_of_the_use_alone(model, p1_up_to_14):
    """The default design of m samples is the mapped-error design of u g^p with p the power for m
    (``sensitivity_power``; 1 at 12 samples), while its predicted errors stay those of u: the same
    as the prediction from trace(M_u Sigma) of its picks."""
    from goniofrost.frost.bayes_selection import select_bayes
    from goniofrost.frost.posterior import cell_noise, prior_variance
    from goniofrost.frost.prediction import calibration_of, predict_typical
    from goniofrost.frost.usage_design import SceneDesign, design_usage, scene_matrix, sensitivity_power

    _, theta_d, _ = GRID.flat_angles(GRID.valid_cells)
    usage = np.where(np.degrees(theta_d) < 10, 1.0, 0.0)
    usage /= usage.sum()
    assert sensitivity_power(12) == 1.0
    weights = design_usage(model, usage, 1.0)
    g = np.exp(np.asarray(model.mean, np.float64)) * (np.asarray(model.reference, np.float64) + model.eps) \
        / np.asarray(model.weight, np.float64)
    np.testing.assert_allclose(weights, usage * g / np.sum(usage * g), rtol=1e-12)
    np.testing.assert_allclose(design_usage(model, usage, 0.25), usage * g ** 0.25 / np.sum(usage * g ** 0.25),
                               rtol=1e-12)
    assert design_usage(model, usage, 0.0) is usage
    uniform = np.full(GRID.n_valid, 1.0 / GRID.n_valid)
    assert np.array_equal(design_usage(model, uniform, 1.0), uniform)  # no scene: the plain design's weights

    aware = select_bayes(model, 12, scene=SceneDesign(usage))
    weighted, unweighted = SceneDesign(weights, sensitivity_power=0), SceneDesign(usage, sensitivity_power=0)
    assert aware.positions.tolist() == select_bayes(model, 12, scene=weighted).positions.tolist()
    assert aware.positions.tolist() != select_bayes(model, 12, scene=unweighted).positions.tolist()
    noise, m_u = cell_noise(model), scene_matrix(model.dictionary, usage)
    expected = []
    for m in range(1, 13):
        d = np.asarray(model.dictionary[aware.positions[:m]], np.float64)
        sigma = np.linalg.inv(np.diag(1 / prior_variance(model)) + d.T @ (d / noise[aware.positions[:m], None]))
        expected.append(predict_typical(calibration_of(model), float(np.sum(m_u * sigma) + usage @ noise), m))
    np.testing.assert_allclose(aware.residuals, expected, rtol=1e-4)


def test_the_sensitivity_power_and_prior_spread_follow_the_number_of_samples():
    """The choices on validation materials (round 7: t = 1; round 8: p = 1 at m = 10 with t up to 1
    and a floor on the effective cells; round 10, on the seeded ones: the floor 6,000 at m = 10 and
    from 15 samples the last band's powers, 0.5 the least), each m taking the choice of the nearest
    of them on a log scale (boundaries sqrt(10 * 20) = 14.1 and sqrt(20 * 40) = 28.3). p = 0.25 (the
    band 15-28 before round 10) is no band's now."""
    from goniofrost.frost.usage_design import (BAND_POWERS, FEW_SAMPLES, MANY_SAMPLES, floor_of_power, prior_spread,
                                               sensitivity_power, spread_floor, spread_of_power)

    assert FEW_SAMPLES == int(np.sqrt(10 * 20)) and MANY_SAMPLES == int(np.sqrt(20 * 40))
    assert [sensitivity_power(m) for m in (1, 6, 10, 12, 14)] == [1.0] * 5
    assert [sensitivity_power(m) for m in (15, 20, 24, 28, 29, 40, 60, 1000)] == [0.5] * 8
    assert [prior_spread(m) for m in (1, 10, 14, 15, 20, 28, 29, 40, 1000)] == [1.0] * 9
    assert [spread_floor(m) for m in (1, 10, 14, 15, 20, 28, 29, 40, 1000)] == [6000.0] * 3 + [0.0] * 6
    assert [spread_of_power(p) for p in (1.0, 0.25, 0.5, 0.75, 2.0)] == [1.0, 0.0, 1.0, 1.0, 0.0]
    assert [floor_of_power(p) for p in (1.0, 0.25, 0.5, 0.75, 2.0)] == [6000.0, 0.0, 0.0, 0.0, 0.0]
    # round 11: up to 14 samples a power per scene of 0.5, 0.75, 1 keeping 3,300 cells; the floor is p = 1's
    assert BAND_POWERS[FEW_SAMPLES] == ((0.5, 0.75, 1.0), 3300.0)
    assert [spread_floor(10, p) for p in (1.0, 0.75, 0.5)] == [6000.0, 0.0, 0.0]
    assert [spread_floor(20, p) for p in (1.0, 0.75, 0.5)] == [0.0] * 3
    for rule in (sensitivity_power, prior_spread, spread_floor):
        with pytest.raises(ValueError, match="positive integer"):
            rule(0)


def test_the_default_scene_design_of_m_samples_uses_the_power_for_m(model, p1_up_to_14):
    """select_bayes without a power (what plan --usage does) equals the design of the power for m:
    p = 1 at 14 samples, the scene's power at 15 (which differ, so the boundary is where the rule
    puts it)."""
    from goniofrost.frost.bayes_selection import select_bayes
    from goniofrost.frost.usage_design import SceneDesign, scene_power

    usage = retro_map()
    few, many = select_bayes(model, 14, scene=SceneDesign(usage)), select_bayes(model, 15, scene=SceneDesign(usage))
    assert few.positions.tolist() == select_bayes(model, 14, scene=SceneDesign(usage, sensitivity_power=1.0)
                                                  ).positions.tolist()
    assert many.positions.tolist() == select_bayes(
        model, 15, scene=SceneDesign(usage, sensitivity_power=scene_power(model, usage, 15))).positions.tolist()
    assert few.positions.tolist() != many.positions[:14].tolist()


def test_an_error_target_ends_on_the_design_of_its_own_length(model, p1_up_to_14):
    """plan --max-error --usage: the design of p = 1 (t up to 1, the floor) up to 14 picks; when it
    does not reach the target there, the design of the scene's power from 15 (t = 1, no floor) with
    more than 14. Either way the plan is the --samples n plan of its length n, and the design of
    n - 1 samples (its own power) does not reach it. The predicted errors use the scene's
    calibration of each design (p, t, F), as plan does."""
    from goniofrost.frost.bayes_selection import select_bayes
    from goniofrost.frost.usage_calibration import calibrate_scene
    from goniofrost.frost.usage_design import FLOOR_FEW, SceneDesign, scene_power

    usage = retro_map()
    later = (scene_power(model, usage, 15), 1.0, 0.0)
    calibrations = {design: calibrate_scene(model, usage, design[0], prior_spread=design[1], spread_floor=design[2])
                    for design in ((1.0, 1.0, FLOOR_FEW), later)}
    asked = set()

    def calibration(*design):
        asked.add(design)
        return calibrations[design]

    def select(m=None, max_error=None):
        return select_bayes(model, m, max_error=max_error, scene=SceneDesign(usage), calibration=calibration)

    few, many = select(14).residuals, select_bayes(model, 40, scene=SceneDesign(usage, sensitivity_power=later[0]),
                                                   calibration=calibrations[later]).residuals
    reached, beyond = min(few[:8]) * 1.0001, min(few) * 0.99  # in 8 picks of p = 1; not in 14
    assert beyond > many.min()  # the design of the later band does reach it
    for target, longer in ((reached, False), (beyond, True)):
        chosen = select(max_error=target)
        n = chosen.positions.size
        assert (n > 14) is longer
        same = select(n)
        assert chosen.positions.tolist() == same.positions.tolist()
        np.testing.assert_allclose(chosen.residuals, same.residuals, rtol=1e-12)
        assert chosen.residuals[-1] <= target < select(n - 1).residuals[-1]
    assert asked == set(calibrations)  # each band's design asked for its own calibration


def test_plan_with_an_error_target_and_a_usage_map_records_the_power_of_its_length(model, model_dir, tmp_path,
                                                                                     p1_up_to_14):
    """plan --max-error --usage: a target the design of p = 1 reaches within 14 samples gives a plan
    of p = 1, one it does not a longer plan of the scene's power from 15 samples (PLAN.json
    usage.sensitivity_power), each meeting the target by the scene's calibration of its own design."""
    from goniofrost.frost.bayes_selection import select_bayes
    from goniofrost.frost.usage_calibration import calibrate_scene
    from goniofrost.frost.usage_design import SceneDesign, scene_power

    usage, path = retro_map(), tmp_path / "retro.npy"
    np.save(path, usage.astype(np.float32))
    few = select_bayes(model, 14, scene=SceneDesign(usage), calibration=calibrate_scene(model, usage, 1.0)).residuals
    for target, power, longer in ((min(few[:8]) * 1.0001, 1.0, False),
                                  (min(few) * 0.99, scene_power(model, usage, 15), True)):
        out = tmp_path / f"plan-{power}.json"
        assert main(["plan", "--model", str(model_dir), "--max-error", f"{target:.9g}", "--usage", str(path),
                     "--out", str(out)]) == 0
        doc = json.loads(out.read_text())
        assert doc["usage"]["sensitivity_power"] == power and (len(doc["samples"]) > 14) is longer
        assert doc["predicted_errors"][-1] <= target


@pytest.mark.parametrize("array, message", [
    (np.ones(7, np.float32), "expected float weights of shape"),
    (np.full(GRID.n_valid, np.nan, np.float32), "weights are not finite"),
    (-np.ones(GRID.n_valid, np.float32), "weights are negative"),
    (np.zeros(GRID.n_valid, np.float32), "every weight is 0"),
    (np.ones(GRID.n_valid, np.int64), "expected float weights of shape"),
])
def test_bad_usage_files_are_refused_in_one_line(model_dir, tmp_path, capsys, array, message):
    path = tmp_path / "bad.npy"
    np.save(path, array)
    out = tmp_path / "plan.json"
    assert main(["plan", "--model", str(model_dir), "--samples", "5", "--usage", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0] and not out.exists()


def test_a_usage_file_that_is_not_npy_and_usage_with_frost_are_refused(model_dir, tmp_path, capsys):
    text = tmp_path / "u.npy"
    text.write_text("not numpy")
    out = tmp_path / "plan.json"
    assert main(["plan", "--model", str(model_dir), "--samples", "5", "--usage", str(text), "--out", str(out)]) == 2
    # numpy's own advice ("load it unsafely using allow_pickle") is not passed on
    assert capsys.readouterr().err.strip().endswith(f"{text}: not a usage map (.npy of float32 weights): not in "
                                                    "NumPy's .npy format")
    assert main(["plan", "--model", str(model_dir), "--samples", "5", "--usage", str(text), "--selector", "frost",
                 "--out", str(out)]) == 2
    assert "--usage applies to --selector bayes only" in capsys.readouterr().err
    assert not out.exists()


def scene_test_model(module, argv: list[str]) -> None:
    """Put the model the scene benchmark's test run trains with ``argv`` (of the training materials
    of its setting) in this process's cache, trained once per test run (``train_once``): the two
    tests below that make a test run trained the same model, 5-6 s of their CPU, when they ran
    in two workers."""
    specs, _, grid, training, *_ = module["setting"](module["parse"](argv))
    train_once("scene-test-model", specs, only=training, grid=grid)


@needs_llvm
def test_the_scene_design_benchmark_runs_at_its_smallest_setting(tmp_path):
    import runpy

    module = runpy.run_path(str(REPO / "benchmarks" / "scene_design.py"), run_name="scene_design")
    # the first of --smallest's 2 inner folds (--only-folds, the same fold model as in a run of both): the
    # loop over the folds is the same, the second fold trained and rendered another model for rows alike
    argv = ["--smallest", "--only-folds", "0", "--scenes", "retro-sphere", "--out", str(tmp_path)]
    scene_test_model(module, argv)
    assert module["main"](argv) == 0
    doc = json.loads((tmp_path / "results.json").read_text())
    val = json.loads((tmp_path / "validation.json").read_text())
    assert set(val["choice"]) == {"4"} and set(val["choice"].values()) <= set(module["CANDIDATES"])
    assert {r["design"] for r in val["rows"]} == {"blind", *module["CANDIDATES"]}
    assert not {r["material"] for r in val["rows"]} & set(doc["test"])  # the validation never sees a test material
    # the test renders: the shipped rule ("aware"), the rule before the hedge, the shipped rule before
    # round 9 (the band's power for every scene; at m = 4 the same design), the blind design
    assert {(r["design"], r["render"]) for r in doc["rows"]} == {
        ("blind", "direct"), ("aware", "direct"), ("g^0.5", "direct"), (module["BEFORE"], "direct"),
        ("blind", "export"), ("aware", "export")}
    assert all(np.isfinite(r["image_rel_mse"]) for r in doc["rows"])
    assert all(r["seen_log_mse"] >= 0 for r in doc["rows"] if r["render"] == "direct")
    assert (tmp_path / "retro-sphere.png").is_file()


@needs_llvm
def test_the_scene_design_benchmark_renders_a_sequential_design_beside_the_shipped_one(tmp_path):
    """--sequential NAME (issue 29 round 5): per test material, the design re-planned at its posterior
    mean, rendered beside the shipped one; "seq half" starts from the shipped design's first half."""
    import runpy

    module = runpy.run_path(str(REPO / "benchmarks" / "scene_design.py"), run_name="scene_design")
    argv = ["--smallest", "--test-only", "--no-export", "--fewer", "--sequential", "seq half", "--scenes",
            "retro-sphere", "--out", str(tmp_path)]
    scene_test_model(module, argv)
    assert module["main"](argv) == 0
    doc = json.loads((tmp_path / "results.json").read_text())
    assert doc["sequential"] == ["seq half"]
    assert {(r["design"], r["m"]) for r in doc["rows"]} >= {("seq half", 4), ("seq half", 2), ("aware", 4)}
    assert all(np.isfinite(r["image_rel_mse"]) for r in doc["rows"])


def test_the_scene_benchmarks_materials_come_in_the_order_of_their_names():
    """Each row's name is its material's: the benchmark tabulates the materials in the order of the
    names it labels the rows with, not the dataset's own order."""
    import runpy

    module = runpy.run_path(str(REPO / "benchmarks" / "scene_design.py"), run_name="scene_design")
    names = ["red-plastic", "aluminium", "gold"]  # the built-in library has gold before aluminium
    assert [m.name for m in module["collected"](["builtin"], names)] == names


def test_the_scene_benchmarks_builtin_test_set_is_fixed_and_never_trained_on():
    """--test-set builtin: every 3rd sorted built-in name from the first (25 of 74), the model trained
    on all 151 shared materials (datasets the built-in library is not part of); the default set
    stays the 22 shared materials held out of a model of the other 129."""
    import runpy

    module = runpy.run_path(str(REPO / "benchmarks" / "scene_design.py"), run_name="scene_design")
    if not (module["SHARED"] / "nbrdf_merl.npz").is_file():
        pytest.skip("the shared materials are not on this machine")
    from goniofrost.bench.data import material_names

    specs, test_specs, _, training, test, *_ = module["setting"](module["parse"](
        ["--out", "unused", "--test-set", "builtin"]))
    builtin = sorted(n for _, n in material_names(["builtin"]))
    assert test_specs == ["builtin"] and "builtin" not in specs and all(s.startswith("nbrdf:") for s in specs)
    assert test == builtin[0::3] and len(test) == 25 and test[:2] == ["aluminium", "black-metallic-paint"]
    assert training == sorted(n for _, n in material_names(specs)) and len(training) == 151
    # --test-set builtin1: the second fresh set, from the second name, disjoint from the first
    specs1, test_specs1, _, training1, test1, *_ = module["setting"](module["parse"](
        ["--out", "unused", "--test-set", "builtin1"]))
    assert test1 == builtin[1::3] and len(test1) == 25 and not set(test1) & set(test)
    assert test_specs1 == ["builtin"] and specs1 == specs and training1 == training
    # --test-set builtin2: the third, from the third name, disjoint from both
    _, test_specs3, _, training3, test3, *_ = module["setting"](module["parse"](
        ["--out", "unused", "--test-set", "builtin2"]))
    assert test3 == builtin[2::3] and len(test3) == 24 and not set(test3) & (set(test) | set(test1))
    assert test_specs3 == ["builtin"] and training3 == training
    # --test-set fresh1: 24 seeded analytic materials, none of the library's (so none of the three above)
    _, test_specs4, _, training4, test4, *_ = module["setting"](module["parse"](
        ["--out", "unused", "--test-set", "fresh1"]))
    assert test_specs4 == ["builtin-random:1:24"] and training4 == training and len(test4) == 24
    assert test4 == sorted(n for _, n in material_names(test_specs4)) and not set(test4) & set(builtin)
    # --test-set fresh2 (round 7): the next seed, none of fresh1's
    _, test_specs5, _, training5, test5, *_ = module["setting"](module["parse"](
        ["--out", "unused", "--test-set", "fresh2"]))
    assert test_specs5 == ["builtin-random:2:24"] and training5 == training and len(test5) == 24
    assert not set(test5) & (set(test4) | set(builtin))
    # --test-set fresh5 (round 9), fresh6 (round 10), fresh7 (round 11), fresh8 (round 12) and fresh9
    # (round 12's confirmation): seeds 5 to 9, none of the seeded validation's (seeds 101 and 102)
    for seed in (5, 6, 7, 8, 9):
        _, test_specs6, _, training6, test6, *_ = module["setting"](module["parse"](
            ["--out", "unused", "--test-set", f"fresh{seed}"]))
        assert test_specs6 == [f"builtin-random:{seed}:24"] and training6 == training and len(test6) == 24
        assert test_specs6[0] not in module["SEEDED_VALIDATION"]
    specs2, test_specs2, _, training2, test2, *_ = module["setting"](module["parse"](["--out", "unused"]))
    assert specs2 == test_specs2 == specs and len(test2) == 22 and len(training2) == 129
    assert not set(test2) & set(training2)


def test_the_tabulated_bsdf_looks_up_the_cell_of_each_direction_pair():
    from goniofrost.brdf.mitsuba_tabulated import full_table, lookup
    from goniofrost.core.grid import half_diff_to_dirs

    cells = GRID.valid_cells[::97]
    values = np.random.default_rng(0).uniform(0.1, 5.0, (GRID.n_valid, 3))
    # the directions at each cell's centre, and their reciprocal swap (the same cell)
    w_i, w_o = half_diff_to_dirs(*GRID.cell_angles(*(np.asarray(i) + 0.5 for i in GRID.unravel(cells))))
    keep = (w_i[:, 2] > 0) & (w_o[:, 2] > 0)
    cells, w_i, w_o = cells[keep], w_i[keep], w_o[keep]
    table = full_table(GRID, values)
    assert cells.size > 100
    np.testing.assert_array_equal(lookup(GRID, table, w_i, w_o), table[cells])
    np.testing.assert_array_equal(lookup(GRID, table, w_o, w_i), table[cells])
    below = w_o * np.array([1.0, 1.0, -1.0])
    assert not lookup(GRID, table, w_i, below).any()


@needs_llvm
def test_two_brdfs_rendered_with_the_tabulated_bsdf_trace_the_same_paths():
    """Same seed and spp: a BRDF half as large gives exactly half the image of the lit sphere
    (cosine-hemisphere sampling and next-event estimation depend on no BRDF value)."""
    from goniofrost.brdf.mitsuba_tabulated import TabulatedScene

    scene = TabulatedScene(SCENES / "retro-sphere.xml", "sample")
    values = np.random.default_rng(1).uniform(0.05, 2.0, (GRID.n_valid, 3))
    image = scene.render(GRID, values, spp=4)
    half = scene.render(GRID, 0.5 * values, spp=4)
    assert image.shape == (64, 64, 3) and image.max() > 0
    np.testing.assert_allclose(half, 0.5 * image, rtol=1e-6, atol=0)
    other = scene.render(GRID, values, spp=4, seed=1)
    assert np.abs(other - image).max() > 1e-3  # another seed traces other paths


# ----- the error in the scene's use: prediction, bound, calibration ------------------------------------
def retro_map() -> np.ndarray:
    """A map that uses only the cells near retro-reflection (theta_d < 10 deg), sum 1."""
    _, theta_d, _ = GRID.flat_angles(GRID.valid_cells)
    usage = np.where(np.degrees(theta_d) < 10, 1.0, 0.0)
    return usage / usage.sum()


def test_the_weighted_error_of_a_held_out_material_is_its_cell_by_cell_error(model):
    """The calibration's true error from the weighted Gram equals sum_c u_c (x_c - d_c s)^2 over
    the cells, for any coefficients."""
    from goniofrost.frost import noise, training
    from goniofrost.frost.calibration import _fold_dictionary
    from goniofrost.frost.usage_calibration import weighted_errors, weighted_gram

    mapped, gram = training.remap(model)
    fold = noise.inner_folds(gram, len(model.names), model.n_components)[1]
    usage = retro_map()
    coefficients = np.random.default_rng(3).normal(0, 0.05, fold.true_coefficients.shape)
    x = np.asarray(mapped, np.float64) @ fold.centring                   # the held-out columns, centred
    d_f = np.asarray(_fold_dictionary(mapped, fold.projector), np.float64)
    explicit = usage @ (x - d_f @ coefficients) ** 2
    np.testing.assert_allclose(weighted_errors(fold, weighted_gram(mapped, usage), coefficients), explicit, rtol=1e-4)


def test_a_uniform_usage_map_predicts_and_bounds_the_error_as_the_whole_brdf(model):
    """For a map that weighs every cell alike the error in the scene's use is the whole BRDF's: the
    calibration fitted again on the held-out training materials is the model's, and so are the
    predicted error and the bound of any samples."""
    from goniofrost.datasets import open_dataset
    from goniofrost.frost.prediction import calibration_of
    from goniofrost.frost.reconstruction import error_bound, predicted_error
    from goniofrost.frost.scene_error import scene_error
    from goniofrost.frost.usage_calibration import calibrate_scene

    uniform = np.full(GRID.n_valid, 1.0 / GRID.n_valid)
    fitted, plain = calibrate_scene(model, uniform, 1.0), calibration_of(model)
    # (to the rounding of the noise stored in float32 and of the Gram's two routes)
    np.testing.assert_allclose(fitted["coefficients"], plain["coefficients"], rtol=1e-3, atol=1e-6)
    np.testing.assert_allclose(fitted["bound"]["scores"], plain["bound"]["scores"], rtol=1e-3, atol=1e-6)
    scene = scene_error(model, uniform, fitted)
    truth = np.asarray(open_dataset("builtin").tabulate(["red-plastic"], GRID)[0], np.float64)
    rows = np.arange(0, GRID.n_valid, GRID.n_valid // 17)[:16]
    sigmas = 0.02 * truth[rows] + 1e-4
    assert predicted_error(model, rows, truth[rows], sigmas, scene=scene) == pytest.approx(
        predicted_error(model, rows, truth[rows], sigmas), rel=1e-3)
    bounds = [error_bound(model, rows, truth[rows], sigmas, 0.8, scene=s) for s in (scene, None)]
    assert bounds[0].upper == pytest.approx(bounds[1].upper, rel=1e-3) and np.isfinite(bounds[1].upper)


def test_plan_with_a_usage_map_carries_the_error_in_the_scenes_use(model, model_dir, tmp_path):
    """PLAN.json holds M, the weighted noise and a calibration of the usage-weighted error with its
    bound; the plan's predicted errors use that calibration."""
    from goniofrost.core.errors import ConfigError
    from goniofrost.frost.posterior import cell_noise, prior_variance
    from goniofrost.frost.prediction import predict_typical
    from goniofrost.frost.scene_error import from_plan
    from goniofrost.frost.usage_design import scene_power

    path, out = tmp_path / "retro.npy", tmp_path / "plan.json"
    np.save(path, retro_map().astype(np.float32))
    assert main(["plan", "--model", str(model_dir), "--samples", "20", "--usage", str(path), "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["usage"]["sensitivity_power"] == scene_power(model, retro_map(), 20)  # the scene's power for 20
    scene = from_plan(doc, model)
    assert scene.matrix.shape == (model.n_components,) * 2 and scene.calibration["bound"]["scores"]
    assert scene.calibration["coefficients"] != model.noise["calibration"]["coefficients"]
    rows = model.grid.valid_position(np.array([GRID.flat_index(*s["cell"]) for s in doc["samples"]]))
    d, noise = np.asarray(model.dictionary[rows], np.float64), cell_noise(model)[rows]
    sigma = np.linalg.inv(np.diag(1 / prior_variance(model)) + d.T @ (d / noise[:, None]))
    design = float(np.sum(scene.matrix * sigma)) + scene.noise_total  # trace(M Sigma) + sum u sigma_c^2
    assert doc["predicted_errors"][-1] == pytest.approx(float(predict_typical(scene.calibration, design, 20)), rel=1e-6)
    doc["usage"]["error"]["matrix"] = [[1.0]]
    with pytest.raises(ConfigError) as refused:
        from_plan(doc, model, out)
    assert str(refused.value) == (f"{out}: usage.error.matrix: expected {model.n_components} x {model.n_components} "
                                  f"finite numbers (the model's components), found 'shape (1, 1)'")


def test_the_prior_spread_weighs_the_expected_sensitivity_under_the_prior(model):
    """Issue 29 round 7: spread t weighs u g^p exp(t p^2 v / 2), v_c = sum_k D_ck^2 prior_var_k the
    prior variance of cell c's mapped value. t = 0 is the design at the prior mean, exactly; t = 1
    is u E[g^p] under the prior (a Monte-Carlo estimate over prior draws agrees); a uniform map
    stays the plain design; select_bayes's prior_spread designs under these weights, and its default
    is the band's spread with the band's floor on the effective cells (round 8)."""
    from goniofrost.frost.bayes_selection import select_bayes
    from goniofrost.frost.posterior import prior_variance
    from goniofrost.frost.usage_design import (SceneDesign, design_mix, design_usage, prior_cell_variance, prior_spread,
                                               scene_power, spread_floor)

    g = np.exp(np.asarray(model.mean, np.float64)) * (np.asarray(model.reference, np.float64) + model.eps) \
        / np.asarray(model.weight, np.float64)
    rng = np.random.default_rng(7)
    cells = rng.choice(GRID.n_valid, 60, replace=False)
    usage = np.zeros(GRID.n_valid)
    usage[cells] = rng.uniform(0.5, 1.5, cells.size)
    usage /= usage.sum()
    for p in (0.25, 1.0):
        assert np.array_equal(design_usage(model, usage, p, spread=0.0), design_usage(model, usage, p))
        assert np.array_equal(design_usage(model, usage, p, spread=0.0), usage * g ** p / np.sum(usage * g ** p))
    # t = 1: the expectation over L = mu + D s, s ~ N(0, diag(prior_var)), by Monte Carlo
    p, draws = 0.5, 200_000
    d = np.asarray(model.dictionary[cells], np.float64)
    s = rng.standard_normal((draws, d.shape[1])) * np.sqrt(prior_variance(model))
    expected = usage[cells] * g[cells] ** p * np.mean(np.exp(p * s @ d.T), axis=0)
    v = prior_cell_variance(model.dictionary, prior_variance(model))
    assert v[cells].max() > 1.0  # the spread matters on these cells
    weights = design_usage(model, usage, p, spread=1.0)
    assert np.all(weights[usage == 0] == 0)
    np.testing.assert_allclose(weights[cells], expected / expected.sum(), rtol=0.03)
    np.testing.assert_allclose(design_usage(model, usage, p, spread=0.5), usage * g ** p * np.exp(p * p * v / 4)
                               / np.sum(usage * g ** p * np.exp(p * p * v / 4)), rtol=1e-10)
    # a uniform map is the plain design whatever the spread
    uniform = np.full(GRID.n_valid, 1.0 / GRID.n_valid)
    assert np.array_equal(design_usage(model, uniform, 1.0, spread=1.0), uniform)
    assert select_bayes(model, 8, scene=SceneDesign(uniform, prior_spread=1.0)).positions.tolist() == \
        select_bayes(model, 8).positions.tolist()
    # the design of spread t is the mapped-error design of its weights; the default is the spread for m
    assert prior_spread(12) == 1.0 and spread_floor(12) == 6000.0 and prior_spread(20) == 1.0
    power = scene_power(model, usage, 12)  # (60 cells: 0.5, whose design has no floor; mixed, round 12)
    assert select_bayes(model, 12, scene=SceneDesign(usage)).positions.tolist() == select_bayes(
        model, 12, scene=SceneDesign(usage, sensitivity_power=power, prior_spread=1.0,
                                    spread_floor=spread_floor(12, power), mix=design_mix(12, power))).positions.tolist()
    assert select_bayes(model, 20, scene=SceneDesign(usage)).positions.tolist() == select_bayes(
        model, 20, scene=SceneDesign(usage, sensitivity_power=scene_power(model, usage, 20), prior_spread=1.0)
    ).positions.tolist()
    spread = select_bayes(model, 12, scene=SceneDesign(usage, sensitivity_power=1.0, prior_spread=1.0)).positions
    assert spread.tolist() == select_bayes(model, 12, scene=SceneDesign(design_usage(model, usage, 1.0, spread=1.0),
                                                                        sensitivity_power=0)).positions.tolist()


def test_a_floor_on_the_effective_cells_picks_each_scenes_spread():
    """Issue 29 round 8: usage_design.floor_spread, the largest t in [0, t_max] whose weights
    exp(log_base + t excess) keep F effective cells (1 / sum w^2): the floor holds at the t it
    returns, t is within the tolerance of the largest such t, t_max when the floor does not bind,
    0 when even t = 0 is below it; a bad floor is refused in one line."""
    from goniofrost.frost.usage_design import SPREAD_TOLERANCE, effective_cells, floor_spread

    rng = np.random.default_rng(3)
    log_base, excess = rng.normal(size=40_000), rng.uniform(0.0, 6.0, 40_000)  # excess: p^2 v / 2 at p = 1

    def cells(t):
        return effective_cells(np.exp(log_base + t * excess))

    at_zero, at_max = cells(0.0), cells(1.0)
    assert at_max < 0.5 * at_zero  # the spread concentrates these weights
    assert effective_cells(np.ones(10)) == pytest.approx(10) and effective_cells(np.eye(1, 10)[0]) == pytest.approx(1)
    for floor in np.linspace(at_max * 1.01, at_zero * 0.99, 7):
        t = floor_spread(log_base, excess, 1.0, floor)
        assert 0 < t < 1 and cells(t) >= floor  # the floor holds ...
        assert cells(t + SPREAD_TOLERANCE) < floor  # ... at (within the tolerance) the largest t that keeps it
    assert floor_spread(log_base, excess, 1.0, at_max * 0.99) == 1.0  # not binding: t_max
    assert floor_spread(log_base, excess, 0.7, 0.0) == 0.7  # no floor
    assert floor_spread(log_base, excess, 1.0, at_zero * 1.01) == 0.0  # below it already at t = 0
    for bad in (-1.0, float("nan"), float("inf"), "3000", True, None):
        with pytest.raises(ValueError) as refused:
            floor_spread(log_base, excess, 1.0, bad)
        assert str(refused.value) == ("usage_design: the floor on the design's effective cells must be a finite "
                                      f"number >= 0, found {bad!r}")
    with pytest.raises(ValueError, match="largest prior spread must be a finite number >= 0, found -1"):
        floor_spread(log_base, excess, -1.0, 10.0)


def test_the_floor_sets_the_spread_of_a_scene_design(model):
    """design_usage(..., spread=t_max, floor=F) is the spread design of the t design_spread reports
    (u g^p exp(t p^2 v / 2)), its weights keep F effective cells; no floor is the spread as it is;
    a floor that allows no spread gives the weights at the prior mean to the bit; a uniform map
    stays the plain design; select_bayes's spread_floor designs under these weights and refuses a
    bad floor in one line."""
    from goniofrost.frost.bayes_selection import select_bayes
    from goniofrost.frost.posterior import prior_variance
    from goniofrost.frost.usage_design import (SceneDesign, design_spread, design_usage, effective_cells,
                                               prior_cell_variance)

    usage = retro_map()
    g = np.exp(np.asarray(model.mean, np.float64)) * (np.asarray(model.reference, np.float64) + model.eps) \
        / np.asarray(model.weight, np.float64)
    v = prior_cell_variance(model.dictionary, prior_variance(model))
    at_zero = effective_cells(design_usage(model, usage, 1.0))
    at_max = effective_cells(design_usage(model, usage, 1.0, spread=1.0))
    assert at_max < at_zero
    floor = 0.5 * (at_zero + at_max)
    t = design_spread(model, usage, 1.0, spread=1.0, floor=floor)
    weights = design_usage(model, usage, 1.0, spread=1.0, floor=floor)
    assert 0 < t < 1 and effective_cells(weights) >= floor
    np.testing.assert_allclose(weights, usage * g * np.exp(t * v / 2) / np.sum(usage * g * np.exp(t * v / 2)),
                               rtol=1e-10)
    assert np.array_equal(design_usage(model, usage, 1.0, spread=1.0, floor=0.0),
                          design_usage(model, usage, 1.0, spread=1.0))
    assert design_spread(model, usage, 1.0, spread=1.0) == 1.0
    assert design_spread(model, usage, 1.0, spread=1.0, floor=at_zero * 2) == 0.0
    assert np.array_equal(design_usage(model, usage, 1.0, spread=1.0, floor=at_zero * 2), design_usage(model, usage, 1.0))
    uniform = np.full(GRID.n_valid, 1.0 / GRID.n_valid)
    assert np.array_equal(design_usage(model, uniform, 1.0, spread=1.0, floor=floor), uniform)
    uniform_floored = SceneDesign(uniform, prior_spread=1.0, spread_floor=floor)
    assert select_bayes(model, 8, scene=uniform_floored).positions.tolist() == select_bayes(model, 8).positions.tolist()
    floored = select_bayes(model, 10, scene=SceneDesign(usage, sensitivity_power=1.0, prior_spread=1.0,
                                                        spread_floor=floor))
    assert floored.positions.tolist() == select_bayes(model, 10, scene=SceneDesign(weights, sensitivity_power=0)
                                                      ).positions.tolist()
    # the selection reports the spread its weights used (what plan records), as design_spread computes it
    assert floored.prior_spread == t
    assert select_bayes(model, 8, scene=uniform_floored).prior_spread == 0.0
    assert select_bayes(model, 8).prior_spread is None
    with pytest.raises(ValueError, match=r"^usage_design: the floor on the design's effective cells must be a finite "
                                         r"number >= 0, found -5\.0$"):
        select_bayes(model, 10, scene=SceneDesign(usage, prior_spread=1.0, spread_floor=-5.0))


def test_plan_records_the_spread_its_floor_chose_for_the_scene(model, model_dir, tmp_path, monkeypatch, p1_up_to_14):
    """With a floor F in the band (usage_design.BANDS), plan --usage designs with the largest t up
    to the band's that keeps F effective cells for this scene and records that t
    (usage.prior_spread) and F (usage.spread_floor); its cells are select_bayes's with them. (The
    band is patched: on this small grid the shipped floor, in cells of the full grid, would not
    leave a spread.)"""
    from goniofrost.brdf.usage import load_usage
    from goniofrost.frost import usage_design
    from goniofrost.frost.bayes_selection import select_bayes
    from goniofrost.frost.usage_design import SceneDesign

    path = tmp_path / "retro.npy"
    np.save(path, retro_map().astype(np.float32))
    usage = load_usage(str(path), GRID.n_valid)
    cells_at = [usage_design.effective_cells(usage_design.design_usage(model, usage, 1.0, spread=t)) for t in (0.0, 1.0)]
    floor = round(0.5 * sum(cells_at))
    monkeypatch.setattr(usage_design, "BANDS", ((14, 1.0, 1.0, float(floor)),) + usage_design.BANDS[1:])
    out = tmp_path / "plan.json"
    assert main(["plan", "--model", str(model_dir), "--samples", "10", "--usage", str(path), "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    t = usage_design.design_spread(model, usage, 1.0, spread=1.0, floor=floor)
    assert 0 < t < 1 and doc["usage"]["prior_spread"] == t and doc["usage"]["spread_floor"] == floor
    chosen = select_bayes(model, 10, scene=SceneDesign(usage, sensitivity_power=1.0, prior_spread=1.0,
                                                       spread_floor=floor))
    assert [s["cell"] for s in doc["samples"]] == np.stack(model.grid.unravel(chosen.cells), axis=1).tolist()
    assert chosen.positions.tolist() != select_bayes(model, 10, scene=SceneDesign(usage, prior_spread=0.0)
                                                     ).positions.tolist()


@needs_llvm
def test_the_scene_design_benchmark_can_choose_on_seeded_materials_no_test_set_uses(tmp_path):
    """--validation-set seeded (issue 29 round 9): the candidates are compared on seeded analytic
    materials (seeds 101 and 102) with one model of all the training specs' materials; no seed of
    a test set (fresh1 to fresh4, and 5, the next in line) is among them."""
    import runpy

    module = runpy.run_path(str(REPO / "benchmarks" / "scene_design.py"), run_name="scene_design")
    seeds = {int(spec.split(":")[1]) for spec in module["SEEDED_VALIDATION"]}
    assert not seeds & ({int(spec.split(":")[1]) for spec in module["FRESH_SETS"].values()} | {5})
    assert module["main"](["--smallest", "--validation-only", "--validation-set", "seeded", "--scenes",
                           "retro-sphere", "--out", str(tmp_path)]) == 0
    val = json.loads((tmp_path / "validation.json").read_text())
    seeded = json.loads((tmp_path / "validation-seeded.json").read_text())
    assert seeded["held"] == ["r101-001-metallic-paint", "r102-001-fabric"]
    assert {r["material"] for r in val["rows"]} == set(seeded["held"])
    assert {r["design"] for r in val["rows"]} == {"blind", *module["CANDIDATES"]}
    # a power per scene is one of its tuple's
    for name, (p, *_) in module["CANDIDATES"].items():
        if isinstance(p, tuple):
            assert seeded["spreads"]["retro-sphere"][name][0] in p


def test_from_29_samples_each_scene_takes_the_largest_power_keeping_4000_effective_cells(model, monkeypatch):
    """Issue 29 round 9: above MANY_SAMPLES a scene's power is the largest of 0.5, 0.75 and 1 whose
    weights (t = 1) keep 4,000 effective cells, 0.5 when none larger does; below, the band's p
    alone. select_bayes's default design is the design of that power and reports it."""
    from goniofrost.frost import usage_design
    from goniofrost.frost.bayes_selection import select_bayes
    from goniofrost.frost.usage_design import SceneDesign, design_usage, effective_cells, scene_power

    assert usage_design.POWERS_MOST == (0.5, 0.75, 1.0) and usage_design.POWER_FLOOR_MOST == 4000.0
    usage = retro_map()
    cells = {p: effective_cells(design_usage(model, usage, p, 1.0, 1.0)) for p in (0.5, 0.75, 1.0)}
    assert cells[1.0] < cells[0.75] < cells[0.5]  # the larger the power, the fewer cells
    kept = [p for p in (0.75, 1.0) if cells[p] >= 4000.0]
    assert scene_power(model, usage, 40) == (max(kept) if kept else 0.5)
    # up to 14 (round 11) the same powers keeping 3,300 cells; from 15 (round 10) the same as from 29
    few = max([p for p in (0.75, 1.0) if cells[p] >= 3300.0], default=0.5)
    assert [scene_power(model, usage, m) for m in (10, 14, 20, 28)] == [few] * 2 + [scene_power(model, usage, 40)] * 2
    uniform = np.full(model.grid.n_valid, 1.0 / model.grid.n_valid)
    assert scene_power(model, uniform, 40) == 0.5
    for floor, power in ((cells[1.0], 1.0), (cells[1.0] * 1.001, 0.75), (cells[0.75] * 1.001, 0.5)):
        monkeypatch.setitem(usage_design.BAND_POWERS, None, (usage_design.POWERS_MOST, floor))
        assert scene_power(model, usage, 29) == power
        chosen = select_bayes(model, 30, scene=SceneDesign(usage))
        assert chosen.sensitivity_power == power
        assert chosen.positions.tolist() == select_bayes(model, 30, scene=SceneDesign(usage, sensitivity_power=power)
                                                         ).positions.tolist()
    assert select_bayes(model, 30).sensitivity_power is None


def test_plan_from_29_samples_records_the_scenes_own_power(model, model_dir, tmp_path, capsys):
    """plan --samples 30 --usage: the power the design used (usage_design.scene_power, one of 0.5,
    0.75, 1) is the one PLAN.json records and the plan says how it was chosen."""
    from goniofrost.frost.usage_design import scene_power

    path, out = tmp_path / "retro.npy", tmp_path / "plan.json"
    np.save(path, retro_map().astype(np.float32))
    assert main(["plan", "--model", str(model_dir), "--samples", "30", "--usage", str(path), "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["usage"]["sensitivity_power"] == scene_power(model, retro_map(), 30)
    assert "the largest of 0.5, 0.75, 1 keeping 4000 effective cells, for 30 samples" in capsys.readouterr().out


def test_up_to_14_samples_each_scene_takes_the_largest_power_keeping_3300_cells_and_p1_the_floor(model, monkeypatch):
    """Issue 29 round 11: up to 14 samples a scene's power is the largest of 0.5, 0.75 and 1 whose
    weights at t = 1 without a floor keep POWER_CELLS_FEW effective cells, 0.5 when none larger
    does; a scene of p = 1 takes t up to 1 with the floor FLOOR_FEW, one of a smaller power t = 1
    without a floor (mixed with the p = 1 floor design since round 12). select_bayes's default is
    that design and reports its power and spread. (The counts are patched to this grid's scale: the
    shipped ones are of the full grid.)"""
    from goniofrost.frost import usage_design
    from goniofrost.frost.bayes_selection import select_bayes
    from goniofrost.frost.usage_design import SceneDesign, design_spread, design_usage, effective_cells, scene_power

    usage = retro_map()
    cells = {p: effective_cells(design_usage(model, usage, p, 1.0, 1.0)) for p in (0.5, 0.75, 1.0)}
    at_zero = effective_cells(design_usage(model, usage, 1.0))
    floor = 0.5 * (cells[1.0] + at_zero)  # binds p = 1 at t = 1, not at t = 0
    monkeypatch.setattr(usage_design, "BANDS", ((14, 1.0, 1.0, floor),) + usage_design.BANDS[1:])
    for count, power in ((cells[1.0], 1.0), (cells[1.0] * 1.001, 0.75), (cells[0.75] * 1.001, 0.5)):
        monkeypatch.setitem(usage_design.BAND_POWERS, 14, (usage_design.POWERS_FEW, count))
        assert scene_power(model, usage, 10) == power
        chosen = select_bayes(model, 10, scene=SceneDesign(usage))
        t = design_spread(model, usage, 1.0, spread=1.0, floor=floor) if power == 1.0 else 1.0
        assert chosen.sensitivity_power == power and chosen.prior_spread == t
        assert (0 < t < 1) is (power == 1.0)  # the floor binds p = 1 only
        assert chosen.positions.tolist() == select_bayes(model, 10, scene=SceneDesign(
            usage, sensitivity_power=power, prior_spread=1.0, spread_floor=floor if power == 1.0 else 0.0,
            mix=0.5 if power < 1 else 0.0)).positions.tolist()


def test_the_default_design_of_10_samples_for_each_shipped_scene(model):
    """Issue 29 round 11, per shipped scene (usage maps recorded on this 30 x 30 x 60 grid): the
    design of 10 samples takes the largest of 0.5, 0.75, 1 whose weights at t = 1 keep 3,300
    effective cells, t = 1 without a floor below p = 1; the counts, of the full grid's cells, leave
    every scene of this small grid 0.5 (the full-grid model of 151 materials gives the grazing plane
    0.5 and the retro sphere and top light 1, BENCHMARKS.md@8b3941b "Issue 29, round 11"); since round 12 a
    scene of p = 0.5 is mixed half and half with the p = 1 floor design."""
    from goniofrost.brdf.mitsuba_usage import record_usage
    from goniofrost.frost.bayes_selection import select_bayes
    from goniofrost.frost.usage_design import POWER_CELLS_FEW, SceneDesign, design_usage, effective_cells

    for scene in ("retro-sphere", "grazing-plane", "top-light"):
        usage, _ = record_usage(SCENES / f"{scene}.xml", "sample", spp=2, grid=GRID)
        cells = {p: effective_cells(design_usage(model, usage, p, 1.0, 1.0)) for p in (0.5, 0.75, 1.0)}
        power = max([p for p in (0.75, 1.0) if cells[p] >= POWER_CELLS_FEW], default=0.5)
        chosen = select_bayes(model, 10, scene=SceneDesign(usage))
        assert power == 0.5 and chosen.sensitivity_power == power and chosen.prior_spread == 1.0, scene
        assert chosen.positions.tolist() == select_bayes(model, 10, scene=SceneDesign(
            usage, sensitivity_power=0.5, prior_spread=1.0, spread_floor=0.0, mix=0.5)).positions.tolist()


def test_the_mixed_weights_are_the_average_of_the_two_designs_weights(model):
    """Issue 29 round 12: a mixed design weighs a w(p = 1, t up to 1, F = FLOOR_FEW) + (1 - a) w(p, t),
    each part summing to 1: the weights sum to 1 and, at a = 0.5, are the average of the two
    designs' weights; its calibration key is not the unmixed design's."""
    from goniofrost.frost.usage_design import FLOOR_FEW, MIX_DESIGN, design_key, design_usage, mixed_weights

    usage = retro_map()
    assert MIX_DESIGN == (1.0, 1.0, FLOOR_FEW)
    floor_design = design_usage(model, usage, 1.0, 1.0, 1.0, FLOOR_FEW)
    own = design_usage(model, usage, 0.5, 1.0, 1.0)
    mixed, t = mixed_weights(model, usage, 0.5, 1.0, 1.0, 0.0, 0.5)
    assert t == 1.0 and mixed.sum() == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(mixed, 0.5 * floor_design + 0.5 * own, rtol=1e-12, atol=0)
    np.testing.assert_array_equal(design_usage(model, usage, 0.5, 1.0, 1.0, mix=0.5), mixed)
    assert design_key(0.5, 1.0, 0.0, 0.5) != design_key(0.5, 1.0, 0.0) == (0.5, 1.0, 0.0)


def test_the_default_design_of_10_samples_is_mixed_exactly_when_the_scenes_power_is_below_1(model, monkeypatch):
    """Issue 29 round 12: up to 14 samples select_bayes's default design of a scene whose power is
    below 1 is the mix (share MIX_FEW = 0.5 of the p = 1 floor design), a scene of p = 1 keeps the
    floor design unmixed, and from 15 samples nothing is mixed. (The counts are patched to this
    grid's scale, as in the test of round 11.)"""
    from goniofrost.frost import usage_design
    from goniofrost.frost.bayes_selection import select_bayes
    from goniofrost.frost.usage_design import SceneDesign, design_mix, design_usage, effective_cells, scene_power

    assert usage_design.MIX_FEW == 0.5 and design_mix(10, 0.5) == 0.5 and design_mix(10, 1.0) == 0.0
    assert design_mix(20, 0.75) == design_mix(40, 1.0) == 0.0
    usage = retro_map()
    cells = {p: effective_cells(design_usage(model, usage, p, 1.0, 1.0)) for p in (0.75, 1.0)}
    for count, power in ((cells[1.0], 1.0), (cells[1.0] * 1.001, 0.75), (cells[0.75] * 1.001, 0.5)):
        monkeypatch.setitem(usage_design.BAND_POWERS, 14, (usage_design.POWERS_FEW, count))
        assert scene_power(model, usage, 10) == power
        chosen = select_bayes(model, 10, scene=SceneDesign(usage)).positions.tolist()
        floor = usage_design.FLOOR_FEW if power == 1.0 else 0.0
        explicit = dict(sensitivity_power=power, prior_spread=1.0, spread_floor=floor)
        assert chosen == select_bayes(model, 10, scene=SceneDesign(usage, mix=0.5 if power < 1 else 0.0, **explicit)
                                      ).positions.tolist()
        if power < 1:  # the mix is a different design here
            assert chosen != select_bayes(model, 10, scene=SceneDesign(usage, **explicit)).positions.tolist()


def test_a_mixed_designs_own_part_takes_its_own_spread_and_calibration_key(model):
    """Issue 29 round 13: the own part of a mixed design (p < 1) takes the band's MIX_SPREAD_FEW = 1
    by default (round 12's design) or select_bayes's ``mix_spread``; the calibration is asked for
    with that t in its key, so the designs of own t = 0 and t = 1 never share one."""
    from goniofrost.frost import usage_design
    from goniofrost.frost.bayes_selection import design_options, select_bayes
    from goniofrost.frost.usage_design import SceneDesign, design_key, mix_spread, mixed_weights

    assert usage_design.MIX_SPREAD_FEW == 1.0 and mix_spread(10) == 1.0
    assert design_key(0.5, 0.0, 0.0, 0.5) != design_key(0.5, 1.0, 0.0, 0.5)
    usage = retro_map()
    asked = []

    def calibration(*key):
        asked.append(key)
        return None  # the model's

    explicit = dict(sensitivity_power=0.5, spread_floor=0.0, mix=0.5)
    at_one = select_bayes(model, 10, scene=SceneDesign(usage, **explicit), calibration=calibration)
    at_zero = select_bayes(model, 10, scene=SceneDesign(usage, mix_spread=0.0, **explicit), calibration=calibration)
    assert asked == [(0.5, 1.0, 0.0, 0.5), (0.5, 0.0, 0.0, 0.5)]
    assert [at_one.design_key, at_zero.design_key] == asked  # what plan records and calibrates
    assert design_options(model, SceneDesign(usage, mix_spread=0.0, **explicit), 10).key == asked[1]
    assert at_one.prior_spread == 1.0 and at_zero.prior_spread == 0.0
    assert at_one.positions.tolist() == select_bayes(model, 10, scene=SceneDesign(
        usage, sensitivity_power=0.5, prior_spread=1.0, spread_floor=0.0, mix=0.5)).positions.tolist()
    assert not np.array_equal(mixed_weights(model, usage, 0.5, 1.0, 0.0, 0.0, 0.5)[0],
                              mixed_weights(model, usage, 0.5, 1.0, 1.0, 0.0, 0.5)[0])


def test_the_scenes_calibration_is_fitted_once_and_read_back_with_the_same_numbers(model, monkeypatch):
    """plan --usage fitted the scene's calibration on the training materials on every run (a minute
    on the full grid); the cache keeps it under the model, the map and the design: the second call
    maps nothing and returns what the first did (as JSON, what PLAN.json carries), and another map
    or power is fitted anew."""
    import json

    from goniofrost.frost import training
    from goniofrost.frost.usage_calibration import calibrate_scene, calibrate_scene_cached

    usage = retro_map()
    first = calibrate_scene_cached(model, usage, 1.0)
    assert json.dumps(first) == json.dumps(calibrate_scene(model, usage, 1.0))
    real = training.remap
    monkeypatch.setattr(training, "remap", lambda *a, **k: pytest.fail("mapped again"))
    assert calibrate_scene_cached(model, usage, 1.0) == first
    monkeypatch.setattr(training, "remap", real)
    uniform = np.full(GRID.n_valid, 1.0 / GRID.n_valid)
    calls = []
    monkeypatch.setattr(training, "remap", lambda *a, **k: calls.append(1) or real(*a, **k))
    calibrate_scene_cached(model, uniform, 1.0)
    calibrate_scene_cached(model, usage, 2.0)
    assert len(calls) == 2
