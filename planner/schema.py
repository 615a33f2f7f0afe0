"""Strict reading of YAML configuration: duplicate and unknown keys are errors, every value checked.

Every failure raises ``ConfigError(source, keypath, expected, found)`` so the user sees the file,
the dotted key path (``axes.sample_tilt.limits_deg``), what was expected and what was found.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Iterable, Mapping

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


def join(keypath: str, key: str) -> str:
    """Dotted key path of ``key`` inside ``keypath``."""
    return f"{keypath}.{key}" if keypath else str(key)


def mapping(value: Any, source: str, keypath: str) -> Mapping:
    """``value`` if it is a mapping with string keys, else a ConfigError."""
    if not isinstance(value, Mapping):
        raise ConfigError(source, keypath, "a mapping (key: value lines)", value)
    for key in value:
        if not isinstance(key, str):
            raise ConfigError(source, join(keypath, str(key)), "a text key", key)
    return value


def check_keys(value: Mapping, source: str, keypath: str, required: Iterable[str],
               optional: Iterable[str] = ()) -> None:
    """Refuse unknown keys and report the first missing required key."""
    required, optional = list(required), list(optional)
    allowed = required + optional
    for key in value:
        if key not in allowed:
            raise ConfigError(source, join(keypath, key), f"one of the keys {', '.join(allowed)}",
                              f"unknown key {key!r}")
    for key in required:
        if key not in value:
            raise ConfigError(source, join(keypath, key), "this key to be present", "nothing")


def number(value: Any, source: str, keypath: str, *, low: float = -math.inf, high: float = math.inf,
           low_open: bool = False, high_open: bool = False) -> float:
    """A finite real number within [low, high] (open ends on request), as float."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ConfigError(source, keypath, "a finite number", value)
    below = value <= low if low_open else value < low
    above = value >= high if high_open else value > high
    if below or above:
        lo, hi = ("(" if low_open else "["), (")" if high_open else "]")
        raise ConfigError(source, keypath, f"a number in {lo}{_fmt(low)}, {_fmt(high)}{hi}", value)
    return float(value)


def numbers(value: Any, source: str, keypath: str, length: int) -> tuple[float, ...]:
    """A list of exactly ``length`` finite numbers."""
    if not isinstance(value, (list, tuple)) or len(value) != length:
        raise ConfigError(source, keypath, f"a list of {length} numbers", value)
    return tuple(number(v, source, f"{keypath}[{i}]") for i, v in enumerate(value))


def text(value: Any, source: str, keypath: str) -> str:
    """A non-empty string."""
    if not isinstance(value, str) or not value.strip():
        raise ConfigError(source, keypath, "a non-empty text", value)
    return value


def boolean(value: Any, source: str, keypath: str) -> bool:
    """true or false."""
    if not isinstance(value, bool):
        raise ConfigError(source, keypath, "true or false", value)
    return value


def choice(value: Any, source: str, keypath: str, allowed: Iterable[str]) -> str:
    """One of the allowed strings."""
    allowed = list(allowed)
    if value not in allowed:
        raise ConfigError(source, keypath, f"one of {', '.join(allowed)}", value)
    return value


def _fmt(x: float) -> str:
    return "inf" if x == math.inf else "-inf" if x == -math.inf else f"{x:g}"
