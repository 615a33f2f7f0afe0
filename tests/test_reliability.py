"""What a reliability probe of the capture found, one test per row: strongly coloured materials,
a monitor under load and odd paths, resume and refusal corner cases. Small and fast: the test
session's 30 x 30 x 60 grid, its 6-material model and short simulated rig."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from goniofrost.capture.journal import Journal
from goniofrost.capture.runner import capture

from test_session import GRID, TRAINING, write_rig

REPO = Path(__file__).resolve().parents[1]
RGL = REPO.parent / "shared" / "data" / "nbrdf_rgl.npz"
BLUE_SILK = f"nbrdf:{RGL}:vch_silk_blue_rgb"


@pytest.fixture(scope="module")
def model():
    from goniofrost.frost.training import train
    return train(["builtin"], only=TRAINING, grid=GRID, k_max=18, cache=True)


def coloured_plan(folder: Path, model, material: str, n_other: int = 2) -> tuple[Path, Path, int]:
    """(rig, plan, plan index of the darkest channel) of a plan holding the reachable cell where
    ``material``'s weakest channel is the smallest fraction of its strongest (bright enough for the
    short test ladder), and ``n_other`` ordinary cells."""
    from planner.reach import reachability
    from planner.schedule import schedule_plan

    from goniofrost.capture.plan_file import plan_document, write_plan
    from goniofrost.capture.rig_file import load_checked_rig
    from goniofrost.core.cache import cache_path
    from goniofrost.datasets import parse_material_spec
    from goniofrost.frost.selection import Selection

    rig_path = write_rig(folder / "rig.yaml")
    rig = load_checked_rig(rig_path)
    reach = np.flatnonzero(reachability(rig, model.grid).mask)
    dataset, name = parse_material_spec(material)
    table = dataset.tabulate([name], model.grid)[0].astype(np.float64)[reach]
    bright = table.max(1) > 0.05                       # enough light for the longest test exposure
    ratio = np.where(bright, table.min(1) / np.maximum(table.max(1), 1e-12), np.inf)
    dark = int(np.argmin(ratio))
    others = [int(i) for i in np.argsort(-table.min(1))[:n_other]]
    positions = np.array([dark, *others])
    cells = model.grid.valid_cells[reach[positions]]
    selection = Selection(reach[positions], cells, np.zeros(len(cells)), 0.0, "all", 18, "frost")
    doc = plan_document(cache_path("models", model.info["cache_key"], ""), model, selection)
    plan_path = folder / "plan.json"
    write_plan(plan_path, schedule_plan(doc, rig))
    plan = json.loads(plan_path.read_text())
    index = next(i for i, s in enumerate(plan["samples"]) if s["w_i"] == doc["samples"][0]["w_i"]
                 and s["w_o"] == doc["samples"][0]["w_o"])
    assert ratio[dark] < 0.02, f"{material}: no cell with a near-zero channel ({ratio[dark]:.3f})"
    return rig_path, plan_path, index


def test_a_strongly_coloured_material_is_captured_with_its_dark_channel_at_its_detection_limit(tmp_path, model):
    """The RGL blue silk has a channel near 0 where another is bright: the capture completes, and
    the dark channel's sample is its true value within its uncertainty (not an error)."""
    from goniofrost.datasets import material_brdf

    rig, plan, k = coloured_plan(tmp_path, model, BLUE_SILK)
    capture(rig, plan, tmp_path / "s", material=BLUE_SILK, speedup=50, progress=False)
    samples = json.loads(plan.read_text())["samples"]
    _, brdf = material_brdf(BLUE_SILK)
    with Journal.open(tmp_path / "s" / "session.sqlite") as journal:
        records = {r.plan_index: r for r in journal.samples()}
    assert sorted(records) == list(range(len(samples)))
    dark = records[k]
    truth = brdf(np.array(samples[k]["w_i"]), np.array(samples[k]["w_o"]))
    c = int(np.argmin(truth))
    assert "detection-limit" in dark.status and truth[c] < 0.02 * truth.max()
    assert abs(dark.rgb[c] - truth[c]) <= 3 * dark.sigma[c] and dark.sigma[c] < 0.05 * max(dark.rgb)
    for r in records.values():   # every channel of every sample within 4 sigma of the truth
        t = brdf(np.array(samples[r.plan_index]["w_i"]), np.array(samples[r.plan_index]["w_o"]))
        assert np.all(np.abs(np.array(r.rgb) - t) <= 4 * np.array(r.sigma) + 0.03 * t), (r.plan_index, r.rgb, t)
