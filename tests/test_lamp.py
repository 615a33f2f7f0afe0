"""The lamp on the simulated drive's Modbus coil and photodiode input register."""
from __future__ import annotations

import logging

import pytest
from pymodbus.client import ModbusTcpClient

from drivers.axis import AxisConfig
from drivers.errors import DeviceError, DeviceTimeout, ExceptionReply, NotConnectedError
from drivers.rig_devices import open_transport
from drivers.lamp import Lamp
from drivers.modbus_drive import ModbusAxis, ModbusLink
from sim.clock import SimClock
from sim.lamp_model import PHOTODIODE_FULL_SCALE, LampModel
from sim.modbus_drive import SimulatedModbusDrive

logging.getLogger("pymodbus").setLevel(logging.CRITICAL)


@pytest.fixture
def drive():
    clock = SimClock(40.0)
    dev = SimulatedModbusDrive(clock, lamp=LampModel(clock, drift_per_hour=0.02, seed=0),
                               coil=0, photodiode_register=0x0200)
    dev.start()
    yield dev
    dev.stop()


def own_section(dev, **kw) -> dict:
    return {"protocol": "modbus-tcp", "host": "127.0.0.1", "port": dev.port, "coil": 0,
            "photodiode_register": 0x0200, **kw}


def own_lamp(dev, **kw) -> Lamp:
    return Lamp.from_section(own_section(dev, **kw))


def connected_lamp(dev, **kw) -> Lamp:
    """A lamp with its own connection, opened by the rig layer."""
    lamp = own_lamp(dev, **kw)
    lamp.connect(open_transport("lamp", own_section(dev, **kw)))
    return lamp


def test_on_off_and_photodiode_follow_the_lamp_model(drive):
    lamp = connected_lamp(drive)
    assert not lamp.is_on() and lamp.photodiode() == 0.0
    lamp.on()
    assert lamp.is_on() and drive.lamp.is_on
    expected = drive.lamp.relative_intensity()
    assert lamp.photodiode() == pytest.approx(expected, abs=2e-4)  # 16-bit counts, sub-ms apart
    lamp.off()
    assert not drive.lamp.is_on and lamp.photodiode() == 0.0
    lamp.close()


def test_full_scale_sets_what_reads_as_one(drive):
    lamp = connected_lamp(drive, full_scale=PHOTODIODE_FULL_SCALE / 2)
    lamp.on()
    assert lamp.photodiode() == pytest.approx(2 * drive.lamp.relative_intensity(), abs=4e-4)
    lamp.close()


def test_official_client_sees_the_coil_the_lamp_wrote(drive):
    lamp = connected_lamp(drive)
    lamp.on()
    client = ModbusTcpClient("127.0.0.1", port=drive.port, timeout=1, retries=0)
    client.connect()
    assert client.read_coils(0, count=1, device_id=1).bits[0] is True
    client.write_coil(0, False, device_id=1)
    assert not lamp.is_on()
    client.close()
    lamp.close()


def test_lamp_shares_the_axis_connection(drive):
    cfg = AxisConfig("camera_arm", (8.0, 172.0), 30.0, 60.0, home_deg=90.0)
    axis = ModbusAxis(cfg)
    lamp = Lamp.from_section({"protocol": "modbus-tcp", "device": "camera_arm", "coil": 0,
                              "photodiode_register": 0x0200}, {"camera_arm": axis})
    assert lamp.link is axis.link
    axis.connect(open_transport("camera_arm", own_section(drive)))
    lamp.connect()
    lamp.on()
    lamp.close()  # the axis owns the link: it stays open
    assert axis.position() == pytest.approx(90.0)
    axis.close()


def test_bad_device_and_unconnected_use(drive):
    with pytest.raises(DeviceError, match="'sample_yaw' is not a Modbus axis"):
        Lamp.from_section({"protocol": "modbus-tcp", "device": "sample_yaw", "coil": 0,
                           "photodiode_register": 0x0200}, {"sample_yaw": object()})
    with pytest.raises(NotConnectedError):
        own_lamp(drive).on()


def test_unmapped_photodiode_register_is_an_exception_reply(drive):
    lamp = connected_lamp(drive, photodiode_register=0x0300)
    with pytest.raises(ExceptionReply) as err:
        lamp.photodiode()
    assert err.value.code == 2 and err.value.command == "read input 0x0300"
    lamp.close()


def test_silent_drive_is_a_timeout(drive):
    lamp = Lamp(ModbusLink("lamp", 1, timeout_s=0.1), retries=0)
    lamp.connect(open_transport("lamp", own_section(drive)))
    drive.inject_fault("no_reply")
    with pytest.raises(DeviceTimeout, match="lamp: write coil 0 on: no reply"):
        lamp.on()
    lamp.close()
