"""On-disk cache of computed arrays, keyed by a content hash of their inputs.

In ``$GONIOFROST_CACHE``, else ``$XDG_CACHE_HOME/goniofrost`` (``~/.cache/goniofrost``). Entries
are written atomically; deleting the folder is always safe.
"""
from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path


def cache_dir() -> Path:
    """The cache folder (created on first use)."""
    env = os.environ.get("GONIOFROST_CACHE")
    if env:
        root = Path(env)
    else:
        base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
        root = Path(base) / "goniofrost"
    root.mkdir(parents=True, exist_ok=True)
    return root


def content_key(*parts) -> str:
    """A hex SHA-256 of JSON-serialisable parts (order matters)."""
    blob = json.dumps(parts, sort_keys=True, default=str).encode()
    return hashlib.sha256(blob).hexdigest()


def cache_path(kind: str, key: str, suffix: str) -> Path:
    """Path of the cache entry ``kind/key + suffix`` (its folder is created)."""
    folder = cache_dir() / kind
    folder.mkdir(parents=True, exist_ok=True)
    return folder / f"{key}{suffix}"


def atomic_replace(tmp: Path, final: Path) -> None:
    """Move a fully written temporary file into place."""
    os.replace(tmp, final)
