"""The rig file's ``sim:`` section: every key checked (unknown, wrong type, out of range: one line
naming the file, key path, expected and found), through the rig loader and the command line (exit 2,
nothing started or written); and the rig loader refuses to run without a validator it names."""
from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from goniofrost.app.cli import main
from goniofrost.rig import file as rig_file
from goniofrost.rig.file import load_checked_rig
from goniofrost.core.errors import ConfigError
from sim.camera import _SIM_CAMERA_KEYS as SIM_CAMERA_KEYS
from sim.config import SIM_KEYS, validate_sim_section

REPO = Path(__file__).resolve().parents[1]
SIM_RIG = REPO / "config" / "rigs" / "sim.yaml"
EXPECTED_KEYS = f"one of the keys {', '.join(SIM_KEYS)}"


def rig_with_sim(tmp_path, sim) -> Path:
    raw = yaml.safe_load(SIM_RIG.read_text())
    raw["sim"] = sim
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    return path


def test_defaults_are_filled_in():
    assert validate_sim_section({}, "rig.yaml") == {"clock_speedup": 1.0, "seed": 0,
                                                    "lamp": {"drift_per_hour": 0.02}, "faults": [],
                                                    "misalignment_deg": {}}
    checked = load_checked_rig(SIM_RIG).sim
    assert (checked["clock_speedup"], checked["seed"], checked["lamp"]) == (20.0, 0, {"drift_per_hour": 0.02})
    assert checked["camera"]["prnu"] == 0.01  # the camera's own defaults, filled by its validator


@pytest.mark.parametrize("sim, keypath, expected, found", [
    ({"clok_speedup": 5}, "sim.clok_speedup", EXPECTED_KEYS, "unknown key 'clok_speedup'"),
    ({"clock_speedup": "fast"}, "sim.clock_speedup", "a number > 0 (simulated seconds per real second)", "fast"),
    ({"clock_speedup": 0}, "sim.clock_speedup", "a number > 0 (simulated seconds per real second)", 0),
    ({"seed": -1}, "sim.seed", "an integer >= 0", -1),
    ({"seed": True}, "sim.seed", "an integer >= 0", True),
    ({"lamp": 0.02}, "sim.lamp", "a mapping with drift_per_hour", 0.02),
    ({"lamp": {"drift": 0.1}}, "sim.lamp.drift", "one of the keys drift_per_hour", "unknown key 'drift'"),
    ({"lamp": {"drift_per_hour": 5}}, "sim.lamp.drift_per_hour",
     "a number in [-1, 1] (relative intensity change per simulated hour)", 5),
    # the image size is the camera model's (camera.intrinsics), not the simulated sensor's
    ({"camera": {"width": 320}}, "sim.camera.width", f"one of the keys {', '.join(SIM_CAMERA_KEYS)}", "unknown key 'width'"),
    ({"camera": {"white_level": 16383}}, "sim.camera.black_level", "an integer in [0, 65535)", "nothing"),
    ([1, 2], "sim", "a mapping", [1, 2]),
    ({"misalignment_deg": [0.6, 1.1]}, "sim.misalignment_deg", "a mapping {axis name: degrees}", [0.6, 1.1]),
    ({"misalignment_deg": {"sample_yaw": 45.0}}, "sim.misalignment_deg.sample_yaw",
     "a zero error in degrees within +-10", 45.0),
    ({"misalignment_deg": {"sample_yaw": "1"}}, "sim.misalignment_deg.sample_yaw",
     "a zero error in degrees within +-10", "1"),
    ({"faults": "stall"}, "sim.faults", "a list of {axis, kind, at_sample} mappings", "stall"),
    ({"faults": ["stall"]}, "sim.faults[0]", "a mapping", "stall"),
    ({"faults": [{"axis": "sample_yaw", "kind": "jam", "at_sample": 3}]}, "sim.faults[0].kind",
     "one of ['no_reply', 'bad_checksum', 'drop_byte', 'alarm', 'stall', 'disconnect', 'miss_reply', 'lamp_dim', "
     "'lamp_cut', 'interlock_open', 'silent']", "jam"),
    ({"faults": [{"axis": "sample_yaw", "kind": "clear", "at_sample": 3}]}, "sim.faults[0].kind",
     "one of ['no_reply', 'bad_checksum', 'drop_byte', 'alarm', 'stall', 'disconnect', 'miss_reply', 'lamp_dim', "
     "'lamp_cut', 'interlock_open', 'silent']", "clear"),
    ({"faults": [{"axis": "sample_yaw", "kind": "stall", "at_sample": -1}]}, "sim.faults[0].at_sample",
     "a plan sample index >= 0", -1),
    ({"faults": [{"axis": "sample_yaw", "kind": "stall"}]}, "sim.faults[0].at_sample",
     "a plan sample index >= 0", "nothing"),
    ({"faults": [{"axis": "sample_yaw", "kind": "stall", "at_sample": 3, "when": 1}]}, "sim.faults[0].when",
     "one of the keys axis, kind, at_sample, level, duration_s", "unknown key 'when'"),
    ({"faults": [{"kind": "stall", "at_sample": 3}]}, "sim.faults[0].axis",
     "the name of an axis of this rig (kind stall)", "nothing"),
    ({"faults": [{"kind": "lamp_dim", "at_sample": 3, "duration_s": 30}]}, "sim.faults[0].level",
     "a number in (0, 1) (the dimmed lamp's intensity factor) (kind lamp_dim)", "nothing"),
    ({"faults": [{"kind": "lamp_cut", "at_sample": 3, "duration_s": 30, "level": 0.5}]}, "sim.faults[0].level",
     "no level for kind lamp_cut", 0.5),
    ({"faults": [{"kind": "lamp_cut", "at_sample": 3, "duration_s": 0}]}, "sim.faults[0].duration_s",
     "a number of nominal seconds > 0", 0),
    ({"faults": [{"axis": "sample_yaw", "kind": "stall", "at_sample": 3, "duration_s": 5}]},
     "sim.faults[0].duration_s", "no duration_s for kind stall", 5),
])
def test_bad_values_name_file_key_expected_and_found(sim, keypath, expected, found):
    with pytest.raises(ConfigError) as err:
        validate_sim_section(sim, "rig.yaml")
    assert (err.value.source, err.value.keypath, err.value.expected, err.value.found) == \
        ("rig.yaml", keypath, expected, found)


def test_the_rig_loader_checks_the_sim_section(tmp_path):
    path = rig_with_sim(tmp_path, {"clok_speedup": 5})
    with pytest.raises(ConfigError, match=rf"^{path}: sim.clok_speedup: expected one of the keys clock_speedup, seed, "):
        load_checked_rig(path)


def test_fault_drills_load_and_must_name_an_axis_of_the_rig(tmp_path):
    drill = {"axis": "sample_yaw", "kind": "stall", "at_sample": 3}
    assert load_checked_rig(rig_with_sim(tmp_path, {"faults": [drill]})).sim["faults"] == [drill]
    path = rig_with_sim(tmp_path, {"faults": [drill, {**drill, "axis": "sample_pitch"}]})
    with pytest.raises(ConfigError) as err:
        load_checked_rig(path)
    assert str(err.value) == (f"{path}: sim.faults[1].axis: expected one of the rig's axes "
                              "['camera_arm', 'sample_tilt', 'sample_yaw'], found 'sample_pitch'")


def test_a_misalignment_loads_and_must_name_axes_of_the_rig(tmp_path):
    built_wrong = {"camera_arm": 0.6, "sample_yaw": -1.1, "sample_tilt": 0.4}
    assert load_checked_rig(rig_with_sim(tmp_path, {"misalignment_deg": built_wrong})).sim["misalignment_deg"] == built_wrong
    path = rig_with_sim(tmp_path, {"misalignment_deg": {"camera_arm": 0.6, "turntable": 1.0}})
    with pytest.raises(ConfigError) as err:
        load_checked_rig(path)
    assert str(err.value) == (f"{path}: sim.misalignment_deg.turntable: expected an axis of the rig "
                              "(camera_arm, sample_yaw, sample_tilt), found 'turntable'")


@pytest.mark.parametrize("sim, line", [
    ({"clok_speedup": 5}, "sim.clok_speedup: expected " + EXPECTED_KEYS + ", found \"unknown key 'clok_speedup'\""),
    ({"clock_speedup": "fast"},
     "sim.clock_speedup: expected a number > 0 (simulated seconds per real second), found 'fast'"),
], ids=["unknown-key", "wrong-type"])
@pytest.mark.parametrize("command", ["capture", "sim"])
def test_command_line_refuses_a_bad_sim_section_with_one_line(tmp_path, capsys, command, sim, line):
    rig = rig_with_sim(tmp_path, sim)
    session = tmp_path / "session"
    args = {"capture": ["capture", "--rig", str(rig), "--plan", str(tmp_path / "plan.json"),
                        "--session", str(session), "--material", "builtin:red-plastic", "--no-progress"],
            "sim": ["sim", "--rig", str(rig)]}[command]
    assert main(args) == 2
    out, err = capsys.readouterr()
    assert err == f"goniofrost {command}: error: {rig}: {line}\n" and out == ""
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rig.yaml"]  # nothing written


@pytest.mark.parametrize("entry, problem", [
    (("sim.config", "validate_sim_sectoin"), "module sim.config has no function validate_sim_sectoin"),
    (("sim.konfig", "validate_sim_section"), "its validator sim.konfig.validate_sim_section is missing"),
])
def test_a_missing_validator_fails_loudly(monkeypatch, entry, problem):
    monkeypatch.setitem(rig_file.VALIDATORS, "sim", entry)
    with pytest.raises(ImportError, match=problem):
        load_checked_rig(SIM_RIG)


def test_a_missing_cross_check_fails_loudly(monkeypatch):
    monkeypatch.setattr(rig_file, "RIG_CHECKS", (("sim.config", "check_sim_against_rigg"),))
    with pytest.raises(ImportError, match="the rig file cannot be checked: module sim.config has no function "
                                          "check_sim_against_rigg"):
        load_checked_rig(SIM_RIG)
