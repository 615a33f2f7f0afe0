"""A day in the lab on the simulated rig: who measured what (the label), a queue of samples, the
catalogue of sessions (`goniofrost sessions`, `goniofrost monitor ROOT`).

Small and fast, as tests/test_session.py: a 6-material model on the 30 x 30 x 60 grid, a 4-sample
plan, a short exposure ladder, a small simulated sensor and a simulated clock 10-50x real time.
"""
from __future__ import annotations

import io
import json
import os
import signal
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest
import yaml

from goniofrost.app.cli import main
from goniofrost.capture.journal import Journal
from goniofrost.capture.records import EventKind, RunStatus, SessionLabel
from goniofrost.monitor.session_view import read_session
from goniofrost.monitor.status import page_state
from test_session import batched_plan, journal_rows, small_plan, write_rig

REPO = Path(__file__).resolve().parents[1]
M = 4
LAB = {"lab": "Optics lab 2", "lens": "50 mm f/8", "lamp": "LED 6500 K"}


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    """(folder, rig file with a lab section, plan file, model), read-only for the module's tests."""
    folder = tmp_path_factory.mktemp("lab")
    rig = write_rig(folder / "rig.yaml")
    doc = yaml.safe_load(rig.read_text())
    doc["lab"] = LAB
    rig.write_text(yaml.safe_dump(doc, sort_keys=False))
    plan, model = small_plan(rig, M, folder / "plan.json")
    return folder, rig, plan, model


def write_queue(path: Path, rig: Path, plan: Path, **extra) -> Path:
    """The issue's two-sample queue, its paths relative to the queue file."""
    doc = {"rig": os.path.relpath(rig, path.parent), "plan": os.path.relpath(plan, path.parent), "root": "sessions",
           "operator": "A. Operator", **extra,
           "samples": [{"sample_id": "S-001", "material": "builtin:red-plastic"},
                       {"sample_id": "S-002", "material": "builtin:green-felt", "note": "second coat"}]}
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def frame_files(session: Path, prefix: str) -> list[str]:
    """The RAW files of every Expose step the session journaled whose name starts with ``prefix``."""
    with Journal.open(session / "session.sqlite") as journal:
        return [Path(s["detail"]["file"]).name for s in journal.steps()
                if s["kind"] == "Expose" and Path(s["detail"]["file"]).name.startswith(prefix)]


def sessions_json(root: Path, capsys, *options) -> list[dict]:
    capsys.readouterr()
    assert main(["sessions", str(root), "--json", *options]) == 0
    return json.loads(capsys.readouterr().out)


# ----- a queue ----------------------------------------------------------------------------------
def test_a_two_sample_queue_calibrates_once_rewhites_between_samples_and_survives_kill_9(setup, tmp_path, capsys):
    folder, rig, plan, _ = setup
    queue = write_queue(tmp_path / "queue.yaml", rig, plan)
    root = tmp_path / "sessions"
    command = [sys.executable, "-m", "goniofrost", "queue", str(queue), "--yes", "--no-progress", "--speedup", "10"]
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=REPO,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    t_end = time.monotonic() + 120  # wait on the second session's journal, not a clock
    while len(journal_rows(root / "S-002")) < 1:
        assert proc.poll() is None, f"the queue ended early: {proc.stderr.read().decode()}"
        assert time.monotonic() < t_end, "no sample of S-002 journaled within 120 s"
        time.sleep(0.01)
    proc.send_signal(signal.SIGKILL)
    assert proc.wait(timeout=10) == -signal.SIGKILL
    before = journal_rows(root / "S-002")
    assert 1 <= len(before) < M and not (root / "S-002" / "report.json").exists(), "the kill must land in S-002"

    capsys.readouterr()
    assert main(["queue", str(queue), "--yes", "--no-progress", "--speedup", "50"]) == 0
    out = capsys.readouterr().out
    assert f"queue 1/2: S-001 already measured in {root / 'S-001'}; skipped" in out
    assert "queue queue.yaml: 2 samples, 1 measured this run, 1 from before" in out

    first, second = root / "S-001", root / "S-002"
    # the dark frames and the flat field were shot once, in the first session; the second re-measured
    # the white reference with them (in its killed run; the resume kept that calibration)
    assert frame_files(first, "dark_") and frame_files(first, "flat_") and frame_files(first, "white")
    assert frame_files(second, "dark_") == [] and frame_files(second, "flat_") == []
    assert frame_files(second, "white")
    with Journal.open(second / "session.sqlite") as journal:
        checks = [e for e in journal.events() if e["kind"] is EventKind.CALIBRATION and "decision" in e["data"]]
        runs, label, samples = journal.runs(), journal.label(), journal.samples()
    assert [c["data"]["decision"] for c in checks] == ["reuse"] and checks[0]["data"]["limit"] == 0.05
    assert 0 <= checks[0]["data"]["drift"] <= 0.05
    # nothing measured twice: the killed run has no end, the resume started from the samples journaled
    assert len(runs) == 2 and runs[0][1] is None and runs[1][0].samples_done == len(before)
    assert runs[1][1].status is RunStatus.FINISHED and [r.plan_index for r in samples] == list(range(M))
    assert [row for row in journal_rows(second) if row[0] < len(before)] == before
    assert label == SessionLabel(operator="A. Operator", sample_id="S-002", notes=("second coat",), **LAB,
                                 queue=str(queue.resolve()))

    # the label in report.json and brdf.json (extended beside the reconstruction's own fields)
    report = json.loads((second / "report.json").read_text())
    assert report["label"] == label.to_dict() and report["material"] == "builtin:green-felt"
    record = json.loads((second / "brdf.json").read_text())
    measured = record["measurement"]
    assert (measured["sample_id"], measured["operator"], measured["notes"], measured["lens"]) == (
        "S-002", "A. Operator", ["second coat"], LAB["lens"])
    assert measured["rig"]["name"] == "sim-rig" and measured["model"] == report["model"]
    assert measured["error_figure"] == record["error_figure"] == report["prediction"]["error_figure"]
    assert "predicted_log_relative_mse" not in measured and "predicted_log_relative_mse" not in record
    assert measured["started_utc"] == runs[0][0].started_utc and measured["goniofrost_version"] == "0.1.0"

    listed = sessions_json(root, capsys)
    assert [(s["name"], s["sample_id"], s["operator"], s["state"], s["samples"], s["samples_planned"])
            for s in listed] == [("S-001", "S-001", "A. Operator", "finished", M, M),
                                 ("S-002", "S-002", "A. Operator", "finished", M, M)]
    assert listed[1]["notes"] == ["second coat"] and listed[1]["material"] == "builtin:green-felt"
    # the catalogue's figure is the median estimate, as a running capture's batches show it
    assert listed[1]["predicted_error"] == report["prediction"]["median_estimate"] != \
        report["prediction"]["point_prediction_before_centring"]
    assert listed[1]["error_figure"] == report["prediction"]["error_figure"]


def test_a_lamp_that_drifted_past_the_queues_limit_calibrates_the_next_sample_in_full(setup, tmp_path, capsys,
                                                                                      monkeypatch):
    folder, rig, plan, _ = setup
    queue = write_queue(tmp_path / "queue.yaml", rig, plan, drift_limit=1e-9)  # any change is too much
    monkeypatch.setattr(sys, "stdin", io.StringIO("\n\n"))  # the operator presses Enter twice
    assert main(["queue", str(queue), "--no-progress", "--speedup", "50"]) == 0
    asked = [line for line in capsys.readouterr().err.splitlines() if "mount sample" in line]
    assert asked == [f"queue {k}/2: mount sample {s} on the stage, then press Enter (Ctrl-C stops the queue; the "
                     f"same command resumes it)" for k, s in ((1, "S-001 (builtin:red-plastic)"),
                                                              (2, "S-002 (builtin:green-felt)"))]
    second = tmp_path / "sessions" / "S-002"
    with Journal.open(second / "session.sqlite") as journal:
        [check] = [e["data"] for e in journal.events() if e["kind"] is EventKind.CALIBRATION and "decision" in e["data"]]
    assert check["decision"] == "recalibrate" and check["drift"] > 1e-9
    assert frame_files(second, "dark_") and frame_files(second, "flat_")


def test_a_queue_whose_standard_input_ended_measures_nothing_without_an_answer(setup, tmp_path, capsys,
                                                                               monkeypatch):
    # the end of input was read as Enter: every sample was measured with whatever stood on the stage
    folder, rig, plan, _ = setup
    queue = write_queue(tmp_path / "queue.yaml", rig, plan)
    monkeypatch.setattr(sys, "stdin", io.StringIO(""))  # < /dev/null, cron: no one to press Enter
    assert main(["queue", str(queue), "--no-progress"]) == 2
    assert capsys.readouterr().err.splitlines()[-1] == (
        "goniofrost queue: error: queue 1/2: no one answered (standard input ended) to mount sample S-001: it was "
        "not measured; run the queue where an operator can press Enter, or pass --yes (a sample changer, the "
        "simulated rig)")
    assert not (tmp_path / "sessions").exists()


def test_a_bad_queue_file_is_one_line_and_nothing_is_made(setup, tmp_path, capsys):
    folder, rig, plan, _ = setup
    queue = write_queue(tmp_path / "queue.yaml", rig, plan)
    doc = yaml.safe_load(queue.read_text())
    doc["samples"][1]["sample_id"] = "S-001"
    queue.write_text(yaml.safe_dump(doc))
    assert main(["queue", str(queue), "--yes"]) == 2
    assert capsys.readouterr().err == (f"goniofrost queue: error: {queue}: samples[1].sample_id: expected a sample id "
                                       f"not used before in the queue, found 'S-001'\n")
    doc["samples"][1] = {"sample_id": "S-002"}  # the simulated rig needs a material
    queue.write_text(yaml.safe_dump(doc))
    assert main(["queue", str(queue), "--yes"]) == 2
    assert capsys.readouterr().err.startswith(f"goniofrost queue: error: {queue}: samples[1].material: expected SPEC:NAME")
    doc["samples"][1] = {"sample_id": "S-002", "material": "builtin:gld"}  # a typo names the queue file too
    queue.write_text(yaml.safe_dump(doc))
    assert main(["queue", str(queue), "--yes"]) == 2
    assert capsys.readouterr().err == (f"goniofrost queue: error: {queue}: samples[1].material: unknown material "
                                       f"'gld' in dataset 'builtin'; did you mean gold?\n")
    assert not (tmp_path / "sessions").exists()


def test_a_fault_in_a_queue_says_to_run_the_queue_again_which_has_no_resume_option(setup, tmp_path, capsys):
    folder, rig, plan, _ = setup
    doc = yaml.safe_load(rig.read_text())
    doc["sim"]["faults"] = [{"axis": "sample_tilt", "kind": "alarm", "at_sample": 1}]
    drilled = tmp_path / "rig.yaml"
    drilled.write_text(yaml.safe_dump(doc, sort_keys=False))
    queue = write_queue(tmp_path / "queue.yaml", drilled, plan)
    capsys.readouterr()
    assert main(["queue", str(queue), "--yes", "--no-progress", "--speedup", "50"]) == 2
    err = capsys.readouterr().err
    assert "device fault at plan sample" in err and err.endswith("Fix the cause, then run the same queue command\n")
    assert "--resume" not in err  # `goniofrost queue --resume` is refused by the parser


def test_a_sample_the_rig_measures_none_of_does_not_stop_the_queue_and_lists_as_nothing_measured(setup, tmp_path,
                                                                                                   capsys):
    """Black velvet is too dark for a ladder of short exposures at every pose: its session has
    nothing to reconstruct (running it again would not change that), so the queue says so, goes on
    to the next sample and exits 2; the same command again takes it without moving the rig."""
    folder, rig, plan, _ = setup
    doc = yaml.safe_load(rig.read_text())
    doc["camera"].update(exposures_s=[0.0005, 0.001, 0.002, 0.004], min_snr=60.0)
    short = tmp_path / "short-ladder.yaml"
    short.write_text(yaml.safe_dump(doc, sort_keys=False))
    queue = write_queue(tmp_path / "queue.yaml", short, plan)
    queue_doc = yaml.safe_load(queue.read_text())
    queue_doc["samples"][0]["material"] = "builtin:black-velvet"
    queue.write_text(yaml.safe_dump(queue_doc, sort_keys=False))
    root = tmp_path / "sessions"
    for run in range(2):
        capsys.readouterr()
        assert main(["queue", str(queue), "--yes", "--no-progress", "--speedup", "50"]) == 2
        out, err = capsys.readouterr()
        assert (f"queue 1/2: S-001: NOTHING MEASURED: {root / 'S-001' / 'session.sqlite'}: 0 of {M} samples measured, "
                f"{M} not measured (below-detection-limit: samples 0 1 2 3)") in out
        assert err.endswith("goniofrost queue: nothing measured for S-001: the rig's exposures cannot measure these "
                            "samples (see their lines above); the others are done\n")
        assert ("2 samples, 1 measured this run, 0 from before" if run == 0 else
                "2 samples, 0 measured this run, 1 from before") + ", 1 with nothing measured (S-001: see above)" in out
        with Journal.open(root / "S-001" / "session.sqlite") as journal:
            assert len(journal.runs()) == 1 and journal.samples() == []   # the second queue run moved nothing
    entries = {e["sample_id"]: e for e in sessions_json(root, capsys)}
    assert (entries["S-001"]["state"], entries["S-001"]["samples"], entries["S-001"]["not_measured"]) == (
        "nothing measured", 0, M)
    assert (entries["S-002"]["state"], entries["S-002"]["samples"]) == ("finished", M - 1)   # its sample 0 too dark
    page = page_state(read_session(root / "S-001"), time.time())
    assert page["state"] == "nothing measured" and "there is no BRDF to reconstruct" in page["hint"]


# ----- the label of a capture, the catalogue ------------------------------------------------------
def capture_args(rig, plan, session, material="builtin:red-plastic", *extra) -> list[str]:
    return ["capture", "--rig", str(rig), "--plan", str(plan), "--session", str(session), "--material", material,
            "--no-progress", "--speedup", "50", *extra]


def test_sessions_lists_states_from_the_run_end_and_a_resume_with_another_sample_is_refused(setup, tmp_path, capsys):
    folder, rig, plan, _ = setup
    root = tmp_path / "day"
    # the first batch (2 samples) is a design unlike every design the model's calibration saw (5
    # samples and more): it goes on, and stops on the target after the second
    batched = batched_plan(tmp_path, rig, plan, [2, 4])
    assert main(capture_args(rig, batched, root / "a-target", "builtin:red-plastic", "--operator", "B. Operator",
                             "--sample-id", "T-7", "--note", "first coat", "--note", "dry", "--target-error",
                             "10000", "--confidence", "0.8")) == 0
    faulty = tmp_path / "faulty.yaml"
    doc = yaml.safe_load(rig.read_text())
    doc["sim"]["faults"] = [{"axis": "sample_tilt", "kind": "alarm", "at_sample": 1}]
    faulty.write_text(yaml.safe_dump(doc, sort_keys=False))
    assert main(capture_args(faulty, plan, root / "b-fault", "builtin:green-felt", "--operator", "A. Operator",
                             "--sample-id", "G-1")) == 2

    listed = sessions_json(root, capsys)
    assert [(s["name"], s["state"], s["operator"], s["sample_id"], s["samples"]) for s in listed] == [
        ("a-target", "target reached", "B. Operator", "T-7", 4), ("b-fault", "faulted", "A. Operator", "G-1", 1)]
    assert listed[0]["notes"] == ["first coat", "dry"] and listed[0]["lab"] == LAB["lab"]
    assert [s["name"] for s in sessions_json(root, capsys, "--operator", "A. Operator")] == ["b-fault"]
    assert [s["name"] for s in sessions_json(root, capsys, "--sample", "T-7")] == ["a-target"]
    # one session folder given as ROOT lists that session (it was an empty table)
    assert [s["name"] for s in sessions_json(root / "b-fault", capsys)] == ["b-fault"]
    assert sessions_json(root, capsys, "--since", "2999-01-01") == []
    assert main(["sessions", str(root), "--since", "yesterday"]) == 2
    assert capsys.readouterr().err == ("goniofrost sessions: error: command line: --since: expected a date YYYY-MM-DD "
                                       "or YYYY-MM-DDTHH:MM (UTC), found 'yesterday'\n")
    assert main(["sessions", str(root)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split() == ["session", "started", "(UTC)", "operator", "sample", "state", "samples",
                                "error", "(log-relative", "MSE)", "duration"]
    assert lines[1].startswith("a-target") and " B. Operator " in lines[1] and " target reached " in lines[1]

    # a resume with another sample id: one line, exit 2, nothing changed (no run, no event, same label)
    session = root / "b-fault"
    with Journal.open(session / "session.sqlite") as journal:
        runs, events, label = journal.runs(), journal.events(), journal.label()
    assert main(capture_args(rig, plan, session, "builtin:green-felt", "--resume", "--sample-id", "G-2")) == 2
    assert capsys.readouterr().err == (
        f"goniofrost capture: error: {session / 'session.sqlite'}: meta.label.sample_id: this session was started "
        f"with sample_id 'G-1', found 'G-2' (--sample-id); resume with the same one, or start a new --session for "
        f"another\n")
    with Journal.open(session / "session.sqlite") as journal:
        assert (journal.runs(), journal.events(), journal.label()) == (runs, events, label)
    # the same sample (and a note more) resumes it; the label keeps its operator and gains the note;
    # a brdf.json already beside brdf.binary keeps its fields
    (session / "brdf.json").write_text(json.dumps({"coating": "by hand", "predicted_log_relative_mse": -1}))
    assert main(capture_args(rig, plan, session, "builtin:green-felt", "--resume", "--note", "resumed")) == 0
    with Journal.open(session / "session.sqlite") as journal:
        assert journal.label() == SessionLabel(operator="A. Operator", sample_id="G-1", notes=("resumed",), **LAB)
    record = json.loads((session / "brdf.json").read_text())
    # the earlier record's own fields kept, a superseded error figure not
    assert record["coating"] == "by hand" and "predicted_log_relative_mse" not in record
    assert record["measurement"]["sample_id"] == "G-1" and record["measurement"]["notes"] == ["resumed"]
    assert [s["state"] for s in sessions_json(root, capsys)] == ["target reached", "finished"]

    # the monitor on the folder serves the catalogue and each session's page under /s/NAME/
    from goniofrost.monitor.server import MonitorServer
    with MonitorServer(root, port=0, catalogue=True) as server:
        page = urllib.request.urlopen(server.url).read().decode()
        assert '<a href="/s/a-target/">a-target</a>' in page and "target reached" in page
        state = json.loads(urllib.request.urlopen(server.url + "s/b-fault/api/state").read())
        assert state["label"]["sample_id"] == "G-1" and "sample G-1" in state["label_text"]
        assert b"static/monitor.js" in urllib.request.urlopen(server.url + "s/b-fault/").read()
        for path in ("s/elsewhere/", "s/..%2F/api/state", "files/a-target/report.json"):
            with pytest.raises(urllib.error.HTTPError) as refused:
                urllib.request.urlopen(server.url + path)
            assert refused.value.code == 404, path


def test_the_rig_files_lab_section_is_checked(setup, tmp_path, capsys):
    folder, rig, plan, _ = setup
    doc = yaml.safe_load(rig.read_text())
    doc["lab"] = {"lab": "Optics lab 2", "lense": "50 mm"}
    bad = tmp_path / "rig.yaml"
    bad.write_text(yaml.safe_dump(doc, sort_keys=False))
    assert main(capture_args(bad, plan, tmp_path / "s")) == 2
    assert capsys.readouterr().err == (f"goniofrost capture: error: {bad}: lab.lense: expected one of the keys "
                                       f"lab, lens, lamp, found \"unknown key 'lense'\"\n")
    assert not (tmp_path / "s").exists()


def test_a_killed_runs_duration_ends_at_its_own_last_sample_not_the_resumed_runs(monkeypatch, tmp_path):
    from types import SimpleNamespace

    import goniofrost.monitor.catalogue as catalogue

    # run 1 started at 1000, committed samples at 1004 and 1006, was killed; run 2 resumed at 1030,
    # committed at 1035 and ended at 1040. It read (1035 - 1000) + (1040 - 1030) = 45 s.
    done = [SimpleNamespace(committed_utc=t) for t in (1004.0, 1006.0, 1035.0)]
    view = SimpleNamespace(unreadable="", run_end=SimpleNamespace(status=RunStatus.FINISHED), capture_alive=False,
                           nothing_measured=False, done=done, not_measured=[], label={}, material=None,
                           rig_name="sim-rig", plan=[{}] * 3, predicted_error=None, error_figure=None,
                           first_started_utc=1000.0,
                           run_spans=((1000.0, None), (1030.0, 1040.0)), report=None)
    monkeypatch.setattr(catalogue, "read_session", lambda folder: view)
    assert catalogue.read_entry(tmp_path).duration_s == 6.0 + 10.0


def test_a_session_whose_report_flags_an_extrapolation_is_listed_so(monkeypatch, tmp_path):
    """sessions listed black-obsidian's 0.5167 (actual 0.99) like any other estimate; its report
    flagged the reconstruction as an extrapolation (samples unlike every training material)."""
    from types import SimpleNamespace

    import goniofrost.monitor.catalogue as catalogue

    def view(flagged: bool):
        return SimpleNamespace(unreadable="", run_end=SimpleNamespace(status=RunStatus.FINISHED), capture_alive=False,
                               nothing_measured=False, done=[], not_measured=[], label={}, material=None,
                               rig_name="sim-rig", plan=[{}], predicted_error=0.5167, first_started_utc=None,
                               error_figure=said, run_spans=(), report={"prediction": {"extrapolation": flagged}})
    said = "error <= 1.2 with 95 % confidence (median estimate 0.517)"
    for flagged, cell in ((True, f"{said} (extrapolation)"), (False, said)):
        monkeypatch.setattr(catalogue, "read_session", lambda folder: view(flagged))
        entry = catalogue.read_entry(tmp_path)
        assert entry.extrapolation is flagged and catalogue.table_rows([entry])[0][6] == cell


def test_the_error_figure_is_one_and_the_same_in_all_seven_outputs(setup, tmp_path, capsys):
    """A small simulated capture with a target error: the summary, report.json, the preview's title,
    the live page's state, `sessions`, brdf.json and `compare` each state the same sentence "error
    <= B with C % confidence (median estimate X)"; the point prediction before centring is in
    report.json alone, under that name."""
    from PIL import Image

    from goniofrost.frost import confidence

    folder, rig, plan, _ = setup
    root = tmp_path / "day"
    session = root / "s-seven"
    batched = batched_plan(tmp_path, rig, plan, [2, 4])
    assert main(capture_args(rig, batched, session, "builtin:red-plastic", "--sample-id", "T-9",
                             "--target-error", "10000", "--confidence", "0.8")) == 0
    report = json.loads((session / "report.json").read_text())
    prediction = report["prediction"]
    said = prediction["error_figure"]
    # the sentence is the bound's and the median estimate's, worded once
    assert said == confidence.figure(prediction["bound"], 0.8, prediction["median_estimate"])
    assert said.startswith("error <= ") and " with 80 % confidence (median estimate " in said
    summary = (session / "summary.txt").read_text()
    assert f"reconstruction (log-relative MSE): {said}" in summary.splitlines()
    title = Image.open(session / "preview.png").text["Title"]
    assert title.splitlines()[:2] == ["T-9, session s-seven vs builtin:red-plastic", said]
    assert page_state(read_session(session), time.time())["error_figure"] == said
    capsys.readouterr()
    [listed] = sessions_json(root, capsys)
    assert listed["error_figure"] == said
    assert main(["sessions", str(root)]) == 0 and said in capsys.readouterr().out
    record = json.loads((session / "brdf.json").read_text())
    assert record["error_figure"] == record["measurement"]["error_figure"] == said
    assert main(["compare", str(session), str(session / "brdf.binary"), "--out", str(tmp_path / "c.png"),
                 "--size", "16", "--json"]) == 0
    compared = json.loads(capsys.readouterr().out)
    assert [i["error_figure"] for i in compared["inputs"]] == [said, said]
    # the point prediction before centring: report.json only, named so
    point = prediction["point_prediction_before_centring"]
    assert point != prediction["median_estimate"] and "predicted_log_relative_mse" not in prediction
    assert f"{point:.3g}" not in said and "predicted_log_relative_mse" not in json.dumps(record)
