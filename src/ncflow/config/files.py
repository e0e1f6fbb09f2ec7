"""Reading settings: configuration files (TOML, YAML) and ``KEY=VALUE`` overrides, merged into a preset.

Files: a TOML or YAML mapping with the same nesting as :class:`~ncflow.config.settings.Config`, e.g. ::

    preset = "fast"
    seed = 3
    [flow]
    width = 96
    [[phases]]
    metric = "varifold"
    steps = 100
    sigmas = [0.5]

``phases``, when given, replaces the preset's list. Dotted command-line overrides
(``flow.width=96``) are applied last. Every value is coerced to its setting's type and the result
validated (:func:`~ncflow.config.checks.validate_config`); a file must be a mapping with string
keys, at most 1 MiB, and a YAML file may not use aliases (``*name``: a few hundred bytes of nested
aliases expand to gigabytes). Error messages quote at most
:data:`~ncflow.config.quoting.QUOTE_LIMIT` characters of any value.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import os
import tomllib
import types
import typing

from ncflow.config.checks import validate_config
from ncflow.config.presets import preset
from ncflow.config.quoting import cut, names, one_line, quote
from ncflow.config.settings import Config
from ncflow.errors import InputError

#: largest configuration file read
MAX_CONFIG_BYTES = 1 << 20
#: most YAML nodes of a configuration file
MAX_YAML_NODES = 100_000


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _coerce(value, typ, where: str):
    origin = typing.get_origin(typ)
    args = typing.get_args(typ)
    if dataclasses.is_dataclass(typ):
        if not isinstance(value, dict):
            raise InputError(f"{where}: expected a table, got {quote(value)}")
        return _build(typ, value, where)
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            value = [value]
        inner = args[0]
        return tuple(_coerce(v, inner, f"{where}[{i}]") for i, v in enumerate(value))
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        errors = []
        for a in args:
            if a is type(None):
                continue
            try:
                return _coerce(value, a, where)
            except InputError as exc:
                errors.append(exc)
        if len(errors) == 1:  # Optional[X]: X's own message
            raise errors[0]
        raise InputError(f"{where}: cannot use {quote(value)}")
    if typ is bool:
        if isinstance(value, str):
            if value.lower() in ("true", "1", "yes", "on"):
                return True
            if value.lower() in ("false", "0", "no", "off"):
                return False
        if isinstance(value, bool):
            return value
        raise InputError(f"{where}: expected true/false, got {quote(value)}")
    if typ is int:
        return _as_int(value, where)
    if typ is float:
        if isinstance(value, str):
            try:
                value = float(value.strip())
            except ValueError:
                raise InputError(f"{where}: expected a number, got {quote(value)}") from None
        if not _is_number(value):
            raise InputError(f"{where}: expected a number, got {quote(value)}")
        out = float(value)  # an int too large for a float raises OverflowError
        if not math.isfinite(out):
            raise InputError(f"{where} must be finite, got {quote(value)}")
        return out
    if typ is str:
        if value is None:
            return "none"  # ``key=none`` of a string setting is the word
        if not isinstance(value, (str, int, float)) or isinstance(value, bool):
            raise InputError(f"{where}: expected a word, got {quote(value)}")
        return str(value)
    return value


def _as_int(value, where: str) -> int:
    """An integer setting from an int, an integral finite float or a decimal string."""
    if isinstance(value, str):
        text = value.strip()
        try:
            value = int(text)
        except ValueError:
            try:
                value = float(text)
            except ValueError:
                raise InputError(f"{where}: expected an integer, got {quote(text)}") from None
    if not _is_number(value):
        raise InputError(f"{where}: expected an integer, got {quote(value)}")
    if isinstance(value, float):
        if not math.isfinite(value):
            raise InputError(f"{where} must be a finite integer, got {quote(value)}")
        if value != int(value):
            raise InputError(f"{where}: expected an integer, got {quote(value)}")
        value = int(value)
    return int(value)


def _check_keys(data: dict, where: str | None, prefix: str = "") -> None:
    for key in data:
        if not isinstance(key, str):
            name = f"{prefix}{quote(key)}"
            raise InputError(f"setting names must be words, got {name} ({type(key).__name__})", where)


def _unknown(unknown, known, prefix: str = "") -> str:
    """The message for unknown setting names: the closest known ones first, then the known ones."""
    close = sorted({m for u in unknown for m in difflib.get_close_matches(str(u)[:100], known, n=3, cutoff=0.7)})
    hint = f"; did you mean {', '.join(prefix + c for c in close)}?" if close else ""
    return f"unknown setting(s) {prefix}{names(unknown)}{hint} (known: {names(known, 12)})"


def _build(cls, data: dict, where: str):
    _check_keys(data, None, f"{where}." if where else "")
    hints = typing.get_type_hints(cls)
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = set(data) - known
    if unknown:
        raise InputError(f"{where}: {_unknown(unknown, known)}")
    base = cls()
    kwargs = {}
    for name, value in data.items():
        kwargs[name] = _coerce(value, hints[name], f"{where}.{name}" if where else name)
    return dataclasses.replace(base, **kwargs)


def _merge(config: Config, data: dict, where: str | None) -> Config:
    """Replace the fields given in ``data`` (nested tables merge into the current sub-config)."""
    _check_keys(data, where)
    hints = typing.get_type_hints(Config)
    known = {f.name for f in dataclasses.fields(Config)}
    unknown = set(data) - known
    if unknown:
        raise InputError(_unknown(unknown, known), where)
    updates = {}
    for name, value in data.items():
        current = getattr(config, name)
        if dataclasses.is_dataclass(current) and isinstance(value, dict):
            _check_keys(value, where, f"{name}.")
            sub_hints = typing.get_type_hints(type(current))
            sub_names = {f.name for f in dataclasses.fields(current)}
            bad = set(value) - sub_names
            if bad:
                raise InputError(_unknown(bad, sub_names, f"{name}."), where)
            updates[name] = dataclasses.replace(
                current, **{k: _coerce(v, sub_hints[k], f"{name}.{k}") for k, v in value.items()}
            )
        else:
            updates[name] = _coerce(value, hints[name], name)
    return dataclasses.replace(config, **updates)


def _yaml_loader():
    """A safe YAML loader that refuses aliases and caps the number of nodes."""
    import yaml

    class Loader(yaml.SafeLoader):
        nodes = 0

        def compose_node(self, parent, index):
            if self.check_event(yaml.AliasEvent):
                mark = self.peek_event().start_mark
                raise InputError(f"YAML aliases (*name) are not allowed (line {mark.line + 1})")
            self.nodes += 1
            if self.nodes > MAX_YAML_NODES:
                raise InputError(f"more than {MAX_YAML_NODES} YAML nodes")
            return super().compose_node(parent, index)

    return Loader


def _read_file(path: str) -> dict:
    try:
        size = os.path.getsize(path)
        if size > MAX_CONFIG_BYTES:
            raise InputError(f"configuration file is too large ({size} bytes; at most {MAX_CONFIG_BYTES})", path)
        if path.lower().endswith((".yaml", ".yml")):
            with open(path, encoding="utf-8") as fh:
                text = fh.read()
            loader = _yaml_loader()(text)
            try:
                data = loader.get_single_data()
            finally:
                loader.dispose()
            data = {} if data is None else data
        elif path.lower().endswith(".toml"):
            with open(path, "rb") as fh:
                data = tomllib.load(fh)
        else:
            raise InputError("configuration files must be .toml, .yaml or .yml", path)
    except InputError as exc:
        if exc.path is None:
            raise InputError(str(exc), path) from None
        raise
    except RecursionError:
        raise InputError("cannot parse configuration (nested too deeply)", path) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read configuration ({one_line(exc)})", path) from None
    except Exception as exc:  # noqa: BLE001 -- parse errors of either library
        if "yaml" in type(exc).__module__ and not isinstance(exc, (ValueError, TypeError)):
            text = getattr(exc, "problem", None) or one_line(exc)
            mark = getattr(exc, "problem_mark", None)
            where = f" at line {mark.line + 1}" if mark is not None else ""
            raise InputError(f"cannot parse configuration ({cut(str(text))}{where})", path) from None
        raise InputError(f"cannot parse configuration ({one_line(exc)})", path) from None
    if not isinstance(data, dict):
        raise InputError(f"configuration must be a mapping of settings, got {type(data).__name__}", path)
    return data


def load_config(path: str | os.PathLike | None = None, preset_name: str | None = None) -> Config:
    """Preset (``preset_name``, else the file's ``preset`` key, else ``fast``) updated by a TOML/YAML file.

    Raises:
        InputError: one line naming the file: unreadable, too large, not a mapping with string
            keys, YAML aliases, unknown settings, or a value out of range (:func:`validate_config`).
    """
    data: dict = {}
    if path is not None:
        path = os.fspath(path)
        if not os.path.exists(path):
            raise InputError("no such file", path)
        if not os.path.isfile(path):
            raise InputError("not a file", path)
        data = _read_file(path)
        _check_keys(data, path)
    name = preset_name or data.get("preset") or "fast"
    if not isinstance(name, str):
        raise InputError(f"preset must be a word, got {quote(name)}", path)
    config = preset(name)
    data = {k: v for k, v in data.items() if k != "preset"}
    try:
        return validate_config(_merge(config, data, path))
    except InputError as exc:
        if path and not str(exc).startswith(str(path)):
            raise InputError(str(exc), path) from None
        raise
    except (OverflowError, RecursionError, TypeError, ValueError) as exc:  # a value no setting can hold
        raise InputError(f"bad setting ({one_line(exc)})", path) from None


def apply_overrides(config: Config, overrides: list[str]) -> Config:
    """Apply ``section.key=value`` strings (e.g. ``flow.width=96``, ``seed=3``)."""
    for item in overrides:
        if "=" not in item:
            raise InputError(f"override {quote(item)} must look like key=value (e.g. flow.width=96)")
        key, value = item.split("=", 1)
        parts = key.strip().split(".")
        if not all(p.isidentifier() for p in parts):
            raise InputError(f"override {quote(item)}: {quote(key.strip())} is not a setting name")
        parsed: typing.Any = value.strip()
        if parsed.startswith("[") and parsed.endswith("]"):
            parsed = [p.strip() for p in parsed[1:-1].split(",") if p.strip()]
        if parsed == "none" or parsed == "None":
            parsed = None
        nested: typing.Any = parsed
        for p in reversed(parts[1:]):
            nested = {p: nested}
        try:
            config = _merge(config, {parts[0]: nested}, None)
        except (OverflowError, TypeError, ValueError) as exc:
            if isinstance(exc, InputError):
                raise
            raise InputError(f"override {quote(item)}: {one_line(exc)}") from None
    return validate_config(config)
