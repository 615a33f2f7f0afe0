"""One program drives a rig at a time (goniofrost.rig.lock): its holder is readable, a second
program is refused naming it, and another process can ask it to stop: a capture on the simulated
rig stops with its own per-axis report, and --resume completes it."""
from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from goniofrost.app.cli import main
from goniofrost.capture.journal import Journal
from goniofrost.capture.records import RunStatus
from goniofrost.rig.lock import RigInUseError, request_stop, rig_holder, rig_lock
from monitor_helpers import MATERIAL, journal_rows, make_plan

REPO = Path(__file__).resolve().parents[1]
M = 4


def test_the_holder_is_readable_and_a_second_program_is_refused_naming_it():
    assert rig_holder("bench rig") is None and request_stop("bench rig") is None
    with rig_lock("bench rig", "rig move") as lock:
        holder = rig_holder("bench rig")
        assert (holder.pid, holder.program, holder.rig) == (os.getpid(), "rig move", "bench rig")
        assert holder == lock.holder and lock.stop_request() is None
        with pytest.raises(RigInUseError) as refused:
            with rig_lock("bench rig", "capture"):
                pass
        assert str(refused.value) == (
            f"rig 'bench rig' is in use by rig move (process {os.getpid()}): one program drives a rig at a time; "
            f"wait for it to finish or stop it (goniofrost rig stop, or Ctrl-C in its terminal)")
        with rig_lock("another rig", "capture"):  # another rig is another lock
            assert rig_holder("another rig").program == "capture"
    assert rig_holder("bench rig") is None  # released: nobody to ask
    with rig_lock("bench rig", "align") as lock:  # a request made to an earlier holder is not this one's
        assert lock.stop_request() is None


@pytest.fixture(scope="module")
def plan(tmp_path_factory):
    return make_plan(tmp_path_factory.mktemp("riglock"), M)


def wait_until(condition, proc, what: str, timeout: float = 60.0):
    """Poll the journal until ``condition()`` is true (or the capture ended, or the timeout)."""
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        if condition():
            return
        if proc.poll() is not None:
            pytest.fail(f"capture ended before {what} ({proc.returncode}): {proc.stderr.read()}")
        time.sleep(0.01)
    proc.kill()
    pytest.fail(f"no {what} within {timeout} s")


def test_rig_stop_stops_a_running_capture_with_its_own_report_and_resume_completes_it(plan, tmp_path, capsys):
    """`goniofrost rig stop` from another terminal (request_stop underneath)."""
    rig, plan_file = plan
    session = tmp_path / "s"
    args = ["capture", "--rig", str(rig), "--plan", str(plan_file), "--session", str(session),
            "--material", MATERIAL, "--no-progress", "--speedup", "5"]
    proc = subprocess.Popen([sys.executable, "-m", "goniofrost", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=REPO)
    try:
        wait_until(lambda: len(journal_rows(session)) >= 1, proc, "a journaled sample")
        asked, asked_utc = time.monotonic(), time.time()
        capsys.readouterr()
        assert main(["rig", "stop", "--rig", str(rig)]) == 0
        assert capsys.readouterr().err.startswith(f"asked capture (process {proc.pid}) to stop sim-rig: ")
        assert proc.wait(timeout=30) == 130
        stopped_s = time.monotonic() - asked
        err = proc.stderr.read()
    finally:
        proc.kill()
    # the holder's own truthful report: who asked, where each axis was confirmed at rest, the lamp
    assert err.startswith(f"goniofrost capture: interrupted by a stop request from process {os.getpid()}")
    assert "Stopped camera_arm at " in err and "the lamp is off" in err and err.count("\n") == 1
    with Journal.open(session / "session.sqlite") as journal:
        _start, end = journal.last_run()
        done = journal.done_indices()
    assert end.status is RunStatus.STOPPED_BY_OPERATOR and end.reason == err[len("goniofrost capture: "):-1]
    assert all(s.confirmed for s in end.stops) and end.lamp_off is True and 1 <= len(done) < M
    print(f"run ended (axes confirmed, lamp off) {end.ended_utc - asked_utc:.2f} s after the request, process "
          f"gone after {stopped_s:.2f} s (load {os.getloadavg()[0]:.1f})")
    assert rig_holder("sim-rig") is None  # the lock went with the process

    assert main([*args, "--resume"]) == 0
    with Journal.open(session / "session.sqlite") as journal:
        runs = journal.runs()
    assert [end.status for _, end in runs] == [RunStatus.STOPPED_BY_OPERATOR, RunStatus.FINISHED]
    assert runs[-1][1].samples_captured == M and runs[-1][0].samples_done == len(done)
