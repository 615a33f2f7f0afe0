"""Strict reading of a YAML configuration file: a key given twice in one mapping is an error.

A missing file or bad syntax raises ``ConfigError``; the sections' key tables check the rest.
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

# A value tagged ``!fill-in`` is a template's example (an address, a port, a measured length): it is
# kept as a FillIn, which no key table accepts, and a rig file holding one is refused naming the keys.
FILL_IN_TAG = "!fill-in"


class FillIn:
    """A template's example value, still to be replaced by the rig's own (``example``)."""

    def __init__(self, example: Any) -> None:
        self.example = example

    def __repr__(self) -> str:
        return f"{FILL_IN_TAG} {self.example!r}"


def _construct_fill_in(loader: _StrictLoader, node: yaml.Node) -> FillIn:
    if isinstance(node, yaml.ScalarNode):
        return FillIn(loader.construct_scalar(node) if node.style else yaml.safe_load(node.value))
    return FillIn(loader.construct_sequence(node, deep=True) if isinstance(node, yaml.SequenceNode)
                  else loader.construct_mapping(node, deep=True))


_StrictLoader.add_constructor(FILL_IN_TAG, _construct_fill_in)


def keys_to_fill_in(raw: Any, keypath: str = "") -> list[str]:
    """The key paths (``axes.camera_arm.driver.host``) of every value tagged ``!fill-in`` in ``raw``."""
    if isinstance(raw, FillIn):
        return [keypath]
    if isinstance(raw, dict):
        return [k for key, value in raw.items() for k in keys_to_fill_in(value, f"{keypath}.{key}".lstrip("."))]
    if isinstance(raw, list):
        return [k for i, value in enumerate(raw) for k in keys_to_fill_in(value, f"{keypath}[{i}]")]
    return []


def check_filled_in(raw: Any, source: str) -> None:
    """ConfigError listing every key still tagged ``!fill-in`` (a template copied but not edited)."""
    keys = keys_to_fill_in(raw)
    if keys:
        raise ConfigError(source, "", f"this rig's own value for each key marked {FILL_IN_TAG} (the template's "
                                      f"example)", f"{len(keys)} keys to fill in: {', '.join(keys)}")


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
