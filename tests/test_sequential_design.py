"""The sequential scene-aware design: continuing the greedy design at a material's posterior mean."""
from __future__ import annotations

import numpy as np
import pytest

from goniofrost.core.grid import MerlGrid

from conftest import train_once

GRID = MerlGrid(30, 30, 60)


@pytest.fixture(scope="module")
def model():
    """Five built-in materials on GRID, k <= 15: trained once per test run (test_usage's and
    test_sequential_design's)."""
    return train_once("five-materials", ["builtin"], only=["white-diffuse", "blue-plastic", "gold", "green-felt",
                                                            "red-plastic"], grid=GRID, k_max=15)


def retro_map() -> np.ndarray:
    _, theta_d, _ = GRID.flat_angles(GRID.valid_cells)
    usage = np.where(np.degrees(theta_d) < 10, 1.0, 0.0)
    return usage / usage.sum()


def material(name: str) -> np.ndarray:
    from goniofrost.datasets.tabulate import collect_materials, tabulate_materials

    return np.asarray(tabulate_materials(collect_materials(["builtin"], only=[name]), GRID)[0], np.float64)


def test_the_posterior_mean_is_the_bayesian_reconstructions(model):
    from goniofrost.frost.reconstruction import reconstruct_bayes
    from goniofrost.frost.sequential_design import posterior_mean

    truth, rows = material("silver"), np.array([5, 900, 4000, 12000, 20000])
    expected = reconstruct_bayes(model, rows, truth[rows], with_std=False).mapped
    np.testing.assert_allclose(posterior_mean(model, rows, model.to_log(truth[rows], rows)), expected, atol=1e-4)


@pytest.mark.parametrize("l", [3, 7])
def test_with_a_uniform_map_it_is_the_plain_designs_continuation(model, l):
    """Any measured values: no scene, no sensitivity; the change of basis at the posterior
    covariance keeps the greedy scores, so the picks are the plain design's next ones."""
    from goniofrost.frost.bayes_selection import select_bayes
    from goniofrost.frost.sequential_design import continue_design

    plain = select_bayes(model, 12).positions
    truth = material("silver")
    uniform = np.full(GRID.n_valid, 1.0 / GRID.n_valid)
    rest = continue_design(model, uniform, plain[:l], model.to_log(truth[plain[:l]], plain[:l]), 12).rows
    assert rest.tolist() == plain[l:].tolist()


@pytest.mark.parametrize("m", [12, 20])
def test_at_the_prior_mean_it_is_the_one_stage_scene_design(model, m):
    """Samples equal to the prior mean leave the posterior mean there: g is the one-stage design's,
    and so are the picks (the power for m, 1 at 12 and 0.25 at 20; the continuation weighs g at the
    posterior mean itself, so the one-stage design of prior spread 0)."""
    from goniofrost.frost.bayes_selection import select_bayes
    from goniofrost.frost.sequential_design import continue_design
    from goniofrost.frost.usage_design import SceneDesign

    usage = retro_map()
    aware = select_bayes(model, m, scene=SceneDesign(usage, prior_spread=0.0)).positions
    first = aware[:m // 2]
    mapped = np.repeat(np.asarray(model.mean, np.float64)[first, None], 3, axis=1)
    assert continue_design(model, usage, first, mapped, m).rows.tolist() == aware[m // 2:].tolist()


def test_a_material_unlike_the_prior_mean_moves_the_continuation(model):
    """A specular material's samples change g, so the continuation differs from the one-stage
    design's, and it never repeats a picked cell."""
    from goniofrost.frost.bayes_selection import select_bayes
    from goniofrost.frost.sequential_design import continue_design
    from goniofrost.frost.usage_design import SceneDesign

    usage, m = retro_map(), 12
    aware = select_bayes(model, m, scene=SceneDesign(usage)).positions
    first, truth = aware[:6], material("chrome")
    rest = continue_design(model, usage, first, model.to_log(truth[first], first), m).rows
    assert rest.size == 6 and not set(rest.tolist()) & set(first.tolist())
    assert rest.tolist() != aware[6:].tolist()
    with pytest.raises(ValueError, match="picks so far"):
        continue_design(model, usage, aware, model.to_log(truth[aware], aware), m)


def test_the_benchmarks_sequential_designs_start_from_the_shipped_design(model):
    """benchmarks/scene_design.py's sequential designs: "half" is the shipped m-sample design's first
    m // 2 picks and then the continuation at the posterior mean; a chain re-plans at every stage."""
    import runpy
    from pathlib import Path

    from goniofrost.frost.bayes_selection import select_bayes
    from goniofrost.frost.sequential_design import continue_design
    from goniofrost.frost.usage_design import SceneDesign

    module = runpy.run_path(str(Path(__file__).resolve().parents[1] / "benchmarks" / "scene_design.py"),
                            run_name="scene_design")
    usage, truth = retro_map(), material("chrome")
    shipped = select_bayes(model, 12, scene=SceneDesign(usage)).positions
    half = module["sequential_picks"](model, usage, truth, (6, 12))
    rest = continue_design(model, usage, shipped[:6], model.to_log(truth[shipped[:6]], shipped[:6]), 12).rows
    assert half.tolist() == shipped[:6].tolist() + rest.tolist()
    chain = module["sequential_picks"](model, usage, truth, (4, 8, 12))
    assert chain[:4].tolist() == select_bayes(model, 8, scene=SceneDesign(usage)).positions[:4].tolist()
    assert len(set(chain)) == 12
    designs = module["sequential_designs"](model, {"retro": usage}, truth, [8, 12], ["seq half"], {})
    assert designs[12][("retro", "seq half")].tolist() == half.tolist() and len(designs[8][("retro", "seq half")]) == 8


def test_a_continuation_keeps_to_the_candidates_it_is_given(model):
    """A rig reaches only some cells (``select_bayes(candidates=)``): the re-planned picks too. The
    mask here shuts exactly the cells the unmasked continuation would take."""
    from goniofrost.frost.bayes_selection import select_bayes
    from goniofrost.frost.sequential_design import continue_design
    from goniofrost.frost.usage_design import SceneDesign

    usage, m, truth = retro_map(), 12, material("chrome")
    first = select_bayes(model, m, scene=SceneDesign(usage)).positions[:6]
    mapped = model.to_log(truth[first], first)
    free = continue_design(model, usage, first, mapped, m).rows
    reach = np.ones(GRID.n_valid, dtype=bool)
    reach[free] = False
    rest = continue_design(model, usage, first, mapped, m, candidates=reach).rows
    assert rest.size == 6 and reach[rest].all() and not set(rest.tolist()) & set(first.tolist())
    with pytest.raises(ValueError, match="bool mask of the"):
        continue_design(model, usage, first, mapped, m, candidates=reach[:10])
