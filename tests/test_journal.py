"""The SQLite session journal and samples.csv: exact round trips, one row per plan sample."""
from __future__ import annotations

import csv
import json
import math
import sqlite3
from contextlib import closing

import pytest

from calib import NotMeasuredReason
from goniofrost.capture.journal import CSV_COLUMNS, Journal, JournalError, NotMeasuredRecord, SampleRecord, SamplesCsv

META = {"plan": {"samples": [1, 2]}, "rig_text": "name: x\n", "kinematic_hash": "abc", "model_hash": "m1"}


def record(i: int) -> SampleRecord:
    return SampleRecord(
        plan_index=i, cell=1000 + i, theta_h_deg=0.1 * i + 1 / 3, theta_d_deg=12.5, phi_d_deg=90.0 + i,
        rgb=(0.1 * i + 1e-17, 0.2, 1 / 7), sigma=(0.001, 0.002, 0.003), snr=123.456,
        joints={"camera_arm": 30.0 + i, "sample_yaw": -4.5}, exposures_s=(0.004, 0.016), frames_taken=5,
        frames_skipped=2, raw_paths=(f"raw/s{i:03d}_0.dng", f"raw/s{i:03d}_1.dng"), lamp_relative=1.0012,
        move_s=2.5, capture_s=0.3, started_utc=1.7e9 + i, committed_utc=1.7e9 + i + 0.5)


def test_samples_meta_calibration_and_events_round_trip_exactly(tmp_path):
    path = tmp_path / "session.sqlite"
    with Journal.create(path, META) as journal:
        journal.set_calibration({"dark": [1.5, 2.0], "white": 0.9})
        for i in (2, 0, 1):
            journal.commit_sample(record(i))
        journal.add_event("fault", "axis stalled", axis="sample_tilt", data={"code": 7})
    with Journal.open(path) as journal:
        assert journal.meta() == {**META, "format_version": 1}
        assert journal.calibration() == {"dark": [1.5, 2.0], "white": 0.9}
        assert journal.samples() == [record(0), record(1), record(2)]
        assert journal.done_indices() == {0, 1, 2}
        [event] = journal.events()
        assert (event["kind"], event["axis"], event["message"], event["data"]) == ("fault", "sample_tilt", "axis stalled", {"code": 7})


def test_a_plan_sample_is_stored_once_and_the_refused_duplicate_changes_nothing(tmp_path):
    path = tmp_path / "session.sqlite"
    with Journal.create(path, META) as journal:
        journal.commit_sample(record(4))
        changed = SampleRecord(**{**record(4).__dict__, "rgb": (9.0, 9.0, 9.0)})
        with pytest.raises(JournalError, match="plan sample 4 is already in the journal"):
            journal.commit_sample(changed)
        assert journal.samples() == [record(4)]


def not_measured(i: int) -> NotMeasuredRecord:
    return NotMeasuredRecord(
        plan_index=i, cell=2000 + i, theta_h_deg=1 / 3, theta_d_deg=80.5, phi_d_deg=12.0 + i,
        reason=NotMeasuredReason.BELOW_DETECTION_LIMIT, snr=(3.25, 0.0, 1 / 7), min_snr=10.0,
        longest_exposure_s=0.128, upper_limit=(1e-3 / 3, 2.5e-4, 1e-17), joints={"camera_arm": 150.0 + i},
        exposures_s=(0.032, 0.128), frames_taken=2, frames_skipped=2, raw_paths=(f"raw/s{i:03d}_e3.dng",),
        lamp_relative=0.9987, move_s=1.25, capture_s=0.16, started_utc=1.7e9 + i, committed_utc=1.7e9 + i + 0.25)


def test_a_sample_not_measured_round_trips_exactly_is_done_and_has_no_value(tmp_path):
    """A not-measured sample keeps every typed field (its reason an enum again), counts as done
    (a resume skips it), and is not among the measured samples the reconstruction reads."""
    path = tmp_path / "session.sqlite"
    with Journal.create(path, META) as journal:
        journal.commit_sample(record(0))
        journal.commit_not_measured(not_measured(1))
        journal.commit_sample(record(2))
    with Journal.open(path) as journal:
        assert journal.not_measured() == [not_measured(1)]
        assert journal.not_measured()[0].reason is NotMeasuredReason.BELOW_DETECTION_LIMIT
        assert journal.samples() == [record(0), record(2)] and journal.done_indices() == {0, 1, 2}
    with Journal.open_read_only(path) as journal:   # what the monitor reads
        assert journal.not_measured() == [not_measured(1)]
    assert not_measured(1).to_dict()["reason"] == "below-detection-limit"


def saturated(i: int) -> NotMeasuredRecord:
    return NotMeasuredRecord(**{**not_measured(i).__dict__, "reason": NotMeasuredReason.SATURATED,
                                "upper_limit": (math.inf,) * 3, "lower_limit": (12.5, 1 / 3, 7e-2)})


def test_a_saturated_sample_round_trips_with_its_lower_limit_and_no_upper_one(tmp_path):
    path = tmp_path / "session.sqlite"
    with Journal.create(path, META) as journal:
        journal.commit_not_measured(saturated(5))
    with Journal.open(path) as journal:
        assert journal.not_measured() == [saturated(5)] and journal.not_measured()[0].reason is NotMeasuredReason.SATURATED
    data = saturated(5).to_dict()   # JSON without Infinity: no upper limit is None
    assert (data["upper_limit"], data["lower_limit"]) == ([None] * 3, [12.5, 1 / 3, 7e-2])
    assert json.loads(json.dumps(data, allow_nan=False)) == data
    assert saturated(5).why() == "patch pixels saturate even at the shortest exposure 0.032 s; BRDF above 12.5/0.333/0.07 1/sr (R/G/B)"
    assert not_measured(1).why() == "SNR 3.2 below the minimum 10 with exposures up to 0.128 s; BRDF below 0.000333/0.00025/1e-17 1/sr (R/G/B)"


def test_a_journal_from_before_the_lower_limits_gains_them_as_zero(tmp_path):
    """A journal written before saturated samples were recorded: its not-measured samples (too
    dark) read back with a lower limit 0, read-only too, and a resume can add saturated ones."""
    path = tmp_path / "session.sqlite"
    with Journal.create(path, META) as journal:
        journal.commit_not_measured(not_measured(1))
    with closing(sqlite3.connect(path)) as db:
        for channel in "rgb":
            db.execute(f"ALTER TABLE not_measured DROP COLUMN lower_{channel}")
        db.commit()
    with Journal.open_read_only(path) as journal:
        assert journal.not_measured() == [not_measured(1)]
    with Journal.open(path) as journal:
        journal.commit_not_measured(saturated(2))
        assert journal.not_measured() == [not_measured(1), saturated(2)]


def test_a_plan_sample_is_either_measured_or_not_measured_never_both(tmp_path):
    path = tmp_path / "session.sqlite"
    with Journal.create(path, META) as journal:
        journal.commit_sample(record(3))
        journal.commit_not_measured(not_measured(4))
        with pytest.raises(JournalError, match="plan sample 3 is already in the journal"):
            journal.commit_not_measured(not_measured(3))
        for again in (lambda: journal.commit_sample(record(4)), lambda: journal.commit_not_measured(not_measured(4))):
            with pytest.raises(JournalError, match="plan sample 4 is already in the journal"):
                again()
        assert journal.samples() == [record(3)] and journal.not_measured() == [not_measured(4)]


def test_a_read_only_journal_from_before_the_not_measured_table_has_none(tmp_path):
    path = tmp_path / "session.sqlite"
    with Journal.create(path, META) as journal:
        journal.commit_sample(record(0))
        journal._db.execute("DROP TABLE not_measured")
    with Journal.open_read_only(path) as journal:
        assert journal.not_measured() == [] and journal.done_indices() == {0}


def test_create_refuses_an_existing_journal_and_open_refuses_a_missing_or_foreign_file(tmp_path):
    path = tmp_path / "session.sqlite"
    Journal.create(path, META).close()
    with pytest.raises(JournalError, match="already exists; pass --resume"):
        Journal.create(path, META)
    with pytest.raises(JournalError, match="no session journal to resume"):
        Journal.open(tmp_path / "other.sqlite")
    junk = tmp_path / "junk.sqlite"
    junk.write_bytes(b"this is not sqlite" * 100)
    with pytest.raises(JournalError, match="not a usable session journal"):
        Journal.open(junk)


def test_journal_uses_wal_and_full_synchronous_commits(tmp_path):
    with Journal.create(tmp_path / "s.sqlite", META) as journal:
        assert journal._db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
        assert journal._db.execute("PRAGMA synchronous").fetchone()[0] == 2  # FULL


def test_steps_are_journaled_as_they_start_and_end_and_readable_by_another_connection(tmp_path):
    path = tmp_path / "session.sqlite"
    with Journal.create(path, META) as journal:
        assert journal.next_run() == 1
        move = journal.start_step(1, "Move", 3, {"joints": [["camera_arm", 30.0]]})
        with sqlite3.connect(f"file:{path}?mode=ro", uri=True) as monitor:  # what a monitor sees meanwhile
            assert monitor.execute("SELECT kind, plan_index, status FROM steps").fetchall() == [("Move", 3, "running")]
        journal.end_step(move, "done", {"seconds": 1.5})
        expose = journal.start_step(1, "Expose", None, {"exposure_s": 0.004, "file": "calibration/dark_e0_0.dng"})
        journal.end_step(expose, "failed", {"error": "camera: no frame"})
        with pytest.raises(JournalError, match=r"step status: expected one of \('done', 'failed', 'interrupted'\), "
                                               r"found 'running'"):
            journal.end_step(expose, "running")
        assert journal._db.execute("PRAGMA synchronous").fetchone()[0] == 2  # samples stay FULL
        assert journal.next_run() == 2
    with Journal.open(path) as journal:
        rows = journal.steps()
    assert [(r["run"], r["kind"], r["plan_index"], r["status"]) for r in rows] == [(1, "Move", 3, "done"),
                                                                                   (1, "Expose", None, "failed")]
    assert rows[0]["detail"] == {"joints": [["camera_arm", 30.0]]} and rows[0]["result"] == {"seconds": 1.5}
    assert rows[1]["result"] == {"error": "camera: no frame"}
    assert all(r["started_utc"] <= r["ended_utc"] for r in rows)


def test_a_journal_without_a_steps_table_gets_one_and_keeps_its_samples(tmp_path):
    path = tmp_path / "session.sqlite"
    with Journal.create(path, META) as journal:
        journal.commit_sample(record(0))
        journal._db.execute("DROP TABLE steps")  # as written before steps were journaled
    with Journal.open(path) as journal:
        assert journal.samples() == [record(0)] and journal.steps() == [] and journal.next_run() == 1


def test_samples_csv_rewrite_drops_a_torn_line_and_values_round_trip(tmp_path):
    path = tmp_path / "samples.csv"
    table = SamplesCsv(path)
    table.rewrite([record(0)])
    table.append(record(1))
    with open(path, "a") as handle:
        handle.write("1.0,2.0,3.")  # a line torn by SIGKILL
    table.rewrite([record(0), record(1)])
    with open(path) as handle:
        rows = list(csv.DictReader(handle))
    assert tuple(rows[0]) == CSV_COLUMNS
    assert [int(r["plan_index"]) for r in rows] == [0, 1]
    assert float(rows[1]["theta_h_deg"]) == record(1).theta_h_deg
    assert tuple(float(rows[1][c]) for c in "rgb") == record(1).rgb
    assert tuple(float(rows[1][f"sigma_{c}"]) for c in "rgb") == record(1).sigma


def _fill(folder) -> None:
    """Fill a small file system: the next write gets ENOSPC."""
    with open(folder / "filler", "wb", buffering=0) as handle:
        with pytest.raises(OSError, match="No space left"):
            while True:
                handle.write(b"\0" * 4096)


def test_a_full_disk_is_an_output_error_naming_the_journal_and_loses_no_committed_sample(mounted):
    from goniofrost.core.errors import OutputError

    folder = mounted("size=512k")
    path = folder / "session.sqlite"
    with Journal.create(path, META) as journal:
        journal.commit_sample(record(0))
        _fill(folder)
        with pytest.raises(OutputError) as caught:
            for i in range(1, 200):  # the WAL grows until the disk refuses a page
                journal.commit_sample(record(i))
        assert str(caught.value) == f"{path}: cannot write: no space left on the device"
        last = i
    (folder / "filler").unlink()
    with Journal.open(path) as journal:  # every sample committed before the refusal is there, once
        assert journal.samples() == [record(i) for i in range(last)]
    csv_path = folder / "samples.csv"
    _fill(folder)
    with pytest.raises(OutputError, match=f"^{csv_path}: cannot write: no space left on the device$"):
        for i in range(10_000):
            SamplesCsv(csv_path).append(record(i))


def test_a_journal_that_cannot_be_created_leaves_nothing_behind(mounted):
    from goniofrost.core.errors import OutputError

    folder = mounted("size=64k")
    _fill(folder)
    with pytest.raises(OutputError, match="no space left on the device"):
        Journal.create(folder / "session.sqlite", {**META, "rig_text": "x" * 100_000})
    assert [p.name for p in folder.iterdir()] == ["filler"]
