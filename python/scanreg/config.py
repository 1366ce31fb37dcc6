"""Configuration files: TOML (or a dict) → a frozen dataclass, strictly.

Works for any (possibly nested) dataclass — :class:`~scanreg.RegistrationSettings`,
:class:`~scanreg.pipeline.odometry2d.OdometryConfig2D`, an odometry config: the field types
say what is accepted.

* A key the dataclass does not have is an error naming the key, its table and the valid keys
  (a typo must fail, not be ignored) — in nested tables too.
* Values are type-checked against the field annotations: ``int``, ``float`` (an int is
  accepted and converted), ``bool``, ``str``, ``Literal[...]``, ``tuple[X, ...]`` /
  ``tuple[X, Y]`` (TOML arrays), ``X | None`` and nested dataclasses (TOML tables). The
  dataclass's own validation (``__post_init__``) then runs, and its errors are prefixed
  with the table.
* Missing keys keep the dataclass defaults. TOML has no null: a field whose default is not
  None can be set to None only from a dict.

Layers, lowest first: the dataclass defaults, then each named preset (:data:`PRESETS`,
partial configs kept as data), then the file or dict, then ``overrides`` (e.g. command-line
flags)::

    cfg = load_config(OdometryConfig, "run.toml", presets=["velodyne-hdl64"])
    Path("out/config.toml").write_text(dump_config(cfg))   # the effective config

:func:`dump_config` writes TOML that :func:`load_config` reads back to an equal object.
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import json
import math
import os
import sys
import types
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, BinaryIO, Literal, TypeVar, Union, get_args, get_origin, get_type_hints

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

T = TypeVar("T")


class ConfigError(ValueError):
    """A configuration is invalid: unknown key, wrong type, bad value. The message starts with
    where (the file, or ``config``) and the table."""


#: Named partial configurations, merged under the user's values (see :func:`load_config`).
#: Sensor presets hold the sensor-dependent fields of an odometry config: ranges in metres
#: (points outside ``[min_range, max_range]`` are dropped) and the map ``voxel_size`` (m).
#: Extend here; every key must be a field of the config class the preset is applied to.
PRESETS: dict[str, dict[str, Any]] = {
    # Velodyne HDL-64E (KITTI): 120 m range, the car's roof hides the first ~3 m.
    "velodyne-hdl64": {"max_range": 100.0, "min_range": 3.0, "voxel_size": 1.0},
    # Ouster OS1-64: 120 m nominal, dense near field.
    "ouster-os1-64": {"max_range": 100.0, "min_range": 1.0, "voxel_size": 0.5},
    # Livox Avia: non-repetitive pattern, 70.4°x77.2° field of view, long range.
    "livox-avia": {"max_range": 200.0, "min_range": 1.0, "voxel_size": 0.5},
    # A 2D SICK LMS-class laser (indoor/outdoor, 80 m).
    "sick-2d": {"max_range": 80.0, "min_range": 0.1, "voxel_size": 0.05},
}


def preset(name: str, table: Mapping[str, Mapping[str, Any]] | None = None) -> dict[str, Any]:
    """A copy of preset ``name`` of ``table`` (default :data:`PRESETS`)."""
    table = PRESETS if table is None else table
    if name not in table:
        raise ConfigError(f"preset: unknown {name!r} (known: {', '.join(sorted(table))})")
    return merge_config({}, table[name])


def merge_config(base: Mapping[str, Any], update: Mapping[str, Any]) -> dict[str, Any]:
    """``base`` updated by ``update``, tables merged key by key (neither input is changed)."""
    out: dict[str, Any] = {}
    for key, value in base.items():
        out[key] = merge_config({}, value) if isinstance(value, Mapping) else value
    for key, value in update.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            out[key] = merge_config(out[key], value)
        elif isinstance(value, Mapping):
            out[key] = merge_config({}, value)
        else:
            out[key] = value
    return out


#: Largest config file read: a config is a few kB; ``/dev/zero`` would be read forever.
MAX_CONFIG_BYTES = 1 << 24
#: TOML integers are 64-bit (the TOML spec); Python's parser reads any size.
_INT64 = (-(2**63), 2**63 - 1)


def _read_at_most(fh: BinaryIO, limit: int) -> bytes:
    """Up to ``limit`` bytes of ``fh``. Not ``fh.read(limit)``: that reserves ``limit`` bytes
    first (16 MB per config read, a fifth of a batch manifest check). Read by the file's
    size, then in steps for a file whose size says nothing (``/dev/zero``, a pipe)."""
    want = min(os.fstat(fh.fileno()).st_size + 1, limit)
    chunks, left = [], limit
    while left > 0:
        ask = min(want, left)
        chunk = fh.read(ask)
        chunks.append(chunk)
        left -= len(chunk)
        if len(chunk) < ask:
            break  # end of file
        want = 1 << 16
    return b"".join(chunks)


def read_config_file(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The tables of a TOML file as a dict (errors name the file and the line)."""
    p = Path(path)
    with p.open("rb") as fh:
        raw = _read_at_most(fh, MAX_CONFIG_BYTES + 1)
    if len(raw) > MAX_CONFIG_BYTES:
        raise ConfigError(f"{p}: larger than {MAX_CONFIG_BYTES} bytes: not a config file")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise ConfigError(f"{p}: not a text file (invalid UTF-8)") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{p}: not valid TOML: {exc}") from None
    except RecursionError:  # tomllib recurses per nested array or inline table
        raise ConfigError(f"{p}: arrays or tables nested too deeply") from None


def _config_fields(cls: type) -> Mapping[str, Any]:
    """``{name: resolved annotation}`` of the fields settable by ``__init__`` (shared: read
    only)."""
    return _resolved_fields(cls)


@functools.cache
def _resolved_fields(cls: type) -> dict[str, Any]:
    # resolving string annotations compiles each one: half the time of a config load
    hints = get_type_hints(cls)
    return {f.name: hints[f.name] for f in dataclasses.fields(cls) if f.init}


def _table_name(table: str) -> str:
    return f"[{table}]" if table else "the top level"


def _type_name(tp: Any) -> str:
    if get_origin(tp) is Literal:
        return " | ".join(repr(a) for a in get_args(tp))
    if isinstance(tp, type):
        return tp.__name__
    return str(tp).replace("typing.", "")


def _is_union(tp: Any) -> bool:
    return get_origin(tp) in (Union, types.UnionType)


@functools.lru_cache(maxsize=1024)
def _shape_cached(tp: Any) -> tuple[Any, ...]:
    return _shape_of(tp)


def _shape(tp: Any) -> tuple[Any, ...]:
    """What annotation ``tp`` accepts, as ``(kind, details)``: worked out once per annotation
    (``get_origin``/``is_dataclass`` on every value were a third of a config load)."""
    try:
        return _shape_cached(tp)
    except TypeError:  # an unhashable annotation: not cached
        return _shape_of(tp)


def _shape_of(tp: Any) -> tuple[Any, ...]:
    if tp is Any:
        return ("any",)
    if dataclasses.is_dataclass(tp) and isinstance(tp, type):
        return ("dataclass",)
    if _is_union(tp):
        return ("union", get_args(tp))
    origin = get_origin(tp)
    if origin is Literal:
        return ("literal", get_args(tp))
    if origin is tuple:
        args = get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis:
            return ("array", args[0])
        return ("tuple", args)
    if tp in (bool, int, float, str):
        return (tp.__name__,)
    return ("other",)


def _coerce(value: Any, tp: Any, key: str, where: str) -> Any:
    """``value`` checked against annotation ``tp`` (ints widened to float, lists to tuples)."""

    def fail(extra: str = "") -> ConfigError:
        shown = repr(value) if not isinstance(value, int) or abs(value) < 10**30 else "<huge>"
        got = f"{type(value).__name__} {shown}"
        return ConfigError(f"{where}: {key}: expected {_type_name(tp)}, got {got}{extra}")

    kind, *details = _shape(tp)
    if kind == "any":
        return value
    if kind == "dataclass":
        if isinstance(value, tp):
            return value
        if not isinstance(value, Mapping):
            raise fail(" (a table)")
        return _build(tp, value, f"{key}", where)
    if kind == "union":
        (arms,) = details
        if value is None:
            if type(None) in arms:
                return None
            raise fail()
        errors = []
        for arm in arms:
            if arm is type(None):
                continue
            try:
                return _coerce(value, arm, key, where)
            except ConfigError as exc:
                errors.append(exc)
        if len(errors) == 1:
            raise errors[0]
        raise fail()
    if kind == "literal":
        (allowed,) = details
        # bool is an int: True must not match Literal[1]
        if any(type(value) is type(a) and value == a for a in allowed):
            return value
        raise ConfigError(
            f"{where}: {key}: expected one of {', '.join(repr(a) for a in allowed)}, got {value!r}"
        )
    if kind in ("array", "tuple"):
        if isinstance(value, (str, bytes)) or not isinstance(value, Sequence):
            raise fail(" (an array)")
        if kind == "array":
            return tuple(_coerce(v, details[0], f"{key}[{i}]", where) for i, v in enumerate(value))
        (args,) = details
        if len(args) != len(value):
            raise fail(f" ({len(value)} items, expected {len(args)})")
        return tuple(
            _coerce(v, a, f"{key}[{i}]", where)
            for i, (v, a) in enumerate(zip(value, args, strict=True))
        )
    if kind == "bool":
        if isinstance(value, bool):
            return value
        raise fail()
    if kind == "int":
        if isinstance(value, int) and not isinstance(value, bool):
            if not _INT64[0] <= value <= _INT64[1]:
                raise fail(" (beyond the 64-bit integers TOML has)")
            return value
        raise fail()
    if kind == "float":
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            try:
                return float(value)
            except OverflowError:  # an integer of 309+ digits
                raise fail(" (too large for a float)") from None
        raise fail()
    if kind == "str":
        if isinstance(value, str):
            return value
        raise fail()
    raise ConfigError(
        f"{where}: {key}: fields of type {_type_name(tp)} cannot be set from a config"
    )


@functools.cache
def _init_fields(cls: type) -> dict[str, dataclasses.Field[Any]]:
    return {f.name: f for f in dataclasses.fields(cls) if f.init}


def _nested_default(cls: type, name: str) -> Any:
    """The default of field ``name`` of ``cls`` when it is a dataclass instance (e.g.
    ``registration: RegistrationSettings = RegistrationSettings(kernel="huber")``), else
    None. Made only for a field the config sets with a table (a default factory builds and
    validates a whole config: making every one on every load cost a quarter of a load)."""
    f = _init_fields(cls)[name]
    if f.default is not dataclasses.MISSING:
        default = f.default
    elif f.default_factory is not dataclasses.MISSING:
        default = f.default_factory()
    else:
        return None
    return default if dataclasses.is_dataclass(default) and not isinstance(default, type) else None


def _build(cls: type[T], data: Mapping[str, Any], table: str, where: str) -> T:
    if not isinstance(data, Mapping):
        raise ConfigError(
            f"{where}: {_table_name(table)}: expected a table, got {type(data).__name__}"
        )
    fields = _config_fields(cls)
    kwargs: dict[str, Any] = {}
    for key, value in data.items():
        if not isinstance(key, str) or key not in fields:
            close = difflib.get_close_matches(str(key), list(fields), n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise ConfigError(
                f"{where}: unknown key {key!r} in {_table_name(table)} "
                f"(valid keys: {', '.join(fields)}){hint}"
            )
        name = f"{table}.{key}" if table else key
        if isinstance(value, Mapping) and (default := _nested_default(cls, key)) is not None:
            # a partial table changes the field's default instance, not the class defaults
            value = merge_config(config_to_dict(default), value)
        kwargs[key] = _coerce(value, fields[key], name, where)
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{where}: {_table_name(table)}: {exc}") from None


def config_from_dict(cls: type[T], data: Mapping[str, Any], *, where: str = "config") -> T:
    """Build dataclass ``cls`` from ``data`` (nested dicts for nested dataclasses), strictly
    (see the module docs). ``where`` prefixes error messages (a file name)."""
    if not (dataclasses.is_dataclass(cls) and isinstance(cls, type)):
        raise TypeError(f"cls: expected a dataclass type, got {cls!r}")
    return _build(cls, data, "", where)


def load_config(
    cls: type[T],
    source: str | os.PathLike[str] | Mapping[str, Any] | None = None,
    *,
    presets: Sequence[str] = (),
    overrides: Mapping[str, Any] | None = None,
    preset_table: Mapping[str, Mapping[str, Any]] | None = None,
) -> T:
    """The effective configuration: ``cls`` defaults < ``presets`` (in order) < ``source``
    (a TOML file or a dict) < ``overrides``.

    Parameters
    ----------
    cls : dataclass type
    source : path of a TOML file, a mapping, or None
    presets : names in ``preset_table`` (default :data:`PRESETS`); later ones win
    overrides : mapping, optional
        Highest-priority values (command-line flags), nested like the file.

    Raises
    ------
    ConfigError
        Unknown key (named with its table and the valid keys), wrong type, or a value the
        dataclass rejects; the message starts with the file (or ``config``).
    """
    if isinstance(presets, str):
        presets = [presets]
    merged: dict[str, Any] = {}
    for name in presets:
        merged = merge_config(merged, preset(name, preset_table))
    where = "config"
    if isinstance(source, (str, os.PathLike)):
        where = os.fspath(source)
        table = read_config_file(source)  # a fresh dict: no copy needed without presets
        merged = merge_config(merged, table) if merged else table
    elif isinstance(source, Mapping):
        merged = merge_config(merged, source)
    elif source is not None:
        raise TypeError(f"source: expected a path, a mapping or None, got {type(source).__name__}")
    if presets and source is not None:
        where = f"{where} (with presets {', '.join(presets)})"
    elif presets:
        where = f"presets {', '.join(presets)}"
    if overrides:
        merged = merge_config(merged, overrides)
    return config_from_dict(cls, merged, where=where)


# --------------------------------------------------------------------------- writing


def config_to_dict(obj: Any) -> dict[str, Any]:
    """The ``__init__`` fields of dataclass ``obj`` as nested dicts (tuples stay tuples)."""
    if not dataclasses.is_dataclass(obj) or isinstance(obj, type):
        raise TypeError(f"obj: expected a dataclass instance, got {type(obj).__name__}")
    out: dict[str, Any] = {}
    for f in dataclasses.fields(obj):
        if not f.init:
            continue
        value = getattr(obj, f.name)
        out[f.name] = config_to_dict(value) if dataclasses.is_dataclass(value) else value
    return out


def _toml_value(value: Any, key: str) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)
    if isinstance(value, (tuple, list)):
        return "[" + ", ".join(_toml_value(v, key) for v in value) + "]"
    raise TypeError(f"{key}: cannot write a {type(value).__name__} to TOML")


def _dump_table(data: Mapping[str, Any], table: str, lines: list[str]) -> None:
    for key, value in data.items():
        if isinstance(value, Mapping):
            continue
        name = f"{table}.{key}" if table else key
        if value is None:
            lines.append(f"# {key} = (unset: None)")
        else:
            lines.append(f"{key} = {_toml_value(value, name)}")
    for key, value in data.items():
        if isinstance(value, Mapping):
            name = f"{table}.{key}" if table else key
            lines.append("")
            lines.append(f"[{name}]")
            _dump_table(value, name, lines)


def dump_config(obj: Any) -> str:
    """The dataclass ``obj`` as TOML text (nested dataclasses as tables; None fields as
    comments); :func:`load_config` of it gives back an equal object."""
    lines: list[str] = [f"# {type(obj).__name__}"]
    _dump_table(config_to_dict(obj), "", lines)
    return "\n".join(lines) + "\n"


def write_config(path: str | Path, obj: Any) -> Path:
    """Write :func:`dump_config` of ``obj`` to ``path``; returns the path."""
    p = Path(path)
    p.write_text(dump_config(obj), encoding="utf-8")
    return p


__all__ = [
    "PRESETS",
    "ConfigError",
    "config_from_dict",
    "config_to_dict",
    "dump_config",
    "load_config",
    "merge_config",
    "preset",
    "read_config_file",
    "write_config",
]
