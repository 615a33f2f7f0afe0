"""The one configuration mechanism (goniofrost.core.config_check): a key table checks a section,
fills its defaults, checks nested sections, and every failure reads the same way."""
from __future__ import annotations

import pytest

from goniofrost.core.config_check import (ABSENT, Key, check_items, check_section, is_natural, is_text, join,
                                          number_in)
from goniofrost.core.errors import ConfigError

INNER = {"x": Key(is_natural, "an integer >= 0", 0)}
TABLE = {
    "name": Key(is_text, "a non-empty text"),
    "seed": Key(is_natural, "an integer >= 0", 7),
    "folder": Key(is_text, "a folder path", ABSENT),
    "inner": Key(lambda v: isinstance(v, dict), "a mapping", {}, nested=lambda v, s, kp: check_section(v, INNER, s, kp)),
    "items": Key(lambda v: isinstance(v, list), "a list", [], nested=lambda v, s, kp: check_items(v, INNER, s, kp)),
    "speed": number_in(0.0, 10.0, low_open=True),
}


def message(section, **kw) -> str:
    with pytest.raises(ConfigError) as err:
        check_section(section, TABLE, "rig.yaml", "top", **kw)
    return str(err.value)


def test_defaults_are_filled_in_an_absent_key_stays_out_and_nested_sections_are_completed():
    out = check_section({"name": "a", "speed": 2, "inner": {"x": 1}}, TABLE, "rig.yaml", "top")
    assert out == {"name": "a", "seed": 7, "inner": {"x": 1}, "items": [], "speed": 2}
    assert check_items([{}], INNER, "rig.yaml", "items") == [{"x": 0}]
    with pytest.raises(ConfigError, match=r"^rig.yaml: top.name: expected a non-empty text, found .nothing.$"):
        check_section({}, TABLE, "rig.yaml", "top")
    assert "folder" not in out


@pytest.mark.parametrize("section, expected", [
    ({"name": "a", "speed": 1, "colour": 1},
     'rig.yaml: top.colour: expected one of the keys name, seed, folder, inner, items, speed, found "unknown key \'colour\'"'),
    ({"speed": 1}, "rig.yaml: top.name: expected a non-empty text, found 'nothing'"),
    ({"name": "a", "speed": 0}, "rig.yaml: top.speed: expected a number in (0, 10], found 0"),
    ({"name": "a", "speed": 1, "inner": {"x": -1}}, "rig.yaml: top.inner.x: expected an integer >= 0, found -1"),
    ({"name": "a", "speed": 1, "items": [{"x": 1}, {"y": 1}]},
     "rig.yaml: top.items[1].y: expected one of the keys x, found \"unknown key 'y'\""),
    ([1], "rig.yaml: top: expected a mapping, found [1]"),
    ({"name": "a", "speed": 1, 3: 1}, "rig.yaml: top.3: expected a text key, found 3"),
])
def test_every_failure_names_file_key_expected_and_found(section, expected):
    assert message(section) == expected


def test_open_sections_keep_unknown_keys_and_the_context_joins_the_list_of_keys():
    out = check_section({"name": "a", "speed": 1, "joints": [1]}, TABLE, "p.json", "", open_keys=True)
    assert out["joints"] == [1]
    assert message({"name": "a", "speed": 1, "colour": 1}, context="(protocol x)").endswith(
        "speed (protocol x), found \"unknown key 'colour'\"")


def test_join():
    assert (join("", "name"), join("axes.arm", "driver"), join("a", 3)) == ("name", "axes.arm.driver", "a.3")
