"""One program drives a rig at a time (goniofrost.rig.lock): its holder is readable, a second
program is refused naming it, and another process can ask it to stop: a capture on the simulated
rig stops with its own per-axis report, and --resume completes it."""
from __future__ import annotations

import json
import os
import pwd
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from goniofrost.app.cli import main
from goniofrost.capture.journal import Journal
from goniofrost.capture.records import RunStatus
from goniofrost.rig.file import load_checked_rig
from goniofrost.rig.lock import (RigInUseError, device_keys, lock_dir, request_stop,
                                    rig_holder, rig_lock)
from monitor_helpers import MATERIAL, journal_rows, make_plan

REPO = Path(__file__).resolve().parents[1]
M = 4


SIM_RIG = REPO / "config" / "rigs" / "sim.yaml"


def real_rig(folder: Path, name: str, yaw_port: str, tilt_port: str, tcp_port: int, unit: int = 1):
    """A rig file naming real endpoints (nothing is opened: the lock only reads them), loaded."""
    section = yaml.safe_load(SIM_RIG.read_text())
    section.update(name=name, simulated=False)
    drivers = {name: axis["driver"] for name, axis in section["axes"].items()}
    drivers["sample_yaw"]["port"], drivers["sample_tilt"]["port"] = yaw_port, tilt_port
    drivers["camera_arm"].update(port=tcp_port, device_id=unit)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "rig.yaml").write_text(yaml.safe_dump(section))
    return load_checked_rig(folder / "rig.yaml")


def sim_rig(folder: Path):
    """The simulated rig file copied into ``folder`` (named sim-rig, as every copy is)."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "sim.yaml").write_text(SIM_RIG.read_text())
    return load_checked_rig(folder / "sim.yaml")


def test_the_holder_is_readable_and_a_second_program_is_refused_naming_it(tmp_path):
    rig = sim_rig(tmp_path / "a")
    assert rig_holder(rig) is None and request_stop(rig) is None
    with rig_lock(rig, "rig move") as lock:
        holder = rig_holder(rig)
        assert (holder.pid, holder.program, holder.rig, holder.uid) == (os.getpid(), "rig move", "sim-rig", os.getuid())
        assert holder.keys == (f"simulated:{tmp_path / 'a' / 'sim.yaml'}",)
        assert holder == lock.holder and lock.stop_request() is None
        with pytest.raises(RigInUseError) as refused:
            with rig_lock(rig, "capture"):
                pass
        assert str(refused.value) == (
            f"rig 'sim-rig' is in use by rig move (process {os.getpid()} of {holder.user}): one program drives a "
            f"device at a time; wait for it to finish or stop it (goniofrost rig stop, or Ctrl-C in its terminal)")
        with rig_lock(sim_rig(tmp_path / "b"), "capture"):  # another rehearsal named alike: its own instance
            assert rig_holder(sim_rig(tmp_path / "b")).program == "capture"
    assert rig_holder(rig) is None  # released: nobody to ask
    with rig_lock(rig, "align") as lock:  # a request made to an earlier holder is not this one's
        assert lock.stop_request() is None


def test_the_lock_is_keyed_by_the_devices_not_by_the_name(tmp_path):
    """Rigs named alike on other devices run side by side; any shared device (a serial port by any
    of its names, a TCP unit) refuses, naming the holder and its rig."""
    bench = real_rig(tmp_path / "1", "bench", "/dev/ttyFAKE0", "/dev/ttyFAKE1", 5020)
    (tmp_path / "by-id").symlink_to("/dev/ttyFAKE1")
    cases = [  # (rig, refused while bench is held)
        (real_rig(tmp_path / "2", "bench", "/dev/ttyFAKE2", "/dev/ttyFAKE3", 5021), False),
        (real_rig(tmp_path / "3", "bench", "/dev/ttyFAKE2", "/dev/ttyFAKE3", 5020, unit=2), False),
        (real_rig(tmp_path / "4", "other", "/dev/ttyFAKE2", str(tmp_path / "by-id"), 5021), True),
        (real_rig(tmp_path / "5", "other", "/dev/ttyFAKE2", "/dev/ttyFAKE3", 5020), True),
    ]
    assert device_keys(bench) == ["serial:/dev/ttyFAKE0", "serial:/dev/ttyFAKE1", "tcp:127.0.0.1:5020/1"]
    with rig_lock(bench, "capture"):
        for rig, refused in cases:
            if not refused:
                with rig_lock(rig, "rig move"):
                    assert rig_holder(rig).program == "rig move"
                continue
            assert rig_holder(rig).rig == "bench"
            with pytest.raises(RigInUseError, match=r"^rig 'other' is in use by capture \(process \d+ of \w+\) "
                                                     r"\(its rig 'bench'\): one program drives a device at a time"):
                with rig_lock(rig, "rig move"):
                    pass


def test_the_locks_live_in_a_folder_every_user_shares(tmp_path, monkeypatch):
    """Sticky and writable by all (nobody removes another's lock); lock files readable and
    writable by all (the next holder, of any user, writes itself in), whatever the umask."""
    folder = tmp_path / "shared" / "locks"
    monkeypatch.delenv("GONIOFROST_LOCK_DIR")
    assert lock_dir() == Path("/tmp/goniofrost-locks")
    monkeypatch.setenv("GONIOFROST_LOCK_DIR", str(folder))
    old = os.umask(0o077)
    try:
        with rig_lock(sim_rig(tmp_path / "a"), "capture") as lock:
            pass
    finally:
        os.umask(old)
    assert stat.S_IMODE(folder.stat().st_mode) == 0o1777
    assert [stat.S_IMODE(p.stat().st_mode) for p in folder.iterdir()] == [0o666]
    assert json.loads(next(folder.iterdir()).read_text())["pid"] == lock.holder.pid


HOLD = """import sys, signal, time
from goniofrost.rig.file import load_checked_rig
from goniofrost.rig.lock import rig_lock
with rig_lock(load_checked_rig(sys.argv[1]), "capture"):
    print("held", flush=True)
    sys.stdin.read()
"""


def test_rig_stop_signals_only_the_holder_of_this_rigs_devices(tmp_path):
    ours = sim_rig(tmp_path / "ours")
    alike = sim_rig(tmp_path / "alike")  # named sim-rig too
    procs = [subprocess.Popen([sys.executable, "-c", HOLD, rig.source], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True, cwd=REPO) for rig in (ours, alike)]
    try:
        assert [p.stdout.readline() for p in procs] == ["held\n", "held\n"]
        holder = request_stop(ours)
        assert (holder.pid, holder.program) == (procs[0].pid, "capture")
        assert procs[0].wait(timeout=30) == -signal.SIGTERM
        assert procs[1].poll() is None and rig_holder(alike).pid == procs[1].pid
        assert request_stop(ours) is None  # nobody holds ours now: nothing is sent
    finally:
        for p in procs:
            p.kill()
            p.wait()


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
        user = pwd.getpwuid(os.getuid()).pw_name
        assert capsys.readouterr().err.startswith(f"asked capture (process {proc.pid} of {user}) to stop sim-rig: ")
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
    assert rig_holder(load_checked_rig(rig)) is None  # the lock went with the process

    assert args[-2:] == ["--speedup", "5"]   # slow enough to be stopped mid-run; the rest at 50
    assert main([*args[:-1], "50", "--resume"]) == 0
    with Journal.open(session / "session.sqlite") as journal:
        runs = journal.runs()
    assert [end.status for _, end in runs] == [RunStatus.STOPPED_BY_OPERATOR, RunStatus.FINISHED]
    assert runs[-1][1].samples_captured == M and runs[-1][0].samples_done == len(done)
