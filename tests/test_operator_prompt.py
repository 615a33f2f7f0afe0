"""The real camera's operator prompt: Enter, ``abort``, a timeout and closed input, answered
through a pseudo-terminal and through a capture process's own standard input (a pipe)."""
from __future__ import annotations

import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from drivers.camera import TARGET_EXPLAINED, FolderCamera, OperatorAbort, OperatorPrompt, OperatorTimeout
from goniofrost.rig.hardware import open_camera

from frame_script import CAMERA_MODEL

REPO = Path(__file__).resolve().parents[1]
PROMPT = b"press Enter when done, or type abort"


@pytest.fixture
def terminal():
    """(master, slave) file descriptors of a pseudo-terminal: the operator types on the master."""
    master, slave = os.openpty()
    yield master, slave
    os.close(master)
    os.close(slave)


def operator(master: int, answer: bytes, shown: list) -> threading.Thread:
    """Type ``answer`` on the terminal once the prompt is on it; what was shown goes to ``shown``."""
    def run():
        seen = b""
        while PROMPT not in seen:
            seen += os.read(master, 1024)
        shown.append(seen.decode())
        os.write(master, answer)
    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


def camera_on(slave: int, tmp_path: Path, timeout_s: float = 10.0) -> FolderCamera:
    prompt = OperatorPrompt(timeout_s, input_fd=slave, output=open(slave, "w", closefd=False))
    return FolderCamera(tmp_path, lambda t: None, ask=prompt)


def test_enter_on_the_terminal_confirms_the_target_change(terminal, tmp_path):
    master, slave = terminal
    cam, shown = camera_on(slave, tmp_path), []
    operator(master, b"\n", shown)
    cam.set_target("white")
    assert cam.target == "white"
    # what the target is, on its own line, then the question on its own line
    lines = "".join(shown).splitlines()
    assert lines == [TARGET_EXPLAINED["white"],
                     "put the 'white' target in front of the camera - press Enter when done, or type abort"]
    assert lines[0].startswith("the 'white' target is the white reference card")


def test_abort_on_the_terminal_is_a_clear_error_and_the_target_stays(terminal, tmp_path):
    master, slave = terminal
    cam = camera_on(slave, tmp_path)
    operator(master, b"  ABORT\n", [])
    with pytest.raises(OperatorAbort, match=r"^put the 'flat' target in front of the camera: the operator "
                                            r"answered 'abort'$"):
        cam.set_target("flat")
    assert cam.target == "sample"


def test_no_answer_times_out_and_an_early_enter_does_not_count(terminal, tmp_path):
    master, slave = terminal
    os.write(master, b"\n")  # typed before the question: discarded
    cam = camera_on(slave, tmp_path, timeout_s=0.2)
    with pytest.raises(OperatorTimeout, match=r"^put the 'white' target in front of the camera: no answer from "
                                              r"the operator within 0.2 s$"):
        cam.set_target("white")
    assert cam.target == "sample"


def test_closed_input_is_an_abort(tmp_path):
    read_end, write_end = os.pipe()
    os.close(write_end)
    prompt = OperatorPrompt(10.0, input_fd=read_end, output=open(os.devnull, "w"))
    try:
        with pytest.raises(OperatorAbort, match=r"no operator can answer \(standard input is closed\)"):
            FolderCamera(tmp_path, lambda t: None, ask=prompt).set_target("white")
    finally:
        os.close(read_end)


def test_the_manual_exposure_prompt_of_open_camera_times_out(terminal, tmp_path):
    master, slave = terminal
    cam = open_camera({"kind": "rawfile", "exposures_s": [0.01], "target_snr": 50, "folder": str(tmp_path),
                       "operator_timeout_s": 0.2, **CAMERA_MODEL})
    cam.ask.input_fd, cam.ask.output = slave, open(os.devnull, "w")  # this terminal instead of the test's stdin
    with pytest.raises(OperatorTimeout, match=rf"^expose one RAW frame of 0.01 s into {tmp_path}: no answer from "
                                              r"the operator within 0.2 s$"):
        cam.capture(0.01, tmp_path / "x.dng")


CHILD = """
import sys
from drivers.camera import CameraError, FolderCamera
cam = FolderCamera(sys.argv[1], lambda t: None, operator_timeout_s=30)
for target in ("white", "flat"):
    try:
        cam.set_target(target)
        print("target", cam.target, flush=True)
    except CameraError as exc:
        print(f"{type(exc).__name__}: {exc}", flush=True)
"""


def test_a_process_is_answered_on_its_own_standard_input(tmp_path):
    child = subprocess.Popen([sys.executable, "-c", CHILD, str(tmp_path)], stdin=subprocess.PIPE,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=REPO)
    try:
        for target, answer in (("white", b"\n"), ("flat", b"abort\n")):
            # what the target is, on its own line, then the question, on stderr before it is answered
            assert child.stderr.readline().decode() == TARGET_EXPLAINED[target] + "\n"
            assert PROMPT in child.stderr.readline()
            child.stdin.write(answer)
            child.stdin.flush()
        out, _ = child.communicate(timeout=30)
    finally:
        child.kill()
    assert out.decode().splitlines() == ["target white", "OperatorAbort: put the 'flat' target in front of the "
                                                         "camera: the operator answered 'abort'"]


def test_a_prompt_during_a_capture_is_on_its_own_lines_not_inside_the_progress_bar(capsys):
    import sys

    from tqdm import tqdm

    from goniofrost.rig.hardware import BarSafeOutput

    with tqdm(total=40, unit="sample", desc="capture", file=sys.stderr) as bar:
        bar.update(3)
        OperatorPrompt(1.0, output=BarSafeOutput()).output.write(TARGET_EXPLAINED["flat"] + "\n")
        bar.update(1)
    lines = capsys.readouterr().err.replace("\r", "\n").split("\n")
    # the explanation is a line of its own: nothing of the bar before it on that line
    assert TARGET_EXPLAINED["flat"] in lines
    assert lines.index(TARGET_EXPLAINED["flat"]) < max(i for i, line in enumerate(lines) if "4/40" in line)
