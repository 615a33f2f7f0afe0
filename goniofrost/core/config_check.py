"""Table-driven checking of one mapping of a configuration file (the rig file's sections).

A table maps each allowed key to ``(check, expected, default)``: ``check(value) -> bool``,
``expected`` says in words what a good value is, ``default`` is used when the key is absent
(``None``: the key is required unless listed in ``optional``). Every failure is one
ConfigError naming the file, the key path, what was expected and what was found.
"""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Callable, Mapping

from goniofrost.core.errors import ConfigError

KeyTable = Mapping[str, tuple[Callable[[object], bool], str, object]]


def is_number(value) -> bool:
    """True for a finite int or float (not a bool)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def check_section(section, keys: KeyTable, source, keypath: str, optional=frozenset()) -> dict:
    """Return a copy of ``section`` with defaults filled in; raise ConfigError on the first problem."""
    if not isinstance(section, dict):
        raise ConfigError(source, keypath, "a mapping", section)
    unknown = sorted(set(section) - set(keys))
    if unknown:
        raise ConfigError(source, f"{keypath}.{unknown[0]}", f"one of {sorted(keys)}", unknown[0])
    out = {}
    for key, (ok, expected, default) in keys.items():
        if key not in section and default is None and key not in optional:
            raise ConfigError(source, f"{keypath}.{key}", expected, "nothing")
        value = section.get(key, default)
        if not ok(value):
            raise ConfigError(source, f"{keypath}.{key}", expected, value)
        out[key] = value
    return out


def read_json_file(path, missing: str):
    """The parsed JSON document at ``path``; ConfigError naming the file when it is absent
    (``expected missing``) or not valid JSON."""
    path = Path(path)
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise ConfigError(path, "", missing, "no such file") from None
    except (OSError, ValueError) as exc:
        raise ConfigError(path, "", "valid JSON", str(exc)) from None
