"""The layers import downwards only (tests/import_layers.py), and the checker itself can fail."""
from __future__ import annotations

from pathlib import Path

import pytest

from import_layers import imports_of, module_graph, package_graph, violations

ROOT = Path(__file__).resolve().parents[1]


def test_the_project_keeps_its_layers():
    found = violations(ROOT)
    assert not found, "layer violations:\n" + "\n".join(map(str, found))


def test_the_graph_is_the_documented_one():
    graph = {here: set(targets) for here, targets in package_graph(ROOT).items()}
    assert "goniofrost.core" not in graph                       # the bottom imports nothing of the project
    for lower in ("planner", "drivers", "calib", "sim"):
        assert {t for t in graph.get(lower, ()) if t.startswith("goniofrost")} <= {"goniofrost.core"}
    assert graph["goniofrost.app"] >= {"goniofrost.capture", "goniofrost.frost", "goniofrost.bench"}
    # the rig sits below capture, and capture is handed the simulation rather than importing it
    assert "goniofrost.rig" in graph["goniofrost.capture"]
    assert {t for t in graph["goniofrost.rig"] if t.startswith("goniofrost")} == {"goniofrost.core"}
    assert not graph["goniofrost.capture"] & {"sim", "goniofrost.datasets"}
    # plans are made above frost, planner and the rig, and capture reads them from below
    assert "goniofrost.plan" in graph["goniofrost.capture"]
    assert {t for t in graph["goniofrost.plan"] if t.startswith("goniofrost")} == {
        "goniofrost.core", "goniofrost.rig", "goniofrost.frost"}


def _tree(tmp_path: Path, files: dict[str, str]) -> Path:
    """A synthetic project: the given modules, and empty __init__.py files for every package."""
    for rel, text in files.items():
        path = tmp_path / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    for package in ("goniofrost", "goniofrost/core", "goniofrost/app", "goniofrost/frost", "goniofrost/capture",
                    "goniofrost/rig", "goniofrost/plan", "goniofrost/datasets", "planner", "drivers", "calib", "sim"):
        (tmp_path / package).mkdir(parents=True, exist_ok=True)
        (tmp_path / package / "__init__.py").touch()
    return tmp_path


CLEAN = {
    "goniofrost/core/errors.py": "import numpy\n",
    "goniofrost/frost/model.py": "from goniofrost.core.errors import X\nfrom . import helpers\n",
    "goniofrost/frost/helpers.py": "",
    "goniofrost/capture/engine.py": "from ..frost.model import M\nimport planner.rig\nfrom goniofrost.rig import hardware\n",
    "goniofrost/rig/hardware.py": "from goniofrost.core.errors import X\nimport drivers.axis\n",
    "goniofrost/rig/simulated.py": "from .hardware import open_camera\nfrom sim.rig import SimulatedRig\n",
    "goniofrost/plan/make.py": "from goniofrost.frost.model import M\nfrom goniofrost.rig import file\nimport planner.reach\n",
    "goniofrost/capture/inputs.py": "from goniofrost.plan.file import read_plan\n",
    "goniofrost/app/cli.py": "from goniofrost.capture import engine\n",
    "goniofrost/__main__.py": "from goniofrost.app.cli import main\n",
    "planner/rig.py": "from goniofrost.core.errors import ConfigError\n",
    "sim/camera.py": "from drivers.camera import Camera\nfrom calib.holder import H\n",
}


def test_a_clean_synthetic_tree_passes(tmp_path):
    assert violations(_tree(tmp_path, CLEAN)) == []


@pytest.mark.parametrize("rel, text, module, imported, rule", [
    ("goniofrost/core/grid.py", "from goniofrost.frost import model\n", "goniofrost.core.grid",
     "goniofrost.frost", "the bottom layer imports nothing of the project"),
    ("goniofrost/core/cache.py", "def f():\n    import planner.rig\n", "goniofrost.core.cache",
     "planner", "the bottom layer imports nothing"),
    ("planner/reach.py", "from goniofrost.frost.model import M\n", "planner.reach",
     "goniofrost.frost", "planner may import only goniofrost.core"),
    ("sim/camera2.py", "from goniofrost.datasets import open_dataset\n", "sim.camera2",
     "goniofrost.datasets", "sim may import only goniofrost.core"),
    ("drivers/axis.py", "from sim.clock import SimClock\n", "drivers.axis",
     "sim", "drivers may import only no other lower package"),
    ("goniofrost/frost/loop.py", "from goniofrost.capture.engine import E\n", "goniofrost.frost.loop",
     "goniofrost.capture", "cycle: goniofrost.capture imports goniofrost.frost back"),
    ("goniofrost/frost/uses_app.py", "from goniofrost.app import cli\n", "goniofrost.frost.uses_app",
     "goniofrost.app", "nothing imports the application layer"),
    ("goniofrost/capture/rel.py", "from ..app.cli import main\n", "goniofrost.capture.rel",
     "goniofrost.app", "nothing imports the application layer"),
    ("goniofrost/rig/stop.py", "from goniofrost.capture.records import R\n", "goniofrost.rig.stop",
     "goniofrost.capture", "goniofrost.rig may import only goniofrost.core"),
    ("goniofrost/rig/file.py", "def f():\n    from goniofrost.datasets import specs\n", "goniofrost.rig.file",
     "goniofrost.datasets", "goniofrost.rig may import only goniofrost.core"),
    ("goniofrost/capture/hw.py", "def f():\n    from sim.rig import SimulatedRig\n", "goniofrost.capture.hw",
     "sim", "goniofrost.capture imports neither sim nor goniofrost.datasets"),
    ("goniofrost/capture/truth.py", "from ..datasets import material_brdf\n", "goniofrost.capture.truth",
     "goniofrost.datasets", "goniofrost.capture imports neither sim nor goniofrost.datasets"),
    ("goniofrost/plan/file.py", "def f():\n    from goniofrost.datasets import specs\n", "goniofrost.plan.file",
     "goniofrost.datasets", "goniofrost.plan may import only goniofrost.core, goniofrost.rig, goniofrost.frost"),
    ("goniofrost/plan/runs.py", "from ..capture.records import R\n", "goniofrost.plan.runs",
     "goniofrost.capture", "goniofrost.plan may import only"),
    ("goniofrost/flat.py", "", "goniofrost.flat", "-", "goniofrost/ holds sub-packages"),
])
def test_each_rule_catches_its_violation(tmp_path, rel, text, module, imported, rule):
    found = violations(_tree(tmp_path, {**CLEAN, rel: text}))
    assert [(v.module, v.imported) for v in found if rule in v.rule] == [(module, imported)], found


def test_relative_and_function_level_imports_are_resolved(tmp_path):
    root = _tree(tmp_path, {"goniofrost/capture/a.py": "from . import b\nfrom ..frost.model import M\n"
                                                          "def f():\n    from drivers import axis\n"})
    assert imports_of(root, root / "goniofrost/capture/a.py") == {
        "goniofrost.capture.b", "goniofrost.frost.model", "drivers"}


def test_an_import_cycle_between_modules_of_one_package_fails(tmp_path):
    # frost.model imports frost.helpers (CLEAN); helpers importing model back closes a circle
    # inside one package, which the package graph cannot see
    root = _tree(tmp_path, {**CLEAN, "goniofrost/frost/helpers.py": "def f():\n    from .model import M\n"})
    found = [(v.module, v.imported) for v in violations(root) if v.rule.startswith("module cycle")]
    assert found == [("goniofrost.frost.helpers", "goniofrost.frost.model"),
                     ("goniofrost.frost.model", "goniofrost.frost.helpers")]
    # through a third module, and through ``from package import module``
    root = _tree(tmp_path, {**CLEAN, "goniofrost/frost/helpers.py": "from goniofrost.frost import third\n",
                            "goniofrost/frost/third.py": "import goniofrost.frost.model\n"})
    found = {v.module for v in violations(root) if v.rule.startswith("module cycle")}
    assert found == {"goniofrost.frost.model", "goniofrost.frost.helpers", "goniofrost.frost.third"}


def test_a_package_that_re_exports_its_modules_is_no_cycle(tmp_path):
    # the package's __init__ imports its modules and they import each other downwards: no circle,
    # though every module is inside the package that imports it
    root = _tree(tmp_path, {**CLEAN, "goniofrost/frost/__init__.py": "from goniofrost.frost.model import M\n",
                            "goniofrost/frost/helpers.py": "from goniofrost.frost import other\n",
                            "goniofrost/frost/other.py": ""})
    assert violations(root) == []
    assert module_graph(root)["goniofrost.frost.helpers"] == {"goniofrost.frost.other"}


def test_the_plan_vocabulary_imports_no_journal():
    # steps.py (the pure plan vocabulary) reads its records from capture.records, not from the
    # SQLite journal that stores them
    graph = module_graph(ROOT)
    assert "goniofrost.capture.records" in graph["goniofrost.capture.steps"]
    assert "goniofrost.capture.journal" not in graph["goniofrost.capture.steps"]


def test_loading_a_rig_file_imports_nothing_of_capture():
    # plan, train and sim load rig files: goniofrost.rig does it without the capture package (nor the
    # datasets), in a fresh interpreter so that no other test's imports count
    import subprocess
    import sys

    code = ("import sys\nfrom goniofrost.rig.file import load_checked_rig\n"
            "load_checked_rig('config/rigs/sim.yaml')\n"
            "print(sorted(m for m in sys.modules if m.startswith(('goniofrost.capture', 'goniofrost.datasets'))))")
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert done.stdout == "[]\n", done.stdout + done.stderr
