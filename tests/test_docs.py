"""The docs site: it builds with warnings as errors and nitpicky, its command and key references
cover every command, option and key, and every tutorial block runs (tests/docs_runner.py)."""
from __future__ import annotations

import html
import importlib
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import SHARED_DATA, made_once
from docs_runner import REPO, TUTORIALS, blocks, run_page, runnable

DOCS = REPO / "docs"
# The model the tutorials train (the same command on every page that needs one): trained once per
# test run into the tutorials' shared cache, so that every page's `goniofrost train` reads it back.
TUTORIAL_TRAIN = ["train", "--dataset", "builtin-random:1:20", "--components", "8", "--grid", "30,30,60",
                  "--rig", "config/rigs/sim.yaml", "--out", "model"]
PAGES = sorted(TUTORIALS.glob("[0-9]*.md"))


@pytest.fixture(scope="module")
def built_site():
    """The site built once with -W -n into the test run's folder: its HTML folder."""
    pytest.importorskip("sphinx", reason="sphinx is not installed (pip install -e '.[docs]')")
    pytest.importorskip("myst_parser", reason="myst-parser is not installed (pip install -e '.[docs]')")

    def build(folder: Path) -> None:
        proc = subprocess.run([sys.executable, "-m", "sphinx", "-W", "-n", "-q", "-b", "html",
                               "-d", str(folder / "doctrees"), str(DOCS), str(folder / "html")],
                              capture_output=True, text=True, timeout=600, cwd=REPO)
        assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-6000:]

    return made_once("docs-site", build) / "html"


def test_the_site_builds_with_warnings_as_errors(built_site):
    assert (built_site / "index.html").is_file()
    for section in ("tutorials", "how-to", "reference", "explanations", "benchmarks", "decisions"):
        assert (built_site / section / "index.html").is_file(), section


def _text_of(markup: str) -> str:
    return html.unescape(re.sub(r"<[^>]+>", " ", markup))


def _text(page: Path) -> str:
    return _text_of(page.read_text())


def command_parsers(parser, path=("goniofrost",)):
    """(path, parser) of every command and sub-command under ``parser`` (``rig check`` included)."""
    import argparse

    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield (*path, name), sub
                yield from command_parsers(sub, (*path, name))


def test_the_command_reference_documents_every_command_and_option(built_site):
    """Each command has its section, and each of its options and positional arguments is named in
    it (the sections are in the order of the parser, so a section ends where the next begins)."""
    from goniofrost.app.cli import build_parser

    page = (built_site / "reference" / "commands.html").read_text()
    commands = list(command_parsers(build_parser()))
    starts = {path: page.find(f'id="{"-".join(path)}"') for path, _ in commands}
    missing = [" ".join(path) for path, start in starts.items() if start < 0]
    assert not missing and len(commands) >= 25, missing
    ends = sorted(starts.values()) + [len(page)]
    for path, parser in commands:
        start = starts[path]
        section = _text_of(page[start:ends[ends.index(start) + 1]])
        for action in parser._actions:
            names = [s for s in action.option_strings if s not in ("-h", "--help")] if action.option_strings \
                else [] if action.dest == "help" else [action.metavar or action.dest]
            missing += [f"{' '.join(path)} {n}" for n in names
                        if not re.search(rf"(?<![\w-]){re.escape(str(n))}(?![\w-])", section)]
    assert not missing, missing


def key_table_modules() -> dict[str, list]:
    """module name -> its key tables, for every module of the project that defines one."""
    sys.path.insert(0, str(DOCS / "_ext"))
    from goniofrost_docs import key_tables

    found = {}
    for package in ("goniofrost", "planner", "drivers", "calib", "sim"):
        for path in sorted((REPO / package).rglob("*.py")):
            source = path.read_text()
            if "Key(" not in source or "config_check" not in source:
                continue
            name = ".".join(path.relative_to(REPO).with_suffix("").parts)
            tables = key_tables(importlib.import_module(name))
            if tables:
                found[name] = tables
    return found


def test_the_key_reference_lists_every_key_of_every_key_table(built_site):
    page = (DOCS / "reference" / "config-keys.md").read_text()
    listed = set(re.findall(r"^```\{keytables\} (\S+)", page, re.M))
    modules = key_table_modules()
    assert set(modules) - listed == set() and {"planner.rig", "goniofrost.capture.queue_file"} <= listed
    text = _text(built_site / "reference" / "config-keys.html")
    missing = [f"{module}.{name}: {key}" for module, tables in modules.items() for name, keys in tables
               for key in keys if not re.search(rf"(?<![\w.]){re.escape(key)}(?![\w])", text)
               or f"{module}.{name}" not in text]
    assert not missing, missing


def test_every_tutorial_block_is_runnable_or_says_why_not():
    assert PAGES, "no tutorials"
    for page in PAGES:
        for block in blocks(page):
            if block.language in ("bash", "sh", "console", "shell"):
                assert block.language == "bash", f"{page.name}:{block.line}: shell blocks are ```bash"
            assert set(block.classes) <= {"real-rig", "full-size"}, f"{page.name}:{block.line}: {block.classes}"
    assert sum(len(runnable(page)) for page in PAGES) >= 20


@pytest.fixture(scope="module")
def tutorial_cache():
    """The tutorials' goniofrost cache, holding the model TUTORIAL_TRAIN trains (once per run)."""
    def make(folder: Path) -> None:
        folder.mkdir()
        env = {**os.environ, "GONIOFROST_CACHE": str(folder / "cache"), "PYTHONPATH": str(REPO)}
        proc = subprocess.run([sys.executable, "-m", "goniofrost", *TUTORIAL_TRAIN[:-1], str(folder / "model")],
                              cwd=REPO, env=env, capture_output=True, text=True, timeout=900)
        assert proc.returncode == 0, proc.stderr

    return made_once("docs-tutorial-cache", make) / "cache"


@pytest.mark.parametrize("page", PAGES, ids=[p.stem for p in PAGES])
def test_the_tutorial_runs_as_written(page, tutorial_cache, tmp_path):
    text = page.read_text()
    if "../shared" in text and not (SHARED_DATA / "nbrdf_merl.npz").is_file():
        pytest.skip(f"the tutorial reads ../shared/data, not found at {SHARED_DATA}")
    if not runnable(page):
        pytest.skip("every block of this tutorial is full-size or needs a real rig")
    if " ".join(TUTORIAL_TRAIN[:2]) in text:
        assert f"goniofrost {' '.join(TUTORIAL_TRAIN)}" in text, "the tutorials train the one shared model"
    env = {**os.environ, "GONIOFROST_CACHE": str(tutorial_cache)}
    status, output, line = run_page(page, tmp_path, env, SHARED_DATA)
    assert status == 0, f"{page.name}: the block at line {line} failed:\n{output[-4000:]}"


FULL_SIZE_PAGES = [p for p in PAGES if any("full-size" in b.classes for b in blocks(p))
                   and not any(b.text.startswith("./dev") for b in runnable(p, full_size=True))]


@pytest.mark.slow
@pytest.mark.parametrize("page", FULL_SIZE_PAGES, ids=[p.stem for p in FULL_SIZE_PAGES])
def test_the_tutorial_runs_at_full_size(page, tmp_path):
    """Every block, the full-size ones too (minutes: a model of the measured databases). The
    demo's page is left out: ./dev sets up the checkout it runs in, and tests/test_demo.py runs the
    demo at full size."""
    if "../shared" in page.read_text() and not (SHARED_DATA / "nbrdf_merl.npz").is_file():
        pytest.skip(f"the tutorial reads ../shared/data, not found at {SHARED_DATA}")
    env = {**os.environ, "GONIOFROST_CACHE": str(tmp_path / "cache")}
    status, output, line = run_page(page, tmp_path / "run", env, SHARED_DATA, full_size=True, timeout=3600)
    assert status == 0, f"{page.name}: the block at line {line} failed:\n{output[-4000:]}"
