"""Typed stage configurations: named presets, and saving / reloading the resolved config of a run.

Each stage defines one ``@dataclass`` whose fields all carry a comment, and a ``PRESETS`` mapping
from preset name (``tiny``, ``small``, ``paper``) to the field values that differ from the
defaults. :func:`preset` builds one; the CLI (tyro) is generated from the same dataclass, and every
run saves the resolved config beside its outputs with :func:`save_config`.
"""

from __future__ import annotations

import dataclasses
import json
import types
import typing
from pathlib import Path
from typing import Any, Literal, Mapping, Sequence, TypeVar

PresetName = Literal["tiny", "small", "paper"]
PRESET_NAMES: tuple[str, ...] = typing.get_args(PresetName)
T = TypeVar("T")


def preset(cls: type[T], name: str, **overrides: Any) -> T:
    """An instance of dataclass ``cls`` with preset ``name`` applied, then ``overrides``.

    ``cls.PRESETS`` maps preset names to dicts of field values (nested dataclass fields take
    nested dicts). A nested override is merged into the preset's group key by key:
    ``optim={"iterations": 600}`` on ``small`` keeps that preset's stage boundaries. Unknown preset
    names and unknown fields raise a ValueError that lists the valid ones.
    """
    presets: Mapping[str, Mapping[str, Any]] = getattr(cls, "PRESETS", {})
    if name not in PRESET_NAMES:
        raise ValueError(f"unknown preset {name!r}; choose one of {list(PRESET_NAMES)}")
    return from_dict(cls, merge(presets.get(name, {}), overrides), partial=True)


def merge(base: Mapping[str, Any], update: Mapping[str, Any]) -> dict[str, Any]:
    """``base`` updated by ``update``, nested dicts merged key by key."""
    out = dict(base)
    for key, value in update.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            out[key] = merge(out[key], value)
        else:
            out[key] = value
    return out


def to_dict(config: Any) -> dict:
    """A JSON-ready dict of a (nested) dataclass; Paths become strings and tuples lists."""

    def convert(value: Any) -> Any:
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            return {f.name: convert(getattr(value, f.name)) for f in dataclasses.fields(value)}
        if isinstance(value, Path):
            return str(value)
        if isinstance(value, (list, tuple)):
            return [convert(v) for v in value]
        if isinstance(value, dict):
            return {str(k): convert(v) for k, v in value.items()}
        return value

    return convert(config)


def _coerce(annotation: Any, value: Any) -> Any:
    if value is None:
        return None
    origin = typing.get_origin(annotation)
    args = typing.get_args(annotation)
    if origin in (typing.Union, types.UnionType):
        non_none = [a for a in args if a is not type(None)]
        return _coerce(non_none[0], value) if len(non_none) == 1 else value
    if dataclasses.is_dataclass(annotation) and isinstance(value, Mapping):
        return from_dict(annotation, value)
    if annotation is Path:
        return Path(value)
    if origin is tuple and isinstance(value, (list, tuple)):
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(args[0], v) for v in value)
        if args and len(args) != len(value):
            raise ValueError(f"expected {len(args)} values, got {len(value)}: {list(value)}")
        return tuple(_coerce(a, v) for a, v in zip(args, value, strict=True)) if args else tuple(value)
    if annotation is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    return value


def from_dict(cls: type[T], values: Mapping[str, Any], partial: bool = True) -> T:
    """Build dataclass ``cls`` from ``values``; nested dataclass fields may be given as dicts.

    With ``partial`` a nested dict updates the nested default instead of replacing it.
    """
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = set(values) - set(fields)
    if unknown:
        raise ValueError(f"{cls.__name__} has no field(s) {sorted(unknown)}; fields are {sorted(fields)}")
    kwargs = {}
    for name, value in values.items():
        annotation = hints[name]
        if partial and dataclasses.is_dataclass(annotation) and isinstance(value, Mapping):
            field = fields[name]
            default = field.default_factory() if field.default_factory is not dataclasses.MISSING else annotation()
            merged = to_dict(default)
            merged.update(value)
            kwargs[name] = from_dict(annotation, merged)
        else:
            try:
                kwargs[name] = _coerce(annotation, value)
            except ValueError as exc:
                raise ValueError(f"{cls.__name__}.{name}: {exc}") from None
    return cls(**kwargs)


def config_difference(saved: Mapping[str, Any], expected: Mapping[str, Any], ignore: Sequence[str] = (),
                      prefix: str = "") -> list[str]:
    """The dotted keys where two config dicts (:func:`radar4dgs.config.to_dict`) differ, as
    ``"optim.iterations: 20 != 1800"`` (saved first); top-level keys in ``ignore`` are skipped."""
    out = []
    for key in sorted(set(saved) | set(expected)):
        if not prefix and key in ignore:
            continue
        a, b = saved.get(key), expected.get(key)
        if isinstance(a, Mapping) and isinstance(b, Mapping):
            out += config_difference(a, b, prefix=f"{prefix}{key}.")
        elif a != b:
            out.append(f"{prefix}{key}: {a!r} != {b!r}")
    return out


def first_differences(lines: Sequence[str], limit: int = 3) -> str:
    """The first ``limit`` of :func:`config_difference`'s lines, and how many more: for a one-line
    refusal that says what differs."""
    more = f"; and {len(lines) - limit} more" if len(lines) > limit else ""
    return "; ".join(lines[:limit]) + more


def save_config(config: Any, path: str | Path) -> Path:
    """Save the resolved config as JSON (atomically), with its class name for reloading."""
    payload = {"class": f"{type(config).__module__}.{type(config).__qualname__}", "config": to_dict(config)}
    from radar4dgs.io.atomic import atomic_write_json  # numpy and PIL: not for `--help`

    return atomic_write_json(path, payload)


def read_config_dict(cls: type, path: str | Path) -> dict[str, Any]:
    """The config dict saved by :func:`save_config` as written (fields added to ``cls`` since
    are absent); refuses a file saved from another class."""
    path = Path(path)
    try:
        payload = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: cannot read config ({exc})") from exc
    expected = f"{cls.__module__}.{cls.__qualname__}"
    if payload.get("class") != expected:
        raise ValueError(f"{path}: holds a {payload.get('class')!r} config, expected {expected!r}")
    return payload["config"]


def load_config(cls: type[T], path: str | Path) -> T:
    """Reload a config saved by :func:`save_config` (absent fields take their defaults)."""
    return from_dict(cls, read_config_dict(cls, path), partial=False)
