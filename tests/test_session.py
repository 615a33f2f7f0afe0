"""Capture sessions on the simulated rig: end to end, SIGKILL + resume, SIGINT, a run that failed
before its first sample, and rig/plan/model files that do not belong together (refused before
anything moves). A device fault mid-session is rehearsed by the drills of tests/test_fault_matrix.py.

Small and fast: a 6-material model on the 30 x 30 x 60 grid, a 5-sample plan, a rig file with a
short exposure ladder and a small simulated sensor, and a simulated clock 10-50x real time.
"""
from __future__ import annotations

import csv
import json
import os
import re
import signal
import sqlite3
import subprocess
import sys
import time
from contextlib import closing
from pathlib import Path

import numpy as np
import pytest
import yaml

from goniofrost.capture.inputs import load_inputs
from goniofrost.capture.options import SessionOptions, StopRule
from goniofrost.capture.runner import capture
from goniofrost.plan.make import PlanRequest
from goniofrost.rig.file import load_checked_rig
from goniofrost.datasets import shown_material
from goniofrost.rig.simulated import rig_devices
from goniofrost.app.cli import main
from goniofrost.core.grid import MerlGrid
from goniofrost.frost import confidence
from goniofrost.capture.journal import Journal
from goniofrost.capture.records import EventKind, RunStatus
from goniofrost.brdf.merl_file import read_merl

from conftest import train_once
from goniofrost.rig.hardware import SimOptions

REPO = Path(__file__).resolve().parents[1]
GRID = MerlGrid(30, 30, 60)
TRAINING = ["white-diffuse", "blue-plastic", "gold", "white-ceramic", "blue-car-paint", "green-felt"]
MATERIAL = "builtin:red-plastic"  # held out of TRAINING
M = 5


def write_rig(path: Path, **camera_arm) -> Path:
    """The simulated rig file with a short calibration (and optional camera_arm overrides)."""
    rig = yaml.safe_load((REPO / "config" / "rigs" / "sim.yaml").read_text())
    rig["camera"].update(exposures_s=[0.002, 0.008, 0.032, 0.128], dark_frames=1, flat_frames=1)
    # a small sensor (2.4 px/mm at the sample): the card still fits the frame at every pose
    rig["camera"]["intrinsics"].update(image_size_px=[240, 180], focal_px=[2400.0, 2400.0],
                                       principal_point_px=[119.5, 89.5])
    rig["axes"]["camera_arm"].update(camera_arm)
    path.write_text(yaml.safe_dump(rig, sort_keys=False))
    return path


def session_model():
    """The small model (TRAINING on GRID, k <= 18) in this process's cache, trained once per test run
    (``train_once``): the session tests' and many other modules'."""
    return train_once("session-model", ["builtin"], only=TRAINING, grid=GRID, k_max=18)


def small_plan(rig: Path, m: int, out: Path, **plan_options):
    """(plan file ``out``, model): the small model (``session_model``) and its m-sample plan on
    ``rig`` (Bayesian unless ``plan_options``, fields of ``PlanRequest``, say otherwise), the setting the
    session tests share."""
    from goniofrost.core.cache import cache_path
    from goniofrost.app.demo import plan_on_rig

    model = session_model()
    request = PlanRequest(samples=m, rig=load_checked_rig(rig), **plan_options)
    return plan_on_rig(model, cache_path("models", model.info["cache_key"], ""), request, out), model


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    """(folder, rig file, plan file, model) shared by the module's tests (read-only)."""
    folder = tmp_path_factory.mktemp("session")
    rig = write_rig(folder / "rig.yaml")
    plan, model = small_plan(rig, M, folder / "plan.json")
    return folder, rig, plan, model


def material_truth() -> np.ndarray:
    """The held-out material on the test grid's valid cells (n_valid, 3) in 1/sr."""
    from goniofrost.datasets import parse_material_spec
    dataset, name = parse_material_spec(MATERIAL)
    return dataset.tabulate([name], GRID)[0].astype(np.float64)


def capture_args(rig, plan, session, *extra) -> list[str]:
    return ["capture", "--rig", str(rig), "--plan", str(plan), "--session", str(session),
            "--material", MATERIAL, "--no-progress", *extra]


def journal_rows(session: Path) -> list[tuple]:
    """(plan_index, committed_utc) of every journaled sample, read by a second connection."""
    path = session / "session.sqlite"
    if not path.exists():
        return []
    try:
        with closing(sqlite3.connect(f"file:{path}?mode=ro", uri=True, timeout=1)) as db:
            return db.execute("SELECT plan_index, committed_utc FROM samples ORDER BY plan_index").fetchall()
    except sqlite3.OperationalError:  # created but no table yet
        return []


def csv_indices(session: Path) -> list[int]:
    with open(session / "samples.csv") as handle:
        return [int(row["plan_index"]) for row in csv.DictReader(handle)]


# ----- end to end ----------------------------------------------------------------------------
def test_session_journals_every_sample_once_reconstructs_and_reports(setup, tmp_path, capsys):
    folder, rig, plan, model = setup
    session = tmp_path / "s"
    assert main(capture_args(rig, plan, session, "--speedup", "50")) == 0
    out = capsys.readouterr().out
    assert f"{M} samples on rig 'sim-rig'" in out and "error against the ground truth builtin:red-plastic" in out

    with Journal.open(session / "session.sqlite") as journal:
        records, events, meta = journal.samples(), journal.events(), journal.meta()
        assert journal.calibration()["version"] == 1
    doc = json.loads(plan.read_text())
    assert [r.plan_index for r in records] == list(range(M))
    assert [r.cell for r in records] == [int(GRID.flat_index(*s["cell"])) for s in doc["samples"]]
    assert meta["model_hash"] == model.content_hash and meta["material"] == MATERIAL
    # the engine's own events; a driver's log record ("device": a read retried on a busy machine)
    # may fall anywhere between them
    kinds = [e["kind"] for e in events if e["kind"] != "device"]
    assert kinds[:4] == ["session", "home", "lamp", "calibration"] and kinds[-3:] == ["lamp", "home", "session"]
    for r, s in zip(records, doc["samples"]):  # the axes reached the plan's joints within tolerance
        assert all(abs(r.joints[a] - s["joints"][a]) <= 0.1 for a in s["joints"])
        assert r.snr >= 10 and all(np.isfinite(r.rgb)) and all(0 < sg < v for sg, v in zip(r.sigma, r.rgb))

    # samples.csv is the journal, readable by the reconstruction's own reader
    from goniofrost.frost.reconstruction import reconstruct_bayes
    from goniofrost.frost.samples_file import read_samples_csv, sample_sigmas
    cells, values, extra = read_samples_csv(session / "samples.csv", GRID)
    np.testing.assert_array_equal(cells, [r.cell for r in records])
    np.testing.assert_array_equal(values, [r.rgb for r in records])
    assert [float(v) for v in extra["sigma_g"]] == [r.sigma[1] for r in records]

    # brdf.binary is the Bayesian reconstruction of exactly those values and their sigmas, on the
    # model's grid, as `goniofrost reconstruct` makes it from samples.csv; its std file beside it
    brdf = read_merl(session / "brdf.binary", GRID)
    expected = reconstruct_bayes(model, GRID.valid_position(cells), values, sigmas=sample_sigmas("x", extra))
    np.testing.assert_allclose(brdf[GRID.valid_cells], expected.brdf, rtol=1e-12)
    np.testing.assert_allclose(read_merl(session / "brdf.std.binary", GRID)[GRID.valid_cells], expected.std, rtol=1e-12)

    report = json.loads((session / "report.json").read_text())
    assert report["prediction"]["point_prediction_before_centring"] == pytest.approx(expected.predicted_error, rel=1e-12)
    assert report["prediction"]["calibrated"] is True and "uncalibrated" not in (session / "summary.txt").read_text()
    # every capture states its calibrated bound, as a target-error capture's last batch would
    from goniofrost.frost.reconstruction import error_bound
    bound = error_bound(model, GRID.valid_position(cells), values, sample_sigmas("x", extra), 0.95)
    assert bound.upper == np.inf  # this small model has no bound calibration at M samples
    assert (report["prediction"]["median_estimate"], report["prediction"]["bound"]) == (bound.median, None)
    assert report["ground_truth"]["median_estimate"] == bound.median
    assert (f"reconstruction (log-relative MSE): error: no bound at 95 % confidence (median estimate "
            f"{bound.median:.3g})") in (session / "summary.txt").read_text().splitlines()
    assert report["prediction"]["error_figure"] == confidence.figure_of(bound)
    assert "target_error" not in report
    assert report["samples"] == M and report["captured_this_run"] == M and report["runs"] == 1
    assert report["times_s"]["motion"] > 0 and report["times_s"]["capture"] > 0
    truth = report["ground_truth"]
    # the bar: no more than 20 % above reconstructing the same cells from exact values
    assert truth["log_relative_mse"] <= 1.2 * truth["log_relative_mse_exact_samples"]
    assert truth["point_prediction_before_centring"] == report["prediction"]["point_prediction_before_centring"]
    assert truth["sample_relative_error_median"] < 0.05
    import matplotlib.image
    from goniofrost.brdf.merl_file import valid_to_full
    from goniofrost.brdf.preview import preview_of
    assert matplotlib.image.imread(session / "preview.png").ndim == 3
    true_brdf = valid_to_full(material_truth(), GRID)
    std = read_merl(session / "brdf.std.binary", GRID)
    assert report["rendering_snr_db"] == pytest.approx(preview_of(brdf, GRID, true_brdf, std=std).snr_db, abs=1e-9)
    assert f"{report['rendering_snr_db']:.2f} dB" in out
    assert (session / "summary.txt").read_text() in out
    # the closing line names every file the capture wrote (it left out brdf.json and summary.txt)
    written = ["brdf.binary", "brdf.std.binary", "brdf.json", "samples.csv", "preview.png", "report.json", "summary.txt"]
    assert out.splitlines()[-1] == f"wrote {', '.join(written)} in {session}"
    assert all((session / name).is_file() for name in written)

    # resuming a session whose samples are all journaled moves nothing and writes the same results,
    # samples.csv from the journal (a kill between the last commit and its CSV line, before the
    # results: with its results written a finished session refuses --resume, test_first_week)
    n_events = len(events)
    full_csv = (session / "samples.csv").read_text()
    (session / "samples.csv").write_text(full_csv[:full_csv.rindex("\n", 0, -1) + 1])
    (session / "report.json").unlink()
    assert main(capture_args(rig, plan, session, "--resume")) == 0
    assert (session / "samples.csv").read_text() == full_csv
    with Journal.open(session / "session.sqlite") as journal:
        assert journal.samples() == records and len(journal.events()) == n_events
    np.testing.assert_array_equal(read_merl(session / "brdf.binary", GRID), brdf)


def test_on_a_rig_built_wrong_the_capture_without_alignment_completes_flagged_and_worse(setup, tmp_path, capsys):
    """The same plan on the simulated rig with the issue's zero errors: the markers sit off the camera
    model's prediction (flagged, under the tolerance), and the samples, measured at other
    directions than recorded, are far worse; with the true offsets they are right again."""
    folder, rig, plan, model = setup
    raw = yaml.safe_load(rig.read_text())
    raw["sim"]["misalignment_deg"] = {"camera_arm": 0.6, "sample_yaw": -1.1, "sample_tilt": 0.4}
    raw["camera"]["marker_tolerance_px"] = 8.0   # this sensor sees 2.4 px/mm, a third of sim.yaml's 8
    wrong = tmp_path / "wrong.yaml"
    wrong.write_text(yaml.safe_dump(raw, sort_keys=False))
    assert main(capture_args(wrong, plan, tmp_path / "s", "--speedup", "50")) == 0
    out = capsys.readouterr().out
    report = json.loads((tmp_path / "s" / "report.json").read_text())
    assert report["markers_off"] and "the rig may be misaligned; run goniofrost align" in out
    unaligned = report["ground_truth"]["sample_relative_error_median_at_measured_directions"]

    from goniofrost.app.demo import plan_on_rig
    from goniofrost.core.cache import cache_path
    exact = tmp_path / "alignment.json"
    exact.write_text(json.dumps({"offsets_deg": raw["sim"]["misalignment_deg"]}))
    aligned_plan = plan_on_rig(model, cache_path("models", model.info["cache_key"], ""),
                               PlanRequest(samples=M, rig=load_checked_rig(wrong, exact)), tmp_path / "plan.json")
    assert main(capture_args(wrong, aligned_plan, tmp_path / "a", "--speedup", "50", "--alignment", str(exact))) == 0
    report = json.loads((tmp_path / "a" / "report.json").read_text())
    aligned = report["ground_truth"]["sample_relative_error_median_at_measured_directions"]
    assert report["markers_off"] == [] and aligned < 0.01 and unaligned > 5 * aligned


# ----- nothing lost ----------------------------------------------------------------------------
def start_capture(rig, plan, session, speedup: str) -> subprocess.Popen:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    return subprocess.Popen([sys.executable, "-m", "goniofrost", *capture_args(rig, plan, session, "--speedup", speedup)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, cwd=REPO)


def wait_for_samples(session: Path, proc: subprocess.Popen, n: int, timeout: float = 60.0) -> list[tuple]:
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        rows = journal_rows(session)
        if len(rows) >= n:
            return rows
        if proc.poll() is not None:
            pytest.fail(f"capture ended early ({proc.returncode}): {proc.stderr.read().decode()}")
        time.sleep(0.01)
    proc.kill()
    pytest.fail(f"no {n} journaled samples within {timeout} s")


# ----- reproducible: the same seed gives the same files, interrupted or not ----------------------
@pytest.fixture(scope="module")
def uninterrupted(setup, tmp_path_factory) -> Path:
    """A session captured in one run at speed-up 50 (read-only)."""
    folder, rig, plan, _ = setup
    session = tmp_path_factory.mktemp("uninterrupted") / "s"
    assert main(capture_args(rig, plan, session, "--speedup", "50")) == 0
    return session


def frames(session: Path) -> dict:
    """{relative path: bytes} of every RAW frame of a session."""
    return {str(p.relative_to(session)): p.read_bytes() for p in sorted(session.glob("*/*.dng"))}


def test_two_runs_with_the_same_seed_give_byte_identical_frames_samples_and_brdf(setup, uninterrupted, tmp_path):
    folder, rig, plan, _ = setup
    session = tmp_path / "s"
    assert main(capture_args(rig, plan, session, "--speedup", "20")) == 0  # other real timing throughout
    for name in ("samples.csv", "brdf.binary"):
        assert (session / name).read_bytes() == (uninterrupted / name).read_bytes(), name
    assert frames(session) == frames(uninterrupted) and len(frames(session)) > M


KILL_POINTS = {  # where the kill lands -> (the condition to wait for, what the resume's summary says)
    "calibration": (lambda s: (s / "calibration" / "dark_e1_0.dng").exists(), f"({M} this run, 0 from before; 2 run(s))"),
    "mid-session": (lambda s: len(journal_rows(s)) >= 2, "this run, "),
    "final reconstruction": (lambda s: len(journal_rows(s)) == M, f"(0 this run, {M} from before; 1 run(s))"),
}


@pytest.mark.parametrize("point", list(KILL_POINTS))
def test_a_run_killed_then_resumed_gives_the_files_of_an_uninterrupted_run(setup, uninterrupted, tmp_path,
                                                                          capsys, point):
    folder, rig, plan, _ = setup
    session = tmp_path / "s"
    reached, summary = KILL_POINTS[point]
    proc = start_capture(rig, plan, session, speedup="10")
    t_end = time.monotonic() + 60
    while not reached(session):
        assert proc.poll() is None and time.monotonic() < t_end, f"capture ended or hung before the {point}"
        time.sleep(0.002)
    proc.send_signal(signal.SIGKILL)
    assert proc.wait(timeout=10) == -signal.SIGKILL
    killed_at = time.time()
    assert not (session / "report.json").exists(), "the kill must land before the results are written"
    if point == "calibration":
        assert journal_rows(session) == [] and not (session / "calibration" / "calibration.npz").exists()
    before = journal_rows(session)
    raw_before = {p.name: p.stat().st_mtime for p in (session / "raw").glob("sample_*.dng")}
    if point == "mid-session":
        assert 2 <= len(before) < M, "the kill must land mid-session"

    assert main(capture_args(rig, plan, session, "--resume", "--speedup", "50")) == 0
    assert summary in capsys.readouterr().out
    after = journal_rows(session)
    assert [i for i, _ in after] == list(range(M)) and csv_indices(session) == list(range(M))
    assert after[:len(before)] == before  # samples journaled before the kill untouched (same commit times)
    with Journal.open(session / "session.sqlite") as journal:
        runs = journal.runs()
    if point == "mid-session":
        # the killed run has a start and no end; the resume's run ends finished
        assert [(start.run, start.samples_done) for start, _ in runs] == [(1, 0), (2, len(before))]
        assert runs[0][1] is None and runs[1][1].status is RunStatus.FINISHED and runs[1][1].samples_captured == M
        assert json.loads((session / "report.json").read_text())["runs"] == 2
    for index, _ in before:  # no RAW file of a sample captured before the kill was taken again
        for path in (session / "raw").glob(f"sample_{index:04d}_e*.dng"):
            assert path.stat().st_mtime == raw_before[path.name] and path.stat().st_mtime < killed_at
    for name in ("samples.csv", "brdf.binary"):
        assert (session / name).read_bytes() == (uninterrupted / name).read_bytes(), f"{name} after a kill in the {point}"
    assert frames(session) == frames(uninterrupted)  # every RAW frame too, those taken again included


def test_a_run_that_failed_before_its_first_sample_does_not_block_the_same_command(setup, uninterrupted,
                                                                                   tmp_path, capsys):
    folder, rig, plan, _ = setup
    doc = yaml.safe_load(rig.read_text())
    doc["sim"]["faults"] = [{"axis": "sample_tilt", "kind": "alarm", "at_sample": 0}]  # the first move fails
    drilled = tmp_path / "rig.yaml"
    drilled.write_text(yaml.safe_dump(doc, sort_keys=False))
    session = tmp_path / "s"
    command = capture_args(drilled, plan, session, "--speedup", "50")
    assert main(command) == 2
    assert "device fault at plan sample 0: sample_tilt: " in capsys.readouterr().err
    assert journal_rows(session) == [] and (session / "session.sqlite").exists()
    assert main(command) == 0  # the same command, no --resume: the drill rehearsed once already
    assert f"({M} this run, 0 from before; 2 run(s))" in capsys.readouterr().out
    for name in ("samples.csv", "brdf.binary"):  # the calibration of the first run was kept, and its state
        assert (session / name).read_bytes() == (uninterrupted / name).read_bytes(), name


def test_a_second_capture_of_a_running_session_is_refused_at_once(setup, tmp_path, capsys):
    folder, rig, plan, _ = setup
    session = tmp_path / "s"
    proc = start_capture(rig, plan, session, speedup="10")
    try:
        wait_for_samples(session, proc, 1)
        for extra in ((), ("--resume",)):
            started = time.monotonic()
            err = run_refused(capture_args(rig, plan, session, *extra), capsys)
            assert err == f"goniofrost capture: error: session {session} is in use by process {proc.pid}; wait " \
                          "for it to finish or stop it (Ctrl-C) before starting another capture on it\n"
            assert time.monotonic() - started < 5        # at once: no device was connected
        rows = journal_rows(session)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
    # the kernel released the killed holder's lock: a resume runs and finds every sample once
    assert main(capture_args(rig, plan, session, "--resume", "--speedup", "50")) == 0
    assert [i for i, _ in journal_rows(session)] == list(range(M)) and journal_rows(session)[:len(rows)] == rows


def test_a_refusal_names_the_process_holding_the_lock_not_the_pid_left_in_its_file(setup, tmp_path, capsys):
    """A run writes its PID into session.lock only once accepted (a refused run leaves the file as
    it was), so while a holder checks its inputs the file still names an earlier run: the refusal
    takes the holder from the kernel's lock table."""
    import fcntl

    folder, rig, plan, _ = setup
    session = tmp_path / "s"
    session.mkdir()
    (session / "session.lock").write_text("999999\n")   # the PID of a run long gone
    fd = os.open(session / "session.lock", os.O_RDWR)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)   # a holder that has not claimed the session yet: this process
        err = run_refused(capture_args(rig, plan, session), capsys)
    finally:
        os.close(fd)
    assert err == f"goniofrost capture: error: session {session} is in use by process {os.getpid()}; wait " \
                  "for it to finish or stop it (Ctrl-C) before starting another capture on it\n"
    assert (session / "session.lock").read_text() == "999999\n" and sorted(p.name for p in session.iterdir()) == [
        "session.lock"]


def test_a_session_that_is_a_file_is_a_one_line_error(setup, tmp_path, capsys):
    folder, rig, plan, _ = setup
    (tmp_path / "s").write_text("not a folder")
    err = run_refused(capture_args(rig, plan, tmp_path / "s"), capsys)
    assert err == f"goniofrost capture: error: {tmp_path / 's'}: cannot write: a part of the path is a file, " \
                  "not a directory\n"
    assert (tmp_path / "s").read_text() == "not a folder"


def test_sigint_stops_every_axis_and_leaves_a_resumable_journal(setup, tmp_path):
    folder, rig, plan, _ = setup
    session = tmp_path / "s"
    proc = start_capture(rig, plan, session, speedup="10")
    wait_for_samples(session, proc, 1)
    proc.send_signal(signal.SIGINT)
    assert proc.wait(timeout=20) == 130
    err = proc.stderr.read().decode()
    # one line, saying where each axis was confirmed at rest and that the lamp is off
    assert err.startswith("goniofrost capture: interrupted by SIGINT") and err.count("\n") == 1
    assert re.search(r"\. Stopped camera_arm at [-\d.]+ deg, sample_yaw at [-\d.]+ deg, sample_tilt at [-\d.]+ deg; "
                     r"the lamp is off\. \d of 5 samples are safe in .*\. Run the same command with --resume to "
                     r"continue\n$", err), err
    with Journal.open(session / "session.sqlite") as journal:
        [event] = [e for e in journal.events() if e["kind"] is EventKind.INTERRUPTED]
        _start, end = journal.last_run()
        assert all(s.confirmed for s in end.stops) and end.lamp_off is True and event["data"]["lamp_off"] is True
        assert [e["kind"] for e in journal.events()][-2:] == [EventKind.STOP, EventKind.LAMP]
        assert end.status is RunStatus.STOPPED_BY_OPERATOR
        assert end.reason == err[len("goniofrost capture: "):-1]  # the terminal's words
        done = journal.done_indices()
    assert 1 <= len(done) < M and sorted(csv_indices(session)) == sorted(done)
    assert not (session / "brdf.binary").exists()


def test_a_full_disk_mid_session_is_one_line_and_the_session_resumes_once_there_is_room(setup, mounted, capsys):
    folder, rig, plan, _ = setup
    disk = mounted("size=1200k")  # room for the calibration and a sample or two, not for five
    session = disk / "s"
    assert main(capture_args(rig, plan, session, "--speedup", "50")) == 2
    err = capsys.readouterr().err
    assert err.startswith("goniofrost capture: error: capture failed ") and err.count("\n") == 1
    assert ": cannot write: no space left on the device" in err and "; the lamp is off. " in err
    assert "run the same command with --resume\n" in err
    assert not [p for p in session.rglob(".*") if p.is_file()]  # no temporary file left behind
    done = [i for i, _ in journal_rows(session)]
    assert len(done) < M
    subprocess.run(["mount", "-o", "remount,size=16m", str(disk)], check=True)
    assert main(capture_args(rig, plan, session, "--resume", "--speedup", "50")) == 0
    assert f"({M - len(done)} this run, {len(done)} from before; 2 run(s))" in capsys.readouterr().out
    assert [i for i, _ in journal_rows(session)] == list(range(M)) and sorted(csv_indices(session)) == list(range(M))


IN_THE_WAY = "cannot write: it is a directory, where the capture writes a file: move it away or choose another --session"


@pytest.mark.parametrize("where, options, expected", [
    ("session.sqlite/", (), "session.sqlite: cannot write: it is a directory, where the session journal goes: move "
                            "it away or choose another --session"),
    ("raw", (), "raw: cannot write: a part of the path is a file, not a directory"),
    ("samples.csv/", (), f"samples.csv: {IN_THE_WAY}"),
    ("brdf.binary/", (), f"brdf.binary: {IN_THE_WAY}"),
    ("report.json/", (), f"report.json: {IN_THE_WAY}"),
    ("brdf.bsdf/", ("--bsdf",), f"brdf.bsdf: {IN_THE_WAY}"),
    ("brdf.bsdf/", ("--bsdf-format", "pbrt"), f"brdf.bsdf: {IN_THE_WAY}"),
])
def test_an_output_path_of_the_session_in_the_way_is_refused_before_the_rig_starts(setup, tmp_path, capsys,
                                                                                    monkeypatch, where, options,
                                                                                    expected):
    """A folder named brdf.binary (or brdf.bsdf with --bsdf) was refused only at the end, after every
    sample had been measured; a file named raw after the calibration had moved the axes. Now each
    is one line before any device is connected, and the folder is left as it was."""
    import goniofrost.rig.hardware as hardware

    folder, rig, plan, _ = setup
    monkeypatch.setattr(hardware, "open_hardware", lambda *a, **k: pytest.fail("the rig was started"))
    session = tmp_path / "s"
    session.mkdir()
    in_the_way = session / where.rstrip("/")
    in_the_way.mkdir() if where.endswith("/") else in_the_way.write_text("not a folder")
    assert main(capture_args(rig, plan, session, "--speedup", "50", *options)) == 2
    assert capsys.readouterr().err == f"goniofrost capture: error: {session / expected}\n"
    assert [p.name for p in session.iterdir()] == [in_the_way.name]
    assert not in_the_way.is_dir() or list(in_the_way.iterdir()) == []


def test_a_folder_named_brdf_bsdf_is_in_the_way_only_of_a_capture_that_writes_it(setup, tmp_path, monkeypatch):
    """Without --bsdf the capture writes no brdf.bsdf: a folder of that name is left alone, and the
    capture goes on to start the rig (stopped there)."""
    import goniofrost.rig.hardware as hardware

    class Started(Exception):
        pass

    def start(*args, **kwargs):
        raise Started

    folder, rig, plan, _ = setup
    monkeypatch.setattr(hardware, "open_hardware", start)
    session = tmp_path / "s"
    (session / "brdf.bsdf").mkdir(parents=True)
    with pytest.raises(Started):
        main(capture_args(rig, plan, session, "--speedup", "50"))


# ----- files that do not belong together --------------------------------------------------------
def run_refused(args, capsys) -> str:
    assert main(args) == 2
    return capsys.readouterr().err


def test_plan_of_another_model_is_refused_before_anything_moves(setup, tmp_path, capsys):
    from goniofrost.frost.model import FrostModel

    folder, rig, plan, model = setup
    other = FrostModel(grid=model.grid, names=list(reversed(model.names)), eps=model.eps,
                       dictionary=np.asarray(model.dictionary), singular_values=np.asarray(model.singular_values),
                       coefficients=np.asarray(model.coefficients), mean=np.asarray(model.mean),
                       reference=np.asarray(model.reference), weight=np.asarray(model.weight))
    other.save(tmp_path / "other-model")
    doc = json.loads(plan.read_text())
    doc["model"]["path"] = str(tmp_path / "other-model")
    (tmp_path / "plan.json").write_text(json.dumps(doc))
    err = run_refused(capture_args(rig, tmp_path / "plan.json", tmp_path / "s"), capsys)
    assert f"{tmp_path / 'plan.json'}: model.hash: expected the hash of the model {tmp_path / 'other-model'}" in err
    assert "this plan was selected with another model" in err
    assert not (tmp_path / "s").exists()


def test_plan_of_another_rig_or_an_unscheduled_plan_is_refused(setup, tmp_path, capsys):
    folder, rig, plan, _ = setup
    faster = write_rig(tmp_path / "faster.yaml", speed_deg_s=45.0)
    err = run_refused(capture_args(faster, plan, tmp_path / "s"), capsys)
    assert f"{plan}: rig.kinematic_hash: expected " in err and f"(scheduled for rig 'sim-rig', {rig})" in err
    doc = json.loads(plan.read_text())
    del doc["rig"]
    (tmp_path / "plan.json").write_text(json.dumps(doc))
    err = run_refused(capture_args(rig, tmp_path / "plan.json", tmp_path / "s"), capsys)
    assert "rig: expected a plan scheduled for a rig (goniofrost plan --rig RIG.yaml), found None" in err
    assert not (tmp_path / "s").exists()


def test_a_plan_for_a_rig_of_another_name_or_with_its_name_edited_is_refused(setup, tmp_path, capsys):
    """The same kinematics under another name (another rig built alike: its own alignment and
    lock), or rig.name edited in the plan: both were accepted, though the README says refused."""
    folder, rig, plan, _ = setup
    other = yaml.safe_load(rig.read_text()) | {"name": "sim-rig-2"}
    (tmp_path / "other.yaml").write_text(yaml.safe_dump(other, sort_keys=False))
    err = run_refused(capture_args(tmp_path / "other.yaml", plan, tmp_path / "s"), capsys)
    assert err == (f"goniofrost capture: error: {plan}: rig.name: expected 'sim-rig-2', the rig of "
                   f"{tmp_path / 'other.yaml'} (a plan is scheduled per rig: goniofrost plan --rig "
                   f"{tmp_path / 'other.yaml'}), found 'sim-rig'\n")
    doc = json.loads(plan.read_text())
    doc["rig"]["name"] = "edited"
    (tmp_path / "plan.json").write_text(json.dumps(doc))
    err = run_refused(capture_args(rig, tmp_path / "plan.json", tmp_path / "s"), capsys)
    assert err == (f"goniofrost capture: error: {tmp_path / 'plan.json'}: rig.name: expected 'sim-rig', the rig of "
                   f"{rig} (a plan is scheduled per rig: goniofrost plan --rig {rig}), found 'edited'\n")
    assert not (tmp_path / "s").exists()


def test_a_joint_target_for_an_axis_the_rig_lacks_is_refused(setup, tmp_path, capsys):
    folder, rig, plan, _ = setup
    doc = json.loads(plan.read_text())
    doc["samples"][2]["joints"]["bogus_axis"] = 10.0
    (tmp_path / "plan.json").write_text(json.dumps(doc))
    err = run_refused(capture_args(rig, tmp_path / "plan.json", tmp_path / "s"), capsys)
    assert err == (f"goniofrost capture: error: {tmp_path / 'plan.json'}: samples[2].joints.bogus_axis: expected one "
                   "of the keys camera_arm, sample_yaw, sample_tilt (the axes of rig 'sim-rig'), found \"unknown key "
                   "'bogus_axis'\"\n")
    assert not (tmp_path / "s").exists()


def test_a_joint_target_outside_the_limits_is_refused_before_anything_moves(setup, tmp_path, capsys):
    folder, rig, plan, _ = setup
    doc = json.loads(plan.read_text())
    doc["samples"][3]["joints"]["sample_tilt"] = 85.0
    (tmp_path / "plan.json").write_text(json.dumps(doc))
    err = run_refused(capture_args(rig, tmp_path / "plan.json", tmp_path / "s"), capsys)
    assert "samples[3].joints.sample_tilt: expected an angle within the axis limits [-80, 80] deg, found 85.0" in err
    assert not (tmp_path / "s").exists()


def _tampered(plan: Path, tmp_path: Path, edit) -> Path:
    doc = json.loads(plan.read_text())
    edit(doc["samples"])
    (tmp_path / "plan.json").write_text(json.dumps(doc))
    return tmp_path / "plan.json"


def test_a_sample_moved_to_another_cell_is_refused_before_anything_moves(setup, tmp_path, capsys):
    folder, rig, plan, model = setup
    doc = json.loads(plan.read_text())
    other = next(s["cell"] for s in doc["samples"][1:] if s["cell"] != doc["samples"][2]["cell"])

    def move(samples):
        samples[2]["cell"] = other
    err = run_refused(capture_args(rig, _tampered(plan, tmp_path, move), tmp_path / "s"), capsys)
    assert f"{tmp_path / 'plan.json'}: samples[2].theta_h_deg: expected " in err
    assert f"(the value of its cell {other})" in err and err.count("\n") == 1
    assert not (tmp_path / "s").exists()


@pytest.mark.parametrize("key, value, field", [
    ("theta_i_deg", lambda s: s["theta_i_deg"] + 0.5, "theta_i_deg"),
    ("w_o", lambda s: [s["w_o"][1], s["w_o"][0], s["w_o"][2]], "w_o"),
    ("w_i", lambda s: "up", "w_i"),
    ("light_camera_swapped", lambda s: not s.get("light_camera_swapped", False), "joints"),
])
def test_a_sample_that_disagrees_with_itself_is_refused(setup, tmp_path, capsys, key, value, field):
    folder, rig, plan, _ = setup
    doc = json.loads(plan.read_text())
    # a sample whose w_i and w_o differ in zenith, so that exchanging light and camera shows
    i = next(i for i, s in enumerate(doc["samples"]) if abs(s["theta_i_deg"] - s["theta_o_deg"]) > 1)

    def edit(samples):
        samples[i][key] = value(samples[i])
    err = run_refused(capture_args(rig, _tampered(plan, tmp_path, edit), tmp_path / "s"), capsys)
    assert f"{tmp_path / 'plan.json'}: samples[{i}].{field}: expected " in err and err.count("\n") == 1
    assert not (tmp_path / "s").exists()


@pytest.mark.parametrize("turn_deg", [2.0, 0.22])
def test_joints_of_another_pose_are_refused(setup, tmp_path, capsys, turn_deg):
    """The plan's joints sit on the axes' command lattices (planner.steps), each within 0.1 deg
    (+ half a step, + 0.001) of one of its cell's IK poses: 0.106 deg for the tilt, a continuous
    axis on a 0.01 deg lattice. 0.22 deg more tilt is another pose wherever in that span the plan
    put the joint (at least 0.114 deg from the pose; where it lands depends on the design's bits,
    which depend on the CPU's BLAS kernels)."""
    folder, rig, plan, _ = setup
    assert json.loads(plan.read_text())["rig"]["command_steps_deg"] == [0.01, 0.087890625, 0.0]

    def turn(samples):
        samples[4]["joints"]["sample_tilt"] += turn_deg
    err = run_refused(capture_args(rig, _tampered(plan, tmp_path, turn), tmp_path / "s"), capsys)
    assert "samples[4].joints: expected joints within [0.106, 0.145, 0.101] deg of a pose of its cell" in err
    assert not (tmp_path / "s").exists()


def test_a_bad_rig_file_is_refused_naming_file_and_key(setup, tmp_path, capsys):
    folder, rig, plan, _ = setup
    bad = yaml.safe_load(rig.read_text())
    del bad["axes"]["sample_tilt"]["limits_deg"]
    (tmp_path / "bad.yaml").write_text(yaml.safe_dump(bad))
    err = run_refused(capture_args(tmp_path / "bad.yaml", plan, tmp_path / "s"), capsys)
    assert f"{tmp_path / 'bad.yaml'}: axes.sample_tilt" in err and "limits_deg" in err
    (tmp_path / "broken.yaml").write_text("name: [unclosed\n")
    err = run_refused(capture_args(tmp_path / "broken.yaml", plan, tmp_path / "s"), capsys)
    assert str(tmp_path / "broken.yaml") in err
    assert not (tmp_path / "s").exists()


def test_an_existing_session_needs_resume_and_resume_needs_the_same_plan(setup, tmp_path, capsys):
    from goniofrost.capture.journal import SampleRecord
    from goniofrost.capture.runner import open_journal, session_meta
    from goniofrost.capture.inputs import load_inputs

    folder, rig, plan, _ = setup
    session = tmp_path / "s"
    meta = session_meta(load_inputs(rig, plan), MATERIAL)
    with open_journal(session, meta, resume=False) as journal:
        journal.commit_sample(SampleRecord(0, 1, 0.0, 0.0, 0.0, (1.0, 1.0, 1.0), (0.1, 0.1, 0.1), 10.0))
    err = run_refused(capture_args(rig, plan, session), capsys)
    assert err == f"goniofrost capture: error: {session / 'session.sqlite'}: a session journal already exists with " \
                  f"1 of {M} samples; pass --resume to continue it or choose a new --session folder\n"
    doc = json.loads(plan.read_text())
    doc["samples"] = doc["samples"][::-1]
    (tmp_path / "plan.json").write_text(json.dumps(doc))
    err = run_refused(capture_args(rig, tmp_path / "plan.json", session, "--resume"), capsys)
    assert "meta.plan_sha256: this session was started with another plan" in err
    err = run_refused(capture_args(rig, plan, tmp_path / "nothing", "--resume"), capsys)
    assert "no session journal to resume" in err
    assert not (tmp_path / "nothing").exists()  # refused: not even the folder and its lock are left


def test_a_plan_made_again_resumes_its_session_and_an_older_journal_its_plan(setup, tmp_path):
    """The same plan command run again writes the same samples with another selection time: the
    session it started is its session (a script that plans and captures can be run again after a
    crash); a journal that recorded the hash with the selection time still resumes its plan."""
    from goniofrost.capture.inputs import load_inputs
    from goniofrost.capture.runner import open_journal, plan_sha256, session_meta

    folder, rig, plan, _ = setup
    doc = json.loads(plan.read_text())
    again = tmp_path / "plan.json"
    again.write_text(json.dumps(doc | {"selection_seconds": doc["selection_seconds"] + 1.5}))
    session = tmp_path / "s"
    with open_journal(session, session_meta(load_inputs(rig, plan), MATERIAL), resume=False):
        pass
    with open_journal(session, session_meta(load_inputs(rig, again), MATERIAL), resume=True):
        pass
    older = tmp_path / "older"
    meta = session_meta(load_inputs(rig, plan), MATERIAL)
    assert meta["plan_sha256"] != plan_sha256(meta["plan"], with_run_record=True)
    with open_journal(older, meta | {"plan_sha256": plan_sha256(meta["plan"], with_run_record=True)}, resume=False):
        pass
    with open_journal(older, meta, resume=True):
        pass


def _state(folder: Path) -> dict:
    """name -> (bytes, mtime_ns) of every file in ``folder``, and the folder's own mtime_ns."""
    files = {p.name: (p.read_bytes(), p.stat().st_mtime_ns) for p in sorted(folder.iterdir())}
    return {"files": files, "folder": folder.stat().st_mtime_ns}


@pytest.mark.parametrize("lock, extra, words", [
    (True, (), "a session journal already exists with 1 of"),
    (False, (), "a session journal already exists with 1 of"),
    (True, ("--resume", "--seed", "7"), "meta.sim_seed: this session was started with another simulated noise seed"),
])
def test_a_refused_existing_session_is_left_untouched(setup, tmp_path, capsys, lock, extra, words):
    """The refusal rewrote session.lock with its own PID and removed the temporaries a killed run
    left: a refused command must change nothing. A lock file absent stays absent (the lock is
    taken on it before the journal can be read, so only the folder's mtime shows it was there)."""
    from goniofrost.capture.journal import SampleRecord
    from goniofrost.capture.runner import open_journal, session_meta, sim_seed
    from goniofrost.capture.inputs import load_inputs

    folder, rig, plan, _ = setup
    session = tmp_path / "s"
    inputs = load_inputs(rig, plan)
    meta = session_meta(inputs, MATERIAL, seed=sim_seed(inputs.rig, None))
    with open_journal(session, meta, resume=False) as journal:
        journal.commit_sample(SampleRecord(0, 1, 0.0, 0.0, 0.0, (1.0, 1.0, 1.0), (0.1, 0.1, 0.1), 10.0))
    if lock:
        (session / "session.lock").write_text("12345\n")   # the PID of the run that made it
    (session / ".brdf.binary.abcd1234").write_bytes(b"half")   # a temporary a killed run left
    for path in (*session.iterdir(), session):   # in the past: a touch would show in mtime_ns
        os.utime(path, ns=(1_000_000_000, 1_000_000_000))
    before = _state(session)
    err = run_refused(capture_args(rig, plan, session, *extra), capsys)
    assert words in err and err.count("\n") == 1
    after = _state(session)
    assert after["files"] == before["files"]
    assert after["folder"] == before["folder"] or not lock


def test_a_journal_without_samples_of_another_session_says_what_to_type(setup, tmp_path, capsys):
    from goniofrost.capture.runner import open_journal, session_meta
    from goniofrost.capture.inputs import load_inputs

    folder, rig, plan, _ = setup
    session = tmp_path / "s"
    open_journal(session, session_meta(load_inputs(rig, plan), MATERIAL), resume=False).close()
    doc = json.loads(plan.read_text())
    doc["samples"] = doc["samples"][::-1]
    (tmp_path / "plan.json").write_text(json.dumps(doc))
    err = run_refused(capture_args(rig, tmp_path / "plan.json", session), capsys)
    assert "meta.plan_sha256: this session was started with another plan" in err and err.count("\n") == 1
    assert err.endswith(f"; it holds no sample yet: to start this session there, delete it "
                        f"(rm {session / 'session.sqlite'}), or choose a new --session\n")


def test_a_signal_during_a_commit_waits_for_it_and_one_during_stopping_is_dropped():
    from goniofrost.capture.signals import Deferral, SessionInterrupted

    deferral, done = Deferral(), []
    with pytest.raises(SessionInterrupted, match="SIGINT"):
        with deferral.critical():
            deferral.handle(signal.SIGINT, None)  # arrives mid-commit: held
            done.append("committed")
    assert done == ["committed"]
    with deferral.ignored():
        deferral.handle(signal.SIGTERM, None)  # a second Ctrl-C while every axis is being stopped
    with pytest.raises(SessionInterrupted, match="SIGTERM"):
        deferral.handle(signal.SIGTERM, None)  # outside both: at once


def test_simulated_rig_options_are_checked_before_anything_moves(setup, tmp_path, capsys):
    folder, rig, plan, _ = setup
    base = ["capture", "--rig", str(rig), "--plan", str(plan), "--session", str(tmp_path / "s")]
    err = run_refused(base, capsys)
    assert "command line: --material: expected SPEC:NAME of the material the simulated rig 'sim-rig' shows" in err
    err = run_refused(base + ["--material", "builtin:red-plastik"], capsys)
    assert err == ("goniofrost capture: error: command line: --material: unknown material 'red-plastik' in dataset "
                   "'builtin'; did you mean red-plastic, grey-plastic, green-plastic?\n")
    err = run_refused(base + ["--material", MATERIAL, "--speedup", "0"], capsys)
    assert "command line: --speedup: expected a simulated clock speed-up > 0, found 0.0" in err
    assert not (tmp_path / "s").exists()


# ----- a capture with a target error -------------------------------------------------------------
def batched_plan(folder: Path, rig, plan, ends) -> Path:
    """The module's plan scheduled again in the batches ``ends``."""
    from goniofrost.plan.file import write_plan
    from goniofrost.rig.file import load_checked_rig
    from planner.schedule import schedule_batches

    doc = json.loads(plan.read_text())
    doc["samples"] = sorted(doc["samples"], key=lambda s: s["selection_index"])
    out = folder / f"plan-{'-'.join(map(str, ends))}.json"
    write_plan(out, schedule_batches(doc, load_checked_rig(rig), ends))
    return out


def test_target_error_stops_after_the_batch_that_reaches_it_and_records_why(setup, tmp_path, capsys):
    folder, rig, plan, model = setup
    batched = batched_plan(tmp_path, rig, plan, [4, 5])
    session = tmp_path / "s"
    # this 6-material model's bound is calibrated on 6 held-out training materials: 95 % cannot be
    # given, and the capture says so before anything moves
    assert main(capture_args(rig, batched, session, "--target-error", "10000")) == 2
    assert ("command line: --confidence: expected at most 0.857 with this model (its bound is calibrated on 6 "
            "held-out training materials; 0.95 needs 19), found 0.95") in capsys.readouterr().err
    assert not session.exists()
    # a target every bound meets (this model predicts wildly from 4 samples): the capture stops
    # after the first batch (not one of 2 samples: this model's calibration saw designs of 5 samples
    # and more, and a 2-sample design is unlike them, an extrapolation that never stops)
    assert main(capture_args(rig, batched, session, "--speedup", "50", "--target-error", "10000",
                             "--confidence", "0.8")) == 0
    out = capsys.readouterr().out
    with Journal.open(session / "session.sqlite") as journal:
        records, events, steps = journal.samples(), journal.events(), journal.steps()
    assert [r.plan_index for r in records] == [0, 1, 2, 3]
    [batch] = [e for e in events if e["kind"] == "batch"]
    assert batch["data"]["decision"] == "target reached" and batch["data"]["samples"] == 4
    assert batch["data"]["confidence"] == 0.8 and batch["data"]["bound"] <= 10000 and batch["data"]["out_of_model"] == []
    assert batch["message"] == (f"batch 1: 4 samples, error <= {batch['data']['bound']:.3g} with 80 % confidence "
                                f"(median estimate {batch['data']['predicted_error']:.3g}), within the target 10000: "
                                f"target reached")
    assert [s["kind"] for s in steps].count("Assess") == 1
    assert events[-1]["kind"] is EventKind.SESSION
    _start, end = journal_last_run(session)
    assert (end.status, end.samples_planned, end.samples_captured, end.batches) == (RunStatus.TARGET_REACHED, 5, 4, 1)
    assert end.reason == f"capture stopped after 4 of 5 samples: target reached: {batch['message'].split(', ', 1)[1].rsplit(':', 1)[0]}"
    assert report_last_run(session) == {"status": "target_reached", "reason": end.reason}
    with open(session / "samples.csv") as handle:
        assert [row["batch"] for row in csv.DictReader(handle)] == ["1"] * 4
    report = json.loads((session / "report.json").read_text())
    target = report["target_error"]
    assert (target["target"], target["samples_used"], target["plan_samples"], target["stopped"]) == (10000.0, 4, 5, "target reached")
    assert (target["confidence"], target["bound"], target["extrapolation"]) == (0.8, batch["data"]["bound"], False)
    assert target["statement"] == batch["message"].split(", ", 1)[1].rsplit(":", 1)[0]
    assert target["batches"][0]["predicted_error"] == pytest.approx(batch["data"]["predicted_error"])
    assert f"target error 10000 at 80 % confidence: target reached after 4 of 5 samples: {target['statement']}" in out
    # resuming a stopped session is refused as finished (it only wrote the same results again),
    # moves nothing and keeps the stopping decision; another target or confidence is refused
    assert main(capture_args(rig, batched, session, "--resume", "--target-error", "10000", "--confidence", "0.8")) == 2
    assert "this session is finished (4 of 5 samples, target_reached)" in capsys.readouterr().err
    with Journal.open(session / "session.sqlite") as journal:
        assert len(journal.events()) == len(events) and len(journal.samples()) == 4
    assert json.loads((session / "report.json").read_text())["target_error"] == target
    assert main(capture_args(rig, batched, session, "--resume", "--target-error", "0.01", "--confidence", "0.8")) == 2
    assert "meta.target_error: this session was started with another target error" in capsys.readouterr().err
    assert main(capture_args(rig, batched, session, "--resume", "--target-error", "10000", "--confidence", "0.7")) == 2
    assert "meta.confidence: this session was started with another confidence: expected 0.8, found 0.7" in capsys.readouterr().err


def scene_plan(folder: Path, rig, plan, ends, model) -> Path:
    """The module's plan in batches ``ends`` as a plan made for a scene: its usage section (a map of
    the cells near retro-reflection) with the error in the scene's use calibrated on the model's
    training materials, as ``plan --usage`` writes it."""
    from goniofrost.plan.file import write_plan
    from goniofrost.frost.scene_error import scene_error
    from goniofrost.frost.usage_calibration import calibrate_scene
    from goniofrost.frost.usage_design import sensitivity_power

    _, theta_d, _ = GRID.flat_angles(GRID.valid_cells)
    usage = np.where(np.degrees(theta_d) < 20, 1.0, 0.0)
    usage /= usage.sum()
    doc = json.loads(batched_plan(folder, rig, plan, ends).read_text())
    doc["usage"] = {"file": "retro.npy", "hash": "retro-20deg", "cells_used": int((usage > 0).sum()),
                    "predicted_errors": "usage-weighted",
                    "sensitivity_power": sensitivity_power(len(doc["samples"])),
                    # t = 0 (round 7's design at 5 samples): the capture's judging is tested, not the
                    # calibration's reach. This 6-material calibration is fitted from m = 5 up, and a
                    # first batch of 2 samples read it below that; with the round-8 default (a floor of
                    # 3,000 effective cells leaves t = 0.19 on this 42k-cell grid) that extrapolation
                    # gave 4e6, where t = 0's stayed under the test's target of 10,000.
                    "error": scene_error(model, usage, calibrate_scene(model, usage, sensitivity_power(len(doc["samples"])),
                                                                       prior_spread=0.0),
                                         "retro-20deg").to_plan()}
    out = folder / "scene-plan.json"
    write_plan(out, doc)
    return out


def test_a_capture_of_a_plan_for_a_scene_judges_and_reports_the_error_in_the_scenes_use(setup, tmp_path, capsys):
    from goniofrost.frost.reconstruction import error_bound, predicted_error
    from goniofrost.frost.scene_error import from_plan

    folder, rig, plan, model = setup
    path = scene_plan(tmp_path, rig, plan, [4, 5], model)
    session = tmp_path / "s"
    assert main(capture_args(rig, path, session, "--speedup", "50", "--target-error", "10000",
                             "--confidence", "0.8")) == 0
    out = capsys.readouterr().out
    with Journal.open(session / "session.sqlite") as journal:
        records, events = journal.samples(), journal.events()
    [batch] = [e for e in events if e["kind"] == "batch"]
    assert batch["data"]["scope"] == "scene" and batch["data"]["decision"] == "target reached"
    assert batch["message"] == (f"batch 1: 4 samples, error in the scene's use <= {batch['data']['bound']:.3g} with "
                                f"80 % confidence (median estimate {batch['data']['predicted_error']:.3g}), within the "
                                f"target 10000: target reached")
    # the bound is the scene's: its own calibration, not the model's
    scene = from_plan(json.loads(path.read_text()), model)
    rows = model.grid.valid_position(np.array([GRID.flat_index(*json.loads(path.read_text())["samples"][r.plan_index]
                                                               ["cell"]) for r in records]))
    values, sigmas = np.array([r.rgb for r in records]), np.array([r.sigma for r in records])
    assert batch["data"]["bound"] == pytest.approx(error_bound(model, rows, values, sigmas, 0.8, scene=scene).upper)
    assert batch["data"]["bound"] != pytest.approx(error_bound(model, rows, values, sigmas, 0.8).upper)
    report = json.loads((session / "report.json").read_text())
    target, scene_section = report["target_error"], report["prediction"]["scene"]
    assert (target["scope"], target["error"]) == ("scene", "error in the scene's use")
    assert target["statement"] == (f"error in the scene's use <= {target['bound']:.3g} with 80 % confidence (median "
                                   f"estimate {target['median_estimate']:.3g}), within the target 10000")
    assert scene_section["predicted_log_relative_mse"] == pytest.approx(
        predicted_error(model, rows, values, sigmas, scene=scene))
    assert scene_section["calibrated"] and scene_section["usage_hash"] == "retro-20deg"
    # the whole BRDF's prediction is calibrated on designs for the whole BRDF, not this one's
    assert report["prediction"]["calibrated"] is False
    assert json.loads((session / "brdf.json").read_text())["measurement"]["predicted_calibrated"] is False
    summary = (session / "summary.txt").read_text()
    assert ("  uncalibrated: the plan's design is for a scene's use (its usage map); the whole BRDF's prediction is "
            "calibrated on designs for the whole BRDF and can be far below the truth") in summary.splitlines()
    assert "target error in the scene's use 10000 at 80 % confidence: target reached after 4 of 5 samples" in out
    assert "predicted error in the scene's use (the plan's usage map): log-relative MSE" in summary
    # a resume rebuilds the report from the journal and the plan: still the scene's error
    (session / "report.json").unlink()
    assert main(capture_args(rig, path, session, "--resume", "--target-error", "10000", "--confidence", "0.8")) == 0
    again = json.loads((session / "report.json").read_text())
    assert again["target_error"] == target and again["prediction"]["scene"] == scene_section
    # a plan for a scene without that calibration (the training materials were not at hand) cannot stop on it
    doc = json.loads(path.read_text())
    doc["usage"]["error"] |= {"calibration": None, "unavailable": "no calibration: datasets gone"}
    path.write_text(json.dumps(doc))
    assert main(capture_args(rig, path, tmp_path / "s2", "--target-error", "0.05", "--confidence", "0.8")) == 2
    assert (f"{path}: usage.error.calibration: expected the calibrated bound on the error in the scene's use "
            f"(plan --usage with the model's training materials at hand), found 'no calibration: datasets gone'"
            ) in capsys.readouterr().err
    assert not (tmp_path / "s2").exists()


def test_target_error_never_met_uses_up_the_plan(setup, tmp_path):
    folder, rig, plan, model = setup
    batched = batched_plan(tmp_path, rig, plan, [2, 4, 5])
    session = tmp_path / "s"
    outcome = capture(load_inputs(rig, batched), session, sim=SimOptions(material=shown_material(MATERIAL), speedup=50),
                      devices=rig_devices, stop=StopRule(1e-12, 0.8), options=SessionOptions(progress=False))
    target = outcome.report["target_error"]
    assert target["stopped"] == "plan used up" and target["samples_used"] == 5
    assert [b["samples"] for b in target["batches"]] == [2, 4, 5]
    assert [b["decision"] for b in target["batches"]] == ["continue", "continue", "plan used up"]
    _start, end = journal_last_run(session)
    assert (end.status, end.samples_captured, end.batches) == (RunStatus.PLAN_USED_UP, 5, 3)
    assert outcome.report["last_run"]["status"] == "plan_used_up"


def test_target_error_needs_a_batched_plan_and_a_positive_number(setup, tmp_path, capsys):
    folder, rig, plan, model = setup
    doc = json.loads(plan.read_text())
    del doc["batch_ends"]
    unbatched = tmp_path / "plan.json"
    unbatched.write_text(json.dumps(doc))
    assert main(capture_args(rig, unbatched, tmp_path / "a", "--target-error", "0.05")) == 2
    assert f"{unbatched}: batch_ends: expected the batches of a Bayesian plan" in capsys.readouterr().err
    assert main(capture_args(rig, plan, tmp_path / "b", "--target-error", "-1")) == 2
    assert "--target-error: expected a log-relative MSE > 0 (e.g. 0.05), found -1.0" in capsys.readouterr().err
    assert main(capture_args(rig, plan, tmp_path / "b", "--target-error", "0.05", "--confidence", "1")) == 2
    assert "--confidence: expected a probability between 0 and 1 (e.g. 0.95), found 1.0" in capsys.readouterr().err
    assert main(capture_args(rig, plan, tmp_path / "b", "--confidence", "0.9")) == 2  # alone it would change nothing
    assert capsys.readouterr().err == ("goniofrost capture: error: command line: --confidence: expected --target-error "
                                       "E as well (the confidence is that of the bound that stops the capture at E), "
                                       "found 0.9\n")
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_a_sample_the_camera_cannot_measure_is_refused_before_anything_moves(setup, tmp_path, capsys):
    folder, rig, plan, _ = setup
    doc = json.loads(plan.read_text())
    # within every axis limit, but the camera sees the holder edge-on (arm 90 deg from the lamp,
    # the sample facing the lamp)
    doc["samples"][2]["joints"] = {"camera_arm": 90.0, "sample_yaw": 0.0, "sample_tilt": 0.0}
    (tmp_path / "plan.json").write_text(json.dumps(doc))
    err = run_refused(capture_args(rig, tmp_path / "plan.json", tmp_path / "s"), capsys)
    assert (f"{tmp_path / 'plan.json'}: samples[2].joints: expected a pose the camera can measure (enough patch "
            f"pixels, the patch in the lamp's beam), found 'PATCH_PIXELS at theta_i ") in err
    assert not (tmp_path / "s").exists()


def test_a_plan_scheduled_with_another_alignment_is_refused_before_anything_moves(setup, tmp_path, capsys):
    folder, rig, plan, model = setup
    from goniofrost.core.cache import cache_path
    from goniofrost.app.demo import plan_on_rig

    aligned = tmp_path / "ALIGNMENT.json"
    aligned.write_text(json.dumps({"offsets_deg": {"camera_arm": 0.2, "sample_yaw": -0.3, "sample_tilt": 0.1}}))
    err = run_refused(capture_args(rig, plan, tmp_path / "s", "--alignment", str(aligned)), capsys)
    assert f"{plan}: alignment.hash: expected " in err and f"(the alignment {aligned} given to this capture)" in err
    assert "found 'None: this plan was scheduled with another alignment" in err
    plan_aligned = plan_on_rig(model, cache_path("models", model.info["cache_key"], ""),
                               PlanRequest(samples=M, rig=load_checked_rig(rig, aligned)), tmp_path / "plan-aligned.json")
    doc = json.loads(plan_aligned.read_text())
    assert doc["alignment"]["offsets_deg"] == {"camera_arm": 0.2, "sample_yaw": -0.3, "sample_tilt": 0.1}
    err = run_refused(capture_args(rig, plan_aligned, tmp_path / "s"), capsys)
    assert "alignment.hash: expected null (no alignment given to this capture: pass the plan's with --alignment)" in err
    other = tmp_path / "other.json"
    other.write_text(json.dumps({"offsets_deg": {"camera_arm": 0.2, "sample_yaw": -0.3, "sample_tilt": 0.0}}))
    err = run_refused(capture_args(rig, plan_aligned, tmp_path / "s", "--alignment", str(other)), capsys)
    assert f"(from {aligned}): this plan was scheduled with another alignment" in err
    assert not (tmp_path / "s").exists()


@pytest.mark.parametrize("content, message", [
    (None, "ALIGNMENT.json: (top level): expected an ALIGNMENT.json file (goniofrost align --out FILE), found 'no such file'"),
    ("{", "ALIGNMENT.json: (top level): expected valid JSON, found 'Expecting property name"),
    ({"offsets": {}}, "ALIGNMENT.json: offsets_deg: expected a mapping {axis name: degrees}, found 'nothing'"),
    ({"offsets_deg": {"camera_arm": 0.1, "sample_yaw": 0.0}},
     "ALIGNMENT.json: offsets_deg.sample_tilt: expected a zero offset in degrees within +-10, found 'nothing'"),
    ({"offsets_deg": {"camera_arm": 0.1, "sample_yaw": 0.0, "sample_tilt": 0.0, "lamp": 1.0}},
     "ALIGNMENT.json: offsets_deg.lamp: expected one of the keys camera_arm, sample_yaw, sample_tilt, found \"unknown key 'lamp'\""),
    ({"offsets_deg": {"camera_arm": "0.1", "sample_yaw": 0.0, "sample_tilt": 0.0}},
     "ALIGNMENT.json: offsets_deg.camera_arm: expected a zero offset in degrees within +-10, found '0.1'"),
    ({"offsets_deg": {"camera_arm": 12.0, "sample_yaw": 0.0, "sample_tilt": 0.0}},
     "ALIGNMENT.json: offsets_deg.camera_arm: expected a zero offset in degrees within +-10, found 12.0"),
    ({"version": 99, "offsets_deg": {"camera_arm": 0.1, "sample_yaw": 0.0, "sample_tilt": 0.0}},
     "ALIGNMENT.json: version: expected 1 (the format this goniofrost reads: an ALIGNMENT.json of goniofrost align), "
     "found 99"),
])
def test_a_bad_alignment_file_is_refused_naming_the_key(setup, tmp_path, capsys, content, message):
    folder, rig, plan, _ = setup
    path = tmp_path / "ALIGNMENT.json"
    if content is not None:
        path.write_text(content if isinstance(content, str) else json.dumps(content))
    err = run_refused(capture_args(rig, plan, tmp_path / "s", "--alignment", str(path)), capsys)
    assert f"{tmp_path}/{message}" in err
    assert not (tmp_path / "s").exists()
    # the same file named by the rig file's alignment key
    raw = yaml.safe_load(rig.read_text())
    raw["alignment"] = "ALIGNMENT.json"
    (tmp_path / "rig.yaml").write_text(yaml.safe_dump(raw))
    err = run_refused(capture_args(tmp_path / "rig.yaml", plan, tmp_path / "s"), capsys)
    assert f"{tmp_path}/{message}" in err


def test_a_bad_misalignment_section_is_refused_naming_the_key(setup, tmp_path, capsys):
    folder, rig, plan, _ = setup
    for value, message in (({"camera_arm": 0.6, "turntable": 1.0},
                             "sim.misalignment_deg.turntable: expected an axis of the rig (camera_arm, sample_yaw, "
                             "sample_tilt), found 'turntable'"),
                           ({"sample_yaw": 45.0}, "sim.misalignment_deg.sample_yaw: expected a zero error in degrees "
                                                  "within +-10, found 45.0"),
                           ([0.6, 1.1], "sim.misalignment_deg: expected a mapping {axis name: degrees}, found [0.6, 1.1]")):
        raw = yaml.safe_load(rig.read_text())
        raw["sim"]["misalignment_deg"] = value
        (tmp_path / "rig.yaml").write_text(yaml.safe_dump(raw))
        err = run_refused(capture_args(tmp_path / "rig.yaml", plan, tmp_path / "s"), capsys)
        assert f"{tmp_path / 'rig.yaml'}: {message}" in err
    assert not (tmp_path / "s").exists()


def journal_last_run(session):
    """The (RunStart, RunEnd) of the session's last run, as the journal's API returns them."""
    with Journal.open(session / "session.sqlite") as journal:
        return journal.last_run()


def report_last_run(session) -> dict:
    return json.loads((session / "report.json").read_text())["last_run"]


def test_the_progress_bar_ends_at_the_count_captured_when_the_target_stops_early(setup, tmp_path, capsys, monkeypatch):
    folder, rig, plan, model = setup
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True)  # bars are drawn on a terminal only
    batched = batched_plan(tmp_path, rig, plan, [4, 5])
    capture(load_inputs(rig, batched), tmp_path / "s", sim=SimOptions(material=shown_material(MATERIAL), speedup=50),
            devices=rig_devices, stop=StopRule(10000.0, 0.8))  # the bound of this 6-material model after 4 samples: below 10000
    last = capsys.readouterr().err.replace("\r", "\n").strip().splitlines()[-1]
    assert last.startswith("capture: 100%") and "| 4/4 " in last, last  # not "4/5"


# ----- a sample too dark for the rig's longest exposure: recorded as not measured, the capture goes on
DARK_MATERIAL = "builtin:black-diffuse"  # plan sample 0 (light at 85.6 deg) is about 7 x darker than the others
DARK_LADDER = [0.0005, 0.001, 0.002, 0.004]  # its longest exposure is too short for that one pose


def short_ladder_rig(rig: Path, out: Path, **camera) -> Path:
    """The module's rig file with the DARK_LADDER (and ``camera`` overrides): the same kinematics."""
    raw = yaml.safe_load(rig.read_text())
    raw["camera"].update(exposures_s=DARK_LADDER, **camera)
    out.write_text(yaml.safe_dump(raw, sort_keys=False))
    return out


def dark_args(rig, plan, session, *extra) -> list[str]:
    return ["capture", "--rig", str(rig), "--plan", str(plan), "--session", str(session),
            "--material", DARK_MATERIAL, "--no-progress", *extra]


@pytest.fixture(scope="module")
def dark(setup, tmp_path_factory):
    """(the short-ladder rig file, a session of DARK_MATERIAL captured with it in one run) (read-only)."""
    folder, rig, plan, _ = setup
    where = tmp_path_factory.mktemp("dark")
    short = short_ladder_rig(rig, where / "short-ladder.yaml")
    assert main(dark_args(short, plan, where / "s", "--speedup", "50")) == 0
    return short, where / "s"


def not_measured_rows(session: Path) -> list[tuple]:
    """(plan_index, committed_utc) of every sample journaled as not measured, read by a second connection."""
    try:
        with closing(sqlite3.connect(f"file:{session / 'session.sqlite'}?mode=ro", uri=True, timeout=1)) as db:
            return db.execute("SELECT plan_index, committed_utc FROM not_measured ORDER BY plan_index").fetchall()
    except sqlite3.OperationalError:  # no journal or no table yet
        return []


def test_a_sample_too_dark_for_the_ladder_is_journaled_not_measured_and_the_capture_finishes(setup, dark, capsys):
    from calib import NotMeasuredReason
    from goniofrost.datasets import material_brdf
    from goniofrost.frost.reconstruction import reconstruct_bayes
    from goniofrost.frost.samples_file import read_samples_csv, sample_sigmas
    from goniofrost.monitor.session_view import read_session
    from goniofrost.monitor.status import page_state
    from planner.kinematics import forward
    from planner.rig import load_rig

    folder, rig, plan, model = setup
    short, session = dark
    with Journal.open(session / "session.sqlite") as journal:
        records, [nm], events, runs = journal.samples(), journal.not_measured(), journal.events(), journal.runs()
    # the typed record: why, the SNR reached, the longest exposure, and an upper limit above the truth
    assert nm.plan_index == 0 and nm.reason is NotMeasuredReason.BELOW_DETECTION_LIMIT
    assert nm.best_snr < nm.min_snr == 10.0 and nm.longest_exposure_s == DARK_LADDER[-1] == nm.exposures_s[-1]
    assert nm.raw_paths and all((session / p).is_file() for p in nm.raw_paths)
    truth = material_brdf(DARK_MATERIAL)[1](*forward(load_rig(short), nm.joints))
    assert np.all(truth < np.array(nm.upper_limit)) and np.all(np.array(nm.upper_limit) < 10 * truth)
    # the capture went on: every other sample measured, the run finished, the event says why
    assert [r.plan_index for r in records] == [1, 2, 3, 4] and csv_indices(session) == [1, 2, 3, 4]
    [event] = [e for e in events if e["kind"] is EventKind.NOT_MEASURED]
    assert event["data"]["plan_index"] == 0 and event["data"]["reason"] == "below-detection-limit"
    assert event["data"]["upper_limit"] == list(nm.upper_limit)
    [(_start, end)] = runs
    assert end.status is RunStatus.FINISHED and end.samples_captured == M

    # the reconstruction is of the measured samples only, as `goniofrost reconstruct` makes it from samples.csv
    cells, values, extra = read_samples_csv(session / "samples.csv", GRID)
    expected = reconstruct_bayes(model, GRID.valid_position(cells), values, sigmas=sample_sigmas("x", extra))
    np.testing.assert_allclose(read_merl(session / "brdf.binary", GRID)[GRID.valid_cells], expected.brdf, rtol=1e-12)

    report = json.loads((session / "report.json").read_text())
    assert (report["samples"], report["plan_samples"]) == (4, M)
    assert report["prediction"]["samples_used"] == 4 and report["prediction"]["not_measured_left_out"] == 1
    assert report["prediction"]["point_prediction_before_centring"] == pytest.approx(expected.predicted_error, rel=1e-12)
    dark_section = report["not_measured"]
    assert (dark_section["count"], dark_section["indices"], dark_section["reasons"]) == (1, [0], {"below-detection-limit": 1})
    [listed] = dark_section["samples"]
    assert (listed["index"], listed["cell"], listed["longest_exposure_s"], listed["upper_limit"]) == (
        0, nm.cell, DARK_LADDER[-1], list(nm.upper_limit))
    summary = (session / "summary.txt").read_text()
    assert f"4 samples measured and 1 not measured on rig 'sim-rig'" in summary
    assert "1 sample(s) NOT MEASURED, left out of the reconstruction and its predicted error" in summary
    assert f"  sample 0: below-detection-limit: SNR {nm.best_snr:.1f} below the minimum 10 with exposures up to 0.004 s" in summary
    assert json.loads((session / "brdf.json").read_text())["measurement"]["samples_not_measured"] == 1

    # the sessions listing and the monitor say so too
    capsys.readouterr()
    assert main(["sessions", str(session.parent), "--json"]) == 0
    [entry] = json.loads(capsys.readouterr().out)
    assert (entry["state"], entry["samples"], entry["not_measured"], entry["samples_planned"]) == ("finished", 4, 1, M)
    assert main(["sessions", str(session.parent)]) == 0
    assert "4/5 (1 not measured)" in capsys.readouterr().out
    page = page_state(read_session(session), time.time())
    assert page["state"] == "finished" and page["count_text"] == "5 of 5 samples (1 not measured)"
    assert page["samples"]["status"] == ["not-measured", "done", "done", "done", "done"]
    assert page["samples"]["flags"][0] == "below-detection-limit" and page["not_measured"][0]["plan_index"] == 0


def test_a_run_killed_after_a_sample_not_measured_resumes_without_taking_it_again(setup, dark, tmp_path, capsys):
    folder, _rig, plan, _ = setup
    short, uninterrupted = dark
    session = tmp_path / "s"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "goniofrost", *dark_args(short, plan, session, "--speedup", "10")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, cwd=REPO)
    t_end = time.monotonic() + 60
    while not not_measured_rows(session):
        assert proc.poll() is None and time.monotonic() < t_end, "capture ended or hung before sample 0 was journaled"
        time.sleep(0.002)
    proc.send_signal(signal.SIGKILL)
    assert proc.wait(timeout=10) == -signal.SIGKILL
    before, measured = not_measured_rows(session), journal_rows(session)
    assert [i for i, _ in before] == [0] and len(measured) < M - 1, "the kill must land mid-session"
    frames_before = {p.name: p.stat().st_mtime_ns for p in (session / "raw").glob("sample_0000_e*.dng")}
    assert frames_before

    assert main(dark_args(short, plan, session, "--resume", "--speedup", "50")) == 0
    assert "4 samples measured and 1 not measured on rig 'sim-rig'" in capsys.readouterr().out
    assert not_measured_rows(session) == before   # not taken again: the same commit
    assert {p.name: p.stat().st_mtime_ns for p in (session / "raw").glob("sample_0000_e*.dng")} == frames_before
    with Journal.open(session / "session.sqlite") as journal:
        assert [e["data"]["plan_index"] for e in journal.events() if e["kind"] is EventKind.NOT_MEASURED] == [0]
        assert [r.plan_index for r in journal.samples()] == [1, 2, 3, 4]
        runs = journal.runs()
    assert [s.samples_done for s, _ in runs] == [0, 1 + len(measured)] and runs[1][1].status is RunStatus.FINISHED
    for name in ("samples.csv", "brdf.binary"):   # what one uninterrupted run gives
        assert (session / name).read_bytes() == (uninterrupted / name).read_bytes(), name
    assert frames(session) == frames(uninterrupted)


BRIGHT_MATERIAL = "builtin:chrome"   # plan samples 1 and 3 sit on its highlight
BRIGHT_LADDER = [0.008, 0.032, 0.128]  # without the module rig's 0.002 s: they saturate even at 0.008 s


def test_samples_saturated_at_the_shortest_exposure_are_journaled_not_measured_and_the_capture_finishes(setup, tmp_path,
                                                                                                        capsys):
    from calib import NotMeasuredReason
    from goniofrost.datasets import material_brdf
    from planner.kinematics import forward
    from planner.rig import load_rig

    folder, rig, plan, _ = setup
    raw = yaml.safe_load(rig.read_text())
    raw["camera"].update(exposures_s=BRIGHT_LADDER)
    (bright_rig := tmp_path / "no-short-exposure.yaml").write_text(yaml.safe_dump(raw, sort_keys=False))
    session = tmp_path / "s"
    assert main(["capture", "--rig", str(bright_rig), "--plan", str(plan), "--session", str(session),
                 "--material", BRIGHT_MATERIAL, "--no-progress", "--speedup", "50"]) == 0
    with Journal.open(session / "session.sqlite") as journal:
        records, missing, runs = journal.samples(), journal.not_measured(), journal.runs()
    assert [r.plan_index for r in records] == [0, 2, 4] and [d.plan_index for d in missing] == [1, 3]
    [(_start, end)] = runs
    assert end.status is RunStatus.FINISHED and end.reason == "all samples captured (not measured: saturated 2)"
    truth = material_brdf(BRIGHT_MATERIAL)[1]
    for d in missing:   # down to the shortest exposure, and a lower limit below the truth
        assert d.reason is NotMeasuredReason.SATURATED and min(d.exposures_s) == BRIGHT_LADDER[0]
        assert np.all(np.isinf(d.upper_limit))
        # below the truth at the direction measured, to the calibration's 2 % (test_calibration)
        at = truth(*forward(load_rig(bright_rig), d.joints))
        assert np.all(0 < np.array(d.lower_limit)) and np.all(np.array(d.lower_limit) < 1.02 * at)
    report = json.loads((session / "report.json").read_text())
    assert report["not_measured"]["reasons"] == {"saturated": 2} and report["prediction"]["samples_used"] == 3
    assert [d["upper_limit"] for d in report["not_measured"]["samples"]] == [[None] * 3] * 2
    summary = (session / "summary.txt").read_text()
    assert ("  to measure the saturated ones: add shorter exposures to camera.exposures_s in the rig file (or dim the "
            "lamp) and capture them in a new session") in summary
    assert f"  sample 1: saturated: {missing[0].why()}" in summary


def test_a_session_with_no_sample_measured_is_a_one_line_error_and_a_resume_takes_none_again(setup, tmp_path, capsys):
    folder, rig, plan, _ = setup
    # a minimum SNR no sample reaches with this ladder (and a bracket that runs to its longest exposure)
    hopeless = short_ladder_rig(rig, tmp_path / "hopeless.yaml", min_snr=1000.0, target_snr=10000.0)
    session = tmp_path / "s"
    for extra in ((), ("--resume",)):
        assert main(dark_args(hopeless, plan, session, "--speedup", "50", *extra)) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and (
            f"{session / 'session.sqlite'}: 0 of 5 samples measured, 5 not measured (below-detection-limit: samples "
            f"0 1 2 3 4): a reconstruction needs at least 1 measured sample(s)") in err
        with Journal.open(session / "session.sqlite") as journal:
            assert [r.plan_index for r in journal.not_measured()] == list(range(M)) and journal.samples() == []
            assert len(journal.runs()) == 1   # the resume moved nothing
    assert not (session / "report.json").exists()


def test_a_target_error_capture_assesses_the_measured_samples_of_each_batch_only(setup, dark, tmp_path):
    folder, rig, plan, model = setup
    short, _ = dark
    batched = batched_plan(tmp_path, rig, plan, [2, 4, 5])
    session = tmp_path / "s"
    outcome = capture(load_inputs(short, batched), session, sim=SimOptions(material=shown_material(DARK_MATERIAL), speedup=50),
                      devices=rig_devices, stop=StopRule(1e-12, 0.8), options=SessionOptions(progress=False))
    with Journal.open(session / "session.sqlite") as journal:
        dark_indices = [r.plan_index for r in journal.not_measured()]
        assessed = [e["data"] for e in journal.events() if e["kind"] is EventKind.BATCH]
    assert len(dark_indices) == 1
    target = outcome.report["target_error"]
    assert [b["samples"] for b in assessed] == [2, 4, 5]
    assert [b["not_measured"] for b in assessed] == [sum(i < end for i in dark_indices) for end in (2, 4, 5)]
    assert [b["predicted_error"] for b in target["batches"]] == [b["predicted_error"] for b in assessed]
    assert (target["samples_used"], target["not_measured"], target["stopped"]) == (4, 1, "plan used up")
