"""Strict reading of a YAML configuration file: a key given twice in one mapping is an error.

A missing file or bad syntax raises ``ConfigError(source, "", expected, found)``; the keys and
values are then checked by the sections' key tables (``goniofrost.core.config_check``).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from goniofrost.core.errors import ConfigError


class _StrictLoader(yaml.SafeLoader):
    """A SafeLoader that refuses a key given twice in one mapping (PyYAML keeps the last silently)."""


def _construct_mapping(loader: _StrictLoader, node: yaml.MappingNode, deep: bool = False) -> dict:
    seen: dict = {}
    for key_node, value_node in node.value:
        key = loader.construct_object(key_node, deep=deep)
        if key in seen:
            raise yaml.constructor.ConstructorError(None, None, f"duplicate key {key}", key_node.start_mark)
        seen[key] = loader.construct_object(value_node, deep=deep)
    return seen


_StrictLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)


def read_yaml(path: str | Path) -> Any:
    """Parse a YAML file strictly; a missing file or bad syntax is a ConfigError naming the file."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(path, "", "a readable YAML file", exc.strerror or str(exc)) from exc
    try:
        return yaml.load(text, Loader=_StrictLoader)
    except yaml.YAMLError as exc:
        raise ConfigError(path, "", "valid YAML", _yaml_problem(exc)) from exc


def _yaml_problem(exc: yaml.YAMLError) -> str:
    """'PROBLEM at line L, column C' of a YAML error (one line, no parser internals)."""
    mark = getattr(exc, "problem_mark", None)
    problem = getattr(exc, "problem", None) or str(exc)
    where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
    return " ".join(f"{problem}{where}".split())
