"""``goniofrost sim --rig RIG --write-rig OUT.yaml``: a rig file (``simulated: false``) whose drivers
point at the running twins and whose camera is the simulation's, so that a capture runs on it
exactly as on a real rig: the real rig path of ``capture`` (rig layer opens the ports, a rawfile
camera with trigger and target commands), in another process than the twins."""
from __future__ import annotations

import json
import os
import pwd
import re
import select
import signal
import subprocess
import sys
from contextlib import contextmanager
from pathlib import Path

import pytest
import yaml

from goniofrost.app.cli import main

from test_session import M, small_plan, write_rig

READY_S = 60.0  # real seconds for `goniofrost sim` to start (imports, twins, camera service)


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    """(rig file of the simulated rig, the written rig file, the endpoints) while `goniofrost sim` runs
    (one process for the module: it starts in seconds on a loaded machine)."""
    tmp_path = tmp_path_factory.mktemp("twins")
    rig = write_rig(tmp_path / "rig.yaml")
    out = tmp_path / "twins.yaml"
    # --write-rig relative to where sim runs (not where the rig file is then used)
    proc = subprocess.Popen([sys.executable, "-m", "goniofrost", "sim", "--rig", str(rig), "--write-rig", out.name,
                             "--speedup", "50", "--material", "builtin:red-plastic"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    try:
        ready, _, _ = select.select([proc.stdout], [], [], READY_S)
        assert ready, "goniofrost sim did not print its endpoints"
        endpoints = json.loads(proc.stdout.readline())
        yield rig, out, endpoints
    finally:
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=30) == 0, proc.stderr.read()


def test_the_written_rig_file_points_at_the_running_twins(served):
    rig, out, endpoints = served
    doc = yaml.safe_load(out.read_text())
    assert doc["simulated"] is False and "sim" not in doc
    drivers = {name: axis["driver"] for name, axis in doc["axes"].items()}
    host, port = endpoints["camera_arm"]["endpoint"].rsplit(":", 1)
    assert (drivers["camera_arm"]["host"], drivers["camera_arm"]["port"]) == (host, int(port)) == ("127.0.0.1", int(port))
    assert drivers["sample_yaw"]["port"] == endpoints["sample_yaw"]["endpoint"] and os.path.exists(drivers["sample_yaw"]["port"])
    assert drivers["sample_tilt"]["port"] == endpoints["sample_tilt"]["endpoint"]
    camera = doc["camera"]
    assert camera["kind"] == "rawfile" and Path(camera["folder"]).is_dir() and Path(camera["folder"]).is_absolute()
    assert "{exposure_s}" in camera["trigger_command"] and "{target}" in camera["target_command"]
    original = yaml.safe_load(rig.read_text())
    assert camera["intrinsics"] == original["camera"]["intrinsics"] and doc["geometry"] == original["geometry"]


def test_a_capture_through_the_written_rig_file_completes(served, tmp_path, capsys):
    rig, out, _ = served
    plan, _ = small_plan(rig, M, tmp_path / "plan.json")
    session = tmp_path / "s"
    assert main(["capture", "--rig", str(out), "--plan", str(plan), "--session", str(session), "--no-progress"]) == 0
    assert capsys.readouterr().err == ""
    with open(session / "samples.csv") as handle:
        assert len(handle.read().strip().splitlines()) == M + 1  # the header and every plan sample
    assert (session / "brdf.binary").is_file()


def test_a_snap_of_the_sample_after_a_snap_of_the_white_card_shows_the_sample(served, tmp_path, capsys):
    # each console command is a new process whose camera starts out believing the sample is in
    # front; the target command must still be sent, or the white card left by the first snap stays
    rig, out, _ = served
    snap = ["rig", "snap", "--rig", str(out), "--json", "--move", "camera_arm=60"]
    assert main([*snap, "--target", "white", "--out", str(tmp_path / "white.png")]) == 0
    capsys.readouterr()
    assert main([*snap, "--target", "sample", "--out", str(tmp_path / "sample.png")]) == 0
    found = json.loads(capsys.readouterr().out)
    assert found["problem"] is None and sorted(found["markers_found"]) == [0, 1, 2, 3], found


def test_the_written_rig_of_the_pylon_rig_keeps_no_pylon_only_camera_key(tmp_path):
    # sim-pylon.yaml's pixel_format and gain_db were copied into the written rawfile camera, which
    # never reads them; a rawfile section now refuses them, so the written file must leave them out
    from types import SimpleNamespace

    from calib.config import validate_camera_section
    from sim.rig_file import real_rig_document

    source = Path(__file__).resolve().parents[1] / "config" / "rigs" / "sim-pylon.yaml"
    service = SimpleNamespace(port=1, folder=tmp_path)
    doc = real_rig_document(source, SimpleNamespace(axes={}, lamp_driver=None), service)
    camera = doc["camera"]
    assert camera["kind"] == "rawfile" and not {"pixel_format", "gain_db", "serial"} & set(camera)
    assert camera["timeout_s"] == 5.0  # what a folder camera reads is kept
    validate_camera_section(camera, "twins.yaml")


# ----- stopping: SIGTERM ends the twins and the camera service at once, ports released -------------
def _refused(port: int) -> bool:
    """Whether a connection to 127.0.0.1:``port`` is refused (nothing listens there any more)."""
    import socket

    try:
        socket.create_connection(("127.0.0.1", port), timeout=5).close()
    except ConnectionRefusedError:
        return True
    return False


def test_the_camera_service_stops_its_thread_and_releases_its_port(tmp_path):
    """stop() closed the listening socket under the thread blocked in its accept(), which that does
    not wake (Linux): the thread lived on, the port still took connections, and stop() returned
    only when its 5 s join timed out (every `goniofrost sim --write-rig` took 5 s to stop)."""
    from sim.camera_service import CameraService, request

    service = CameraService(camera=None, folder=tmp_path / "frames")
    service.start()
    assert request(service.port, "hello", timeout_s=10).startswith("error unknown request")  # it serves
    service.stop()
    assert not service._thread.is_alive()
    assert _refused(service.port)
    service.stop()   # idempotent


@contextmanager
def sim_writing(tmp_path, out):
    """`goniofrost sim --write-rig OUT` on a small rig in ``tmp_path``, started and ready: yields
    (the process, its endpoints); killed on the way out if a test left it running."""
    rig = write_rig(tmp_path / "rig.yaml")
    proc = subprocess.Popen([sys.executable, "-m", "goniofrost", "sim", "--rig", str(rig), "--write-rig", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    try:
        ready, _, _ = select.select([proc.stdout], [], [], READY_S)
        assert ready, "goniofrost sim did not print its endpoints"
        yield proc, json.loads(proc.stdout.readline())
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


@pytest.mark.parametrize("stop", [signal.SIGTERM, signal.SIGINT])
def test_sim_with_a_written_rig_stops_on_a_signal_and_releases_every_port(tmp_path, stop):
    """The whole command: ready line, SIGTERM (or Ctrl-C's SIGINT), exit 0 with nothing but its
    serving line and the removal of the rig file on stderr, the Modbus drive's port and the camera
    service's port released (the serial twins' ptys are not checked after the exit: another process
    may be given the same /dev/pts number), and the rig file gone with its empty frames folder: left
    behind, it pointed at endpoints that no longer exist, and a later `rig status --rig twins.yaml`
    failed with a refused connection that did not say why."""
    import re

    out = tmp_path / "twins.yaml"
    with sim_writing(tmp_path, out) as (proc, endpoints):
        camera_port = int(re.search(r"--port (\d+)", yaml.safe_load(out.read_text())["camera"]["trigger_command"])[1])
        modbus_port = int(endpoints["camera_arm"]["endpoint"].rsplit(":", 1)[1])
        assert not _refused(camera_port) and not _refused(modbus_port)
        proc.send_signal(stop)
        _, err = proc.communicate(timeout=READY_S)   # a bound against a hang, not a measure of the stop
    assert proc.returncode == 0, err
    assert err.splitlines()[0].startswith("goniofrost sim: serving ")
    assert err.splitlines()[1:] == [f"goniofrost sim: removed {out}: its twins have stopped, so its endpoints are gone"]
    assert _refused(camera_port) and _refused(modbus_port)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rig.yaml"]   # nor twins.yaml.frames, empty


def test_sim_leaves_a_rig_file_replaced_while_it_ran_and_keeps_the_frames_taken(tmp_path):
    """The rig file is removed only if it is still the one this sim wrote (another `sim --write-rig`
    of the same name may have replaced it: that one's twins still run); frames in the frames folder
    are kept, and the stop says both."""
    out, frames = tmp_path / "twins.yaml", tmp_path / "twins.yaml.frames"
    with sim_writing(tmp_path, out) as (proc, _):
        (tmp_path / "other.yaml").write_text("# another sim's twins\n")
        os.replace(tmp_path / "other.yaml", out)
        (frames / "frame_000000.dng").write_bytes(b"a frame")
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=READY_S)   # a bound against a hang, not a measure of the stop
    assert proc.returncode == 0, err
    assert err.splitlines()[1:] == [f"goniofrost sim: left {out}: it is not the file this sim wrote (replaced since); "
                                    f"the frames in {frames} are kept"]
    assert out.read_text() == "# another sim's twins\n" and [p.name for p in frames.iterdir()] == ["frame_000000.dng"]


def test_rig_stop_during_status_watch_stops_the_axes_and_switches_the_lamp_off(served, capsys):
    """`rig stop` during `rig status --watch` left the lamp on: the watcher died of its SIGTERM
    (exit 143, no report). Now the watcher stops every axis, switches the lamp off and says what
    each confirmed, as every holder of the rig does (issue 51, B3)."""
    _, out, _ = served
    assert main(["rig", "lamp", "on", "--rig", str(out)]) == 0
    assert status(out, capsys)["lamp"]["on"] is True
    proc = subprocess.Popen([sys.executable, "-m", "goniofrost", "rig", "status", "--rig", str(out), "--watch",
                             "--interval", "0.1", "--json"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        ready, _, _ = select.select([proc.stdout], [], [], READY_S)
        assert ready and json.loads(proc.stdout.readline())["lamp"]["on"] is True  # it holds the rig, watching
        assert main(["rig", "stop", "--rig", str(out)]) == 0
        assert proc.wait(timeout=30) == 130
        err = proc.stderr.read()
    finally:
        proc.kill()
    assert re.fullmatch(rf"goniofrost rig status: interrupted by a stop request from process {os.getpid()}\. Stopped "
                        r"camera_arm at -?[\d.]+ deg, sample_yaw at -?[\d.]+ deg, sample_tilt at -?[\d.]+ deg; the lamp "
                        r"is off\.\n", err), err
    assert status(out, capsys)["lamp"]["on"] is False


def status(rig, capsys) -> dict:
    capsys.readouterr()
    assert main(["rig", "status", "--rig", str(rig), "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_rig_stop_switches_the_lamp_off_itself_when_the_holder_cannot(served, capsys):
    """A holder that dies of rig stop's SIGTERM without stopping anything (here a bare process
    holding the rig's lock, as a program of another version or a hung one killed would): once it
    has let go, rig stop connects, stops every axis and switches the lamp off itself, and says so."""
    _, out, _ = served
    assert main(["rig", "lamp", "on", "--rig", str(out)]) == 0
    name = yaml.safe_load(out.read_text())["name"]
    code = ("import sys, time; from goniofrost.rig.lock import rig_lock; from goniofrost.rig.file import load_checked_rig\n"
            f"with rig_lock(load_checked_rig({str(out)!r}), 'bare holder'):\n    print('held', flush=True)\n"
            "    time.sleep(600)\n")
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline() == "held\n"
        capsys.readouterr()
        assert main(["rig", "stop", "--rig", str(out)]) == 0
        assert proc.wait(timeout=30) == -signal.SIGTERM
    finally:
        proc.kill()
    err = capsys.readouterr().err
    assert err.startswith(f"asked bare holder (process {proc.pid} of {pwd.getpwuid(os.getuid()).pw_name}) to stop {name}: ") \
        and err.count("\n") == 2, err
    assert re.fullmatch(r"stopped camera_arm at -?[\d.]+ deg, sample_yaw at -?[\d.]+ deg, sample_tilt at -?[\d.]+ deg; "
                        r"lamp off", err.splitlines()[1]), err
    assert status(out, capsys)["lamp"]["on"] is False


# ----- issue 51: the rehearsal rig's clock and material -------------------------------------------
def test_the_written_rig_file_names_its_twins_clock_and_camera_service(served):
    _, out, _ = served
    twins = yaml.safe_load(out.read_text())["twins"]
    assert twins["clock_speedup"] == 50.0 and isinstance(twins["camera_service_port"], int)


def test_a_dry_run_on_the_written_rig_compares_moves_on_the_twins_clock(served, tmp_path, capsys):
    # the twins run 20 x (here 50 x) faster than the wall clock: 33 of 36 moves were marked DIFFERS
    rig, out, _ = served
    plan, _ = small_plan(rig, M, tmp_path / "plan.json")
    capsys.readouterr()
    assert main(["capture", "--rig", str(out), "--plan", str(plan), "--dry-run", "--no-progress"]) == 0
    said = capsys.readouterr().out.splitlines()
    doc = json.loads(plan.read_text())
    planned = sum(s["move_s"] for s in doc["samples"]) + doc["return_home_s"]
    measured = float(said[0].split("measured ")[1].split(" s")[0])
    assert said[0].endswith("on the twins' clock (speed-up 50)")
    # measured 0.3 s of 12.6 s planned on the wall clock; on the twins' clock no move is faster than
    # its trapezoid, and the host's polling (10 ms real, 0.5 s of the twins' at 50 x) only adds
    assert planned * 0.95 <= measured <= planned * 3, said


def test_a_capture_on_the_written_rig_measures_the_material_it_names(served, tmp_path, capsys):
    # the material was fixed when `sim --write-rig` started (red plastic here): another one meant
    # new twins, new ports and a new rig file
    rig, out, _ = served
    plan, _ = small_plan(rig, M, tmp_path / "plan.json")
    reports = {}
    for material in ("builtin:gold", None):
        session = tmp_path / f"s-{material}"
        extra = ["--material", material] if material else []
        assert main(["capture", "--rig", str(out), "--plan", str(plan), "--session", str(session), "--no-progress",
                     *extra]) == 0
        reports[material] = json.loads((session / "report.json").read_text())
    gold = reports["builtin:gold"]
    assert gold["material"] == "builtin:gold" and gold["ground_truth"]["sample_relative_error_median"] < 0.05
    # a capture that names none sees the material `sim --material` gave, whatever the last capture set
    plain = reports[None]
    assert plain["material"] is None
    with open(tmp_path / "s-None" / "samples.csv") as a, open(tmp_path / "s-builtin:gold" / "samples.csv") as b:
        red, gold_rows = [line.split(",") for line in a.read().splitlines()[1:]], \
            [line.split(",") for line in b.read().splitlines()[1:]]
    # gold reflects more red than blue; red plastic's diffuse part is red too but far darker in blue
    # and green: compare the samples' own colours instead of guessing a threshold per material
    assert [row[3:6] for row in red] != [row[3:6] for row in gold_rows]


def test_a_material_on_the_written_rig_is_checked_before_anything_moves(served, tmp_path, capsys):
    rig, out, _ = served
    plan, _ = small_plan(rig, M, tmp_path / "plan.json")
    capsys.readouterr()
    assert main(["capture", "--rig", str(out), "--plan", str(plan), "--session", str(tmp_path / "s"), "--no-progress",
                 "--material", "builtin:no-such"]) == 2
    assert "command line: --material: unknown material 'no-such'" in capsys.readouterr().err
    assert not (tmp_path / "s").exists()
