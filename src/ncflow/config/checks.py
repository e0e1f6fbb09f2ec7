"""The one walker over a settings tree and the one validator that reads each field's :class:`Rule`.

:func:`walk` yields every leaf setting with its dotted name (``flow.width``, ``phases[0].lr``);
:func:`validate_config` checks each one against its declared type and its rule (finite numbers,
integral integers, bounds, choices, checks) and then the few rules between settings, raising one
:class:`~ncflow.errors.InputError` line that names the setting.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import types
import typing
from collections.abc import Iterator

from ncflow.config.quoting import quote
from ncflow.config.settings import Config, Rule, rule_of
from ncflow.errors import InputError


@dataclasses.dataclass(frozen=True)
class Leaf:
    """One leaf setting of a tree: its dotted name, its table's (``""`` at the top), its field (None
    for an item of ``phases`` that is no phase table), its declared type and its value.
    """

    name: str
    table: str
    field: dataclasses.Field | None
    hint: object
    value: object


@functools.cache
def _hints(cls) -> dict:
    return typing.get_type_hints(cls)


def walk(config, prefix: str = "", table: str = "") -> Iterator[Leaf]:
    """Every leaf setting of ``config`` (phases as ``phases[i].NAME``), depth first in field order."""
    for f in dataclasses.fields(config):
        value, name = getattr(config, f.name), f"{prefix}{f.name}"
        if dataclasses.is_dataclass(value):
            yield from walk(value, f"{name}.", name)
        elif f.name == "phases" and isinstance(value, tuple):
            for i, phase in enumerate(value):
                where = f"{name}[{i}]"
                if dataclasses.is_dataclass(phase):
                    yield from walk(phase, f"{where}.", where)
                else:
                    yield Leaf(where, table, None, None, phase)
        else:
            yield Leaf(name, table, f, _hints(type(config))[f.name], value)


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _base(hint) -> tuple[object, bool]:
    """(the type of a setting without ``| None``, whether None is allowed)."""
    args = typing.get_args(hint)
    if typing.get_origin(hint) in (typing.Union, types.UnionType) and type(None) in args:
        return next(a for a in args if a is not type(None)), True
    return hint, False


def _say(template: str, leaf: Leaf, **extra) -> InputError:
    return InputError(template.format(name=leaf.name, table=leaf.table, value=quote(leaf.value), **extra))


def _check_type(leaf: Leaf, base) -> None:
    """One line when a value is not of its declared type (or not finite)."""
    v, name = leaf.value, leaf.name
    if isinstance(v, (list, dict, set)):
        raise InputError(f"{name}: expected a single value, got {quote(v)}")
    if base is bool and not isinstance(v, bool):
        raise InputError(f"{name} must be true or false")
    if base is int and not (_is_number(v) and isinstance(v, int)):
        raise InputError(f"{name} must be an integer, got {quote(v)}")
    items = v if typing.get_origin(base) is tuple else (v,)
    if base is float or typing.get_origin(base) is tuple:
        for item in items:
            if not _is_number(item):
                raise InputError(f"{name}: expected a number, got {quote(item)}")
            if not math.isfinite(item):
                raise InputError(f"{name} must be finite, got {quote(item)}")
    if base is str and not isinstance(v, str):
        raise InputError(f"{name}: expected a word, got {quote(v)}")


def _check_rule(leaf: Leaf, rule: Rule, base) -> None:
    """One line when a value is out of its rule's range, choices or check."""
    problem = rule.problem(leaf.value)
    if problem is None:
        return
    if base is int and not problem.count("{value}"):
        if rule.lo is not None and leaf.value < rule.lo:
            raise _say((problem or "{name} must be at least {lo}") + " (got {value})", leaf, lo=rule.lo)
        raise _say("{name} must be at most {hi} (got {value})", leaf, hi=rule.hi)
    raise _say(problem or "{name} is out of range (got {value})", leaf)


BETWEEN_SETTINGS = (
    (
        lambda c: not (c.flow.skinning and c.flow.div_free),
        "flow.div_free needs flow.skinning=false (blended bone velocities are not divergence-free)",
    ),
    (
        lambda c: all(p.quadrature == 1 or p.metric == "varifold" for p in c.phases),
        'a phase\'s quadrature applies to the Varifold only (metric = "varifold")',
    ),
    (lambda c: len(c.phases) >= 1, "at least one phase is needed"),
    (lambda c: c.total_steps >= 1, "the phases have no steps"),
)
"""The rules that tie settings together: (test of the whole configuration, message)."""


def validate_config(config: Config) -> Config:
    """Check every setting against its declared type and its :class:`~ncflow.config.settings.Rule`,
    then :data:`BETWEEN_SETTINGS`; raise :class:`InputError` naming the first setting that fails.
    Returns ``config``.
    """
    if not isinstance(config, Config):
        raise InputError(f"expected a Config, got {type(config).__name__}")
    for leaf in walk(config):
        if leaf.field is None:
            raise InputError(f"{leaf.name} must be a phase table, got {quote(leaf.value)}")
        base, optional = _base(leaf.hint)
        if leaf.value is None and optional:
            continue
        _check_type(leaf, base)
        _check_rule(leaf, rule_of(leaf.field), base)
    for holds, message in BETWEEN_SETTINGS:
        if not holds(config):
            raise InputError(message)
    return config
