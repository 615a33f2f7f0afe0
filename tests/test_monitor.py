"""The monitor without a browser: the read-only session reader, the page state (states, ETA,
colours), the path checks, and the HTTP server on a real session (traversal, writes, pictures).
The browser tests are in test_monitor_browser.py."""
from __future__ import annotations

import http.client
import json
import socket
import sqlite3
import time
import urllib.request
from pathlib import Path

import cv2
import numpy as np
import pytest

from goniofrost.app.cli import main
from goniofrost.capture.journal import Journal, SampleRecord
from goniofrost.capture.records import RunEnd, RunStatus
from goniofrost.capture.inputs import load_inputs
from goniofrost.capture.options import SessionOptions, StopRule
from goniofrost.capture.runner import capture
from goniofrost.datasets import shown_material
from goniofrost.rig.simulated import rig_devices
from goniofrost.monitor.server import MonitorServer
from goniofrost.monitor.session_view import DoneSample, PlanSample, SessionView, Stop, read_session
from goniofrost.monitor.safe_path import UnsafePath, session_file
from goniofrost.monitor.status import page_state
from monitor_helpers import MATERIAL, folder_state, make_plan
from goniofrost.rig.hardware import SimOptions

M = 5


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    """A finished 5-sample session on the simulated rig (read-only for the tests)."""
    folder = tmp_path_factory.mktemp("monitor")
    rig, plan = make_plan(folder, M)
    capture(load_inputs(rig, plan), folder / "s", sim=SimOptions(material=shown_material(MATERIAL), speedup=50),
            devices=rig_devices, options=SessionOptions(progress=False))
    return folder / "s"


# ----- the page state from a view ---------------------------------------------------------------
def plan_samples(moves) -> tuple:
    return tuple(PlanSample(i, (i, 1, 2), 10.0 * i, 20.0 + i, {"camera_arm": 30.0 + i}, m) for i, m in enumerate(moves))


def done_sample(i, move_s, capture_s, started, wall, snr=100.0) -> DoneSample:
    return DoneSample(i, snr, (0.004, 0.016), (0.1, 0.2, 0.3), (0.001, 0.002, 0.003), "ok", {}, move_s, capture_s,
                      started, started + wall, (f"raw/sample_{i:04d}_e1.dng",))


def view(**kw) -> SessionView:
    events = kw.pop("events", ({"t_utc": 1000.0, "kind": "session", "axis": None, "message": "started with 0 of 4 samples done"},))
    base = dict(session_dir=Path("/s"), journal_found=True, plan_key="k", plan=plan_samples([2, 4, 6, 8]),
                events=events, run_started_utc=1000.0, calibrated=True)
    return SessionView(**{**base, **kw})


def test_a_session_whose_only_measured_samples_are_sentinels_has_nothing_measured():
    """Sentinels only check a reconstruction: with every design sample not measured there is
    nothing to reconstruct (the capture's TooFewSamplesError), whatever the sentinels gave."""
    from goniofrost.monitor.session_view import NotMeasuredSample

    dark = tuple(NotMeasuredSample(i, "saturated", (0.0,) * 3, 10.0, 0.004, (np.inf,) * 3, (1.0,) * 3, (0.004,),
                                   1.0, 0.1, 1000.0, 1001.0, ()) for i in (0, 1, 3))
    plan_doc = {"samples": [{}, {}, {"sentinel": True}, {}]}
    end = RunEnd(run=1, status=RunStatus.FINISHED, reason="all samples captured", samples_planned=4, samples_captured=4,
                 batches=0, started_utc=1000.0, ended_utc=1002.0)
    sentinel_only = view(done=(done_sample(2, 2, 1, 1001.0, 1.5),), not_measured=dark, plan_doc=plan_doc, run_end=end)
    assert sentinel_only.nothing_measured
    assert page_state(sentinel_only, now_utc=1010.0)["state"] == "nothing measured"
    design_measured = view(done=(done_sample(2, 2, 1, 1001.0, 1.5),), not_measured=dark, plan_doc={"samples": [{}] * 4})
    assert not design_measured.nothing_measured and not view(done=(), not_measured=()).nothing_measured


def test_before_three_samples_the_eta_scales_planned_moves_and_capture_time_by_the_wall_per_rig_second():
    # rig seconds of the two done samples: 2 + 1 and 4 + 3 = 10, their wall time 1.5 + 3.5 = 5 (ratio 0.5);
    # left: samples 2 and 3, planned moves 6 and 8, each with the median capture time 2 s -> 18 rig s
    v = view(done=(done_sample(0, 2, 1, 1001.0, 1.5), done_sample(1, 4, 3, 1003.0, 3.5)))
    st = page_state(v, now_utc=1007.0)
    assert st["state"] == "running" and st["count_text"] == "2 of 4 samples"
    assert st["eta_s"] == pytest.approx(9.0) and st["eta_text"] == "about 9 s left"
    assert st["samples"]["status"] == ["done", "done", "next", "pending"]
    assert st["samples"]["snr"] == [100.0, 100.0, None, None]
    assert st["samples"]["exposure_s"] == [pytest.approx(0.02), pytest.approx(0.02), None, None]
    # a sample of an earlier run (before a resume: another day, maybe another speed-up) is not used
    v = view(done=(done_sample(0, 2, 5, 10.0, 99.0), done_sample(1, 4, 3, 1003.0, 3.5)))
    assert page_state(v, now_utc=1007.0)["eta_s"] == pytest.approx(3.5 / 7 * (6 + 3 + 8 + 3))
    assert page_state(view(), now_utc=1001.0)["eta_text"] == "ETA after the first sample"


def test_with_three_samples_of_different_moves_the_eta_fits_wall_time_to_move_time_and_a_per_sample_rest():
    # a simulated clock 10x real time (k = 0.1) and 0.5 s per sample of rendering and journaling (c)
    moves, t, done = [2.0, 4.0, 6.0], 1001.0, []
    for i, move in enumerate(moves):
        done.append(done_sample(i, move, 0.3, t, 0.1 * move + 0.5))
        t += 0.1 * move + 0.5
    v = view(plan=plan_samples([2, 4, 6, 8, 10]), done=tuple(done))
    st = page_state(v, now_utc=t)
    assert st["eta_s"] == pytest.approx(0.1 * (8 + 10) + 0.5 * 2) and st["eta_from_utc"] == pytest.approx(t)
    assert st["last_event"]["message"] == "sample 2 journaled (SNR 100, 1 frames)"


def test_the_state_follows_the_last_run_and_a_silent_capture_is_called_stalled_only_from_outside():
    one = (done_sample(0, 2, 1, 1001.0, 1.5),)
    assert page_state(view(journal_found=False, note="no session.sqlite yet"), 0)["state"] == "waiting"
    assert page_state(view(calibrated=False), 1001)["hint"].startswith("homing and calibrating")
    idle = page_state(view(done=one), now_utc=1002.5 + 301)
    assert idle["state"] == "stalled" and "--resume" in idle["hint"]
    assert page_state(view(done=one), now_utc=1002.5 + 301, attached=True)["state"] == "running"
    stop = Stop(RunStatus.FAULT, "device fault at plan sample 1: sample_yaw: alarm. Every axis was stopped; ...", "sample_yaw: alarm",
                "sample_yaw", 1, 1003.0)
    faulted = page_state(view(done=one, stop=stop), 1004)
    assert faulted["state"] == "faulted" and faulted["stop"]["message"] == stop.message and faulted["stop"]["plan_index"] == 1
    assert faulted["hint"] == "faulted with 1 of 4 samples safe in the journal: what happened and what to do below"
    assert faulted["samples"]["status"] == ["done", "failed", "pending", "pending"] and faulted["eta_s"] is None
    assert faulted["poses"] == {"current": None, "next": None}  # no rig given: no drawings
    interrupted = page_state(view(done=one, stop=Stop(RunStatus.STOPPED_BY_OPERATOR, "interrupted (SIGINT): ...", "", None, 1, 1003.0)), 1004)
    assert interrupted["state"] == "interrupted"
    all_done = tuple(done_sample(i, 2, 1, 1001.0 + i, 1.0) for i in range(4))
    assert page_state(view(done=all_done), 1010)["state"] == "reconstructing"
    assert page_state(view(done=all_done, report={"samples": 4}), 1010)["state"] == "finished"
    failed = page_state(view(done=one), 1004, ended_message="goniofrost capture: error: disk full")
    assert (failed["state"], failed["hint"]) == ("failed", "goniofrost capture: error: disk full")
    # with the session lock readable, liveness is known: no stall guessing
    assert page_state(view(done=one, capture_alive=True), now_utc=1002.5 + 3000)["state"] == "running"
    gone = page_state(view(done=one, capture_alive=False), now_utc=1003)
    assert gone["state"] == "stopped" and gone["hint"].endswith("run the same capture command with --resume to continue")
    gone = page_state(view(done=all_done, capture_alive=False), now_utc=1010)
    assert gone["state"] == "stopped" and gone["hint"].endswith("--resume to write the results")
    assert page_state(view(done=one, capture_alive=False), 1003, attached=True)["state"] == "running"
    # a target-error capture that stopped early is finished, with why, not "stopped ... killed"
    two = tuple(done_sample(i, 2, 1, 1001.0 + i, 1.0) for i in range(2))
    reached = RunEnd(1, RunStatus.TARGET_REACHED, "capture stopped after 2 of 4 samples: target reached", 4, 2, 1,
                     1000.0, 1004.0)
    st = page_state(view(done=two, run_end=reached, report={"samples": 2}, capture_alive=False), 1010)
    assert (st["state"], st["count_text"]) == ("finished", "2 of 4 samples")
    assert st["hint"] == "finished: capture stopped after 2 of 4 samples: target reached; results written to /s"
    assert st["run_end"] == {"status": "target_reached", "reason": reached.reason, "samples_planned": 4,
                             "samples_captured": 2} and st["stop"] is None
    assert page_state(view(done=two, run_end=reached), 1005, attached=True)["state"] == "reconstructing"
    exposing = {"kind": "Expose", "plan_index": 1, "status": "running", "started_utc": 1003.0,
                "detail": {"exposure_s": 0.032, "file": "raw/sample_0001_e2.dng", "index": 1}}
    assert page_state(view(done=one, step=exposing), 1003.1)["hint"] == \
        "capturing: 1 of 4 samples journaled; now: exposing 0.032 s for sample 1 (raw/sample_0001_e2.dng)"


# ----- reading a journal that is being written ----------------------------------------------------
META = {"plan": {"samples": [{"cell": [1, 2, 3], "theta_i_deg": 10.0, "theta_o_deg": 20.0, "joints": {}, "move_s": 1.0}] * 3},
        "plan_sha256": "p", "rig_text": "name: x\n", "rig_name": "x", "model_hash": "m"}


def record(i: int) -> SampleRecord:
    return SampleRecord(plan_index=i, cell=7, theta_h_deg=1.0, theta_d_deg=2.0, phi_d_deg=3.0, rgb=(0.1, 0.2, 0.3),
                        sigma=(0.01, 0.01, 0.01), snr=50.0 + i, started_utc=100.0 + i, committed_utc=100.5 + i)


def test_the_reader_follows_a_writer_never_blocks_it_and_leaves_the_journal_as_it_was(tmp_path):
    path = tmp_path / "session.sqlite"
    writer = Journal.create(path, META)
    writer.commit_sample(record(0))
    assert [d.plan_index for d in read_session(tmp_path).done] == [0]
    writer.commit_sample(record(1))  # not blocked by the reader
    writer.add_event("session", "started with 1 of 3 samples done")
    seen = read_session(tmp_path)
    assert [d.snr for d in seen.done] == [50.0, 51.0] and seen.events[-1]["message"].startswith("started")
    writer.close()

    before = folder_state(tmp_path)
    listing = sorted(p.name for p in tmp_path.iterdir())
    assert listing == ["session.sqlite"]  # the writer checkpointed and removed its WAL
    assert len(read_session(tmp_path).done) == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == listing and folder_state(tmp_path) == before

    with Journal.open(path) as resumed:  # a resume after reading: still WAL, still writable
        assert resumed._db.execute("PRAGMA journal_mode").fetchone() == ("wal",)
        resumed.commit_sample(record(2))
        assert len(read_session(tmp_path).done) == 3
    with pytest.raises(sqlite3.OperationalError, match="readonly"):
        Journal.open_read_only(path)._db.execute("DELETE FROM samples")


def test_a_missing_or_half_created_journal_reads_as_waiting(tmp_path):
    assert read_session(tmp_path / "nothing").journal_found is False
    sqlite3.connect(tmp_path / "session.sqlite").close()  # created, no table yet
    got = read_session(tmp_path)
    assert got.journal_found is False and "not readable yet" in got.note


def damaged_sessions(root: Path) -> dict:
    """Under ``root``: a good session ("a-good", one sample, finished) and three damaged journals
    written by the same script: garbage over the whole file ("b-garbage"), over all but its 100-byte
    header ("c-malformed"), and a meta record that is not JSON ("d-record"). Name -> journal path."""
    from journal_script import ScriptedSession

    paths = {}
    for name in ("a-good", "b-garbage", "c-malformed", "d-record"):
        (root / name).mkdir(parents=True)
        script = ScriptedSession(root / name, 2)
        script.start_run()
        script.calibrate()
        script.capture(0)
        script.end_run(RunStatus.FINISHED, "finished")
        script.close()
        paths[name] = root / name / "session.sqlite"
    data = paths["b-garbage"].read_bytes()
    paths["b-garbage"].write_bytes(b"\x5a" * len(data))
    data = paths["c-malformed"].read_bytes()
    paths["c-malformed"].write_bytes(data[:100] + b"\x5a" * (len(data) - 100))
    with sqlite3.connect(paths["d-record"]) as db:
        db.execute("UPDATE meta SET value = '{' WHERE key = 'plan'")
    db.close()
    return paths


DAMAGE = {"b-garbage": "file is not a database", "c-malformed": "database disk image is malformed",
          "d-record": "a record does not decode: JSONDecodeError: Expecting property name enclosed in double "
                      "quotes: line 1 column 2 (char 1)"}


def test_a_damaged_journal_is_listed_unreadable_with_its_error_and_the_other_sessions_still_are(tmp_path, capsys):
    """A corrupt journal was listed as "not started" (its SQLite error swallowed), and a record that
    did not decode ended `goniofrost sessions` in a traceback."""
    paths = damaged_sessions(tmp_path)
    before = folder_state(tmp_path)
    assert main(["sessions", str(tmp_path)]) == 0
    out, err = capsys.readouterr()
    lines = out.splitlines()
    assert err == "" and len(lines) == 8
    assert lines[1].split()[0] == "a-good" and lines[1].split()[5:7] == ["finished", "1/2"]
    assert [line.split() for line in lines[2:5]] == [
        [name, "-", "-", "-", "unreadable", "-", "-", "-"] for name in ("b-garbage", "c-malformed", "d-record")]
    assert lines[5:] == [f"{name}: unreadable journal: {paths[name]}: {why}" for name, why in DAMAGE.items()]
    assert main(["sessions", str(tmp_path), "--json"]) == 0
    listed = json.loads(capsys.readouterr().out)
    assert [(e["name"], e["state"], e["problem"]) for e in listed] == [("a-good", "finished", None)] + [
        (name, "unreadable", f"{paths[name]}: {why}") for name, why in DAMAGE.items()]
    for name, why in DAMAGE.items():   # the session's own page says so too
        view = read_session(tmp_path / name)
        assert (view.journal_found, view.unreadable) == (False, f"{paths[name]}: {why}")
        assert page_state(view, time.time())["state"] == "unreadable"
        assert page_state(view, time.time())["hint"] == (
            f"the session journal cannot be read ({paths[name]}: {why}): it is damaged or not a journal; the files "
            f"beside it are untouched")
    with MonitorServer(tmp_path, port=0, catalogue=True) as server:
        page = urllib.request.urlopen(server.url).read().decode()
        assert '<a href="/s/b-garbage/">b-garbage</a>' in page and page.count("<td>unreadable</td>") == 3
        state = json.loads(urllib.request.urlopen(server.url + "s/c-malformed/api/state").read())
        assert state["state"] == "unreadable" and state["count_text"] == "no plan yet"
    assert folder_state(tmp_path) == before   # read-only, damaged or not


def test_a_damaged_read_of_a_journal_a_capture_holds_is_not_readable_yet(tmp_path):
    """While a capture holds the session, a read can race its writes (an immutable read and a
    checkpoint): that is "not readable yet", read again, never "unreadable"."""
    from goniofrost.capture.session_lock import session_lock

    paths = damaged_sessions(tmp_path)
    with session_lock(tmp_path / "b-garbage"):
        view = read_session(tmp_path / "b-garbage")
    assert (view.unreadable, view.note) == ("", f"{paths['b-garbage']}: not readable yet (file is not a database)")
    assert page_state(view, time.time())["state"] == "waiting"


def test_a_capture_killed_mid_session_reads_as_stopped_and_its_steps_as_they_happened(tmp_path):
    import signal

    from test_session import start_capture, wait_for_samples
    rig, plan = make_plan(tmp_path, M)
    session = tmp_path / "s"
    proc = start_capture(rig, plan, session, speedup="10")
    wait_for_samples(session, proc, 2)
    alive = read_session(session)
    assert alive.capture_alive is True and alive.step is not None and alive.reached is not None
    assert page_state(alive, alive.events[-1]["t_utc"])["state"] == "running"
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=10)
    gone = read_session(session)
    state = page_state(gone, gone.events[-1]["t_utc"])
    assert gone.capture_alive is False and state["state"] == "stopped"
    with Journal.open(session / "session.sqlite") as journal:  # the reader's two step rows are the journal's
        steps = journal.steps()
    moved = [st for st in steps if st["kind"] == "Move" and st["status"] == "done"][-1]
    assert gone.step == {k: steps[-1][k] for k in ("kind", "plan_index", "detail", "status", "started_utc")}
    assert gone.reached == {"joints": moved["result"]["joints"], "plan_index": moved["plan_index"], "kind": "Move"}
    assert f"with {len(gone.done)} of {M} samples safe" in state["hint"]
    assert state["poses"]["current"] is None  # no rig passed: no drawings (the browser tests draw them)


# ----- paths --------------------------------------------------------------------------------------
@pytest.fixture
def tree(tmp_path):
    session = tmp_path / "session"
    (session / "raw").mkdir(parents=True)
    (session / "report.json").write_text("{}")
    (session / "raw" / "a b.dng").write_bytes(b"raw")
    (tmp_path / "secret.txt").write_text("outside")
    (session / "out-link").symlink_to(tmp_path / "secret.txt")
    (session / "raw-link").symlink_to(session / "raw")
    return session


@pytest.mark.parametrize("requested", [
    "../secret.txt", "..%2Fsecret.txt", "%2e%2e/secret.txt", "%2E%2E%2Fsecret.txt", "raw/../../secret.txt",
    "raw%2F..%2F..%2Fsecret.txt", "/etc/passwd", "%2Fetc%2Fpasswd", "%252e%252e%252fsecret.txt",
    "out-link", "raw-link/../../secret.txt", "raw", "", "%00report.json", "raw\\..\\..\\secret.txt", "%ff", "..",
])
def test_paths_outside_the_session_or_not_files_are_refused(tree, requested):
    with pytest.raises(UnsafePath):
        session_file(tree, requested)


def test_files_inside_the_session_are_found_through_any_encoding(tree):
    assert session_file(tree, "report.json") == tree.resolve() / "report.json"
    assert session_file(tree, "raw/a%20b.dng") == tree.resolve() / "raw" / "a b.dng"
    assert session_file(tree, "raw-link/a%20b.dng") == tree.resolve() / "raw" / "a b.dng"  # a link that stays inside


# ----- the server on a real session ----------------------------------------------------------------
def request(server, method: str, path: str, host: str | None = None, timeout: float = 10) -> tuple[int, dict, bytes]:
    """A raw HTTP request (the path is sent exactly as given, no client-side normalising); the
    headers are looked up without regard to case (uvicorn sends them in lower case)."""
    conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=timeout)
    conn.putrequest(method, path, skip_host=True)
    conn.putheader("Host", host or f"127.0.0.1:{server.port}")
    conn.endheaders()
    answer = conn.getresponse()
    body = answer.read()
    conn.close()
    return answer.status, answer.headers, body


def test_the_server_serves_session_files_and_refuses_traversal_writes_and_foreign_hosts(finished, tmp_path):
    (finished.parent / "secret.txt").write_text("outside the session")
    before = folder_state(finished)
    with MonitorServer(finished, port=0) as server:
        status, headers, body = request(server, "GET", "/files/report.json")
        assert status == 200 and body == (finished / "report.json").read_bytes()
        assert headers["Content-Type"].startswith("application/json")
        assert "default-src 'none'" in headers["Content-Security-Policy"]
        for path in ("/files/../secret.txt", "/files/..%2Fsecret.txt", "/files/%2e%2e%2fsecret.txt",
                     "/files//etc/passwd", "/files/%2Fetc%2Fpasswd", "/files/raw/..%2F..%2Fsecret.txt",
                     "/static/../server.py", "/static/%2e%2e%2fserver.py", "/../secret.txt",
                     "/fil%65s/..%2Fsecret.txt"):
            status, _, body = request(server, "GET", path)
            assert status == 404 and b"outside the session" not in body and b"import" not in body, path
        for method in ("POST", "PUT", "DELETE", "PATCH"):
            status, headers, _ = request(server, method, "/files/report.json")
            assert status == 405 and headers["Allow"] == "GET, HEAD"
        status, _, _ = request(server, "GET", "/api/state", host="attacker.example:8765")
        assert status == 403  # DNS rebinding: a page of another site cannot read the session
        status, _, body = request(server, "GET", "/api/state")
        state = json.loads(body)
        assert status == 200 and state["state"] == "finished" and state["count_text"] == f"{M} of {M} samples"
        assert "report.json" in state["files"] and "session.sqlite-wal" not in state["files"]
    assert folder_state(finished) == before  # nothing written, not even SQLite's side files


def test_a_frame_has_its_region_of_interest_outlined_around_the_sample_patch(finished):
    with Journal.open(finished / "session.sqlite") as journal:  # the reddest measured sample (off the highlight)
        k = max(journal.samples(), key=lambda r: r.rgb[0] / r.rgb[1]).plan_index
    with MonitorServer(finished, port=0) as server:
        request(server, "GET", "/api/state")
        status, headers, body = request(server, "GET", f"/api/frame.png?sample={k}")
        assert status == 200 and headers["X-Shows"] == str(k)
        info = json.loads(headers["X-Info"])
        image = cv2.imdecode(np.frombuffer(body, np.uint8), cv2.IMREAD_COLOR)
        assert image.shape[1] == 320 and info["roi_pixels"] >= 96 and info["file"].startswith(f"sample_{k:04d}_e")
        outline = np.all(image == (60, 220, 60), axis=-1)  # the ROI colour (BGR)
        ys, xs = np.nonzero(outline)
        assert outline.sum() > 20
        inside = image[ys.min() + 3:ys.max() - 2, xs.min() + 3:xs.max() - 2].reshape(-1, 3).mean(0)
        assert inside[2] > 1.5 * inside[1] and inside[2] > 1.5 * inside[0]  # red-plastic inside the outline
        card = image[ys.max() + 12:ys.max() + 16, xs.min():xs.max()].reshape(-1, 3).mean(0)
        assert np.ptp(card) < 0.15 * card.mean()  # the white card below the patch shows white (balanced)
        status, headers, body = request(server, "GET", f"/api/preview.png?done={M}")
        spheres = cv2.imdecode(np.frombuffer(body, np.uint8), cv2.IMREAD_COLOR)
        assert status == 200 and headers["X-Shows"] == str(M) and spheres.shape == (96, 3 * 96, 3)
        assert spheres[48, 48, 2] > spheres[48, 48, 1]  # a red sphere
        # pictures are rate-limited: right after one, the last one comes back with when to ask again
        other = (k + 1) % M
        status, headers, _ = request(server, "GET", f"/api/frame.png?sample={other}")
        assert status == 200 and headers["X-Shows"] == str(k) and int(headers["X-Retry-After-Ms"]) >= 200
        time.sleep(int(headers["X-Retry-After-Ms"]) / 1000)
        status, headers, body = request(server, "GET", f"/api/frame.png?sample={other}")
        assert status == 200 and headers["X-Shows"] == str(other)
        # a sample not in the journal is answered at once, with its own message
        status, headers, body = request(server, "GET", "/api/frame.png?sample=99")
        assert status == 404 and body == b"sample 99 is not in the journal" and headers["X-Shows"] == "99"


def test_the_monitor_command_refuses_a_file_a_bad_port_and_a_taken_port(tmp_path, capsys):
    # (a folder that does not exist yet is watched: test_queue_file)
    (tmp_path / "a-file").write_text("not a folder")
    assert main(["monitor", str(tmp_path / "a-file")]) == 2
    # the README's `goniofrost monitor SESSION_DIR|ROOT`: the usage line and the error name both
    assert capsys.readouterr().err == (
        "goniofrost monitor: error: command line: SESSION_DIR|ROOT: expected a session folder (goniofrost capture "
        f"--session DIR) or a folder of session folders (a queue's root), found '{tmp_path / 'a-file'}'\n")
    from goniofrost.app.cli import build_parser
    sub = next(a for a in build_parser()._actions if a.dest == "command").choices["monitor"]
    assert "SESSION_DIR|ROOT" in sub.format_usage()
    assert main(["monitor", str(tmp_path), "--port", "70000"]) == 2
    assert "--port: expected a TCP port 0..65535 (0 picks a free one), found 70000" in capsys.readouterr().err
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        assert main(["monitor", str(tmp_path), "--port", str(port)]) == 2
    assert f"monitor: cannot serve on 127.0.0.1:{port}" in capsys.readouterr().err


def test_a_host_address_this_computer_does_not_have_says_to_pass_another_host(tmp_path, capsys):
    # 192.0.2.1 (TEST-NET-1, RFC 5737) is no address of this computer: binding it is refused at
    # once; the message said "pass another --port" for it
    assert main(["monitor", str(tmp_path), "--host", "192.0.2.1", "--port", "0"]) == 2
    assert capsys.readouterr().err == (
        "goniofrost monitor: error: monitor: cannot serve on 192.0.2.1:0 (Cannot assign requested address); "
        "pass another --host (an address of this computer, e.g. 127.0.0.1)\n")


def test_the_preview_is_the_sessions_reconstruction_at_the_cells_the_spheres_show(finished):
    from goniofrost.brdf.preview import preview_of
    from goniofrost.capture.reconstruction import reconstruct_session
    from goniofrost.monitor.images import estimate_for_preview, session_inputs, sphere_positions
    from goniofrost.monitor.rig_pose import rig_from_text

    view = read_session(finished)
    inputs = session_inputs(view, rig_from_text(view.rig_text, "journal"))
    grid = inputs.model.grid
    from goniofrost.brdf.merl_file import valid_to_full
    whole = valid_to_full(reconstruct_session(inputs, view.done).brdf, grid)  # what the capture wrote to brdf.binary
    part = estimate_for_preview(inputs, view.done)
    shown = grid.valid_cells[sphere_positions(grid)]
    assert 100 < shown.size < grid.n_valid / 2
    # float32 dictionary products over a subset of rows vs all rows: rounding in another order
    np.testing.assert_allclose(part[shown], whole[shown], rtol=2e-5)
    computed = np.union1d(shown, inputs.cells[[d.plan_index for d in view.done]])  # and the sampled cells
    assert np.isnan(np.delete(part, computed, axis=0)).all() and not np.isnan(part[computed]).any()
    np.testing.assert_allclose(preview_of(part, grid, size=96).estimate, preview_of(whole, grid, size=96).estimate,
                               rtol=2e-5)


def test_the_monitor_command_serves_a_finished_session_until_ctrl_c(finished):
    import re
    import signal
    import subprocess
    import sys
    import urllib.request

    # -X faulthandler: should it outlive Ctrl-C, SIGABRT prints every thread's stack (it did once in a
    # loaded suite run on 3 December, with no stack to read; 150 runs of this sequence alone never did)
    # A suite started in the background of a non-interactive shell (``./dev test &``) ignores SIGINT, and
    # a Python started with SIGINT ignored keeps it ignored: the command starts with the default, as from
    # a terminal (it outlived Ctrl-C in every such run, its main thread sleeping in the loop).
    ignored = signal.getsignal(signal.SIGINT) == signal.SIG_IGN
    if ignored:
        signal.signal(signal.SIGINT, signal.SIG_DFL)
    try:
        proc = subprocess.Popen([sys.executable, "-X", "faulthandler", "-m", "goniofrost", "monitor", str(finished),
                                 "--port", "0"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    finally:
        if ignored:
            signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        line = proc.stdout.readline()
        url = re.fullmatch(rf"goniofrost monitor: (http://127\.0\.0\.1:\d+/) shows {re.escape(str(finished))} "
                           r"\(read-only\); Ctrl-C stops\n", line).group(1)
        state = json.loads(urllib.request.urlopen(url + "api/state", timeout=10).read())
        assert state["state"] == "finished" and state["count_text"] == f"{M} of {M} samples"
        assert b"<title>goniofrost monitor</title>" in urllib.request.urlopen(url, timeout=10).read()
        proc.send_signal(signal.SIGINT)
        try:  # communicate, not wait: it drains both pipes, so a chatty child cannot block on a full one
            _, err = proc.communicate(timeout=60)  # a bound, not a wait: on a loaded machine 10 s was seen to pass
        except subprocess.TimeoutExpired:
            proc.send_signal(signal.SIGABRT)
            pytest.fail(f"goniofrost monitor outlived Ctrl-C by 60 s; its threads:\n{proc.communicate()[1][-8000:]}")
        assert proc.returncode == 0, err
    finally:
        proc.kill()


# ----- the catalogue's session names, the Host header, concurrent downloads (issue 51: B4, B8) ----
def scripted_sessions(root: Path, names) -> None:
    """A finished one-sample session (a scripted journal) under ``root`` for each name."""
    from journal_script import ScriptedSession

    for name in names:
        script = ScriptedSession(root / name, 2)
        script.start_run()
        script.calibrate()
        script.capture(0)
        script.end_run(RunStatus.FINISHED, "finished")
        script.close()


def test_session_names_with_a_space_a_non_ascii_letter_or_a_percent_sign_are_decoded_once(tmp_path):
    """B4: /s/with%20space/ answered 404 (the name was not percent-decoded), and a folder named
    a%41 was served at /s/a%41/ (as if %41 were part of the name) rather than at /s/a%2541/."""
    scripted_sessions(tmp_path, ("with space", "café", "a%41", "plain"))
    with MonitorServer(tmp_path, port=0, catalogue=True) as server:
        page = request(server, "GET", "/")[2].decode()
        for name, link in (("with space", "with%20space"), ("café", "caf%C3%A9"), ("a%41", "a%2541")):
            assert f'<a href="/s/{link}/">{name}</a>' in page
            status, _, body = request(server, "GET", f"/s/{link}/api/state")
            assert status == 200 and json.loads(body)["count_text"] == "1 of 2 samples", (name, status, body)
            status, _, body = request(server, "GET", f"/s/{link}/files/session.sqlite")
            assert status == 200 and body == (tmp_path / name / "session.sqlite").read_bytes()
        assert request(server, "GET", "/s/a%41/api/state")[:3:2] == (404, b"no such session: aA")
        status, headers, _ = request(server, "GET", "/s/with%20space")
        assert status == 301 and headers["Location"] == "/s/with%20space/"
        for path in ("/s/..%2Fsecret/api/state", "/s/%2e%2e/api/state", "/s/plain%2F..%2Fplain/api/state",
                     "/s/%ff/api/state", "/s/plain/files/..%2Fcaf%C3%A9%2Fsession.sqlite"):
            assert request(server, "GET", path)[0] == 404, path


def test_a_request_with_two_host_headers_is_refused(finished):
    """B8: the monitor checked only the first Host header (a second, foreign one was answered)."""
    with MonitorServer(finished, port=0) as server:
        for hosts in ([f"127.0.0.1:{server.port}", "attacker.example"], [f"127.0.0.1:{server.port}"] * 2):
            with socket.create_connection(("127.0.0.1", server.port), timeout=10) as sock:
                head = "GET /api/state HTTP/1.1\r\n" + "".join(f"Host: {h}\r\n" for h in hosts) + "\r\n"
                sock.sendall(head.encode())
                answer = sock.makefile("rb").read()
            assert answer.split(b"\r\n", 1)[0] == b"HTTP/1.1 400 Bad Request", (hosts, answer[:200])
            assert b"count_text" not in answer


def test_forty_concurrent_downloads_wait_their_turn_and_all_get_the_whole_file(tmp_path, monkeypatch):
    """B8: with 40 readers at once, 80 of 200 downloads were answered 503 (4 transfers at a time):
    beyond MAX_TRANSFERS (4 here, so that most of the 40 wait) they now queue, and every one gets
    every byte."""
    import threading

    from goniofrost.monitor import views

    monkeypatch.setattr(views, "MAX_TRANSFERS", 4)
    (tmp_path / "big.bin").write_bytes(np.random.default_rng(0).bytes(8 << 20))
    readers, start, got = 40, threading.Barrier(40, timeout=30), []

    def read(server):
        start.wait()   # every request sent at once
        status, _, body = request(server, "GET", "/files/big.bin", timeout=60)
        got.append((status, len(body)))
    with MonitorServer(tmp_path, port=0) as server:
        threads = [threading.Thread(target=read, args=(server,)) for _ in range(readers)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(timeout=120)
    assert sorted(got) == [(200, 8 << 20)] * readers


def test_another_app_mounts_the_read_only_views_beside_its_own_routes(finished):
    """The shape the instrument server builds on: its own routes (a POST here) before the views,
    one Host check for both, and the views still answer only GET and HEAD."""
    from starlette.applications import Starlette
    from starlette.middleware import Middleware
    from starlette.responses import PlainTextResponse
    from starlette.routing import Route

    from goniofrost.monitor.app import Guard, monitor_lifespan, monitor_routes
    from goniofrost.monitor.hub import Sites
    from goniofrost.monitor.server import AppServer

    sites = Sites(finished, catalogue=False)
    routes = [Route("/api/ping", lambda request: PlainTextResponse("pong"), methods=["POST"]), *monitor_routes(sites)]
    app = Starlette(routes=routes, middleware=[Middleware(Guard, host="127.0.0.1")], lifespan=monitor_lifespan(sites))
    with AppServer(app, port=0) as server:
        assert request(server, "POST", "/api/ping")[::2] == (200, b"pong")
        assert request(server, "POST", "/files/report.json")[0] == 405
        assert request(server, "POST", "/api/ping", host="attacker.example")[0] == 403
        status, _, body = request(server, "GET", "/api/state")
        assert status == 200 and json.loads(body)["state"] == "finished"
