"""Runs the shell and Python blocks of a tutorial page (docs/tutorials/*.md) as a reader would.

A page's ```` ```bash ```` and ```` ```python ```` blocks run in order in one bash process (so a
background job of one block can be stopped by a later one), in a fresh folder laid out like a
checkout: ``config`` is the repository's, ``../shared`` the measured-material data when it is at
hand. ``goniofrost`` and ``python`` are the running interpreter's. A block preceded by the
attribute line ``{.real-rig}`` needs a real rig and never runs; ``{.full-size}`` marks a block
that runs at full size (minutes), run only when ``full_size`` is asked for.
"""
from __future__ import annotations

import os
import re
import shlex
import signal
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
TUTORIALS = REPO / "docs" / "tutorials"
RUN_LANGUAGES = ("bash", "python")
SKIP_CLASSES = {"real-rig": "needs a real rig", "full-size": "runs at full size"}
_FENCE = re.compile(r"^```(\w*)\s*$")
_MARK = "### docs-runner block "


@dataclass(frozen=True)
class Block:
    line: int          # 1-based line of the opening fence
    language: str
    text: str
    classes: tuple[str, ...]


def blocks(page: Path) -> list[Block]:
    """Every fenced block of ``page`` with its language and the classes of a ``{.name}`` line just
    above it."""
    found, lines, i = [], page.read_text().splitlines(), 0
    while i < len(lines):
        match = _FENCE.match(lines[i])
        if not match or not match.group(1):
            i += 1
            continue
        above = lines[i - 1].strip() if i else ""
        classes = tuple(re.findall(r"\.([\w-]+)", above)) if above.startswith("{") else ()
        end = next(j for j in range(i + 1, len(lines)) if lines[j].startswith("```"))
        found.append(Block(i + 1, match.group(1), "\n".join(lines[i + 1:end]) + "\n", classes))
        i = end + 1
    return found


def runnable(page: Path, full_size: bool = False) -> list[Block]:
    """The blocks of ``page`` that run: bash and python, not a real rig's, full-size ones only
    when ``full_size``."""
    return [b for b in blocks(page) if b.language in RUN_LANGUAGES and "real-rig" not in b.classes
            and (full_size or "full-size" not in b.classes)]


def script(page: Path, run: list[Block]) -> str:
    """One bash script of the blocks ``run``: a marker on stderr before each, every one under
    ``set -euo pipefail``; a python block runs through ``python``."""
    parts = ["set -euo pipefail"]
    for block in run:
        parts.append(f"echo {shlex.quote(f'{_MARK}{block.line}')} >&2")
        if block.language == "python":
            parts.append(f"python - <<'GONIOFROST_DOCS_PY'\n{block.text}GONIOFROST_DOCS_PY")
        else:
            parts.append(block.text)
    return "\n".join(parts) + "\n"


def workspace(folder: Path, shared_data: Path | None) -> Path:
    """A folder laid out like a checkout beside ../shared: ``folder/goniofrost`` (returned) with the
    repository's ``config``, ``folder/shared/data`` the measured materials (when given) and
    ``folder/bin`` with ``goniofrost`` and ``python``."""
    work = folder / "goniofrost"
    work.mkdir(parents=True)
    (work / "config").symlink_to(REPO / "config")
    if shared_data is not None:
        (folder / "shared").mkdir()
        (folder / "shared" / "data").symlink_to(shared_data)
    bin_dir = folder / "bin"
    bin_dir.mkdir()
    for name, command in (("goniofrost", f"{shlex.quote(sys.executable)} -m goniofrost"),
                          ("python", shlex.quote(sys.executable))):
        (bin_dir / name).write_text(f'#!/bin/sh\nexec {command} "$@"\n')
        (bin_dir / name).chmod(0o755)
    return work


def run_page(page: Path, folder: Path, env: dict, shared_data: Path | None = None,
             full_size: bool = False, timeout: float = 600) -> tuple[int, str, int | None]:
    """Run ``page``'s blocks in a new workspace under ``folder``: (exit status, output, line of the
    block that failed or None). The whole process group is ended afterwards (a background job a
    failed page left running included)."""
    work = workspace(folder, shared_data)
    env = {**env, "PATH": f"{folder / 'bin'}{os.pathsep}{env.get('PATH', '')}",
           "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), env.get("PYTHONPATH", "")]))}
    proc = subprocess.Popen(["bash", "-c", script(page, runnable(page, full_size))], cwd=work, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        output, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        output, _ = proc.communicate()
        output += f"\n(timed out after {timeout} s)"
    finally:
        try:
            os.killpg(proc.pid, signal.SIGTERM)
        except ProcessLookupError:
            pass
    marks = [int(m) for m in re.findall(rf"^{_MARK}(\d+)$", output, re.M)]
    status = proc.returncode if proc.returncode is not None else -1
    return status, output, (marks[-1] if marks and status != 0 else None)
