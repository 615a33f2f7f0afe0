"""Map a requested file name to a file inside the session folder, or refuse it.

The server never serves a path outside the session: the URL path is percent-decoded exactly
once, and refused if it is empty, absolute, holds a ``..`` component, a backslash, a NUL or a
control character, or if the real path (every symlink resolved) is not strictly inside the
session folder's real path, or is not a regular file. Any OS error on the way (a name too long
for the file system, a loop of links, a permission) refuses it the same way; the refusal names
at most SHOWN_CHARS of what was asked (a 60000-character path is not echoed back).
"""
from __future__ import annotations

import os
from pathlib import Path, PurePosixPath
from urllib.parse import unquote


SHOWN_CHARS = 120


class UnsafePath(Exception):
    """A requested path that is not a file inside the session (the server answers 404)."""


def session_file(session_dir, requested: str) -> Path:
    """The real path of the file ``requested`` (as it appears in the URL, still percent-encoded)
    names inside ``session_dir``; raise UnsafePath otherwise."""
    try:
        name = unquote(requested, errors="strict")
    except UnicodeDecodeError:
        raise UnsafePath(f"refused path {shown(requested)}: not UTF-8") from None
    if not name or "\\" in name or any(ord(ch) < 32 for ch in name):
        raise UnsafePath(f"refused path {shown(requested)}")
    parts = PurePosixPath(name).parts
    if PurePosixPath(name).is_absolute() or ".." in parts or not parts:
        raise UnsafePath(f"refused path {shown(requested)}")
    return inside(session_dir, Path(session_dir).joinpath(*parts), requested)


def shown(text: str) -> str:
    """``text`` quoted for a message, cut to SHOWN_CHARS characters."""
    return repr(text) if len(text) <= SHOWN_CHARS else f"{text[:SHOWN_CHARS]!r}... ({len(text)} characters)"


def inside(session_dir, path, what: str = "") -> Path:
    """``path``'s real path if it is a regular file strictly inside ``session_dir``'s real path."""
    root = Path(os.path.realpath(session_dir))
    try:
        real = Path(os.path.realpath(path))
        is_file = real.is_file()
    except (OSError, ValueError) as exc:   # ENAMETOOLONG, ELOOP, EACCES...; ValueError: an embedded NUL
        raise UnsafePath(f"refused path {shown(what or str(path))}: {getattr(exc, 'strerror', None) or exc}") from None
    if root not in real.parents or not is_file:
        raise UnsafePath(f"refused path {shown(what or str(path))}: not a file inside {root}")
    return real
