"""The fault matrix: every fault kind on every protocol, rehearsed mid-session from the rig file's
``sim: faults:`` through the command line, then ``--resume``.

Each faulted run must exit 2 with one line on the terminal (no library hex dumps), report axis by
axis what confirmed the stop (and match what the simulated devices really did), say whether the
lamp confirmed it is off, and journal the drill; the resumed run must capture every plan sample
exactly once (journal and samples.csv), never rehearse the drill again, and give samples.csv and
brdf.binary (and every RAW frame) byte-identical to an uninterrupted run without the drill.

Kept fast: the small rig and plan of tests/test_session.py (5 samples, 192 x 144 sensor, a
four-exposure ladder), clock speed-up 50, the model, plan and uninterrupted run shared by the module.
The default run rehearses a covering matrix (``COVERING``: each fault kind once, each protocol
twice, the lamp's drive both heard and unheard); the full 18 cases run under ``-m slow``.
"""
from __future__ import annotations

import csv
import dataclasses
import json
import sqlite3
from contextlib import closing
from pathlib import Path

import pytest
import yaml

from goniofrost.app.cli import main
from goniofrost.capture import runner
from goniofrost.capture.journal import Journal
from goniofrost.capture.records import EventKind, RunStatus
from sim.faults import FAULT_KINDS

from test_session import MATERIAL, frames, small_plan, write_rig

M, AT_SAMPLE = 5, 2  # the drill strikes at plan sample 2: two samples are safe before it
AXES = ("camera_arm", "sample_yaw", "sample_tilt")  # Modbus TCP, Dynamixel, SMC100
COMMS = ("no_reply", "bad_checksum", "drop_byte", "disconnect")  # the device can no longer be heard
# (kind, axis) of the default run: every kind once, every protocol twice; on the camera arm's drive
# (which hosts the lamp) one fault that silences it and one that does not; the unplugged servo
# whose goal is checked
COVERING = (("no_reply", "camera_arm"), ("alarm", "camera_arm"), ("disconnect", "sample_yaw"),
            ("bad_checksum", "sample_yaw"), ("drop_byte", "sample_tilt"), ("stall", "sample_tilt"))
CASES = [pytest.param(kind, axis, id=f"{kind}-{axis}", marks=() if (kind, axis) in COVERING else pytest.mark.slow)
         for axis in AXES for kind in FAULT_KINDS]


def test_the_default_matrix_covers_every_kind_once_and_every_protocol_twice():
    kinds = [kind for kind, _ in COVERING]
    axes = [axis for _, axis in COVERING]
    assert sorted(kinds) == sorted(FAULT_KINDS) and all(axes.count(axis) == 2 for axis in AXES)
    assert {kind in COMMS for kind, axis in COVERING if axis == "camera_arm"} == {True, False}
    assert ("disconnect", "sample_yaw") in COVERING and len(CASES) == len(FAULT_KINDS) * len(AXES)


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    """(folder, rig file, plan, uninterrupted session) shared by the matrix (read-only)."""
    folder = tmp_path_factory.mktemp("matrix")
    rig = write_rig(folder / "rig.yaml")
    # FROST's plan: the drill needs every axis to move at its sample, which this plan gives
    plan, _ = small_plan(rig, M, folder / "plan.json", selector="frost")
    samples = json.loads(plan.read_text())["samples"]
    for axis in AXES:  # every axis moves at the drill's sample, so every drill strikes there
        assert abs(samples[AT_SAMPLE]["joints"][axis] - samples[AT_SAMPLE - 1]["joints"][axis]) > 0.5
    reference = folder / "reference"
    assert main(args(rig, plan, reference)) == 0
    return folder, rig, plan, reference


def args(rig, plan, session, *extra) -> list[str]:
    return ["capture", "--rig", str(rig), "--plan", str(plan), "--session", str(session), "--material", MATERIAL,
            "--no-progress", "--speedup", "50", *extra]


def drill_rig(rig: Path, out: Path, axis: str, kind: str) -> Path:
    """The rig with one drill. Its drivers keep their retries: fewer would make the drilled faults
    fail faster, but also let a reply late on a loaded machine fail the resume."""
    doc = yaml.safe_load(rig.read_text())
    doc["sim"]["faults"] = [{"axis": axis, "kind": kind, "at_sample": AT_SAMPLE}]
    out.write_text(yaml.safe_dump(doc, sort_keys=False))
    return out


def journal(session: Path) -> tuple[list[int], list[tuple[str, dict]]]:
    with closing(sqlite3.connect(f"file:{session / 'session.sqlite'}?mode=ro", uri=True)) as db:
        indices = [r[0] for r in db.execute("SELECT plan_index FROM samples ORDER BY plan_index")]
        events = [(k, json.loads(d)) for k, d in db.execute("SELECT kind, data FROM events ORDER BY id")]
    return indices, events


def csv_indices(session: Path) -> list[int]:
    with open(session / "samples.csv") as handle:
        return sorted(int(row["plan_index"]) for row in csv.DictReader(handle))


@pytest.mark.parametrize("kind, axis", CASES)
def test_a_drill_mid_session_stops_truthfully_and_the_resume_gives_the_uninterrupted_files(
        bench, tmp_path, capsys, monkeypatch, kind, axis):
    folder, rig, plan, reference = bench
    drilled = drill_rig(rig, tmp_path / "rig.yaml", axis, kind)
    session = tmp_path / "s"
    seen = {}
    capture = runner.capture

    def watched(*a, **kw):  # keep the simulated devices, to compare the report with what they really did
        def ready(hardware):
            seen.update(devices={name: hardware.simulation.device(name) for name in AXES},
                        lamp=hardware.simulation.lamp_model)
        return capture(*a, **kw | {"sim": dataclasses.replace(kw["sim"], on_ready=ready)})
    monkeypatch.setattr(runner, "capture", watched)

    # ----- the faulted run: exit 2, one line, a truthful stop report --------------------------------
    assert main(args(drilled, plan, session)) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"goniofrost capture: error: device fault at plan sample "
                                                   f"{AT_SAMPLE}: {axis}: "), err
    assert err.endswith(f"{AT_SAMPLE} of {M} samples are safe in {session / 'session.sqlite'}. Fix the cause, "
                        "then run the same command with --resume\n")
    done, events = journal(session)
    assert done == list(range(AT_SAMPLE))
    [stop] = [d for k, d in events if k == "stop"]
    stops = {s["axis"]: s for s in stop["stops"]}
    unconfirmed = {name for name, s in stops.items() if not s["confirmed"]}
    assert unconfirmed == ({axis} if kind in COMMS else set())
    for name, s in stops.items():
        device = seen["devices"][name]
        if s["confirmed"]:  # where the device said it rests is where the simulated axis really is
            assert s["position_deg"] == pytest.approx(device.true_position_deg(), abs=0.1)
            assert f"{name} at {s['position_deg']:.2f} deg" in err
        else:
            assert s["under_way"] and f"{name} did not confirm the stop: it may still be moving towards " \
                                      f"{s['moving_to']:.1f} deg" in err
    if kind == "disconnect" and axis == "sample_yaw":  # the unplugged servo really kept going to its goal
        assert seen["devices"][axis].motion.target == pytest.approx(
            stops[axis]["moving_to"] * seen["devices"][axis].counts_per_deg, abs=0.5)
    [lamp] = [d for k, d in events if k == "lamp" and "off" in d]
    lamp_heard = not (axis == "camera_arm" and kind in COMMS)  # the lamp is on the camera-arm drive
    assert lamp["off"] is lamp_heard
    assert ("; the lamp is off. " if lamp_heard else "; the lamp did not confirm it is off: it may still be on. ") in err
    if lamp_heard:
        assert seen["lamp"].is_on is False
    drills = [d["state"] for k, d in events if k == "drill"]
    assert drills == ["armed", "struck"]
    # the fault is journaled with the axis, and the run's end with the failed sample and the
    # terminal's words (the monitor shows them)
    message = err[len("goniofrost capture: error: "):-1]
    with Journal.open(session / "session.sqlite") as handle:
        [fault] = [e for e in handle.events() if e["kind"] is EventKind.FAULT]
        _start, end = handle.last_run()
    assert fault["axis"] == axis and fault["message"] in message
    assert (end.status, end.reason, end.axis, end.detail) == (RunStatus.FAULT, message, axis, fault["message"])
    assert end.plan_index == AT_SAMPLE and not (session / "brdf.binary").exists()

    # ----- the resume: every sample once, no second rehearsal, the uninterrupted files ---------------
    assert main(args(drilled, plan, session, "--resume")) == 0
    out = capsys.readouterr()
    assert out.err == "" and f"({M - AT_SAMPLE} this run, {AT_SAMPLE} from before; 2 run(s))" in out.out
    done, events = journal(session)
    assert done == list(range(M)) and csv_indices(session) == list(range(M))
    assert [d["state"] for k, d in events if k == "drill"] == ["armed", "struck"]  # not armed again
    for name in ("samples.csv", "brdf.binary"):
        assert (session / name).read_bytes() == (reference / name).read_bytes(), name
    assert frames(session) == frames(reference)  # every RAW frame, those of the faulted sample included


# One missed reply per protocol (the load case of a busy host): the drill's twin loses the reply to
# the move it just started, then answers again. The driver reads the move back instead of sending
# it again, the device log says so, and the capture completes with the uninterrupted files.
# How each driver reads the move back: Modbus MOVE on (or at the target), Dynamixel Goal Position,
# SMC100 TH (PA has no reply: the reply lost is that of the TE after it).


@pytest.mark.parametrize("axis", AXES)
def test_a_twin_that_misses_one_reply_still_completes_the_capture(bench, tmp_path, capsys, axis):
    folder, rig, plan, reference = bench
    drilled = drill_rig(rig, tmp_path / "rig.yaml", axis, "miss_reply")
    session = tmp_path / "s"
    assert main(args(drilled, plan, session)) == 0
    assert capsys.readouterr().err == ""
    done, events = journal(session)
    assert done == list(range(M))
    assert [d["state"] for k, d in events if k == "drill"] == ["armed", "struck"]
    with closing(sqlite3.connect(f"file:{session / 'session.sqlite'}?mode=ro", uri=True)) as db:
        device_log = [m for (m,) in db.execute("SELECT message FROM events WHERE kind = 'device' ORDER BY id")]
    assert any(m.startswith(f"{axis}: ") and "read back: the device took it" in m for m in device_log), device_log
    for name in ("samples.csv", "brdf.binary"):
        assert (session / name).read_bytes() == (reference / name).read_bytes(), name
