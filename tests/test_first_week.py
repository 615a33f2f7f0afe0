"""An operator's first week on the simulated rig (issue 51): each finding as the operator met it."""
from __future__ import annotations

import io
import json
import re

import pytest

from goniofrost.app.cli import main

from test_rig_console import SIM_RIG, TEMPLATE, twins  # noqa: F401 - twins is a fixture
from test_session import setup, uninterrupted  # noqa: F401 - fixtures


class _Terminal(io.StringIO):
    """stdout as a terminal: what `rig status --watch` wrote to it, escapes included."""

    def isatty(self) -> bool:
        return True


STAMP = re.compile(r"^reading at \d{4}-\d\d-\d\d \d\d:\d\d:\d\d UTC$")


def test_status_watch_stamps_each_reading_in_a_log(twins, capsys):
    # it printed one table a second with no time: a log of readings could not say when each was
    path, _ = twins
    capsys.readouterr()
    assert main(["rig", "status", "--rig", str(path), "--watch", "--interval", "0.05", "--count", "2"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 10 and "\x1b" not in "".join(lines)   # not a terminal: no cursor moves
    assert STAMP.match(lines[0]) and STAMP.match(lines[5])
    assert [line.split()[0] for line in lines[1:5]] == ["camera_arm", "sample_yaw", "sample_tilt", "lamp"]


def test_status_watch_json_stamps_each_reading(twins, capsys):
    path, _ = twins
    capsys.readouterr()
    assert main(["rig", "status", "--rig", str(path), "--json", "--watch", "--interval", "0.05", "--count", "2"]) == 0
    docs = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert len(docs) == 2 and all(re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ", d["time_utc"]) for d in docs)


def test_status_watch_redraws_in_place_on_a_terminal(twins, monkeypatch):
    # on a terminal it scrolled a new table each second; now the cursor goes back up over the last one
    path, _ = twins
    terminal = _Terminal()
    monkeypatch.setattr("sys.stdout", terminal)
    assert main(["rig", "status", "--rig", str(path), "--watch", "--interval", "0.05", "--count", "3"]) == 0
    text = terminal.getvalue()
    assert text.count("\x1b[5F\x1b[J") == 2 and text.startswith("reading at ")
    frames = [f for f in text.split("\x1b[5F\x1b[J")]
    assert len(frames) == 3 and all(STAMP.match(f.splitlines()[0]) for f in frames)


# ----- item 8: a finished session ------------------------------------------------------------------
def _finished_session(uninterrupted, tmp_path):
    import shutil

    session = tmp_path / "s"
    shutil.copytree(uninterrupted, session)
    return session


def test_a_finished_session_says_it_is_finished_with_or_without_resume(setup, uninterrupted, tmp_path, capsys):
    # it answered "pass --resume to continue it", and --resume then only wrote the same results again
    from test_session import M, capture_args

    _, rig, plan, _ = setup
    session = _finished_session(uninterrupted, tmp_path)
    before = {p.name: p.read_bytes() for p in session.iterdir() if p.is_file()}
    expected = (f"goniofrost capture: error: {session}: this session is finished ({M} of {M} samples, finished): "
                f"nothing is left to capture; its results are in {session}; to measure again, choose a new "
                f"--session folder\n")
    for extra in ((), ("--resume",)):
        capsys.readouterr()
        assert main(capture_args(rig, plan, session, *extra)) == 2
        assert capsys.readouterr().err == expected
        assert {p.name: p.read_bytes() for p in session.iterdir() if p.is_file()} == before


def test_a_finished_session_without_its_results_writes_them_on_resume(setup, uninterrupted, tmp_path, capsys):
    # killed while writing its results: the journal holds every sample, --resume writes them
    from test_session import capture_args

    _, rig, plan, _ = setup
    session = _finished_session(uninterrupted, tmp_path)
    report = (session / "report.json").read_bytes()
    (session / "report.json").unlink()
    capsys.readouterr()
    assert main(capture_args(rig, plan, session)) == 2
    assert capsys.readouterr().err.endswith(f"its results are not written yet: pass --resume to write them, or "
                                            f"choose a new --session folder to measure again\n")
    assert main(capture_args(rig, plan, session, "--resume")) == 0
    assert (session / "report.json").is_file()


# ----- item 9: the template rig file ------------------------------------------------------------------
TO_FILL = ["name", "axes.camera_arm.driver.host", "axes.sample_yaw.driver.port", "axes.sample_tilt.driver.port",
           "camera.folder", "camera.intrinsics.focal_px", "camera.mount.distance_mm"]


def test_an_unedited_template_is_refused_with_the_keys_to_fill_in(capsys):
    # `rig check --offline` called the template "sound", its example addresses and ports included
    assert main(["rig", "check", "--rig", str(TEMPLATE), "--offline"]) == 2
    err = capsys.readouterr().err
    assert err == (f"goniofrost rig: error: {TEMPLATE}: 1 problem(s):\n  {TEMPLATE}: (top level): expected this "
                   f"rig's own value for each key marked !fill-in (the template's example), found "
                   f"'{len(TO_FILL)} keys to fill in: {', '.join(TO_FILL)}'\n")


def test_an_unedited_template_is_refused_by_every_loader(tmp_path):
    from goniofrost.rig.file import load_checked_rig
    from goniofrost.core.errors import ConfigError

    with pytest.raises(ConfigError, match=f"found '{len(TO_FILL)} keys to fill in: name, axes.camera_arm"):
        load_checked_rig(TEMPLATE)


def test_the_template_filled_in_is_sound(tmp_path, capsys):
    filled = tmp_path / "lab.yaml"
    filled.write_text(TEMPLATE.read_text().replace("!fill-in ", ""))
    assert main(["rig", "check", "--rig", str(filled), "--offline"]) == 0
    assert "the rig file is sound (3 axes, a lamp, camera rawfile)" in capsys.readouterr().out


# ----- item 4: the return home the plan lists -------------------------------------------------------
def test_a_capture_returns_home_at_the_end_as_its_plan_says(setup, uninterrupted):
    # PLAN.json's return_home_s and planned_motion_s count the move home; the capture stayed at
    # the last sample's pose (and its report took the return out of the planned motion)
    from goniofrost.capture.journal import Journal
    from goniofrost.capture.records import EventKind
    from goniofrost.rig.file import load_checked_rig

    _, rig, plan, _ = setup
    with Journal.open(uninterrupted / "session.sqlite", read_only=True) as journal:
        events, steps = journal.events(), journal.steps()
    assert [s["kind"] for s in steps][-2:] == ["LampOff", "Home"]
    last = [e for e in events if e["kind"] in (EventKind.HOME, EventKind.LAMP)][-2:]
    assert [e["message"] for e in last] == ["lamp off", "homed camera_arm, sample_yaw, sample_tilt"]
    home = dict(zip(load_checked_rig(rig).joint_names, load_checked_rig(rig).home))
    assert last[1]["data"] == pytest.approx(home, abs=0.1)
    report = json.loads((uninterrupted / "report.json").read_text())
    assert report["times_s"]["planned_motion"] == json.loads(plan.read_text())["planned_motion_s"]


# ----- item 3: the poses on the monitor's page ------------------------------------------------------
def _joints(arm: float) -> dict:
    return {"camera_arm": arm, "sample_yaw": 0.0, "sample_tilt": 0.0}


def _pose_view(**kw):
    from goniofrost.monitor.session_view import PlanSample
    from test_monitor import view

    plan = tuple(PlanSample(i, (i, 1, 2), 10.0 * i, 20.0 + i, _joints(30.0 + 4 * i), 2.0) for i in range(4))
    return view(plan=plan, **kw)


def _done(i: int):
    from goniofrost.monitor.session_view import DoneSample

    return DoneSample(i, 100.0, (0.004,), (0.1, 0.2, 0.3), (0.001,) * 3, "ok", _joints(30.0 + 4 * i), 2.0, 1.0,
                      1001.0 + i, 1001.5 + i, ())


@pytest.fixture(scope="module")
def sim_rig():
    from goniofrost.rig.file import load_checked_rig

    return load_checked_rig(SIM_RIG)


def _arm(pose) -> float:
    return dict((name, deg) for name, _role, deg in pose["joints"])["camera_arm"]


def test_after_a_fault_the_page_shows_the_pose_the_stop_confirmed_and_no_next(sim_rig):
    # it showed "now: sample 2 ... camera_arm 38.05 deg" beside "Stopped camera_arm at 9.96 deg"
    from goniofrost.capture.records import AxisStop, RunEnd, RunStatus
    from goniofrost.monitor.session_view import Stop
    from goniofrost.monitor.status import page_state

    stops = (AxisStop("camera_arm", True, 9.96), AxisStop("sample_yaw", True, 0.0), AxisStop("sample_tilt", True, 0.0))
    end = RunEnd(1, RunStatus.FAULT, "Stopped camera_arm at 9.96 deg", 4, 2, 0, 1000.0, 1004.0, axis="camera_arm",
                 plan_index=2, stops=stops)
    v = _pose_view(done=(_done(0), _done(1)), reached={"joints": _joints(38.05), "plan_index": 2}, run_end=end,
                   stop=Stop(end.status, end.reason, "", "camera_arm", 2, 1004.0))
    poses = page_state(v, 1005.0, rig=sim_rig)["poses"]
    assert poses["current"]["label"] == "where the stop left it (every axis confirmed at rest)"
    assert _arm(poses["current"]) == pytest.approx(9.96) and poses["next"] is None
    # an axis whose stop was not confirmed: its last commanded pose, and the label says which
    unsure = RunEnd(1, RunStatus.FAULT, "...", 4, 2, 0, 1000.0, 1004.0, stops=(AxisStop("camera_arm", False),) + stops[1:])
    poses = page_state(_pose_view(done=(_done(0), _done(1)), reached={"joints": _joints(38.05), "plan_index": 2},
                                  run_end=unsure, stop=Stop(unsure.status, "...", "", None, 2, 1004.0)),
                       1005.0, rig=sim_rig)["poses"]
    assert poses["current"]["label"] == "where the stop left it (camera_arm not confirmed: the last pose it reached shown)"
    assert _arm(poses["current"]) == pytest.approx(38.05)


def test_while_a_sample_is_measured_now_and_next_are_different_samples(sim_rig):
    # it showed "now: sample 33" and "next: sample 33" while sample 33 was being exposed
    from goniofrost.monitor.status import page_state

    v = _pose_view(done=(_done(0), _done(1)), reached={"joints": _joints(38.0), "plan_index": 2})
    poses = page_state(v, 1004.0, rig=sim_rig)["poses"]
    assert (poses["current"]["label"], poses["next"]["label"]) == ("sample 2 (reached)", "sample 3 (target)")


def test_a_finished_session_shows_home_and_no_next(sim_rig):
    # a target-error capture that stopped after 3 of 4 samples still showed "next: sample 3 (target)"
    from goniofrost.capture.records import RunEnd, RunStatus
    from goniofrost.monitor.status import page_state

    end = RunEnd(1, RunStatus.TARGET_REACHED, "target reached", 4, 3, 1, 1000.0, 1010.0)
    home = {a.name: a.home_deg for a in sim_rig.ordered_axes}
    v = _pose_view(done=(_done(0), _done(1), _done(2)), run_end=end, report={"samples": 3},
                   reached={"joints": home, "plan_index": None, "kind": "Home"})
    st = page_state(v, 1011.0, rig=sim_rig)
    assert st["state"] == "finished" and st["poses"]["next"] is None
    assert st["poses"]["current"]["label"] == "home (reached)" and _arm(st["poses"]["current"]) == 90.0


def test_the_last_confirmed_pose_is_read_from_a_home_step_too(tmp_path):
    from goniofrost.monitor.session_view import _reached

    steps = [{"kind": "Move", "status": "done", "plan_index": 4, "result": {"joints": _joints(40.0)}},
             {"kind": "LampOff", "status": "done", "plan_index": None, "result": {}},
             {"kind": "Home", "status": "done", "plan_index": None, "result": {"joints": _joints(90.0), "seconds": 2.0}}]
    assert _reached(steps) == {"joints": _joints(90.0), "plan_index": None, "kind": "Home"}
    assert _reached(steps[:2]) == {"joints": _joints(40.0), "plan_index": 4, "kind": "Move"}


# ----- item 2: long silent steps ------------------------------------------------------------------
def test_train_shows_its_stages_on_a_terminal_and_nothing_in_a_log(monkeypatch, tmp_path):
    # train ran 115 s and 197 s with nothing but a brief tabulating bar
    from goniofrost.core.grid import MerlGrid
    from goniofrost.frost.training import train

    four = ["white-diffuse", "blue-plastic", "gold", "green-felt"]
    terminal = _Terminal()
    monkeypatch.setattr("sys.stderr", terminal)
    train(["builtin"], only=four, grid=MerlGrid(10, 10, 20), k_max=6, cache=True, progress=True)
    shown = re.findall(r"train (\d)/6: ([a-z -]+) \(", terminal.getvalue())
    assert [name for _, name in dict.fromkeys(shown)] == ["tabulating", "mapping", "components",
                                                          "noise cross-validation", "dictionary", "saving"]
    log = io.StringIO()  # not a terminal: no bar (a cached model is not trained again either)
    monkeypatch.setattr("sys.stderr", log)
    train(["builtin"], only=four, grid=MerlGrid(10, 10, 20), k_max=6, cache=False, progress=True)
    assert log.getvalue() == ""


def test_the_demo_says_it_is_training_and_how_long_that_takes(monkeypatch, tmp_path, capsys):
    from goniofrost.app import demo
    from goniofrost.core.grid import MerlGrid

    grid = MerlGrid(10, 10, 20)
    said = demo.training_note("red-plastic", grid, None)
    assert said.startswith("demo: training the model on the 73 built-in materials other than red-plastic") and "once: the model is cached" in said
    assert "about 1 to 2 min on 2 cores" in said
    demo.train_without("red-plastic", grid, progress=False)
    assert demo.training_note("red-plastic", grid, None) is None  # cached: nothing to wait for


# ----- item 1: rig check probes the camera ----------------------------------------------------------
def _check_json(path, capsys) -> tuple[int, dict, str]:
    capsys.readouterr()
    code = main(["rig", "check", "--rig", str(path), "--json"])
    captured = capsys.readouterr()
    return code, json.loads(captured.out), captured.err


def _camera(doc) -> dict:
    return next(d for d in doc["devices"] if d["device"] == "camera")


def test_check_grabs_a_frame_of_the_simulated_camera(tmp_path, capsys):
    from test_session import write_rig

    code, doc, _ = _check_json(write_rig(tmp_path / "rig.yaml"), capsys)
    camera = _camera(doc)
    assert code == 0 and camera["answers"] and camera["error"] is None
    assert camera["link"] == "sim (the simulated camera)" and camera["identity"] == "model Sim Gonio Cam"
    assert camera["exposure_range_s"] == [0.002, 0.128]   # the simulated camera takes any: its ladder's
    frame = camera["frame"]
    assert frame["exposure_s"] == 0.002 and len(frame["median"]) == 3 and frame["saturated_fraction"] == 0.0


def _pylon_rig(tmp_path, **camera):
    import yaml

    from test_pylon_session import write_rig

    path = write_rig(tmp_path / "pylon.yaml")
    raw = yaml.safe_load(path.read_text())
    raw["camera"].update(camera)
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    return path


def test_check_names_the_pylon_camera_its_exposure_range_and_a_frame(tmp_path, capsys):
    pytest.importorskip("pypylon")
    code, doc, _ = _check_json(_pylon_rig(tmp_path), capsys)
    camera = _camera(doc)
    assert code == 0 and camera["answers"], camera
    assert camera["identity"].startswith("vendor Basler, model Emulation, serial 0815-")
    lo, hi = camera["exposure_range_s"]
    assert lo <= 0.000015625 and hi >= 0.128 and camera["frame"]["exposure_s"] == pytest.approx(0.000015625, rel=0.1)


def test_check_of_a_pylon_camera_with_a_wrong_serial_exits_2(tmp_path, capsys):
    # it passed with exit 0: only `rig snap` found the camera missing
    pytest.importorskip("pypylon")
    code, doc, err = _check_json(_pylon_rig(tmp_path, serial="40012345"), capsys)
    camera = _camera(doc)
    assert code == 2 and not camera["answers"] and "camera" in err.splitlines()[-1]
    assert "no camera with serial '40012345'" in camera["error"]
    assert camera["causes"][0].startswith("camera.serial is not this camera's")


def test_check_of_a_rawfile_camera_whose_service_is_dead_exits_2(twins, tmp_path, capsys):
    # a rig file of `sim --write-rig` whose camera service has stopped passed with exit 0
    import socket
    import sys

    import yaml

    path, _ = twins
    with socket.socket() as s:  # a loopback port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    raw = yaml.safe_load(path.read_text())
    client = f"{sys.executable} -m sim.camera_service --port {port}"
    raw["camera"].update(timeout_s=5.0, trigger_command=f"{client} expose {{exposure_s}}",
                         target_command=f"{client} target {{target}}")
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    capsys.readouterr()
    assert main(["rig", "check", "--rig", str(path)]) == 2
    captured = capsys.readouterr()
    camera_line = next(line for line in captured.out.splitlines() if line.startswith("camera "))
    assert " NO " in camera_line and f"no simulated camera on 127.0.0.1:{port}" in captured.out
    assert captured.err == "goniofrost rig: error: 1 of 5 devices did not answer cleanly: camera\n"


# ----- item 10: no compilation inside selection_seconds ----------------------------------------------
def test_every_kernel_a_selection_calls_is_compiled_when_its_module_is_imported():
    # selection_seconds is timed inside select_bayes / select_cells, after their modules' imports:
    # a kernel compiled on its first call would put numba's compilation (15 to 19 s after a plain
    # install, without ./dev setup) inside the timed selection; a kernel with its signatures is
    # compiled (or loaded from numba's cache) at import, before the clock starts
    from goniofrost.frost import bayes_kernels, bayes_selection, selection, somp_kernels

    called = {bayes_kernels: ("init_forms", "update_forms"), somp_kernels: ("pack_atoms", "block_scores", "rank1_step")}
    for module, names in called.items():
        for name in names:
            assert getattr(module, name).signatures, f"{module.__name__}.{name} compiles on its first call"
    for module, kernels in ((bayes_selection, bayes_kernels), (selection, somp_kernels)):
        used = set(re.findall(r"kernels\.(\w+)\(", open(module.__file__).read()))
        assert used <= set(called[kernels]), used


def test_a_move_timed_on_the_twins_clock_allows_the_hosts_latency_times_the_speed_up():
    # at 20 x a host's 50 ms to send a move and poll its arrival is 1 s of the twins' clock: at load
    # 20 a dry run on the twins marked 13 to 26 of 37 moves DIFFERS by 0.6 to 1.6 s
    from goniofrost.app.rig_console import dry_run_text
    from goniofrost.capture.console import HOST_LATENCY_S, TimedMove, latency_allowance

    assert latency_allowance(1.0) == 0.5 and latency_allowance(20.0) == pytest.approx(0.5 + 19 * HOST_LATENCY_S)
    late = TimedMove(3, 0.93, 1.61, latency_allowance(20.0))
    assert not late.differs and TimedMove(3, 0.93, 1.61).differs
    assert TimedMove(3, 2.0, 2.0 + latency_allowance(20.0) + 0.01, latency_allowance(20.0)).differs
    text = dry_run_text([late, TimedMove(None, 1.0, 1.1, latency_allowance(20.0))], 20.0)
    assert text.splitlines()[1] == f"every move within 20 % or {latency_allowance(20.0):g} s of the plan"
