"""The monitor page in a real headless Chromium (Debian's ``chromium``; .ci/run installs it),
driven by Playwright: what a person sees during a simulated capture, after a fault, on a resume,
and on a session that records a predicted error."""
from __future__ import annotations

import json
import os
import queue
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from goniofrost.capture.engine import SessionFault
from goniofrost.capture.journal import Journal, SampleRecord
from goniofrost.capture.inputs import load_inputs
from goniofrost.capture.options import SessionOptions
from goniofrost.capture.runner import capture
from goniofrost.datasets import shown_material
from goniofrost.rig.simulated import rig_devices
from goniofrost.monitor.server import MonitorServer
from monitor_helpers import MATERIAL, drilled_rig, make_plan
from goniofrost.rig.hardware import SimOptions

CHROMIUM = Path(os.environ.get("GONIOFROST_CHROMIUM", "/usr/bin/chromium"))
REPO = Path(__file__).resolve().parents[1]
M = 5
LOADED_MS = 30_000  # a page's first state can take seconds on a loaded 2-core host

pytestmark = pytest.mark.skipif(not CHROMIUM.exists(), reason=f"needs headless Chromium at {CHROMIUM} "
                                "(Debian's chromium package; .ci/run installs it)")


@pytest.fixture(scope="module")
def browser():
    from playwright.sync_api import sync_playwright

    with sync_playwright() as playwright:
        chromium = playwright.chromium.launch(executable_path=str(CHROMIUM))
        yield chromium
        chromium.close()


@pytest.fixture
def page(browser):
    """A fresh page; any script error or failed console message fails the test."""
    context = browser.new_context(viewport={"width": 1280, "height": 1000})
    tab = context.new_page()
    errors = []
    tab.on("pageerror", lambda exc: errors.append(str(exc)))
    yield tab
    context.close()
    assert errors == []


@pytest.fixture(scope="module")
def plan(tmp_path_factory):
    folder = tmp_path_factory.mktemp("browser")
    return make_plan(folder, M)


def expect(locator):
    from playwright.sync_api import expect as pw_expect

    return pw_expect(locator)


def statuses(page) -> list[str]:
    """The plan chart's dots' statuses in plan order (a next or failed dot is drawn last, on top)."""
    return page.eval_on_selector_all(
        "#plan-dots circle", "dots => { const s = []; dots.forEach(d => { s[+d.dataset.index] = d.dataset.status; }); return s; }")


def test_the_page_follows_a_capture_started_with_monitor(plan, page, tmp_path):
    rig, plan_file = plan
    session = tmp_path / "s"
    proc = subprocess.Popen(
        [sys.executable, "-m", "goniofrost", "capture", "--rig", str(rig), "--plan", str(plan_file), "--session",
         str(session), "--material", MATERIAL, "--no-progress", "--speedup", "10", "--monitor", "--port", "0"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        line = proc.stderr.readline()
        url = re.search(r"monitor page at (http://127\.0\.0\.1:\d+/) \(read-only view of ", line).group(1)
        page.goto(url)
        # how the count grows step by step is checked on a scripted journal (no race) below
        expect(page.locator("#state")).to_have_text("finished", timeout=90_000)
        out, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    expect(page.locator("#count")).to_have_text(f"{M} of {M} samples")
    # the final state stays on the page after the capture process (and its server) ended
    expect(page.locator("#connection")).to_contain_text("the monitor stopped serving")
    assert statuses(page) == ["done"] * M
    assert page.eval_on_selector_all("#snr-chart circle", "d => d.filter(c => c.style.display !== 'none').length") == M
    assert page.eval_on_selector("#frame-img", "img => img.naturalWidth") == 320
    assert page.eval_on_selector("#preview-img", "img => img.naturalWidth") == 3 * 96
    expect(page.locator("#frame-caption")).to_contain_text("region of interest")
    expect(page.locator("#file-list")).to_contain_text("report.json")
    expect(page.locator("#summary-text")).to_contain_text(f"{M} samples on rig 'sim-rig'")
    assert page.locator("#fault").is_hidden()


def test_a_fault_shows_the_terminals_words_and_the_page_follows_the_resume(plan, page, tmp_path):
    rig, plan_file = plan
    session = tmp_path / "s"
    urls, outcome = queue.Queue(), {}
    # the rig file's drill strikes at plan sample 2 on the capture's own clock (no racing thread)
    rig, axis = drilled_rig(rig, plan_file, 2, tmp_path / "drilled.yaml")

    def run(**kw):
        from goniofrost.app.monitoring import monitored
        try:
            with monitored(session, "127.0.0.1", 0, "capture") as server:
                urls.put(server.url)
                capture(load_inputs(rig, plan_file), session, sim=SimOptions(material=shown_material(MATERIAL), speedup=10),
                        devices=rig_devices, options=SessionOptions(progress=False), **kw)
        except SessionFault as exc:
            outcome["fault"] = str(exc)

    worker = threading.Thread(target=run)
    worker.start()
    page.goto(urls.get(timeout=30))
    expect(page.locator("#state")).to_have_text("faulted", timeout=60_000)
    worker.join(timeout=60)
    message = outcome["fault"]
    assert message.startswith("device fault at plan sample ") and axis in message
    expect(page.locator("#fault")).to_be_visible()
    expect(page.locator("#fault-message")).to_have_text(message)  # exactly what the terminal prints
    expect(page.locator("#fault-title")).to_have_text("Stopped on a fault")
    failed = int(re.match(r"device fault at plan sample (\d+)", message).group(1))
    assert failed == 2  # where the drill was set to strike
    with Journal.open(session / "session.sqlite") as journal:
        done = len(journal.done_indices())
    assert done == 2  # samples 0 and 1, before the drill
    expect(page.locator("#count")).to_have_text(f"{done} of {M} samples")
    assert statuses(page)[failed] == "failed" and statuses(page).count("done") == done

    # the review page of the stopped session, then the resume as it happens
    with MonitorServer(session, port=0) as server:
        page.goto(server.url)
        expect(page.locator("#state")).to_have_text("faulted")
        resume = threading.Thread(target=capture, args=(load_inputs(rig, plan_file), session),
                                  kwargs={"sim": SimOptions(material=shown_material(MATERIAL), speedup=10),
                                          "devices": rig_devices, "options": SessionOptions(resume=True, progress=False)})
        resume.start()
        expect(page.locator("#state")).to_have_text("finished", timeout=60_000)
        resume.join(timeout=60)
        expect(page.locator("#count")).to_have_text(f"{M} of {M} samples")
        assert statuses(page) == ["done"] * M
        assert page.locator("#fault").is_hidden()


def test_a_recorded_predicted_error_is_shown_and_a_silent_session_is_called_stalled(page, tmp_path):
    rig_text = (REPO / "config" / "rigs" / "sim.yaml").read_text()
    samples = [{"cell": [10, 20, 30], "theta_i_deg": 20.0 + i, "theta_o_deg": 40.0, "move_s": 1.0,
                "joints": {"camera_arm": 60.0, "sample_yaw": 10.0 * i, "sample_tilt": 5.0}} for i in range(3)]
    meta = {"plan": {"samples": samples}, "plan_sha256": "p", "rig_text": rig_text, "rig_name": "sim-rig",
            "model_path": str(tmp_path / "no-model"), "model_hash": "m", "plan_file": str(tmp_path / "plan.json")}
    long_ago = time.time() - 3600
    with Journal.create(tmp_path / "session.sqlite", meta) as journal:
        journal.add_event("session", "started with 0 of 3 samples done")
        for i in range(2):
            journal.commit_sample(SampleRecord(i, 7, 1.0, 2.0, 3.0, (0.1, 0.2, 0.3), (0.01,) * 3, 80.0,
                                               joints=samples[i]["joints"], started_utc=long_ago, committed_utc=long_ago + 1))
        # the fields the engine journals for an Assess step (the message is not read)
        journal.add_event("batch", "batch 1 reconstructed", data={
            "batch": 0, "samples": 2, "predicted_error": 0.0421, "bound": 0.0873, "confidence": 0.95, "target": 0.05,
            "decision": "continue", "out_of_model": []})
        journal._db.execute("UPDATE events SET t_utc = ?", (long_ago + 2,))
    with MonitorServer(tmp_path, port=0) as server:
        page.goto(server.url)
        expect(page.locator("#predicted-error")).to_have_text(
            "reconstruction (log-relative MSE): error <= 0.0873 with 95 % confidence (median estimate 0.0421)",
            timeout=LOADED_MS)
        expect(page.locator("#assessment")).to_have_text(
            "after 2 samples: error <= 0.0873 with 95 % confidence, target 0.05 not reached yet (median estimate 0.0421)",
            timeout=LOADED_MS)
        expect(page.locator("#count")).to_have_text("2 of 3 samples")
        expect(page.locator("#state")).to_have_text("stalled")
        expect(page.locator("#hint")).to_contain_text("run the same capture command with --resume")
        expect(page.locator("#pose-next .pose-label")).to_have_text("sample 2 (target)")
        expect(page.locator("#pose-next .joints")).to_contain_text("sample_yaw20.00°")
        expect(page.locator("#preview-caption")).to_contain_text("the session's model cannot be opened")
        assert json.loads(page.evaluate("JSON.stringify(window.goniofrostMonitor.state.samples.status)")) == \
            ["done", "done", "next"]
        # a plan made for a scene: the assessment is of the error in the scene's use, and says so
        with Journal.open(tmp_path / "session.sqlite") as journal:
            journal.add_event("batch", "batch 1 reconstructed", data={
                "batch": 0, "samples": 2, "predicted_error": 0.0121, "bound": 0.0305, "confidence": 0.95,
                "target": 0.05, "decision": "target reached", "out_of_model": [], "scope": "scene"})
        expect(page.locator("#assessment")).to_have_text(
            "error in the scene's use <= 0.0305 with 95 % confidence (median estimate 0.0121), within the target 0.05",
            timeout=LOADED_MS)


def test_a_target_reached_session_is_shown_finished_with_why_it_stopped_step_by_step(page, tmp_path):
    """A scripted journal (no live capture to race): after each write the page shows it; a capture
    whose target error stopped it after 2 of 4 samples, its process gone, is finished, not killed."""
    from goniofrost.capture.records import RunStatus
    from journal_script import ScriptedSession

    from goniofrost.capture.session_lock import session_lock

    script = ScriptedSession(tmp_path, 4, batch_ends=[2, 4], target=0.05)
    reason = ("capture stopped after 2 of 4 samples: target reached: error <= 0.05 with 95 % confidence "
              "(median estimate 0.0312)")
    try:
        with MonitorServer(tmp_path, port=0) as server:
            with session_lock(tmp_path):  # the capture process holds its session while it runs
                page.goto(server.url)
                script.start_run()
                script.calibrate()
                expect(page.locator("#count")).to_have_text("0 of 4 samples", timeout=LOADED_MS)
                for i in range(2):  # the count follows each journaled sample while the run is under way
                    script.capture(i)
                    expect(page.locator("#count")).to_have_text(f"{i + 1} of 4 samples", timeout=LOADED_MS)
                    expect(page.locator("#state")).to_have_text("running", timeout=LOADED_MS)
                assert statuses(page) == ["done", "done", "next", "pending"]
                script.batch(2, 0.0312, 0.05, "target reached", bound=0.0471)
                expect(page.locator("#predicted-error")).to_have_text(
                    "reconstruction (log-relative MSE): error <= 0.0471 with 95 % confidence (median estimate 0.0312)",
                    timeout=LOADED_MS)
                expect(page.locator("#assessment")).to_have_text(
                    "error <= 0.0471 with 95 % confidence (median estimate 0.0312), within the target 0.05",
                    timeout=LOADED_MS)
                script.end_run(RunStatus.TARGET_REACHED, reason)
                expect(page.locator("#state")).to_have_text("reconstructing", timeout=LOADED_MS)
                script.write_report(0.0312)
            # the process is gone (its lock with it): finished, with why, not "stopped ... killed"
            expect(page.locator("#state")).to_have_text("finished", timeout=LOADED_MS)
            expect(page.locator("#hint")).to_have_text(f"finished: {reason}; results written to {tmp_path}",
                                                       timeout=LOADED_MS)
            expect(page.locator("#count")).to_have_text("2 of 4 samples", timeout=LOADED_MS)
            assert page.locator("#fault").is_hidden()
            expect(page.locator("#summary-text")).to_contain_text("2 samples on rig 'sim-rig'", timeout=LOADED_MS)
    finally:
        script.close()


def test_an_operators_stop_is_shown_interrupted_with_the_terminals_words(page, tmp_path):
    from goniofrost.capture.records import RunEnd, RunStatus
    from goniofrost.rig.stop import AxisStop
    from journal_script import ScriptedSession

    script = ScriptedSession(tmp_path, 3)
    try:
        with MonitorServer(tmp_path, port=0) as server:
            page.goto(server.url)
            script.start_run()
            script.calibrate()
            script.capture(0)
            expect(page.locator("#count")).to_have_text("1 of 3 samples", timeout=LOADED_MS)
            words = ("interrupted by a stop request from process 42 at plan sample 1. Stopped camera_arm at 60.00 deg; "
                     "the lamp is off. 1 of 3 samples are safe. Run the same command with --resume to continue")
            script.journal.end_run(RunEnd(script.start.run, RunStatus.STOPPED_BY_OPERATOR, words, 3, 1, 0,
                                          script.start.started_utc, time.time(), detail="a stop request: run stopped",
                                          plan_index=1, stops=(AxisStop("camera_arm", True, 60.0),), lamp_off=True))
            expect(page.locator("#state")).to_have_text("interrupted", timeout=LOADED_MS)
            expect(page.locator("#fault-title")).to_have_text("Interrupted", timeout=LOADED_MS)
            expect(page.locator("#fault-message")).to_have_text(words, timeout=LOADED_MS)
            assert statuses(page) == ["done", "failed", "pending"]
    finally:
        script.close()


def test_a_queues_root_watched_before_it_exists_lists_its_sessions_and_pending_samples(plan, page, tmp_path,
                                                                                       monkeypatch):
    """The list of a queue's root opened before the queue starts (the folder is not there yet); the
    queue measures its first sample and no one answers for the second: the page (it reloads every
    5 s) lists the first as finished, with a link to its page, and the other two pending, in the
    queue's order."""
    import io

    import yaml

    from goniofrost.app.cli import main

    rig, plan_file = plan
    queue = tmp_path / "queue.yaml"
    queue.write_text(yaml.safe_dump({
        "rig": os.path.relpath(rig, tmp_path), "plan": os.path.relpath(plan_file, tmp_path), "root": "day",
        "samples": [{"sample_id": "Z-1", "material": MATERIAL}, {"sample_id": "A-2", "material": "builtin:gold"},
                    {"sample_id": "M-3", "material": "builtin:green-felt"}]}, sort_keys=False))
    root = tmp_path / "day"
    with MonitorServer(root, port=0, catalogue=True) as server:
        page.goto(server.url)
        expect(page.locator("section.card")).to_contain_text(f"{root} does not exist yet")
        assert page.locator("#sessions tbody tr").count() == 0
        monkeypatch.setattr(sys, "stdin", io.StringIO("\n"))   # Enter for the first sample, then no one
        assert main(["queue", str(queue), "--no-progress", "--speedup", "50"]) == 2
        rows = page.locator("#sessions tbody tr")
        expect(rows).to_have_count(3, timeout=LOADED_MS)
        assert [rows.nth(k).locator("td").nth(4).inner_text() for k in range(3)] == ["finished", "pending", "pending"]
        assert [rows.nth(k).locator("td").first.inner_text() for k in range(3)] == ["Z-1", "A-2", "M-3"]
        expect(page.locator("section.card")).to_contain_text("1 session(s), 2 pending")
        page.locator("#sessions a", has_text="Z-1").click()
        expect(page.locator("#state")).to_have_text("finished", timeout=LOADED_MS)
