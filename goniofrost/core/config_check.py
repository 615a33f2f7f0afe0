"""The one configuration mechanism: a key table per section, checked by ``check_section``.

Each owner package declares its sections as key tables::

    KEYS = {"seed": Key(is_natural, "an integer >= 0", default=0),       # optional, with a default
            "camera": Key(is_mapping, "a mapping", nested=check_camera),  # required, own keys checked
            "folder": Key(is_text, "a folder path", default=ABSENT)}     # optional, stays out

Every failure is one ``ConfigError(source, keypath, expected, found)``, read
``SOURCE: KEY.PATH: expected EXPECTED, found FOUND`` (an unknown key, a missing key, a section
that is not a mapping, a bad value).
"""
from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from goniofrost.core.errors import ConfigError


class _Marker:
    def __init__(self, name: str) -> None:
        self.name = name

    def __repr__(self) -> str:
        return self.name


REQUIRED = _Marker("REQUIRED")  # the key must be given
ABSENT = _Marker("ABSENT")      # the key may be left out and then stays out of the checked section

# nested(value, source, keypath) -> the value with its own content checked (and completed)
Nested = Callable[[Any, str, str], Any]


@dataclass(frozen=True)
class Key:
    """One key of a section: ``check(value) -> bool``, what a good value is in words, its default
    (``REQUIRED``, ``ABSENT`` or the value used when the key is left out) and an optional
    validator of the value's own content (``nested``), run after ``check``."""

    check: Callable[[Any], bool]
    expected: str
    default: Any = REQUIRED
    nested: Nested | None = None


KeyTable = Mapping[str, Key]


def join(keypath: str, key) -> str:
    """Dotted key path of ``key`` inside ``keypath`` ("" is the top level)."""
    return f"{keypath}.{key}" if keypath else str(key)


def check_section(section, keys: KeyTable, source, keypath: str, *, open_keys: bool = False,
                  context: str = "") -> dict:
    """A copy of the mapping ``section`` with defaults filled in and nested sections checked.

    Raises ConfigError on the first problem, in the module's forms. ``open_keys``: keys the table
    does not know are kept as given (a document other layers extend, such as PLAN.json);
    ``context`` is added to the list of allowed keys (e.g. "(protocol smc100)").
    """
    if not isinstance(section, Mapping):
        raise ConfigError(source, keypath, "a mapping", section)
    out = {key: value for key, value in section.items() if open_keys and key not in keys}
    for key in section:
        if not isinstance(key, str):
            raise ConfigError(source, join(keypath, key), "a text key", key)
        if key not in keys and not open_keys:
            raise ConfigError(source, join(keypath, key),
                              " ".join(filter(None, (f"one of the keys {', '.join(keys)}", context))),
                              f"unknown key {key!r}")
    for key, spec in keys.items():
        if key not in section and spec.default is REQUIRED:
            raise ConfigError(source, join(keypath, key), spec.expected, "nothing")
        if key not in section and spec.default is ABSENT:
            continue
        value = section.get(key, spec.default)
        if not spec.check(value):
            raise ConfigError(source, join(keypath, key), spec.expected, value)
        out[key] = spec.nested(value, source, join(keypath, key)) if spec.nested else value
    return out


def check_items(items, keys: KeyTable, source, keypath: str) -> list[dict]:
    """``check_section`` of each mapping of the list ``items`` (key paths ``keypath[i]``)."""
    return [check_section(item, keys, source, f"{keypath}[{i}]") for i, item in enumerate(items)]


# ----- checks shared by the key tables ------------------------------------------------------------
def is_number(value) -> bool:
    """True for a finite int or float (not a bool)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def is_int(value) -> bool:
    """True for an int (not a bool)."""
    return isinstance(value, int) and not isinstance(value, bool)


def is_natural(value) -> bool:
    """True for an int >= 0 (not a bool)."""
    return is_int(value) and value >= 0


def is_text(value) -> bool:
    """True for a string that is not blank."""
    return isinstance(value, str) and value.strip() != ""


def is_bool(value) -> bool:
    """True for true or false."""
    return isinstance(value, bool)


def is_mapping(value) -> bool:
    """True for a mapping."""
    return isinstance(value, Mapping)


def is_list(value) -> bool:
    """True for a list."""
    return isinstance(value, list)


def int_in(low: int, high: int) -> Callable[[Any], bool]:
    """The check of an int in [low, high]."""
    return lambda value: is_int(value) and low <= value <= high


def one_of(*values) -> Callable[[Any], bool]:
    """The check of a value among ``values``."""
    return lambda value: value in values


def numbers(length: int, each: Callable[[Any], bool] = is_number) -> Callable[[Any], bool]:
    """The check of a list of exactly ``length`` finite numbers, each passing ``each``."""
    return lambda value: (isinstance(value, (list, tuple)) and len(value) == length
                          and all(is_number(v) and each(v) for v in value))


def number_in(low: float = -math.inf, high: float = math.inf, *, low_open: bool = False,
              high_open: bool = False) -> Key:
    """A required key holding a finite number in [low, high] (open ends on request); its expected
    text reads "a number in (0, inf)"."""
    def check(value) -> bool:
        if not is_number(value):
            return False
        return (value > low if low_open else value >= low) and (value < high if high_open else value <= high)
    brackets = ("(" if low_open else "[", ")" if high_open else "]")
    return Key(check, f"a number in {brackets[0]}{_fmt(low)}, {_fmt(high)}{brackets[1]}")


def _fmt(x: float) -> str:
    return "inf" if x == math.inf else "-inf" if x == -math.inf else f"{x:g}"


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
