"""Reply timeouts and retry counts are rig keys of every driver section, checked like every other
key, with the manuals' defaults when absent; the rig layer opens each connection with them."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
import yaml

from drivers.config import validate_driver_section
from drivers.rig_devices import axis_from_spec
from goniofrost.rig.file import load_checked_rig
from goniofrost.core.errors import ConfigError

SIM_RIG = Path(__file__).resolve().parents[1] / "config" / "rigs" / "sim.yaml"
RIG = yaml.safe_load(SIM_RIG.read_text())
# axis -> (protocol, the driver's reply timeout attribute in seconds, its default)
DEFAULTS = {"camera_arm": ("modbus-tcp", lambda a: a.link.timeout_s, 0.3),
            "sample_yaw": ("dynamixel", lambda a: a.reply_timeout_ms / 1000.0, 0.1),
            "sample_tilt": ("smc100", lambda a: a.reply_timeout_s, 0.2)}


@pytest.mark.parametrize("name", DEFAULTS)
def test_reply_timeout_and_retries_come_from_the_driver_section(name):
    protocol, timeout_of, default = DEFAULTS[name]
    spec = load_checked_rig(SIM_RIG).axes[name]
    assert spec.driver["protocol"] == protocol
    # the simulated rig's own timeout aside (its twins answer from threads of a busy process)
    spec = dataclasses.replace(spec, driver={k: v for k, v in spec.driver.items() if k != "reply_timeout_ms"})
    axis = axis_from_spec(spec)
    assert (timeout_of(axis), axis.config.retries) == (pytest.approx(default), 2)
    driver = {**spec.driver, "reply_timeout_ms": 750, "retries": 4}
    validate_driver_section(driver, "rig.yaml", f"axes.{name}.driver")
    axis = axis_from_spec(dataclasses.replace(spec, driver=driver))
    assert (timeout_of(axis), axis.config.retries) == (pytest.approx(0.75), 4)


@pytest.mark.parametrize("name", DEFAULTS)
@pytest.mark.parametrize("key, value, expected", [
    ("reply_timeout_ms", 0, "a positive reply timeout in ms"),
    ("retries", 11, "an integer 0-10 (extra attempts of an idempotent read after a reply timeout or a damaged reply; default 2)"),
])
def test_bad_timeout_or_retries_name_the_key(name, key, value, expected):
    section = {**RIG["axes"][name]["driver"], key: value}
    with pytest.raises(ConfigError) as err:
        validate_driver_section(section, "rig.yaml", f"axes.{name}.driver")
    assert (err.value.keypath, err.value.expected, err.value.found) == (f"axes.{name}.driver.{key}", expected, value)
