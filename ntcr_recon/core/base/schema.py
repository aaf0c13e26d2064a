"""The configuration schema: each key declared once, on its dataclass field, with default, unit, range and text.

A configuration section is a frozen dataclass whose fields carry a `Setting` in their metadata::

    @dataclass(frozen=True)
    class FusionConfig:
        slop: float = setting(0.015, "stamps of a pair differ by at most this", unit="s", minimum=0, maximum=10,
                              exclusive_minimum=True)

The field's type annotation is the key's type; the Setting says the rest. From this one declaration come the
conversion and range check of a loaded value (`build_section`, `check_section`), the ROS parameter descriptors
(`ntcr_recon.ros.node_support`) and the comments of the documented configuration file (`config_file`).

Why stdlib dataclasses rather than pydantic: a rig installs its dependencies through rosdep/apt, and Ubuntu
24.04 (Jazzy's platform) ships pydantic 1.10 while PyPI installs give 2.x, whose APIs differ; the schema also
has to produce ROS descriptors, refuse values with messages that name the dotted key and cut the value to a
short excerpt, and keep the sections plain frozen dataclasses (hashable, `cached_property`) - a few dozen lines
over `dataclasses.field(metadata=...)` do all of that with no dependency.
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import math
import reprlib
import types
import typing
from collections.abc import Iterable, Mapping, Sized
from dataclasses import dataclass
from typing import Any

SETTING = "ntcr_setting"  # the dataclass field metadata key holding a Setting
MAX_LIST_ITEMS = 64       # a list of any length (camera_names) holds at most this many


class ConfigError(ValueError):
    """A configuration that cannot be used; the message names the dotted key."""


@dataclass(frozen=True)
class Setting:
    """What a configuration key means and which values it accepts (elementwise for a tuple)."""

    description: str
    unit: str = ""
    minimum: float | None = None
    maximum: float | None = None
    exclusive_minimum: bool = False
    exclusive_maximum: bool = False
    choices: tuple = ()
    off: float | None = None          # a value outside the range that switches the feature off (e.g. 0)
    required: bool = False            # a configuration file must give it (the default is only a placeholder)
    max_length: int = 256             # strings: longer is not a name, a serial number or a path

    def range_text(self) -> str:
        """E.g. `(0, 10] s`, `[1, 500]`, `'tube' | 'poisson'`, `0 (off) or [1e-05, 0.1] m`; '' when unbounded."""
        if self.choices:
            return " | ".join(_plain(choice) for choice in self.choices)
        if self.minimum is None and self.maximum is None:
            return ""
        low = "(-inf" if self.minimum is None else ("(" if self.exclusive_minimum else "[") + _plain(self.minimum)
        high = "inf)" if self.maximum is None else _plain(self.maximum) + (")" if self.exclusive_maximum else "]")
        text = f"{low}, {high}" + (f" {self.unit}" if self.unit else "")
        return f"{_plain(self.off)} (off) or {text}" if self.off is not None else text

    def admits(self, value) -> bool:
        """Whether a converted scalar lies in the range (or is one of the choices, or the `off` value)."""
        if self.choices:
            return value in self.choices
        if self.off is not None and value == self.off:
            return True
        if self.minimum is not None and (value < self.minimum or (self.exclusive_minimum and value == self.minimum)):
            return False
        return self.maximum is None or not (value > self.maximum or (self.exclusive_maximum
                                                                     and value == self.maximum))


def setting(default, description: str, **limits) -> Any:
    """A dataclass field with its default and its Setting (see Setting for the limits)."""
    return dataclasses.field(default=default, metadata={SETTING: Setting(description, **limits)})


@dataclass(frozen=True)
class Key:
    """One schema key: its field name, scalar type, tuple length (None: a scalar), nullability and Setting."""

    name: str
    scalar: type               # bool, int, float or str
    length: int | None         # a tuple's length (0: any), None for a scalar
    nullable: bool
    setting: Setting
    default: Any

    @property
    def type_name(self) -> str:
        if self.length is None:
            return self.scalar.__name__
        return f"list of {self.length or ''} {self.scalar.__name__}".replace("  ", " ")


@functools.cache
def keys_of(cls: type) -> dict[str, Key]:
    """The schema keys of a section dataclass, in declaration order (fields without a Setting are not keys)."""
    hints = typing.get_type_hints(cls)
    keys = {}
    for field in dataclasses.fields(cls):
        if SETTING not in field.metadata:
            continue
        scalar, length, nullable = _parse_annotation(hints[field.name])
        keys[field.name] = Key(field.name, scalar, length, nullable, field.metadata[SETTING], field.default)
    return keys


def _parse_annotation(annotation) -> tuple[type, int | None, bool]:
    """(scalar type, tuple length or None, nullable) of `float`, `float | None`, `tuple[float, float, float]`."""
    nullable = False
    if isinstance(annotation, types.UnionType) or typing.get_origin(annotation) is typing.Union:
        members = [a for a in typing.get_args(annotation) if a is not type(None)]
        nullable, annotation = len(members) < len(typing.get_args(annotation)), members[0]
    if typing.get_origin(annotation) is tuple:
        items = typing.get_args(annotation)
        return items[0], 0 if items[-1] is Ellipsis else len(items), nullable
    return annotation, None, nullable


# ---- values -----------------------------------------------------------------------------------------------------

_EXCERPT = reprlib.Repr()
_EXCERPT.maxstring, _EXCERPT.maxother, _EXCERPT.maxlist, _EXCERPT.maxtuple, _EXCERPT.maxdict = 48, 48, 6, 6, 4
_EXCERPT.maxlevel = 2


def excerpt(value: Any) -> str:
    """A short printable excerpt of any value: a refused 2 GB string must not become a 2 GB message."""
    try:
        text = _EXCERPT.repr(value)
    except ValueError:  # an int beyond Python's digit limit for str()
        return f"<an integer of {value.bit_length()} bits>"
    if isinstance(value, str | bytes) and len(value) > _EXCERPT.maxstring:
        return f"{text} ({len(value)} characters)"
    return text


def convert(dotted: str, key: Key, value: Any) -> Any:
    """`value` converted to the key's type and checked against its range; ConfigError naming `dotted`."""
    if value is None and key.nullable:
        return None
    if key.length is None:
        return _check_range(dotted, key, _scalar(dotted, key, value))
    if isinstance(value, str | bytes | Mapping) or not isinstance(value, Sized | Iterable):
        raise ConfigError(f"{dotted} must be a {key.type_name}, got {excerpt(value)}")
    # a list, a tuple or the array.array of a ROS array parameter; its size checked before it is copied
    items = list(value) if isinstance(value, Sized) and len(value) <= MAX_LIST_ITEMS else None
    if items is None or (len(items) != key.length if key.length else not items):
        what = "numbers" if key.scalar in (int, float) else "values"
        count = key.length or f"1 to {MAX_LIST_ITEMS}"
        raise ConfigError(f"{dotted} needs {count} {what}, got {excerpt(value)}")
    return tuple(_check_range(dotted, key, _scalar(dotted, key, item)) for item in items)


def _scalar(dotted: str, key: Key, value: Any) -> Any:
    kind = key.scalar
    if kind is bool:
        if isinstance(value, bool):
            return value
    elif kind is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        if isinstance(value, float) and math.isfinite(value) and value.is_integer():
            return int(value)  # 30.0 for 30, as ROS parameters may come
    elif kind is float:
        if isinstance(value, int | float) and not isinstance(value, bool):
            try:
                number = float(value)
            except OverflowError:  # an integer beyond the float range
                raise ConfigError(f"{dotted} must be a finite number, got {excerpt(value)}") from None
            if not math.isfinite(number):
                raise ConfigError(f"{dotted} must be a finite number, got {excerpt(value)}")
            return number
    elif kind is str:
        # D405 serial numbers are all digits: `-p cam_a.serial_number:=...` hands them over as integers
        if isinstance(value, int) and not isinstance(value, bool) and key.name == "serial_number" \
                and value.bit_length() < 1024:  # a longer one is no serial (and str() of it may be refused)
            value = str(value)
        if isinstance(value, str):
            if len(value) > key.setting.max_length:
                raise ConfigError(f"{dotted} must be at most {key.setting.max_length} characters, "
                                  f"got {excerpt(value)}")
            return value
    raise ConfigError(f"{dotted} must be of type {kind.__name__}, got {excerpt(value)}")


def _check_range(dotted: str, key: Key, value: Any) -> Any:
    s = key.setting
    if isinstance(value, bool) or not isinstance(value, int | float | str) or s.admits(value):
        return value
    if s.choices:
        raise ConfigError(f"{dotted} must be {' or '.join(repr(c) for c in s.choices)}, got {excerpt(value)}")
    if value <= 0 and s.minimum is not None and (s.minimum > 0 or (s.minimum == 0 and s.exclusive_minimum)):
        raise ConfigError(f"{dotted} must be > 0 (range {s.range_text()}), got {excerpt(value)}")
    raise ConfigError(f"{dotted} must lie in {s.range_text()}, got {excerpt(value)}")


# ---- sections ---------------------------------------------------------------------------------------------------

def unknown_key_error(parent: str, key: Any, known: Iterable[str]) -> ConfigError:
    """The refusal of an unknown key, suggesting the nearest known one (a typo such as `filter` for `filters`)."""
    known = sorted(str(k) for k in known)
    name = key if isinstance(key, str) and len(key) <= 64 else excerpt(key)
    nearest = difflib.get_close_matches(str(name), known, n=1)
    hint = f"; did you mean {nearest[0]!r}?" if nearest else f" (known: {', '.join(known)})"
    return ConfigError(f"unknown key {parent + '.' if parent else ''}{name}{hint}")


def build_section(cls: type, mapping: Any, prefix: str, **fixed):
    """An instance of section `cls` from a mapping of its keys (missing keys keep their defaults).

    Refuses a non-mapping, an unknown key (suggesting the nearest), a missing required key and any value
    outside its type or range, each naming `<prefix>.<key>`. `fixed`: fields that are not keys (a name).
    """
    if not isinstance(mapping, Mapping):
        raise ConfigError(f"{prefix} must be a mapping of keys, got {excerpt(mapping)}")
    keys = keys_of(cls)
    for name in mapping:
        if name not in keys:
            raise unknown_key_error(prefix, name, keys)
    for key in keys.values():
        if key.setting.required and mapping.get(key.name) is None:
            raise ConfigError(f"missing key {prefix}.{key.name}")
    values = {name: convert(f"{prefix}.{name}", keys[name], value) for name, value in mapping.items()}
    return cls(**fixed, **values)


def check_section(instance: Any, prefix: str) -> None:
    """Check every key's value of an existing section instance (built in code rather than loaded)."""
    for key in keys_of(type(instance)).values():
        convert(f"{prefix}.{key.name}", key, getattr(instance, key.name))


def section_mapping(instance: Any) -> dict[str, Any]:
    """The keys of a section instance as plain YAML values (tuples as lists)."""
    return {name: list(value) if isinstance(value := getattr(instance, name), tuple) else value
            for name in keys_of(type(instance))}


def _plain(value: Any) -> str:
    return repr(value) if isinstance(value, str) else f"{value:g}" if isinstance(value, float) else str(value)
