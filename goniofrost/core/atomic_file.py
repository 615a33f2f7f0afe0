"""Write a file so that readers see either the old file or the whole new one, never a part.

A temporary sibling is written, fsynced and renamed over the target. Used for every result file.
"""
from __future__ import annotations

import errno
import os
import re
import tempfile
from contextlib import contextmanager
from pathlib import Path

from goniofrost.core.errors import GoniofrostError, OutputError

# errno -> what a user reads after "PATH: cannot write: "
REASONS = {
    errno.EISDIR: "it is a directory; give a file name",
    errno.ENOTDIR: "a part of the path is a file, not a directory",
    errno.EROFS: "the file system is read-only",
    errno.ENOSPC: "no space left on the device",
    errno.EDQUOT: "disk quota exceeded",
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
    errno.ENOENT: "a folder of the path does not exist and cannot be created",
    errno.EEXIST: "a part of the path is a file, not a directory",   # mkdir over a file
}


SHORT_WRITE = re.compile(r"\d+ requested and \d+ written")


@contextmanager
def output_errors(path):
    """Turn an OSError raised while writing ``path`` into a one-line ``OutputError`` naming it."""
    try:
        yield
    except OutputError:
        raise
    except OSError as exc:
        raise OutputError(path, reason_of(exc, path)) from exc


def reason_of(exc: OSError, path) -> str:
    """What a user reads after "PATH: cannot write: " for ``exc``. numpy's ``tofile`` reports a
    short write without an errno ("N requested and M written"): a full file system."""
    if exc.errno in REASONS:
        return REASONS[exc.errno]
    if exc.errno is None and SHORT_WRITE.fullmatch(str(exc)):
        return f"{REASONS[errno.ENOSPC]} ({exc})"
    return exc.strerror or str(exc)


def check_output_dir(path) -> None:
    """Raise ``OutputError`` now if the folder ``path`` could not be created or written later.

    Creates nothing: a command checks its output folder before long work, and bad input
    elsewhere must still leave no trace.
    """
    path = Path(path)
    with output_errors(path):
        existing = next(p for p in (path, *path.parents) if p.exists())
        if not existing.is_dir():
            raise NotADirectoryError(errno.ENOTDIR, os.strerror(errno.ENOTDIR), str(existing))
        if not os.access(existing, os.W_OK):
            code = errno.EROFS if os.statvfs(existing).f_flag & os.ST_RDONLY else errno.EACCES
            raise OSError(code, os.strerror(code), str(existing))


def check_output_file(path, directory: str = REASONS[errno.EISDIR]) -> None:
    """Raise ``OutputError`` now if the file ``path`` could not be written later: a directory in
    its place (``directory``: the reason then; a file name the user did not choose, such as a
    session's brdf.binary, needs other advice than "give a file name"), or a folder that could not
    be created or written (``check_output_dir``). Creates nothing: for commands that write their
    file after moving axes or minutes of work."""
    path = Path(path)
    if path.is_dir():
        raise OutputError(path, directory)
    check_output_dir(path.parent)


def check_output_suffix(out, suffix, why: str, option: str = "--out") -> None:
    """Raise ``GoniofrostError`` now unless the output name ``out`` ends in ``suffix`` (any case; a
    tuple: one of them): a command whose file format is fixed must not write it under a name that
    says another one (``export --out brdf.txt`` held an RGL tensor, ``plan --out plan.yaml`` JSON).
    ``why``: the format written, in the message's brackets."""
    suffixes = (suffix,) if isinstance(suffix, str) else tuple(suffix)
    if not str(out).lower().endswith(tuple(s.lower() for s in suffixes)):
        raise GoniofrostError(f"{option} {out}: expected a file name ending in {' or '.join(suffixes)} ({why})")


def check_output_folder_exists(out) -> None:
    """Raise ``OutputError`` now unless the folder of the output file ``out`` exists: for a
    command that should not make folders (``reconstruct --out /nonexistent/dir/x.binary`` made
    /nonexistent/dir)."""
    folder = Path(out).parent
    if not folder.is_dir():
        check_output_dir(folder)  # a file in the way says so first
        raise OutputError(folder, "no such folder; create it first")


def check_not_an_input(out, inputs: dict, option: str = "--out") -> None:
    """Raise ``OutputError`` now if the output ``out`` is one of the ``inputs`` (option -> path, a
    file or a folder such as a model) or lies inside one: writing it would destroy what was read."""
    out = Path(out).resolve()
    for name, path in inputs.items():
        if path is None:
            continue
        path = Path(path).resolve()
        if out == path or path in out.parents:
            raise OutputError(out, f"{option} would overwrite the input {name} {path}; give another name")


def write_bytes_atomic(path, payload: bytes) -> None:
    """Replace ``path`` with ``payload`` atomically (parent folders are created).

    Raises ``OutputError`` (nothing written, no temporary file left) when the path cannot be
    written: a directory in the way, a read-only or full file system, a file where a folder is
    expected.
    """
    write_buffers_atomic(path, [payload])


def write_buffers_atomic(path, buffers) -> None:
    """``write_bytes_atomic`` of the concatenation of ``buffers`` (bytes-like objects, e.g.
    numpy arrays' memoryviews, written in turn without joining them into one copy)."""
    path = Path(path)
    with output_errors(path):
        if path.is_dir():
            raise IsADirectoryError(errno.EISDIR, os.strerror(errno.EISDIR), str(path))
        path.parent.mkdir(parents=True, exist_ok=True)
        _write_via_temporary(path, buffers)


def _write_via_temporary(path: Path, buffers) -> None:
    """Write a temporary sibling, fsync it and rename it over ``path``; remove it on failure."""
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        # mkstemp creates the file 0600; give the result the usual permissions (umask applies)
        umask = os.umask(0)
        os.umask(umask)
        os.fchmod(fd, 0o666 & ~umask)
        with os.fdopen(fd, "wb") as handle:
            for buffer in buffers:
                handle.write(buffer)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


TEMPORARY_NAME = re.compile(r"\.(?P<name>.+)\.[A-Za-z0-9_]{8}")   # mkstemp(prefix=".NAME.")


def remove_stale_temporaries(folder) -> list:
    """Remove the temporaries of atomic writes into ``folder`` that a killed process left
    (``.NAME.XXXXXXXX``); call it only while no other process may write there (a held lock).
    Returns the names removed."""
    removed = []
    for p in Path(folder).iterdir():
        if TEMPORARY_NAME.fullmatch(p.name) and p.is_file():
            p.unlink(missing_ok=True)
            removed.append(p.name)
    return sorted(removed)


def write_text_atomic(path, text: str) -> None:
    """Replace ``path`` with UTF-8 ``text`` atomically."""
    write_bytes_atomic(path, text.encode("utf-8"))
