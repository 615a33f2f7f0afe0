"""Map a requested file name to a file inside the session folder, or refuse it.

The server never serves a path outside the session: the URL path is percent-decoded exactly
once, and refused if it is empty, absolute, holds a ``..`` component, a backslash, a NUL or a
control character, or if the real path (every symlink resolved) is not strictly inside the
session folder's real path, or is not a regular file.
"""
from __future__ import annotations

import os
from pathlib import Path, PurePosixPath
from urllib.parse import unquote


class UnsafePath(Exception):
    """A requested path that is not a file inside the session (the server answers 404)."""


def session_file(session_dir, requested: str) -> Path:
    """The real path of the file ``requested`` (as it appears in the URL, still percent-encoded)
    names inside ``session_dir``; raise UnsafePath otherwise."""
    try:
        name = unquote(requested, errors="strict")
    except UnicodeDecodeError:
        raise UnsafePath(f"refused path {requested!r}: not UTF-8") from None
    if not name or "\\" in name or any(ord(ch) < 32 for ch in name):
        raise UnsafePath(f"refused path {requested!r}")
    parts = PurePosixPath(name).parts
    if PurePosixPath(name).is_absolute() or ".." in parts or not parts:
        raise UnsafePath(f"refused path {requested!r}")
    return inside(session_dir, Path(session_dir).joinpath(*parts), requested)


def inside(session_dir, path, what: str = "") -> Path:
    """``path``'s real path if it is a regular file strictly inside ``session_dir``'s real path."""
    root = Path(os.path.realpath(session_dir))
    real = Path(os.path.realpath(path))
    if root not in real.parents or not real.is_file():
        raise UnsafePath(f"refused path {what or str(path)!r}: not a file inside {root}")
    return real
