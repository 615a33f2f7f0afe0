"""Median command round trip per protocol on the simulated rig, and the time of a three-axis move sequence.

Runs the real drivers against the simulated devices of a rig (in this process: serial devices on
ptys, Modbus on loopback TCP). Round trip = one ``axis.position()`` (Dynamixel READ of Present
Position, SMC100 ``TP``, Modbus read of the feedback position registers). The move sequence homes
all axes, then visits ``--poses`` random poses (seeded), all three axes moving together; it reports
real and simulated seconds against the planned time (sum over poses of the slowest axis's
trapezoid). Timings on a shared machine are noisy: medians of repeats, with p10/p90.

    .venv/bin/python benchmarks/drivers_rtt.py [--rig config/rigs/sim.yaml] [--speedup 20]
        [--repeats 300] [--poses 10] [--seed 0]
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from drivers.axis import trapezoid_time  # noqa: E402
from drivers.rig_devices import RigDevices  # noqa: E402
from goniofrost.rigfile import load_rig  # noqa: E402
from sim.rig import SimulatedRig  # noqa: E402


def round_trips(axis, repeats: int) -> list[float]:
    """Real seconds of ``repeats`` position reads, one at a time."""
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        axis.position()
        out.append(time.perf_counter() - t0)
    return out


def move_sequence(rig, devices, clock, poses: int, seed: int) -> dict:
    """Visit ``poses`` random poses with all axes moving together; real, simulated and planned seconds."""
    rng = np.random.default_rng(seed)
    names = list(devices.axes)
    specs = {n: rig.axes[n] for n in names}
    targets = [{n: float(rng.uniform(*specs[n].limits_deg)) for n in names} for _ in range(poses)]
    planned, here = 0.0, {n: devices.axes[n].position() for n in names}
    real0, sim0 = time.perf_counter(), clock.now()
    for pose in targets:
        statuses = [devices.axes[n].move_to(pose[n]) for n in names]
        for status in statuses:
            status.wait()
        planned += max(trapezoid_time(pose[n] - here[n], specs[n].speed_deg_s, specs[n].accel_deg_s2)
                       for n in names)
        here = pose
    return {"real_s": time.perf_counter() - real0, "sim_s": clock.now() - sim0, "planned_s": planned}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rig", default="config/rigs/sim.yaml")
    p.add_argument("--speedup", type=float, default=20.0)
    p.add_argument("--repeats", type=int, default=300)
    p.add_argument("--poses", type=int, default=10)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    rig = load_rig(args.rig)
    with SimulatedRig(rig, speedup=args.speedup, seed=args.seed) as sim:
        with RigDevices.from_sections(sim.resolved_driver_sections()) as devices:
            for status in [a.home() for a in devices.axes.values()]:
                status.wait()
            print(f"round trip of one position read, {args.repeats} repeats (ms):")
            for name, axis in devices.axes.items():
                ms = np.array(round_trips(axis, args.repeats)) * 1e3
                protocol = rig.axes[name].driver["protocol"]
                print(f"  {protocol:<11} {name:<12} median {statistics.median(ms):6.2f}  "
                      f"p10 {np.percentile(ms, 10):6.2f}  p90 {np.percentile(ms, 90):6.2f}")
            seq = move_sequence(rig, devices, sim.clock, args.poses, args.seed)
    print(f"three-axis move sequence, {args.poses} poses, speed-up {args.speedup:g}: "
          f"real {seq['real_s']:.2f} s, simulated {seq['sim_s']:.2f} s, planned {seq['planned_s']:.2f} s "
          f"(overhead {100 * (seq['sim_s'] / seq['planned_s'] - 1):+.1f} %)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
