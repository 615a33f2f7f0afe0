"""Median command round-trip per protocol on the simulated devices, and a three-axis move sequence.

Run: ``.venv/bin/python benchmarks/drivers_roundtrip.py [--repeats 300] [--speedup 20]``

Round trips are measured twice per protocol: with the plain official client (pyserial line for the
SMC100, pymodbus for Modbus TCP/RTU, dynamixel-sdk READ of Present Position) and through the
goniofrost driver (``Axis.position()``). The move sequence drives the three axes of
``config/rigs/sim.yaml`` together through a list of poses and compares the wall time with the
planned time (longest trapezoid per step / speed-up). Timings are medians; on a shared machine
they are noisy.
"""
from __future__ import annotations

import argparse
import logging
import statistics
import sys
import time
from pathlib import Path


ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from drivers.axis import trapezoid_time  # noqa: E402
from goniofrost.rig.file import load_checked_rig  # noqa: E402
from drivers.rig_devices import RigDevices  # noqa: E402
from sim.clock import SimClock  # noqa: E402
from sim.modbus_drive import SimulatedModbusDrive  # noqa: E402
from sim.rig import SimulatedRig  # noqa: E402

POSES = [  # camera_arm, sample_yaw, sample_tilt (deg)
    (60.0, 30.0, 10.0), (120.0, -45.0, -20.0), (30.0, 90.0, 35.0), (150.0, 0.0, -5.0), (90.0, 0.0, 0.0)]


def median_ms(fn, repeats: int) -> float:
    """Median wall time of ``fn()`` in milliseconds (after 10 warm-up calls)."""
    for _ in range(10):
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * statistics.median(times)


def raw_clients(endpoints: dict, repeats: int) -> dict[str, float]:
    import dynamixel_sdk as sdk
    import serial
    from pymodbus.client import ModbusTcpClient

    out = {}
    tilt = endpoints["sample_tilt"]
    with serial.Serial(tilt["endpoint"], tilt["baud"], timeout=1) as ser:
        def tp():
            ser.write(b"1TP\r\n")
            ser.read_until(b"\r\n")
        out["smc100 (pyserial, 1TP)"] = median_ms(tp, repeats)
    host, port = endpoints["camera_arm"]["endpoint"].rsplit(":", 1)
    client = ModbusTcpClient(host, port=int(port), timeout=1, retries=0)
    client.connect()
    out["modbus-tcp (pymodbus, read 2 regs)"] = median_ms(
        lambda: client.read_holding_registers(0x0120, count=2, device_id=1), repeats)
    client.close()
    yaw = endpoints["sample_yaw"]
    port_h, packet = sdk.PortHandler(yaw["endpoint"]), sdk.PacketHandler(2.0)
    port_h.openPort()
    port_h.setBaudRate(yaw["baud"])
    out["dynamixel (sdk, read Present Position)"] = median_ms(
        lambda: packet.read4ByteTxRx(port_h, yaw["id"], 132), repeats)
    port_h.closePort()
    return out


def rtu_round_trips(repeats: int) -> dict[str, float]:
    from drivers.axis import AxisConfig
    from drivers.modbus_drive import ModbusAxis
    from drivers.rig_devices import open_transport
    from pymodbus.client import ModbusSerialClient
    from pymodbus.framer import FramerType

    dev = SimulatedModbusDrive(SimClock(20.0), transport="rtu", baud=115200)
    entry = dev.start()
    try:
        client = ModbusSerialClient(entry["endpoint"], framer=FramerType.RTU, baudrate=115200,
                                    parity="N", timeout=1, retries=0)
        client.connect()
        raw = median_ms(lambda: client.read_holding_registers(0x0120, count=2, device_id=1), repeats)
        client.close()
        axis = ModbusAxis(AxisConfig("rtu", (0.0, 180.0), 30.0, 60.0), rtu=True)
        axis.connect(open_transport("rtu", {"protocol": "modbus-rtu", "port": entry["endpoint"], "parity": "N"}))
        drv = median_ms(axis.position, repeats)
        axis.close()
    finally:
        dev.stop()
    return {"modbus-rtu (pymodbus, read 2 regs)": raw, "modbus-rtu (driver position())": drv}


def move_sequence(rig, devices: RigDevices, speedup: float) -> tuple[float, float]:
    """Wall time of the pose sequence and its planned time (longest trapezoid per step / speed-up)."""
    axes = devices.axes
    names = ("camera_arm", "sample_yaw", "sample_tilt")
    planned, current = 0.0, {n: axes[n].position() for n in names}
    t0 = time.perf_counter()
    for pose in POSES:
        statuses = [axes[n].move_to(deg) for n, deg in zip(names, pose)]
        for status in statuses:
            status.wait()
        planned += max(trapezoid_time(deg - current[n], rig.axes[n].speed_deg_s,
                                      rig.axes[n].accel_deg_s2) for n, deg in zip(names, pose))
        current = dict(zip(names, pose))
    return time.perf_counter() - t0, planned / speedup


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=300)
    parser.add_argument("--speedup", type=float, default=20.0)
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING)
    rig = load_checked_rig(ROOT / "config" / "rigs" / "sim.yaml")
    with SimulatedRig(rig, speedup=args.speedup) as sim:
        results = raw_clients(sim.endpoints, args.repeats)
        devices = RigDevices.from_rig(sim.resolved_rig())
        devices.connect_all()
        try:
            for name, axis in devices.axes.items():
                results[f"{axis.status().details.get('protocol', name)} (driver position())"] = \
                    median_ms(axis.position, args.repeats)
            for axis in devices.axes.values():
                axis.home().wait()
            wall, planned = move_sequence(rig, devices, args.speedup)
        finally:
            devices.close_all()
    results.update(rtu_round_trips(args.repeats))
    for name, ms in results.items():
        print(f"{name:45s} median {ms:7.3f} ms")
    print(f"three-axis sequence of {len(POSES)} poses: {wall:.3f} s wall, {planned:.3f} s planned "
          f"(speed-up {args.speedup:g})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
