"""``goniofrost serve`` driven over loopback by a real HTTP client on the small simulated rig: the
queue, pause, resume and stop of a capture; a drilled lamp failure suspending it; the token and the
origin; malformed requests refused naming the field with nothing queued or moved; kill -9
mid-capture and a restart losing and repeating no sample."""
from __future__ import annotations

import json
import logging
import os
import signal
import subprocess
import sys
import re
import time
from pathlib import Path

import pytest
import requests
import yaml

from goniofrost.rig.file import load_checked_rig
from goniofrost.rig.lock import rig_holder
from monitor_helpers import MATERIAL, journal_rows, make_plan

REPO = Path(__file__).resolve().parents[1]
logging.getLogger("pymodbus").setLevel(logging.CRITICAL)  # a silenced drive makes pymodbus log errors
M = 4
TIMEOUT_S = 120.0


@pytest.fixture(scope="module")
def plan(tmp_path_factory):
    """(rig file, plan file): the small simulated rig, its lamp off while a capture is paused."""
    rig, plan_file = make_plan(tmp_path_factory.mktemp("serve"), M)
    rig.write_text(rig.read_text() + "pause: {lamp: 'off', lamp_tolerance: 0.01}\n")
    return rig, plan_file


class Server:
    """A ``goniofrost serve`` process on port 0 of loopback, its URL and token read from the lock."""

    def __init__(self, rig: Path, root: Path, speedup: float = 20) -> None:
        self.rig, self.root = rig, root
        self.proc = subprocess.Popen([sys.executable, "-m", "goniofrost", "serve", "--rig", str(rig), "--root",
                                      str(root), "--port", "0", "--speedup", str(speedup)], cwd=REPO,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        line = self.proc.stdout.readline()
        if not line:
            pytest.fail(f"serve did not start: {self.proc.stderr.read()}")
        holder = rig_holder(load_checked_rig(rig))
        assert holder.program == "serve" and holder.pid == self.proc.pid
        assert line.startswith(f"goniofrost serve: sim-rig held; serving on {holder.url}?token=")
        self.url = holder.url.rstrip("/")
        self.token = Path(holder.token_file).read_text().strip()
        assert line.strip().endswith(self.token) and Path(holder.token_file).stat().st_mode & 0o777 == 0o600
        self.auth = {"Authorization": f"Bearer {self.token}"}

    def get(self, path: str):
        return requests.get(self.url + path, timeout=30)

    def post(self, path: str, body=None, headers=None, **kw):
        return requests.post(self.url + path, json=body, headers=self.auth if headers is None else headers,
                             timeout=60, **kw)

    def status(self) -> dict:
        return self.get("/api/status").json()

    def wait(self, condition, what: str):
        """Poll until ``condition()`` is true; fail after TIMEOUT_S or when the server ended."""
        deadline = time.monotonic() + TIMEOUT_S
        while time.monotonic() < deadline:
            value = condition()
            if value:
                return value
            if self.proc.poll() is not None:
                pytest.fail(f"serve ended before {what}: {self.proc.stderr.read()}")
            time.sleep(0.02)
        pytest.fail(f"no {what} within {TIMEOUT_S} s: {self.status()}")

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


def entry(plan_file: Path, **extra) -> dict:
    return {"plan": plan_file.name, "material": MATERIAL, "sample_id": "red-1", "operator": "ada", **extra}


@pytest.fixture
def server(plan, tmp_path):
    rig, plan_file = plan
    root = tmp_path / "root"
    root.mkdir()
    (root / plan_file.name).write_text(plan_file.read_text())
    served = Server(rig, root)
    yield served
    served.close()


def test_a_capture_is_queued_paused_resumed_and_stopped(server, plan):
    rig, plan_file = plan
    assert server.status()["state"] == "idle"
    assert set(server.get("/openapi.json").json()["components"]["schemas"]["State"]["enum"]) == {
        "idle", "running", "paused", "suspended", "stopping", "fault"}
    added = server.post("/api/queue", entry(plan_file, target_error=None))
    assert added.status_code == 201, added.text
    session = server.root / "sessions" / "0001-red-1"
    server.wait(lambda: server.status()["state"] == "running", "a running capture")
    assert server.post("/api/pause", {"operator": "ada"}).json()["state"] == "running"  # until the safe point
    paused = server.wait(lambda: (s := server.status())["state"] == "paused" and s, "the pause")
    assert paused["reason"] == "paused at plan sample 0" and paused["current"]["id"] == added.json()["id"]
    assert paused["lamp"] == {"on": False, "photodiode": 0.0}  # the rig file's pause: {lamp: off}
    assert journal_rows(session) == []  # paused before the first sample's move
    assert server.post("/api/resume", {"operator": "bob"}).json()["state"] == "paused"
    server.wait(lambda: len(journal_rows(session)) >= 1, "a sample after the resume")
    records = events(server, server.status()["events"])
    lamp = [(r["type"], r.get("on")) for r in records if r["type"] in ("lamp", "relit")]
    assert lamp == [("lamp", False), ("lamp", True), ("relit", None)]  # on again before the sample
    relit = next(r for r in records if r["type"] == "relit")
    assert abs(relit["photodiode"] / relit["before"] - 1) <= 0.01 and relit["before"] > 0.9
    assert relit["t_utc"] < journal_rows(session)[0][1]  # relit before sample 0 was committed
    assert server.post("/api/stop", {"operator": "cy"}).status_code == 200
    ended = server.wait(lambda: (q := server.get("/api/queue").json())[0]["state"] != "running" and q, "the stop")[0]
    assert ended["state"] == "stopped" and json.loads(ended["result"])["reason"].startswith(
        "interrupted by a stop request from cy at 127.0.0.1")
    status = server.status()
    assert (status["state"], status["held"]) == ("idle", True)
    assert 1 <= len(journal_rows(session)) < M
    waiting = server.post("/api/queue", entry(plan_file, sample_id="red-2", operator="dee")).json()
    assert server.get("/api/queue").json()[1]["state"] == "pending"  # the queue is held after the stop
    delete = lambda headers=None: requests.delete(f"{server.url}/api/queue/{waiting['id']}",  # noqa: E731
                                                  headers=server.auth if headers is None else headers, timeout=30)
    assert delete({}).status_code == 401 and delete().json() == {"removed": waiting["id"]}
    assert (delete().status_code, delete().json()["field"]) == (404, "id")
    assert [e["id"] for e in server.get("/api/queue").json()] == [added.json()["id"]]
    actions = [(a["who"], a["action"]) for a in server.get("/api/actions").json()]
    assert actions == [("ada", "queue_add"), ("ada", "pause"), ("bob", "resume"), ("cy", "stop"),
                       ("dee", "queue_add"), ("?", "queue_remove")]


def events(server, until: int) -> list[dict]:
    """The event stream's records 0 .. ``until`` - 1."""
    records = []
    with requests.get(server.url + "/api/events?since=0", stream=True, timeout=30) as stream:
        for line in stream.iter_lines(decode_unicode=True):
            if line.startswith("data: "):
                records.append(json.loads(line[len("data: "):]))
                if records[-1]["seq"] + 1 >= until:
                    break
    return records


def test_a_dimmed_lamp_suspends_a_queued_capture_which_resumes_by_itself(plan, tmp_path):
    from goniofrost.capture.journal import Journal

    rig, plan_file = plan
    doc = yaml.safe_load(rig.read_text())
    doc["sim"]["faults"] = [{"kind": "lamp_dim", "at_sample": 1, "level": 0.5, "duration_s": 28}]
    doc["suspenders"] = {"lamp_floor": 0.8, "hold_clear_s": 10, "poll_s": 5}  # 40 s of simulated clock
    dimmed = rig.parent / "dimmed.yaml"
    dimmed.write_text(yaml.safe_dump(doc, sort_keys=False))
    root = tmp_path / "root"
    root.mkdir()
    (root / plan_file.name).write_text(plan_file.read_text())
    server = Server(dimmed, root)
    try:
        assert server.post("/api/queue", entry(plan_file)).status_code == 201
        status = server.wait(lambda: (s := server.status())["state"] == "suspended" and s, "the suspension")
        assert status["reason"] == ("run suspended before plan sample 1: lamp_low (photodiode 0.499 of nominal, "
                                    "below the floor 0.8)") and status["suspension"] == "lamp_low"
        done = server.wait(lambda: (q := server.get("/api/queue").json())[0]["state"] == "done" and q[0], "the end")
        states = [(r["state"], r["reason"]) for r in events(server, server.status()["events"]) if r["type"] == "state"]
        assert states == [("running", None), ("suspended", status["reason"]), ("running", None), ("idle", None)]
    finally:
        server.close()
    session = root / json.loads(done["result"])["session"]
    assert [index for index, _ in journal_rows(session)] == list(range(M))
    with Journal.open(session / "session.sqlite", read_only=True) as journal:
        [s] = journal.suspensions()
    assert (s.reason, s.plan_index, s.waited_s, str(s.end)) == ("lamp_low", 1, 40.0, "resumed")
    report = json.loads((session / "report.json").read_text())
    assert report["suspensions"]["count"] == 1
    # the simulated material is compared with what was measured, as a capture --material's report is
    assert report["ground_truth"]["material"] == MATERIAL


def test_a_drive_silent_between_runs_is_reopened_with_back_off_on_the_simulated_clock(plan, tmp_path):
    """The instrument in-process on the simulated devices: its idle reads find the drive silent, it
    says fault with the reason and reopens it after 0.5, 1 and 2 s of simulated clock (the drill lasts
    3 s of it), then is idle again; nothing was moved."""
    from goniofrost.rig.lock import rig_lock
    from goniofrost.rig.simulated import simulated_devices
    from goniofrost.server.instrument import Instrument
    from goniofrost.server.store import Store

    doc = yaml.safe_load(plan[0].read_text())
    doc["sim"]["faults"] = [{"axis": "camera_arm", "kind": "silent", "at_sample": 0, "duration_s": 3}]
    doc["axes"]["camera_arm"]["driver"]["reply_timeout_ms"] = 30  # a silent read gives up in 3 x 30 ms
    (tmp_path / "rig.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    rig = load_checked_rig(tmp_path / "rig.yaml")
    store = Store(tmp_path)
    with rig_lock(rig, "serve") as lock, simulated_devices(rig, speedup=1000) as hw:
        instrument = Instrument(rig, hw, lock, store, run_entry=None, idle_read_s=0.01).start()
        try:
            until = lambda what, test: wait_for(lambda: test(instrument.status()), what)  # noqa: E731
            pose = until("a first reading", lambda s: s["pose"].get("camera_arm") is not None and s["pose"])
            t0 = hw.clock.nominal_time()
            hw.simulation.arm_faults(0)  # camera_arm answers nothing for 3 s of simulated clock
            fault = until("the fault", lambda s: s["state"] == "fault" and s)
            assert fault["reason"].startswith("camera_arm does not answer (camera_arm: ")
            until("idle again", lambda s: s["state"] == "idle" and s["events"] > fault["events"] + 3)
            reasons = [r["reason"] for r in instrument.events_since(0) if r["type"] == "state"]
            assert [r and r.rsplit(": ", 1)[-1] for r in reasons] == [
                "reopening in 0.5 s (attempt 1)", "reopening in 1 s (attempt 2)", "reopening in 2 s (attempt 3)", None]
            assert [r["attempts"] for r in instrument.events_since(0) if r["type"] == "reconnected"] == [3]
            assert hw.clock.nominal_time() - t0 == pytest.approx(3.5)
            assert instrument.status()["pose"] == pose
        finally:
            instrument.close()
            store.close()


def test_a_run_suspended_for_the_operator_resumes_on_the_instruments_resume(plan, tmp_path):
    """resume: operator: the instrument (in-process, on the simulated devices) says suspended until
    its resume() (what POST /api/resume calls) reaches the engine's SuspendWatch, then running."""
    import threading

    from goniofrost.capture.executor import StepExecutor
    from goniofrost.capture.signals import SessionInterrupted
    from goniofrost.capture.suspension import SuspendWatch
    from goniofrost.rig.lock import rig_lock
    from goniofrost.rig.simulated import simulated_devices
    from goniofrost.rig.suspenders import Suspenders
    from goniofrost.server.instrument import Instrument
    from goniofrost.server.store import Store

    doc = yaml.safe_load(plan[0].read_text())
    doc["sim"]["faults"] = [{"kind": "lamp_cut", "at_sample": 0, "duration_s": 10}]
    doc["suspenders"] = {"lamp_floor": 0.8, "hold_clear_s": 5, "poll_s": 5, "resume": "operator"}
    (tmp_path / "rig.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    rig = load_checked_rig(tmp_path / "rig.yaml")
    store = Store(tmp_path)
    with rig_lock(rig, "serve") as lock, simulated_devices(rig, speedup=1000) as hw:
        instrument = Instrument(rig, hw, lock, store, run_entry=None)
        hw.lamp.on()
        def check_stop() -> None:  # the engine's: a stop request ends the wait
            if instrument.stop_asked:
                raise SessionInterrupted(instrument.stop_asked)

        watch = SuspendWatch(Suspenders.from_section(rig.suspenders), StepExecutor(hw, tmp_path), None,
                             check_stop, lambda: 1)
        watch.listen(instrument.gate)
        hw.simulation.arm_faults(0)
        run = threading.Thread(target=watch.may_continue, args=(0,))
        run.start()
        try:
            status = wait_for(lambda: (s := instrument.status())["state"] == "suspended" and s, "the suspension")
            assert status["suspension"] == "lamp_low" and status["reason"].startswith(
                "run suspended before plan sample 0: lamp_low (photodiode 0.000 of nominal")
            wait_for(lambda: watch.waited >= 30, "a clear lamp held for hold_clear_s")  # still waiting for us
            assert instrument.status()["state"] == "suspended"
            instrument.resume()
            run.join(timeout=TIMEOUT_S)
            after = instrument.status()
        finally:
            if run.is_alive():
                instrument.stop("the test")  # a wait that did not end ends at its next poll
                run.join(timeout=TIMEOUT_S)
        assert (after["state"], after["suspension"], after["reason"]) == ("running", None, None)
    store.close()


def wait_for(condition, what: str):
    """Poll ``condition()`` until it is true; fail after TIMEOUT_S."""
    deadline = time.monotonic() + TIMEOUT_S
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(0.01)
    pytest.fail(f"no {what} within {TIMEOUT_S} s")


def test_no_token_a_wrong_token_another_origin_and_malformed_requests_change_nothing(server, plan):
    rig, plan_file = plan
    pose = server.status()["pose"]
    good = entry(plan_file)
    refusals = [
        (server.post("/api/queue", good, headers={}), 401, "authorization"),
        (server.post("/api/move", {"targets": {"camera_arm": 60}}, headers={}), 401, "authorization"),
        (server.post("/api/queue", good, headers={"Authorization": "Bearer nope"}), 403, "authorization"),
        (server.post("/api/lamp", {"on": True}, headers={"Authorization": "Bearer nope"}), 403, "authorization"),
        (server.post("/api/move", {"targets": {"camera_arm": 60}},
                     headers={**server.auth, "Origin": "http://evil.example"}), 403, "origin"),
        (server.post("/api/queue", entry(plan_file, plan="no-such-plan.json")), 422, "plan"),
        (server.post("/api/queue", entry(plan_file, plan="../plan4.json")), 422, "plan"),
        (server.post("/api/queue", entry(plan_file, material="builtin:no-such-material")), 422, "material"),
        (server.post("/api/queue", entry(plan_file, target_error=-1)), 422, "target_error"),
        (server.post("/api/queue", entry(plan_file, colour="red")), 422, "colour"),
        (server.post("/api/move", {"targets": {"camera_arm": 200}}), 422, "targets.camera_arm"),
        (server.post("/api/queue", None, data=b"{" + b" " * 20000 + b"}",
                     headers={**server.auth, "Content-Type": "application/json"}), 413, "body"),
        (server.post("/api/queue", entry(plan_file, target_error=0.5, confidence=0.9999)), 422, "confidence"),
    ]
    assert [(r.status_code, r.json()["field"]) for r, _, _ in refusals] == [(s, f) for _, s, f in refusals]
    assert "limits [8, 172]" in refusals[10][0].json()["error"]
    assert re.fullmatch(r"confidence: expected at most 0\.\d{3} with this model \(its bound is calibrated on \d+ "
                        r"held-out training materials; 0\.9999 needs 9999\), found 0\.9999",
                        refusals[-1][0].json()["error"]), refusals[-1][0].json()["error"]
    assert server.get("/").status_code == 200  # the instrument's page, beside the API
    assert "<table id=\"sessions\">" in server.get("/sessions").text  # the monitor's list of the root's sessions
    foreign = requests.get(server.url + "/api/status", headers={"Host": "evil.example"}, timeout=30)
    assert foreign.status_code == 403
    assert server.get("/api/queue").json() == [] and server.get("/api/actions").json() == []
    status = server.status()
    assert (status["state"], status["pose"]) == ("idle", pose)


def test_a_paused_capture_survives_a_restart_and_kill_9_loses_and_repeats_no_sample(server, plan):
    rig, plan_file = plan
    assert server.post("/api/queue", entry(plan_file)).status_code == 201
    session = server.root / "sessions" / "0001-red-1"
    server.wait(lambda: server.status()["state"] == "running", "a running capture")
    server.post("/api/pause")
    server.wait(lambda: server.status()["state"] == "paused", "the pause")
    server.close()  # Ctrl-C of a paused server: the entry stays to be resumed
    assert server.proc.returncode == 0 and server.proc.stderr.read() == ""
    resumed = Server(rig, server.root)
    try:
        resumed.wait(lambda: len(journal_rows(session)) >= 1, "a journaled sample after the restart")
        resumed.proc.kill()
        resumed.proc.wait()
    finally:
        resumed.close()
    killed_at = len(journal_rows(session))
    assert killed_at < M, "the capture ended before the kill: make M larger"
    again = Server(rig, server.root, speedup=100)   # the rest, without a kill to catch: at full speed
    try:
        done = again.wait(lambda: (q := again.get("/api/queue").json())[0]["state"] == "done" and q[0], "the resume")
        rows = journal_rows(session)
        assert [index for index, _ in rows] == list(range(M))  # 0 lost, 0 repeated
        assert json.loads(done["result"])["session"] == "sessions/0001-red-1"
        assert again.status()["state"] == "idle"
    finally:
        again.close()


def test_the_rig_command_asks_the_running_server_and_the_event_stream_tells(server, plan, capsys):
    """`goniofrost rig home/move/lamp/stop` find the server through the device lock and use its API
    (the server keeps the devices: nothing else could open them); snap writes under the root."""
    from goniofrost.app.cli import main

    rig, _ = plan
    for words in (["home", "--yes"], ["move", "camera_arm=60", "sample_yaw=10"], ["lamp", "on"], ["stop"]):
        assert main(["rig", words[0], "--rig", str(rig), *words[1:]]) == 0, capsys.readouterr().err
    err = capsys.readouterr().err
    assert "reached camera_arm 60.000 deg, sample_yaw 10.0" in err
    assert f"asked serve (process {server.proc.pid} of " in err and f"at {server.url} to stop sim-rig: it is idle" in err
    status = server.status()
    assert abs(status["pose"]["camera_arm"] - 60) < 0.05 and status["lamp"]["on"] is True
    snap = server.post("/api/snap", {"name": "here.png"})
    assert snap.status_code == 200 and (server.root / "snaps" / "here.png").stat().st_size > 0
    assert [a["action"] for a in server.get("/api/actions").json()] == ["home", "move", "lamp", "stop", "snap"]
    assert server.get("/api/actions").json()[0]["who"].endswith("(goniofrost rig)")
    records = events(server, status["events"])  # every record before the status read
    assert [r["seq"] for r in records] == list(range(status["events"]))
    assert [r["state"] for r in records if r["type"] == "state"] == ["running", "idle"] * 3  # home, move, lamp
    assert [r["on"] for r in records if r["type"] == "lamp"] == [True]


def test_rig_status_snap_and_the_queue_command_ask_the_running_server(server, plan, tmp_path, capsys):
    """`goniofrost rig status/snap` read through the server; `goniofrost queue QUEUE.yaml` adds its
    samples to the server's queue (held here by a stop, so nothing runs)."""
    from goniofrost.app.cli import main

    rig, plan_file = plan
    assert main(["rig", "status", "--rig", str(rig), "--json"]) == 0
    said = json.loads(capsys.readouterr().out)
    assert said["server"] == {"url": server.url, "state": "idle", "reason": None, "current": None}
    assert {a["axis"]: a["position_deg"] for a in said["axes"]} == server.status()["pose"]
    assert main(["rig", "status", "--rig", str(rig)]) == 0
    assert capsys.readouterr().out.startswith(f"sim-rig is held by serve (process {server.proc.pid} of ")
    assert main(["rig", "snap", "--rig", str(rig), "--move", "camera_arm=30", "--out", str(tmp_path / "frame.png"),
                 "--json"]) == 0
    snapped = json.loads(capsys.readouterr().out)
    assert snapped["png"] == str(tmp_path / "frame.png") and snapped["problem"] is None
    assert (tmp_path / "frame.png").read_bytes() == (server.root / "snaps" / "frame.png").read_bytes()
    server.post("/api/stop")  # the queue is held: what is added waits
    queue = server.root / "queue.yaml"
    queue.write_text(f"rig: {rig}\nplan: {plan_file.name}\nroot: elsewhere\noperator: ada\n"
                     f"samples:\n  - {{sample_id: S-1, material: {MATERIAL}}}\n"
                     f"  - {{sample_id: S-2, material: {MATERIAL}, target_error: 0.5, confidence: 0.8, note: second}}\n")
    assert main(["queue", str(queue)]) == 0
    assert capsys.readouterr().out == (f"queue queue.yaml: added S-1 (id 1), S-2 (id 2) to the queue of the server at "
                                       f"{server.url}; sessions in {server.root / 'sessions'} (goniofrost sessions "
                                       f"{server.root / 'sessions'})\n")
    add = ["queue", "add", "--rig", str(rig), "--plan", str(server.root / plan_file.name), "--material", MATERIAL]
    assert main([*add, "--sample-id", "S-3", "--operator", "bo", "--target-error", "0.5", "--confidence", "0.8"]) == 0
    assert capsys.readouterr().out == (f"queue: added S-3 (id 3) to the queue of the server at {server.url}; "
                                       f"its session in {server.root / 'sessions'}\n")
    assert main([*add, "--sample-id", "S-4", "--target-error", "-1"]) == 2  # the server's check, its field named
    err = capsys.readouterr().err
    assert err.startswith(f"goniofrost queue: error: the server at {server.url} refused POST /api/queue (422): ")
    assert "target_error" in err and err.count("\n") == 1
    rows = [(e["sample_id"], e["state"], e["operator"], e["note"], e["target_error"], e["confidence"])
            for e in server.get("/api/queue").json()]
    assert rows[:2] == [("S-1", "pending", "ada", "", None, 0.95), ("S-2", "pending", "ada", "second", 0.5, 0.8)]
    assert rows[2:] == [("S-3", "pending", "bo", "", 0.5, 0.8)]
    assert not (server.root / "elsewhere").exists()
    assert [a["action"] for a in server.get("/api/actions").json()] == ["move", "snap", "stop"] + ["queue_add"] * 3


def test_a_refused_start_warns_off_loopback_names_the_holder_and_leaves_the_root_alone(plan, tmp_path, capsys):
    from goniofrost.app.cli import main
    from goniofrost.rig.lock import rig_lock

    rig, _ = plan
    root = tmp_path / "root"
    root.mkdir()
    with rig_lock(load_checked_rig(rig), "capture") as lock:
        assert main(["serve", "--rig", str(rig), "--root", str(root), "--host", "0.0.0.0", "--port", "0"]) == 2
    assert capsys.readouterr().err == (
        "goniofrost serve: WARNING: listening on 0.0.0.0: anyone on that network with the token can move the rig; "
        "use it only on a trusted network\n"
        f"goniofrost serve: error: rig 'sim-rig' is in use by {lock.holder.who()}: one program drives a device at "
        f"a time; wait for it to finish or stop it (goniofrost rig stop, or Ctrl-C in its terminal)\n")
    assert list(root.iterdir()) == []


def test_one_server_per_root(server, plan, capsys):
    from goniofrost.app.cli import main

    other = server.root.parent / "other-rig"
    other.mkdir()
    (other / "sim.yaml").write_text(plan[0].read_text())  # another simulated instance: its devices are free
    before = sorted(p.name for p in server.root.iterdir())
    assert main(["serve", "--rig", str(other / "sim.yaml"), "--root", str(server.root), "--port", "0"]) == 2
    assert capsys.readouterr().err == (f"goniofrost serve: error: --root: {server.root} is served by another "
                                       f"goniofrost serve (process {server.proc.pid}); one server per root\n")
    assert sorted(p.name for p in server.root.iterdir()) == before and server.status()["state"] == "idle"


def test_pending_entries_are_reordered_and_the_camera_view_is_a_small_png(server, plan):
    """POST /api/queue/{id}/move reorders the pending entries (a wrong id or ``before`` names the
    field and changes nothing); POST /api/camera answers a PNG of the current pose, saturated
    pixels red, and without the token nothing is taken."""
    import cv2
    import numpy as np

    rig, plan_file = plan
    assert server.post("/api/stop").json()["state"] == "idle"  # holds the queue: the entries stay pending
    a, b, c = (server.post("/api/queue", entry(plan_file, sample_id=f"s{k}")).json()["id"] for k in range(3))
    assert server.post(f"/api/queue/{c}/move", {"before": a}).json() == {"pending": [c, a, b]}
    assert server.post(f"/api/queue/{c}/move", {"before": None}).json() == {"pending": [a, b, c]}
    assert server.post(f"/api/queue/{a}/move", {"before": c, "operator": "ada"}).json() == {"pending": [b, a, c]}
    refused = [server.post("/api/queue/999/move", {"before": a}), server.post(f"/api/queue/{a}/move", {"before": 999}),
               server.post(f"/api/queue/{a}/move", {"before": a}), server.post(f"/api/queue/{a}/move", {"before": "1"}),
               server.post(f"/api/queue/{a}/move", {"before": b}, headers={})]
    assert [(r.status_code, r.json()["field"]) for r in refused] == [
        (404, "id"), (422, "before"), (422, "before"), (422, "before"), (401, "authorization")]
    assert [e["id"] for e in server.get("/api/queue").json()] == [b, a, c]
    paths = server.get("/openapi.json").json()["paths"]
    assert {"/api/queue/{id}/move", "/api/camera", "/api/rig"} <= set(paths)

    assert server.post("/api/camera", {"exposure_s": 0.002}, headers={}).status_code == 401  # not journaled: not taken
    assert server.post("/api/camera", {"exposure_s": -1}).json()["field"] == "exposure_s"
    assert server.post("/api/camera", {"black": 0.5, "white": 0.1}).json()["field"] == "white"
    for path, body in (("/api/lamp", {"on": True}), ("/api/home", {}),
                       ("/api/move", {"targets": {"camera_arm": 30, "sample_tilt": 30}})):  # the card faces the lamp
        assert server.post(path, body).status_code == 200

    def view(**body):
        answer = server.post("/api/camera", body)
        assert answer.status_code == 200 and answer.headers["content-type"] == "image/png", answer.text
        return cv2.imdecode(np.frombuffer(answer.content, np.uint8), cv2.IMREAD_COLOR), json.loads(answer.headers["X-Info"])
    short, short_info = view(exposure_s=0.002, black=0.0, white=0.05)
    long, long_info = view(exposure_s=1.28)  # 10 x the ladder's longest rung: the white card saturates
    assert short.shape == long.shape == (90, 120, 3)  # the 240 x 180 sensor at half resolution
    assert (short_info["auto"], short_info["black"], short_info["white"], short_info["saturated_px"]) == (False, 0, 0.05, 0)
    assert long_info["auto"] and long_info["exposure_s"] == 1.28 and long_info["saturated_fraction"] > 0
    red = np.all(long == (0, 0, 255), axis=-1)
    assert red.sum() >= long_info["saturated_px"] > 0
    actions = [(a["who"], a["action"]) for a in server.get("/api/actions").json()]  # every frame taken is journaled
    assert actions[4:] == [("?", "queue_move"), ("?", "queue_move"), ("ada", "queue_move"), ("?", "lamp"),
                           ("?", "home"), ("?", "move"), ("?", "camera"), ("?", "camera")]


def test_the_store_reorders_pending_entries_and_reads_a_root_served_before_reordering(tmp_path):
    """A serve.sqlite made before entries had a position keeps its order; a move swaps positions
    among the pending entries only; a running, ended or unknown entry is not moved."""
    import sqlite3

    from goniofrost.server.store import DB_FILE, SCHEMA, Store

    with sqlite3.connect(tmp_path / DB_FILE) as old:
        old.executescript(SCHEMA.replace(", position INTEGER", ""))
        for sample in ("a", "b", "c"):
            old.execute("INSERT INTO queue (plan, sample_id, operator, note, confidence, state, added_utc) "
                        "VALUES ('p.json', ?, '', '', 0.9, 'pending', 0)", (sample,))
    store = Store(tmp_path)
    try:
        d = store.add({"plan": "p.json", "material": None, "sample_id": "d", "operator": "", "note": "",
                       "target_error": None, "confidence": 0.9})["id"]
        assert [(e["id"], e["position"]) for e in store.entries()] == [(1, 1), (2, 2), (3, 3), (4, 4)]
        store.started(1, "sessions/0001-a")
        assert store.move(d, 2) == [4, 2, 3] and store.move(2, None) == [4, 3, 2]
        assert store.move(1, None) is None and store.move(9, None) is None and store.move(3, 1) is None
        assert [e["sample_id"] for e in store.entries()] == ["a", "d", "c", "b"]
        assert store.next_entry()["id"] == 1  # the running entry first, then the pending ones in order
        store.ended(1, "done", {})
        assert store.next_entry()["id"] == d
    finally:
        store.close()
