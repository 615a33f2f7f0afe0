"""What a reliability probe of the capture found, one test per row: strongly coloured materials,
a monitor under load and odd paths, resume and refusal corner cases. Small and fast: the test
session's 30 x 30 x 60 grid, its 6-material model and short simulated rig."""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest

from goniofrost.capture.journal import Journal
from goniofrost.capture.inputs import load_inputs
from goniofrost.capture.options import SessionOptions, StopRule
from goniofrost.capture.runner import capture
from goniofrost.datasets import shown_material
from goniofrost.rig.simulated import rig_devices

from test_session import GRID, session_model, write_rig
from goniofrost.rig.hardware import SimOptions

REPO = Path(__file__).resolve().parents[1]
RGL = REPO.parent / "shared" / "data" / "nbrdf_rgl.npz"
BLUE_SILK = f"nbrdf:{RGL}:vch_silk_blue_rgb"


@pytest.fixture(scope="module")
def model():
    return session_model()


def coloured_plan(folder: Path, model, material: str, n_other: int = 2) -> tuple[Path, Path, int]:
    """(rig, plan, plan index of the darkest channel) of a plan holding the reachable cell where
    ``material``'s weakest channel is the smallest fraction of its strongest (bright enough for the
    short test ladder), and ``n_other`` ordinary cells."""
    from planner.reach import reachability
    from planner.schedule import schedule_plan

    from goniofrost.plan.file import plan_document, write_plan
    from goniofrost.rig.file import load_checked_rig
    from goniofrost.core.cache import cache_path
    from goniofrost.datasets import parse_material_spec
    from goniofrost.frost.selection import Selection

    rig_path = write_rig(folder / "rig.yaml")
    rig = load_checked_rig(rig_path)
    reach = np.flatnonzero(reachability(rig, model.grid).mask)
    dataset, name = parse_material_spec(material)
    table = dataset.tabulate([name], model.grid)[0].astype(np.float64)[reach]
    bright = table.max(1) > 0.05                       # enough light for the longest test exposure
    ratio = np.where(bright, table.min(1) / np.maximum(table.max(1), 1e-12), np.inf)
    dark = int(np.argmin(ratio))
    others = [int(i) for i in np.argsort(-table.min(1))[:n_other]]
    positions = np.array([dark, *others])
    cells = model.grid.valid_cells[reach[positions]]
    selection = Selection(reach[positions], cells, np.zeros(len(cells)), 0.0, "all", 18, "frost")
    doc = plan_document(cache_path("models", model.info["cache_key"], ""), model, selection)
    plan_path = folder / "plan.json"
    write_plan(plan_path, schedule_plan(doc, rig))
    plan = json.loads(plan_path.read_text())
    index = next(i for i, s in enumerate(plan["samples"]) if s["w_i"] == doc["samples"][0]["w_i"]
                 and s["w_o"] == doc["samples"][0]["w_o"])
    assert ratio[dark] < 0.02, f"{material}: no cell with a near-zero channel ({ratio[dark]:.3f})"
    return rig_path, plan_path, index


def test_a_strongly_coloured_material_is_captured_with_its_dark_channel_at_its_detection_limit(tmp_path, model):
    """The RGL blue silk has a channel near 0 where another is bright: the capture completes, and
    the dark channel's sample is its true value within its uncertainty (not an error)."""
    from goniofrost.datasets import material_brdf

    rig, plan, k = coloured_plan(tmp_path, model, BLUE_SILK)
    capture(load_inputs(rig, plan), tmp_path / "s", sim=SimOptions(material=shown_material(BLUE_SILK), speedup=50),
            devices=rig_devices, options=SessionOptions(progress=False))
    samples = json.loads(plan.read_text())["samples"]
    _, brdf = material_brdf(BLUE_SILK)
    with Journal.open(tmp_path / "s" / "session.sqlite") as journal:
        records = {r.plan_index: r for r in journal.samples()}
    assert sorted(records) == list(range(len(samples)))
    report = json.loads((tmp_path / "s" / "report.json").read_text())
    assert k in report["detection_limit"] and "have a channel at its detection limit" in \
        (tmp_path / "s" / "summary.txt").read_text()
    dark = records[k]
    truth = brdf(np.array(samples[k]["w_i"]), np.array(samples[k]["w_o"]))
    c = int(np.argmin(truth))
    assert "detection-limit" in dark.status and truth[c] < 0.02 * truth.max()
    assert abs(dark.rgb[c] - truth[c]) <= 3 * dark.sigma[c] and dark.sigma[c] < 0.05 * max(dark.rgb)
    for r in records.values():   # every channel of every sample within 4 sigma of the truth
        t = brdf(np.array(samples[r.plan_index]["w_i"]), np.array(samples[r.plan_index]["w_o"]))
        assert np.all(np.abs(np.array(r.rgb) - t) <= 4 * np.array(r.sigma) + 0.03 * t), (r.plan_index, r.rgb, t)


# ----- the monitor ----------------------------------------------------------------------------
@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    """A finished 3-sample session (read-only for the tests)."""
    from monitor_helpers import MATERIAL, make_plan
    folder = tmp_path_factory.mktemp("finished")
    rig, plan = make_plan(folder, 3)
    capture(load_inputs(rig, plan), folder / "s", sim=SimOptions(material=shown_material(MATERIAL), speedup=50),
            devices=rig_devices, options=SessionOptions(progress=False))
    return folder / "s"


def test_very_long_or_deep_paths_are_a_404_not_a_closed_connection(finished, caplog):
    from goniofrost.monitor.server import MonitorServer
    from test_monitor import request
    with MonitorServer(finished, port=0) as server:
        for path in ("/files/" + "a" * 60000, "/files/" + "a/" * 5000 + "x", "/files/" + "%2F".join(["b"] * 3000)):
            status, _, body = request(server, "GET", path)
            assert status == 404 and body.startswith(b"refused path '") and len(body) < 400, (status, body[:200])
        status, _, body = request(server, "GET", "/files/report.json")
        assert status == 200 and body == (finished / "report.json").read_bytes()


def test_the_frame_and_preview_answer_for_what_was_asked_from_the_start(finished):
    from goniofrost.monitor.server import MonitorServer
    from test_monitor import request
    with MonitorServer(finished, port=0) as server:   # no /api/state asked first
        status, headers, body = request(server, "GET", "/api/preview.png?done=3")
        assert status == 200 and headers["X-Shows"] == "3" and body.startswith(b"\x89PNG")
        status, headers, body = request(server, "GET", "/api/frame.png?sample=1")
        assert status == 200 and headers["X-Shows"] == "1"
        for k in (-5, 99):   # right after a picture: still this sample's own answer
            status, headers, body = request(server, "GET", f"/api/frame.png?sample={k}")
            assert status == 404 and body == f"sample {k} is not in the journal".encode() and headers["X-Shows"] == str(k)


def test_a_journal_left_by_a_killed_writer_is_read_from_a_copy(tmp_path):
    """A writer killed with its -wal and -shm in the folder (copied while it is open, as kill -9
    leaves them): the monitor reads every committed sample and changes no byte of the folder."""
    import shutil

    from goniofrost.monitor.session_view import read_session
    from monitor_helpers import folder_state
    from test_monitor import META, record

    live, dead = tmp_path / "live", tmp_path / "dead"
    live.mkdir()
    dead.mkdir()
    journal = Journal.create(live / "session.sqlite", META)
    journal.commit_sample(record(0))
    journal.commit_sample(record(1))
    for name in ("session.sqlite", "session.sqlite-wal", "session.sqlite-shm"):
        shutil.copyfile(live / name, dead / name)
    journal.close()
    (dead / "session.lock").write_text("")   # nobody holds it
    before = folder_state(dead)
    mtimes = {p.name: p.stat().st_mtime_ns for p in dead.iterdir()}
    view = read_session(dead)
    assert [d.plan_index for d in view.done] == [0, 1] and view.capture_alive is False
    assert folder_state(dead) == before and {p.name: p.stat().st_mtime_ns for p in dead.iterdir()} == mtimes


def monitor_load(session: Path, clients: int, seconds: float, idle: int, big: str,
                 slow_bytes: int | None = None, settle: bool = True) -> dict:
    """Start ``goniofrost monitor`` on ``session`` in its own process; hold ``idle`` sockets that
    send half a request, and run ``clients`` clients asking for pages, the state and the big file
    ``big`` (read slowly: 4 KiB per 10 ms, the whole file or its first ``slow_bytes`` before the
    client hangs up) for ``seconds``; return counts, and the server's memory and threads (at the
    start, at the peak and, with ``settle``, once anyio's idle workers ended: up to 10 s later)."""
    import asyncio
    import re
    import subprocess
    import sys

    proc = subprocess.Popen([sys.executable, "-m", "goniofrost", "monitor", str(session), "--port", "0"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        port = int(re.search(r":(\d+)/", proc.stdout.readline()).group(1))

        def status() -> tuple[int, int]:
            text = Path(f"/proc/{proc.pid}/status").read_text()
            return (int(re.search(r"VmRSS:\s+(\d+)", text).group(1)) // 1024,
                    int(re.search(r"Threads:\s+(\d+)", text).group(1)))

        async def get(path: str, slow: bool) -> int:
            reader, writer = await asyncio.open_connection("127.0.0.1", port)
            writer.write(f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n\r\n".encode())
            await writer.drain()
            line = await reader.readline()
            got = 0
            while chunk := await reader.read(65536 if not slow else 4096):
                got += len(chunk)
                if slow:
                    if slow_bytes is not None and got >= slow_bytes:
                        break  # hangs up mid-file, as a closed browser tab does
                    await asyncio.sleep(0.01)
            writer.close()
            return int(line.split()[1])

        async def client(n: int, until: float, out: dict) -> None:
            paths = ("/", "/api/state", f"/files/{big}", "/static/monitor.js", "/files/" + "a/" * 3000)
            k = n
            while asyncio.get_running_loop().time() < until:
                path = paths[k % len(paths)]
                k += 1
                try:
                    code = await asyncio.wait_for(get(path, slow=path.endswith(big)), 30)
                    out[code] = out.get(code, 0) + 1
                except ConnectionRefusedError:
                    out["refused"] = out.get("refused", 0) + 1
                except (asyncio.TimeoutError, OSError) as exc:
                    out[type(exc).__name__] = out.get(type(exc).__name__, 0) + 1

        async def main() -> dict:
            held = []
            for _ in range(idle):
                reader, writer = await asyncio.open_connection("127.0.0.1", port)
                writer.write(b"GET /api/sta")
                held.append(writer)
            await asyncio.sleep(0)
            out: dict = {}
            until = asyncio.get_running_loop().time() + seconds
            await asyncio.gather(*(client(n, until, out) for n in range(clients)))
            out["peak"] = status()
            for writer in held:
                writer.close()
            return out

        start = status()
        out = asyncio.run(main())
        out["start"] = start
        if settle:
            deadline = time.monotonic() + 30.0   # anyio's idle worker threads end after 10 s
            while (end := status())[1] > start[1] and time.monotonic() < deadline:
                time.sleep(0.2)
            out["end"] = end
        return out
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def load_session(tmp_path: Path, size_mb: int) -> Path:
    session = tmp_path / "s"
    session.mkdir()
    (session / "brdf.std.binary").write_bytes(np.random.default_rng(0).bytes(size_mb << 20))
    (session / "report.json").write_text("{}")
    return session


def check_load(out: dict, idle: int) -> None:
    from goniofrost.monitor.app import MAX_WORKERS
    assert "refused" not in out and 503 not in out and out.get(200, 0) > 0 and out.get(404, 0) > 0, out  # queued, not refused
    assert out["peak"][0] - out["start"][0] < 100, out           # MB of resident memory
    assert out["peak"][1] <= out["start"][1] + MAX_WORKERS, out  # threads bounded, not one per socket
    if "end" in out:
        assert out["end"][1] == out["start"][1], out             # and back to normal once it is over


def test_the_monitor_holds_many_clients_and_idle_sockets(tmp_path):
    """Small: 40 clients for 2 s beside 60 half-sent requests, on a 8 MB file read slowly (its first
    256 KiB, then the client hangs up: a whole 8 MB at 400 KB/s would hold the test for 20 s). The
    threads' return to normal, 10 s of anyio's idle timeout, is the full-size test's to wait for."""
    out = monitor_load(load_session(tmp_path, 8), clients=40, seconds=2.0, idle=60, big="brdf.std.binary",
                       slow_bytes=256 << 10, settle=False)
    check_load(out, 60)


@pytest.mark.slow
def test_the_monitor_holds_200_clients_and_300_idle_sockets(tmp_path):
    """Full size: 200 clients for 10 s beside 300 half-sent requests, on a 35 MB file read slowly."""
    out = monitor_load(load_session(tmp_path, 35), clients=200, seconds=10.0, idle=300, big="brdf.std.binary")
    print("monitor load 200 clients x 10 s + 300 idle:", out)
    check_load(out, 300)


# ----- resume, refusals, one-line errors ------------------------------------------------------
def run_cli(capsys, *argv) -> tuple[int, str]:
    from goniofrost.app.cli import main
    code = main([str(a) for a in argv])
    return code, capsys.readouterr().err.strip()


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """(rig, plan) of a 3-sample plan on the test rig."""
    from monitor_helpers import make_plan
    return make_plan(tmp_path_factory.mktemp("small"), 3)


def capture_argv(rig, plan, session, *extra):
    from monitor_helpers import MATERIAL
    return ["capture", "--rig", rig, "--plan", plan, "--session", session, "--material", MATERIAL,
            "--no-progress", "--speedup", "50", *extra]


def test_a_resume_with_another_seed_is_refused_and_stale_temporaries_are_removed(finished, tmp_path, capsys):
    import shutil
    session = tmp_path / "s"
    shutil.copytree(finished, session)
    meta = Journal.open(session / "session.sqlite")
    stored = meta.meta()
    meta.close()
    rig, plan = stored["rig_file"], stored["plan_file"]
    code, err = run_cli(capsys, *capture_argv(rig, plan, session, "--resume", "--seed", "7"))
    assert code == 2 and err == (
        f"goniofrost capture: error: {session / 'session.sqlite'}: meta.sim_seed: this session was started with another simulated noise "
        f"seed (--seed or sim.seed): expected 0, found 7; resume with the same --rig, --plan, --material, --seed, "
        f"--target-error and --confidence, or start a new --session")
    # a kill during the atomic writes of the results left their temporaries: the resume removes them
    for name in (".brdf.binary.k2j_x9ab", ".brdf.std.binary.0a1b2c3d"):
        (session / name).write_bytes(b"half")
    (session / "report.json").unlink()   # written last: not yet there
    code, _ = run_cli(capsys, *capture_argv(rig, plan, session, "--resume"))
    assert code == 0 and not list(session.glob(".brdf*"))


def test_a_plan_with_a_duplicated_sample_and_a_drill_past_the_plan_are_refused(small, tmp_path, capsys):
    import yaml
    rig, plan = small
    doc = json.loads(plan.read_text())
    doc["samples"][2] = dict(doc["samples"][0])
    twice = tmp_path / "twice.json"
    twice.write_text(json.dumps(doc))
    code, err = run_cli(capsys, *capture_argv(rig, twice, tmp_path / "a"))
    assert code == 2 and err == (f"goniofrost capture: error: {twice}: samples[2].cell: expected a cell not already in the plan "
                                 f"(samples[0] has it), found {doc['samples'][0]['cell']}")
    drilled = yaml.safe_load(Path(rig).read_text())
    drilled["sim"]["faults"] = [{"axis": "camera_arm", "kind": "alarm", "at_sample": 3}]
    drill_rig = tmp_path / "drill.yaml"
    drill_rig.write_text(yaml.safe_dump(drilled))
    code, err = run_cli(capsys, *capture_argv(drill_rig, plan, tmp_path / "b"))
    assert code == 2 and err == f"goniofrost capture: error: {drill_rig}: sim.faults[0].at_sample: expected a plan sample index 0..2, found 3"
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_a_foreign_folder_is_not_a_session_and_a_refused_run_leaves_nothing(small, tmp_path, capsys):
    import yaml
    rig, plan = small
    foreign = tmp_path / "photos"
    foreign.mkdir()
    (foreign / "holiday.jpg").write_bytes(b"jpeg")
    code, err = run_cli(capsys, *capture_argv(rig, plan, foreign))
    assert code == 2 and err == (f"goniofrost capture: error: {foreign}: cannot write: it is not a session folder (no "
                                 f"session.sqlite; it holds holiday.jpg): choose a new or empty --session folder")
    assert sorted(p.name for p in foreign.iterdir()) == ["holiday.jpg"]
    # a real rig whose serial port does not exist: refused when connecting, before any step
    real = yaml.safe_load(Path(rig).read_text())
    real["simulated"] = False
    for axis in real["axes"].values():
        if axis.get("port") == "sim":
            axis["port"] = str(tmp_path / "no-such-tty")
    real_rig = tmp_path / "real.yaml"
    real_rig.write_text(yaml.safe_dump(real))
    session = tmp_path / "new"
    from goniofrost.app.cli import main
    code = main(["capture", "--rig", str(real_rig), "--plan", str(plan), "--session", str(session), "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("goniofrost capture: error: ") and err.count("\n") == 1, err
    assert not session.exists()


def test_a_preview_of_a_binary_with_nan_cells_is_refused(tmp_path, capsys):
    from goniofrost.brdf.merl_file import write_merl
    table = np.full((GRID.size, 3), 0.1)
    table[GRID.valid_cells[:5], 1] = np.nan   # written as -1: missing values on valid cells
    path = tmp_path / "holes.binary"
    write_merl(path, table, GRID)
    code, err = run_cli(capsys, "preview", path, "--out", tmp_path / "p.png")
    assert code == 2 and err == (f"goniofrost preview: error: {path}: valid cells without a value (negative in the "
                                 f"file): 5, first at (i_th, i_td, i_pd) = (0, 0, 0); expected a BRDF value >= 0 at every "
                                 f"cell above the horizon")
    assert not (tmp_path / "p.png").exists()


def test_samples_csv_angles_out_of_range_are_named_in_plain_numbers(tmp_path):
    from goniofrost.frost.reconstruction import ReconstructionError
    from goniofrost.frost.samples_file import read_samples_csv
    path = tmp_path / "samples.csv"
    path.write_text("theta_h_deg,theta_d_deg,phi_d_deg,r,g,b\n10,20,30,0.1,0.1,0.1\n200,20,30,0.1,0.1,0.1\n")
    with pytest.raises(ReconstructionError) as got:
        read_samples_csv(path, GRID)
    assert str(got.value) == f"{path}: line 3: theta_h_deg=200 is out of range: expected 0 to 90 degrees"
    path.write_text("theta_h_deg,theta_d_deg,phi_d_deg,r,g,b\n60,60,0,0.1,0.1,0.1\n")
    with pytest.raises(ReconstructionError, match=r"line 2: angles theta_h_deg=60, theta_d_deg=60, phi_d_deg=0 "
                                                  r"fall in cell \(\d+, \d+, \d+\), which is not a valid cell"):
        read_samples_csv(path, GRID)
