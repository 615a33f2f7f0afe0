"""What the camera can measure is part of reachability: the pixel bound, the new reasons, the
scheduler's choice of measurable poses, and cells up to 85 deg on the simulated rig."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from calib.holder import SAMPLE_MARKER_IDS
from calib.roi import polygon_mask, predict_view
from goniofrost.rig.file import load_checked_rig
from goniofrost.core.grid import MerlGrid
from planner.candidates import candidate_poses, measurable_reason
from planner.kinematics import Reason, forward
from planner.reach import compute_reasons, reachability
from planner.schedule import UnreachableSampleError, schedule_plan
from planner.view import roi_pixels
from sim.camera_bench import direction, rig_like

RIG_FILE = Path(__file__).resolve().parents[1] / "config" / "rigs" / "sim.yaml"
GRID = MerlGrid(30, 30, 60)


@pytest.fixture(scope="module")
def rig():
    return load_checked_rig(RIG_FILE)


def _variant(tmp_path, name, edit) -> Path:
    raw = yaml.safe_load(RIG_FILE.read_text())
    edit(raw)
    path = tmp_path / name
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    return path


def _channels(shape):
    ch = np.zeros(shape, dtype=np.uint8)   # RGGB
    ch[0::2, 1::2] = 1
    ch[1::2, 0::2] = 1
    ch[1::2, 1::2] = 2
    return ch


def test_the_pixel_bound_never_exceeds_the_region_the_capture_rasterises(rig):
    """The planner's closed-form count is a lower bound of what calib.roi's mask really keeps,
    per colour channel, at random poses up to edge-on, and tight where it matters."""
    cam, rng = rig.view.camera, np.random.default_rng(7)
    channels = _channels((cam.height, cam.width))
    poses = [rig_like(direction(rng.uniform(0, 89), 0), direction(th, rng.uniform(0, 360)))
             for th in np.concatenate([rng.uniform(0, 80, 40), rng.uniform(80, 89.8, 80)])]
    w_i, w_o = (np.array(p) for p in zip(*poses))
    bound = roi_pixels(rig.view, w_i, w_o)
    for k in range(len(poses)):
        view = predict_view(cam, w_i[k], w_o[k], SAMPLE_MARKER_IDS, rig.camera["roi_margin"])
        mask = polygon_mask(view.patch, (cam.height, cam.width))
        actual = min(int(np.sum(mask & (channels == c))) for c in range(3))
        assert bound[k] <= actual, (k, bound[k], actual)
        if actual > 500:   # conservative near the limit (worst-case lattice), close to it elsewhere
            assert bound[k] >= 0.8 * actual
    assert np.any(bound == 0) and np.any(bound > 1000)


def test_cells_up_to_85_degrees_are_measurable_on_the_simulated_rig(rig):
    """Every candidate pose whose view is at most 85 deg from the normal keeps enough pixels,
    and every reachable cell with both angles <= 85 deg is measurable."""
    w_i, w_o = GRID.cell_directions(GRID.valid_cells)
    joints, _, reason = candidate_poses(rig, w_i, w_o)
    geometric = ~np.isin(reason, [Reason.ARM_SEPARATION, Reason.ARM_LIMIT, Reason.STAGE_LIMIT, Reason.BELOW_SURFACE])
    f_i, f_o = forward(rig, joints[geometric])
    view_deg = np.degrees(np.arccos(np.clip(f_o[:, 2], -1, 1)))
    light_deg = np.degrees(np.arccos(np.clip(f_i[:, 2], -1, 1)))
    assert np.all(reason[geometric][(view_deg <= 85.0) & (light_deg <= 89.0)] == Reason.OK)
    assert np.all(reason[geometric][light_deg > 89.0] == Reason.LIGHT_GRAZING)   # lamp.max_incidence_deg
    assert np.any(reason[geometric][view_deg > 88.8] == Reason.PATCH_PIXELS)
    cells = compute_reasons(rig, GRID)
    theta = np.degrees(np.arccos(np.stack([w_i[:, 2], w_o[:, 2]], 1))).max(1)
    geometric_cells = ~np.isin(cells, [Reason.ARM_SEPARATION, Reason.ARM_LIMIT, Reason.STAGE_LIMIT])
    assert np.all(cells[geometric_cells & (theta <= 85.0)] == Reason.OK)
    # the camera's reason is its own: those cells are reachable, only unmeasurable
    assert 0 < np.sum(cells == Reason.PATCH_PIXELS) < 0.01 * cells.size
    assert np.all(theta[cells == Reason.PATCH_PIXELS] > 85.0)


def test_the_reach_map_reports_the_camera_and_the_beam_as_reasons(rig, tmp_path):
    small = load_checked_rig(_variant(tmp_path, "small.yaml", lambda r: r["camera"]["intrinsics"].update(
        image_size_px=[240, 180], focal_px=[2400.0, 2400.0], principal_point_px=[119.5, 89.5])))
    narrow = load_checked_rig(_variant(tmp_path, "beam.yaml", lambda r: r["lamp"].update(beam_diameter_mm=20.0)))
    wide = load_checked_rig(_variant(tmp_path, "wide.yaml", lambda r: r["lamp"].update(beam_diameter_mm=60.0)))
    counts = {name: reachability(r, GRID).counts() for name, r in
              (("sim", rig), ("small", small), ("narrow", narrow), ("wide", wide))}
    # a coarser camera (2.4 px/mm) loses more grazing cells; the geometry is the same for all
    assert counts["small"]["PATCH_PIXELS"] > 5 * counts["sim"]["PATCH_PIXELS"] > 0
    for name in counts:
        assert counts[name]["ARM_SEPARATION"] == counts["sim"]["ARM_SEPARATION"]
    # a 20 mm beam misses the 17 mm patch's corners (12 mm out) unless grazing light narrows it
    assert counts["narrow"]["LAMP_BEAM"] > 0.5 * GRID.n_valid and counts["wide"]["LAMP_BEAM"] == 0
    # an unmeasurable pose of the geometric kind stays geometric
    assert measurable_reason(narrow, np.array([20.0, 10.0, 0.0])) == Reason.LAMP_BEAM
    assert measurable_reason(narrow, np.array([20.0, 85.0, 0.0])) == Reason.OK   # light 85 deg off the normal


def _plan(cells) -> dict:
    from goniofrost.plan.file import sample_entries
    return {"grid": GRID.as_dict(), "samples": sample_entries(GRID, np.asarray(cells))}


def test_the_scheduler_uses_only_poses_the_camera_can_measure(rig):
    w_i, w_o = GRID.cell_directions(GRID.valid_cells)
    theta_i = np.degrees(np.arccos(w_i[:, 2]))
    theta_o = np.degrees(np.arccos(w_o[:, 2]))
    _, _, reason = candidate_poses(rig, w_i, w_o)
    # one view grazing past what the camera resolves, the light not: measurable only swapped
    swap_only = np.flatnonzero((reason[:, :2] == Reason.PATCH_PIXELS).all(1) & (reason[:, 2:] == Reason.OK).any(1))
    assert swap_only.size > 0
    cells = GRID.valid_cells[swap_only[:3]]
    doc = schedule_plan(_plan(cells), rig)
    assert all(s["light_camera_swapped"] for s in doc["samples"])
    joints = np.array([[s["joints"][n] for n in rig.joint_names] for s in doc["samples"]])
    assert np.all(measurable_reason(rig, joints) == Reason.OK)
    # both grazing, or one beyond the lamp's 89 deg (the camera cannot see it there and the light,
    # swapped, cannot light it): no pose can measure it, and the plan says so
    both = np.flatnonzero(compute_reasons(rig, GRID) == Reason.PATCH_PIXELS)
    lo, hi = np.minimum(theta_i, theta_o)[both], np.maximum(theta_i, theta_o)[both]
    assert both.size > 0 and np.all((lo > 85.0) | (hi > 89.0))
    with pytest.raises(UnreachableSampleError, match=r"plan sample 0 \(cell \(\d+, \d+, \d+\)\) cannot be reached "
                                                     r"on this rig: PATCH_PIXELS"):
        schedule_plan(_plan(GRID.valid_cells[both[:1]]), rig)


def test_the_lamp_beam_diameter_is_checked(tmp_path):
    from goniofrost.core.errors import ConfigError
    bad = _variant(tmp_path, "bad.yaml", lambda r: r["lamp"].update(beam_diameter_mm=0))
    with pytest.raises(ConfigError, match=r"bad\.yaml: lamp\.beam_diameter_mm: expected a number in \(0, inf\], found 0"):
        load_checked_rig(bad)


def test_a_light_beyond_the_lamps_largest_incidence_is_not_measurable(rig, tmp_path):
    # the rig's light is horizontal: the yaw turns the sample's normal away from it
    assert measurable_reason(rig, np.array([20.0, 88.9, 0.0])) == Reason.OK
    assert measurable_reason(rig, np.array([20.0, 89.1, 0.0])) == Reason.LIGHT_GRAZING   # default 89 deg
    steep = load_checked_rig(_variant(tmp_path, "steep.yaml", lambda r: r["lamp"].update(max_incidence_deg=80)))
    assert measurable_reason(steep, np.array([20.0, 79.0, 0.0])) == Reason.OK
    assert measurable_reason(steep, np.array([20.0, 81.0, 0.0])) == Reason.LIGHT_GRAZING
    # a cell is kept when some pose lights it within the limit (the swap by reciprocity included),
    # and every candidate pose the planner may use has its light within the limit
    w_i, w_o = GRID.cell_directions(GRID.valid_cells)
    joints, usable, _ = candidate_poses(rig, w_i, w_o)
    light, _ = forward(rig, joints[usable])
    assert np.all(light[:, 2] >= np.cos(np.radians(89.0)))
    counts = {name: reachability(r, GRID).counts() for name, r in (("sim", rig), ("steep", steep))}
    assert 0 < counts["sim"]["LIGHT_GRAZING"] < counts["steep"]["LIGHT_GRAZING"]
    assert reachability(rig, GRID).mask.sum() > reachability(steep, GRID).mask.sum()


@pytest.mark.parametrize("value, found", [(0, "0"), (90.5, "90.5"), ("high", "'high'")])
def test_the_lamps_largest_incidence_is_checked(tmp_path, value, found):
    from goniofrost.core.errors import ConfigError
    bad = _variant(tmp_path, "bad.yaml", lambda r: r["lamp"].update(max_incidence_deg=value))
    with pytest.raises(ConfigError, match=rf"bad\.yaml: lamp\.max_incidence_deg: expected a number in \(0, 90\], "
                                          rf"found {found}$"):
        load_checked_rig(bad)
