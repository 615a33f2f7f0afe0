"""Rig files: the shipped rigs load; malformed files give file, key path, expected and found."""
from __future__ import annotations

import copy
from pathlib import Path

import pytest
import yaml

from goniofrost.core.errors import ConfigError
from goniofrost.rig.file import load_checked_rig as load_full_rig
from planner.rig import Role, load_rig

REPO = Path(__file__).resolve().parents[1]
SIM = REPO / "config" / "rigs" / "sim.yaml"
TEMPLATE = REPO / "config" / "rigs" / "template.yaml"


@pytest.fixture(scope="module")
def sim_raw() -> dict:
    return yaml.safe_load(SIM.read_text())


def write(tmp_path, data) -> Path:
    path = tmp_path / "rig.yaml"
    path.write_text(data if isinstance(data, str) else yaml.safe_dump(data))
    return path


def test_sim_rig_loads_with_the_design_geometry():
    rig = load_rig(SIM)
    assert rig.name == "sim-rig" and rig.simulated is True
    assert rig.geometry.light_direction == (1.0, 0.0, 0.0)
    assert rig.geometry.min_arm_separation_deg == 8.0 and rig.geometry.tilt_limit_deg == 80.0
    assert rig.joint_names == ("camera_arm", "sample_yaw", "sample_tilt")
    assert rig.axis(Role.CAMERA_ARM).limits_deg == (8.0, 172.0)
    assert rig.axis("sample_tilt").speed_deg_s == 20.0 and rig.home == (90.0, 0.0, 0.0)
    assert rig.axes["sample_yaw"].driver["protocol"] == "dynamixel"
    assert rig.source == str(SIM)


def test_template_and_composed_loader_accept_the_shipped_rigs(tmp_path):
    assert load_full_rig(SIM).kinematic_hash == load_rig(SIM).kinematic_hash
    filled = tmp_path / "template.yaml"  # its examples taken as the rig's values
    filled.write_text(TEMPLATE.read_text().replace("!fill-in ", ""))
    template = load_full_rig(filled)
    assert template.simulated is False and set(template.joint_names) == {a for a in template.axes}


def test_kinematic_hash_ignores_driver_endpoints_but_not_speeds(tmp_path, sim_raw):
    base = load_rig(SIM).kinematic_hash
    moved = copy.deepcopy(sim_raw)
    moved["axes"]["camera_arm"]["driver"]["port"] = 5020
    assert load_rig(write(tmp_path, moved)).kinematic_hash == base
    faster = copy.deepcopy(sim_raw)
    faster["axes"]["sample_tilt"]["speed_deg_s"] = 25.0
    assert load_rig(write(tmp_path, faster)).kinematic_hash != base


def _edit(raw, keypath, value):
    data = copy.deepcopy(raw)
    *parents, last = keypath.split(".")
    node = data
    for key in parents:
        node = node[key]
    if value is _DELETE:
        del node[last]
    else:
        node[last] = value
    return data


_DELETE = object()

BAD_CASES = [
    # (key path edited, new value, key path reported, expected text, found)
    ("axes.camera_arm.speed", 3.0, "axes.camera_arm.speed", "one of the keys role, limits_deg", "unknown key 'speed'"),
    ("geometry.light_dir", [1, 0, 0], "geometry.light_dir", "one of the keys light_direction", "unknown key 'light_dir'"),
    ("colour", "red", "colour", "one of the keys name, simulated, geometry, axes", "unknown key 'colour'"),
    ("axes.sample_tilt.accel_deg_s2", _DELETE, "axes.sample_tilt.accel_deg_s2", "a number in (0, inf]", "nothing"),
    ("axes.sample_tilt.speed_deg_s", -5, "axes.sample_tilt.speed_deg_s", "a number in (0, inf]", -5),
    ("axes.sample_tilt.speed_deg_s", "fast", "axes.sample_tilt.speed_deg_s", "a number in (0, inf]", "fast"),
    ("axes.sample_yaw.limits_deg", [10, -10], "axes.sample_yaw.limits_deg", "[low, high] with low < high", [10.0, -10.0]),
    ("axes.sample_yaw.limits_deg", [10], "axes.sample_yaw.limits_deg", "a list of 2 numbers", [10]),
    ("axes.camera_arm.home_deg", 200.0, "axes.camera_arm.home_deg", "a number in [8, 172]", 200.0),
    ("axes.camera_arm.role", "arm", "axes.camera_arm.role", "one of camera_arm, sample_yaw, sample_tilt", "arm"),
    ("axes.sample_yaw.role", "camera_arm", "axes", "exactly one axis with role camera_arm", "2 (camera_arm, sample_yaw)"),
    ("geometry.light_direction", [0, 0, 1], "geometry.light_direction", "a horizontal unit vector [x, y, 0]", [0.0, 0.0, 1.0]),
    ("geometry.tilt_limit_deg", 95, "geometry.tilt_limit_deg", "a number in (0, 90)", 95),
    ("simulated", "yes", "simulated", "true or false", "yes"),
    ("axes.sample_tilt.driver", "smc100", "axes.sample_tilt.driver", "a mapping", "smc100"),
    ("lamp.power", 3, "lamp.power", "one of the keys driver", "unknown key 'power'"),
]


@pytest.mark.parametrize("edit_path, value, keypath, expected, found", BAD_CASES,
                         ids=[c[0] + ("-del" if c[1] is _DELETE else "") for c in BAD_CASES])
def test_malformed_rig_names_file_key_expected_and_found(tmp_path, sim_raw, edit_path, value, keypath,
                                                          expected, found):
    path = write(tmp_path, _edit(sim_raw, edit_path, value))
    with pytest.raises(ConfigError) as info:
        load_rig(path)
    err = info.value
    assert (err.source, err.keypath, err.found) == (str(path), keypath, found)
    assert err.expected.startswith(expected)
    assert str(err).startswith(f"{path}: {keypath}: expected {expected}")


def test_duplicate_key_and_bad_yaml_are_refused(tmp_path):
    text = SIM.read_text().replace("  tilt_limit_deg: 80.0", "  tilt_limit_deg: 80.0\n  tilt_limit_deg: 70.0")
    with pytest.raises(ConfigError, match=r"expected valid YAML, found 'duplicate key tilt_limit_deg at line 14, column 3'"):
        load_rig(write(tmp_path, text))
    with pytest.raises(ConfigError, match=r"rig.yaml: \(top level\): expected valid YAML"):
        load_rig(write(tmp_path, "name: [unclosed\n"))
    with pytest.raises(ConfigError, match=r"expected a mapping"):
        load_rig(write(tmp_path, "- just\n- a list\n"))
    with pytest.raises(ConfigError, match=r"expected a readable YAML file"):
        load_rig(tmp_path / "missing.yaml")


def test_section_validators_see_each_driver_camera_and_sim_section(tmp_path):
    seen = []

    def record(section, source, keypath):
        seen.append(keypath)

    def refuse_sim(section, source, keypath):
        raise ConfigError(source, f"{keypath}.clock_speedup", "a number > 0", section["clock_speedup"])

    load_rig(SIM, {"driver": record, "camera": record, "sim": record})
    assert sorted(seen) == sorted(["axes.camera_arm.driver", "axes.sample_yaw.driver",
                                   "axes.sample_tilt.driver", "lamp.driver", "camera", "sim"])
    with pytest.raises(ConfigError, match=r"sim.yaml: sim.clock_speedup: expected a number > 0, found 20.0"):
        load_rig(SIM, {"sim": refuse_sim})


def test_a_validator_may_complete_its_section_with_defaults():
    def complete(section, source, keypath):
        return {**section, "min_snr": 10.0}

    rig = load_rig(SIM, {"camera": complete})
    assert rig.camera["min_snr"] == 10.0 and rig.camera["kind"] == "sim"
    assert "min_snr" not in load_rig(SIM).camera
