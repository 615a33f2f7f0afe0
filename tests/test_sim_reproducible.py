"""Reproducible simulation: lamp drift and exposures run on the clock's nominal time, which only the
device commands advance, so two simulated rigs driven by the same commands give identical readings
and identical DNG files however much real time passes between the commands."""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import yaml

from drivers.axis import AxisConfig
from drivers.rig_devices import open_transport
from drivers.lamp import Lamp
from drivers.modbus_drive import ModbusAxis
from sim.camera_bench import CameraBench
from sim.clock import SimClock
from sim.lamp_model import LampModel
from sim.modbus_drive import SimulatedModbusDrive
from sim.motion import TrapezoidMotion

RIG = Path(__file__).resolve().parents[1] / "config" / "rigs" / "sim.yaml"
FAST_DRIFT = 3.6  # per hour: 0.1 % per simulated second, so that one move changes the lamp visibly


def test_nominal_time_counts_moves_side_by_side_and_exposures_end_to_end():
    clock = SimClock(1e6)
    a, b = TrapezoidMotion(clock, 0.0, 10.0, 10.0), TrapezoidMotion(clock, 0.0, 10.0, 10.0)
    a.start_move(40.0)  # 5 s: accelerate 1 s, cruise 3 s, brake 1 s
    b.start_move(10.0)  # 2 s, started with it: side by side
    assert clock.nominal_time() == 5.0
    clock.sleep(0.5)    # an exposure after the move
    assert clock.nominal_time() == 5.5
    time.sleep(0.01)    # real time passing (10^4 simulated seconds on now()) is not nominal time
    b.start_move(0.0)   # 2 s after what came before
    assert clock.nominal_time() == 7.5 and clock.now() > 1e4


def lamp_readings(real_pause_s: float) -> list[float]:
    """Photodiode readings over Modbus around two moves of the drive, pausing in real time between."""
    clock = SimClock(200.0)
    drive = SimulatedModbusDrive(clock, lamp=LampModel(clock, drift_per_hour=FAST_DRIFT, seed=1), position_deg=90.0)
    drive.start()
    axis = ModbusAxis(AxisConfig("camera_arm", (8.0, 172.0), 30.0, 60.0, home_deg=90.0, tolerance_deg=0.02),
                      )
    lamp = Lamp.from_section({"protocol": "modbus-tcp", "device": "camera_arm", "coil": 0,
                              "photodiode_register": 0x0200}, {"camera_arm": axis})
    try:
        axis.connect(open_transport("camera_arm", {"protocol": "modbus-tcp", "host": "127.0.0.1",
                                                   "port": drive.port}))
        lamp.connect()
        lamp.on()
        readings = [lamp.photodiode()]
        for target in (150.0, 30.0):
            axis.move_to(target).wait()
            time.sleep(real_pause_s)
            readings.append(lamp.photodiode())
        return readings
    finally:
        axis.close()
        drive.stop()


def test_same_commands_give_the_same_lamp_readings_whatever_the_real_time_between():
    quick, slow = lamp_readings(0.0), lamp_readings(0.3)  # 0.3 s real = 60 s on the wall-clock time
    assert quick == slow
    assert len(set(quick)) == 3  # the lamp did drift over the moves: the comparison is not vacuous


def camera_run(folder: Path, real_pause_s: float, seed: int = 5) -> tuple[list[bytes], list[float]]:
    """Three exposures and photodiode readings on a camera bench, pausing in real time between."""
    rig = yaml.safe_load(RIG.read_text())
    camera = {**rig["camera"], "intrinsics": {"image_size_px": [96, 64], "focal_px": [800.0, 800.0],
                                              "principal_point_px": [47.5, 31.5]}}   # a small frame
    grey = ("test:grey", lambda w_i, w_o: np.full(3, 0.2))
    bench = CameraBench(grey, rig["sim"]["camera"], camera, seed=seed, speedup=100.0, drift_per_hour=FAST_DRIFT)
    bench.lamp.on()
    frames, readings = [], []
    for i, exposure in enumerate((0.5, 2.0, 1.0)):
        path = folder / f"{i}.dng"
        bench.camera.capture(exposure, path)
        frames.append(path.read_bytes())
        readings.append(bench.lamp.photodiode())
        time.sleep(real_pause_s)
    return frames, readings


def test_same_commands_give_byte_identical_frames_whatever_the_real_time_between(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    frames_a, readings_a = camera_run(tmp_path / "a", 0.0)
    frames_b, readings_b = camera_run(tmp_path / "b", 0.2)  # 0.2 s real = 20 s on the wall clock
    assert readings_a == readings_b and len(set(readings_a)) == 3
    assert [len(f) for f in frames_a] == [len(f) for f in frames_b]
    for i, (a, b) in enumerate(zip(frames_a, frames_b)):
        assert a == b, f"frame {i} differs"


def test_another_seed_gives_other_noise(tmp_path):
    for name in ("a", "b"):
        (tmp_path / name).mkdir()
    frames, _ = camera_run(tmp_path / "a", 0.0, seed=5)
    other_frames, _ = camera_run(tmp_path / "b", 0.0, seed=6)
    assert all(a != b for a, b in zip(frames, other_frames))
