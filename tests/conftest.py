"""Shared fixtures: the measured-material data beside the project, a private cache folder, small
file systems mounted for a test (read-only, full)."""
from __future__ import annotations

import fcntl
import os
import shutil
import subprocess
import sys
import uuid
from pathlib import Path

import pytest
from hypothesis import settings

# pytest caches each test module's assertion-rewritten code in tests/__pycache__ unless
# sys.dont_write_bytecode, which PYTHONDONTWRITEBYTECODE (set on these machines) sets: then every
# pytest-xdist worker rewrote every test module on every run, 10-11 s of CPU a worker (a collection
# of 13 s against 4.5 s with the cache). The cached code is checked against its source's mtime and
# size, as Python's own .pyc is; what a test runs is the same either way. The package's modules
# imported in-process write their .pyc too, as set-up's warm stage writes them (app.warm).
sys.dont_write_bytecode = False

# Property tests draw the same examples on every run (derandomize: from each test's source) and keep no
# example database: a test run is deterministic, and a case one machine happened to find is not
# replayed on it alone (a grazing round trip failed in one worktree only, replayed from .hypothesis).
settings.register_profile("goniofrost", derandomize=True, database=None)
settings.load_profile("goniofrost")

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("GONIOFROST_SHARED_DATA", REPO.parent / "shared" / "data"))
# The test run's folder, the same for all its pytest-xdist workers (set by _private_cache): made_once's.
RUN_FOLDER = None


@pytest.fixture(autouse=True, scope="session")
def _private_cache(tmp_path_factory):
    """Every test process uses its own cache folder, never the user's, and its own rig-lock folder
    (module-scoped fixtures run captures before any per-test folder exists: a test run must never
    take, or ask to stop, a rig lock of another program on this computer)."""
    global RUN_FOLDER
    root = tmp_path_factory.getbasetemp()
    RUN_FOLDER = root.parent if "PYTEST_XDIST_WORKER" in os.environ else root
    os.environ["GONIOFROST_CACHE"] = str(tmp_path_factory.mktemp("cache"))
    os.environ["GONIOFROST_LOCK_DIR"] = str(tmp_path_factory.mktemp("session-locks"))
    yield


@pytest.fixture(autouse=True)
def _private_rig_locks(tmp_path_factory, monkeypatch):
    """Each test its own rig locks (subprocesses inherit them): tests of other checkouts on this
    computer driving a simulated rig of the same name must not refuse ours."""
    monkeypatch.setenv("GONIOFROST_LOCK_DIR", str(tmp_path_factory.mktemp("locks")))


# The reply timeout (ms) of every driver talking to a simulated twin in a test (sim.rig.SLOW_HOST_ENV):
# a twin answers from a thread of the test's own process, which at load 8-11 on 2 cores can miss a
# real bus's 100-300 ms (reply timeouts seen in the dynamixel, rig console, monitor, session, sentinel
# and pylon tests). It cannot hide a defect: a twin answers in well under a millisecond when the
# host is quiet, so a longer wait only ever passes a reply that did come, and an axis drilled to fall
# silent (sim.faults.SILENT_KINDS) keeps its product timeout, so the tests of drilled silence get
# their timeouts as promptly as before. Real hardware keeps the drivers' defaults (nothing reads this outside sim.rig).
TWIN_REPLY_TIMEOUT_MS = 3000


@pytest.fixture(autouse=True)
def _patient_twins(monkeypatch):
    """Every test's simulated twins (and those of the commands it runs) get TWIN_REPLY_TIMEOUT_MS."""
    from sim.rig import SLOW_HOST_ENV

    monkeypatch.setenv(SLOW_HOST_ENV, str(TWIN_REPLY_TIMEOUT_MS))


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """../shared/data (or $GONIOFROST_SHARED_DATA); tests that need it skip without it."""
    if not (SHARED_DATA / "nbrdf_merl.npz").is_file():
        pytest.skip(f"measured-material data not found in {SHARED_DATA}")
    return SHARED_DATA


@pytest.fixture(scope="session")
def merl_npz(shared_data) -> Path:
    return shared_data / "nbrdf_merl.npz"


@pytest.fixture(scope="session")
def rgl_npz(shared_data) -> Path:
    return shared_data / "nbrdf_rgl.npz"


@pytest.fixture
def mounted(tmp_path):
    """mount(options) -> a fresh tmpfs folder with those mount options; unmounted afterwards."""
    points = []

    def mount(options: str) -> Path:
        point = tmp_path / f"mnt-{uuid.uuid4().hex[:6]}"
        point.mkdir()
        done = subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(point)], capture_output=True)
        if done.returncode != 0:
            pytest.skip(f"cannot mount a tmpfs here: {done.stderr.decode().strip()}")
        points.append(point)
        return point

    yield mount
    for point in points:
        subprocess.run(["umount", str(point)], check=True)


def made_once(name: str, make) -> Path:
    """The folder ``make(folder)`` fills, made once per test run: the first pytest-xdist worker to
    ask makes it in the run's folder, the others wait for it and use it (every worker used to
    make the same thing, mostly a training of 2-8 s of CPU)."""
    folder = RUN_FOLDER / name
    with open(folder.with_suffix(".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        if not folder.is_dir():
            part = folder.with_suffix(".part")
            shutil.rmtree(part, ignore_errors=True)
            make(part)
            part.rename(folder)
    return folder


def trained_once(name: str, fit):
    """The model ``fit()`` returns, trained once per test run (``made_once``)."""
    from goniofrost.frost.model import FrostModel

    return FrostModel.load(made_once(name, lambda folder: fit().save(folder)), mmap=False)


def train_once(name: str, *args, **kwargs):
    """goniofrost's ``train(*args, cache=True, **kwargs)`` in this process's cache, the model trained
    once per test run (``made_once``: in a cache of its own) and copied into this cache: the
    fixtures of many modules train the same small models, which every worker trained."""
    from goniofrost.frost.training import train

    own = os.environ["GONIOFROST_CACHE"]

    def make(folder):
        os.environ["GONIOFROST_CACHE"] = str(folder)
        try:
            train(*args, cache=True, **kwargs)
        finally:
            os.environ["GONIOFROST_CACHE"] = own

    for entry in (made_once(name, make) / "models").iterdir():
        if not (Path(own) / "models" / entry.name).exists():  # never over a model this process has open
            shutil.copytree(entry, Path(own) / "models" / entry.name)
    return train(*args, cache=True, **kwargs)


@pytest.fixture(scope="session")
def synthetic24():
    """A model of 24 synthetic materials (test_frost's synthetic_tables, seed 1) on a 10 x 10 x 20
    grid, K <= 30, with its noise model: trained once per test run for the training, selection
    and Bayesian tests."""
    from test_frost import synthetic_tables

    from goniofrost.core.grid import MerlGrid
    from goniofrost.frost.training import TrainingOptions, fit_model

    grid = MerlGrid(10, 10, 20)
    return trained_once("synthetic24", lambda: fit_model(
        synthetic_tables(grid, 24, seed=1), [f"mat{i}" for i in range(24)], grid, TrainingOptions(k_max=30)))


@pytest.fixture(scope="session")
def small_trained():
    """(a model of 40 synthetic materials on a 10 x 10 x 20 grid, its 15-sample Bayesian design):
    trained once per test run for the sentinel and check-cell tests (the training is most of
    their time)."""
    import numpy as np
    from test_frost import synthetic_tables

    from goniofrost.core.grid import MerlGrid
    from goniofrost.frost.bayes_selection import select_bayes
    from goniofrost.frost.training import TrainingOptions, fit_model

    grid = MerlGrid(10, 10, 20)
    model = trained_once("small_trained", lambda: fit_model(
        synthetic_tables(grid, 40, seed=3), [f"mat{i}" for i in range(40)], grid, TrainingOptions(k_max=30)))
    return model, np.asarray(select_bayes(model, 15).positions, dtype=np.int64)


@pytest.fixture(scope="session")
def full_grid_exports():
    """name -> goniofrost's RGL tensor export (.bsdf, default options, ``builtin:NAME`` its source) of
    the built-in terracotta, red-plastic and gold on the full grid: made once per test run for the
    full-grid checks of test_mitsuba_export and test_spectral_export (each built the same fields,
    2-3 s of CPU a material)."""
    import numpy as np

    from goniofrost.brdf.merl_file import valid_to_full
    from goniofrost.brdf.mitsuba_export import export_mitsuba
    from goniofrost.core.grid import FULL_GRID
    from goniofrost.datasets import open_dataset
    from goniofrost.datasets.tabulate import tabulate_cached

    names = ("terracotta", "red-plastic", "gold")

    def export(folder):
        folder.mkdir()
        for name in names:
            values = tabulate_cached(open_dataset("builtin"), [name], FULL_GRID, progress=False)[0]
            export_mitsuba(folder / f"{name}.bsdf", valid_to_full(values.astype(np.float64), FULL_GRID), FULL_GRID,
                           source=f"builtin:{name}")

    folder = made_once("full-grid-exports", export)
    return {name: folder / f"{name}.bsdf" for name in names}
