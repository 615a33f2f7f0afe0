"""The simulated SMC100 against an independent client: QMI's ``Newport_SMC100CC`` driver (PyPI
``qmi``), which knows nothing of goniofrost. It reads the identity (VE), TE and TB after a refused
command, PT, homes (OR), moves (PA, PR), reads TP, TH and TS, over the twin's pty."""
from __future__ import annotations

import time

import pytest
from qmi.core.context import QMI_Context
from qmi.core.exceptions import QMI_InstrumentException
from qmi.instruments.newport import Newport_Smc100Cc
from qmi.instruments.newport.actuators import LinearActuator

from sim.clock import SimClock
from sim.smc100 import SimulatedSMC100

# a rotation stage seen through QMI's linear-actuator model (units of the controller, deg); its travel
# is wider than the controller's SL/SR (-50, 50), so that QMI sends a PA the controller refuses
STAGE = LinearActuator(-80.0, 80.0, 20.0, 0.001, 0.001, 0.0, 0.0001)


@pytest.fixture
def qmi_smc(monkeypatch):
    # QMI waits 0.5 s after every TE for a real controller to execute; the twin has executed
    # the command before it answers, so the wait only slows the test down
    monkeypatch.setattr(Newport_Smc100Cc, "COMMAND_EXEC_TIME", 0.0)
    device = SimulatedSMC100(SimClock(40.0), address=1, position=3.0, velocity=20.0, acceleration=40.0,
                             limits=(-50.0, 50.0))
    device.start()
    context = QMI_Context("goniofrost-test")
    smc = Newport_Smc100Cc(context, "smc", f"serial:{device._port.path}:baudrate=57600", "SIM-0001", {1: STAGE})
    smc.open()
    yield smc, device
    smc.close()
    device.stop()


def wait_state(smc, state: str, timeout_s: float = 5.0) -> None:
    t_end = time.monotonic() + timeout_s
    while smc.get_positioner_error_and_state()[1] != state:
        assert time.monotonic() < t_end, f"not {state!r} in time"
        time.sleep(0.01)


def test_qmi_reads_the_identity_and_the_error_text_of_a_refused_command(qmi_smc):
    smc, device = qmi_smc
    idn = smc.get_idn()
    assert (idn.vendor, idn.model, idn.version, idn.serial) == ("Newport", "SMC100CC", "2.0.0", "SIM-0001")
    assert smc.get_positioner_error_and_state() == ([], "NOT REFERENCED from RESET")
    assert smc.get_error() == ("@", "No error")  # QMI's own text for "@"
    assert smc.get_motion_time(10.0) == pytest.approx(1.0)  # 10 units at VA 20, AC 40
    assert device.true_position_deg() == 3.0 and device.state == 0x0A  # nothing moved


def test_qmi_homes_moves_and_reads_positions(qmi_smc):
    smc, device = qmi_smc
    smc.home_search()
    wait_state(smc, "READY from HOMING.")
    with pytest.raises(QMI_InstrumentException, match="^Error G: DISPLACEMENT OUT OF LIMITS$"):
        smc.move_absolute(60.0)  # beyond SR: QMI reads TE, then TB for the text
    assert smc.get_positioner_error_and_state() == ([], "READY from HOMING.")
    smc.move_absolute(12.5)
    wait_state(smc, "READY from MOVING.")
    assert smc.get_position() == pytest.approx(12.5) and smc.get_setpoint() == pytest.approx(12.5)
    smc.move_relative(-2.5)
    wait_state(smc, "READY from MOVING.")
    assert smc.get_position() == pytest.approx(10.0) and device.true_position_deg() == pytest.approx(10.0)
