"""Command-line options that set the fields of a typed config dataclass, and the config built back.

A command lists its options once, as :class:`Option` entries naming the config field(s) each sets;
:func:`add_config_arguments` turns them into argparse arguments and :func:`config_from_args`
builds the config from the parsed values, so no command copies fields by hand:

- the default is the config's own value (the ``base`` instance given, or the field's default),
- a ``Literal[...]`` field becomes ``choices`` in the Literal's order,
- a ``bool`` field becomes a switch that flips its default (``--force``, ``--no-restrict``),
- ``int``/``float`` fields get the checked number types of :mod:`backend.commands.options`
  unless the option names a narrower one.

Fields are dotted paths into nested configs (``train.densify.max_gaussians``); an option that
names several fields sets the same value into each (``--seed`` into every stage of a decomposition).
A value of ``None`` (an option left out whose default is ``None``) leaves the fields as they are.
"""

from __future__ import annotations

import argparse
import dataclasses
import typing
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any, Literal

from backend.commands import options as opt

_FROM_CONFIG: Any = object()  # Option.default when the config's own value is the default


@dataclass(frozen=True)
class Option:
    """One command-line option and the config field(s) it sets."""

    flag: str
    """The option as typed: ``--max-angle``."""
    fields: str | tuple[str, ...]
    """Dotted path of the config field it sets; several: the same value goes into each."""
    help: str
    """The text --help shows (argparse formats it: ``%%`` for a percent sign)."""
    type: Callable[[str], Any] | None = None
    """Parser of the value (a checked number type); default: from the field's annotation."""
    default: Any = _FROM_CONFIG
    """Default when it is not the config's value: ``None`` leaves each field as it is."""
    metavar: str | tuple[str, ...] | None = None
    """The value's name in --help; default: the option's name in capitals."""
    nargs: int | None = None
    """Values the option takes (a tuple field: ``--size W H``); default one."""

    @property
    def paths(self) -> tuple[str, ...]:
        return (self.fields,) if isinstance(self.fields, str) else self.fields


def add_config_arguments(parser: argparse.ArgumentParser | argparse._ArgumentGroup, base: Any,
                         options: Iterable[Option]) -> None:
    """Add ``options`` to ``parser`` (or an argument group); ``base``: the config instance or class
    whose values are the defaults."""
    for o in options:
        annotation = _annotation(base, o.paths[0])
        value = _value(base, o.paths[0])
        default = value if o.default is _FROM_CONFIG else o.default
        kwargs: dict[str, Any] = {"default": default, "help": o.help}
        if o.metavar is not None:
            kwargs["metavar"] = o.metavar
        if o.nargs is not None:
            kwargs["nargs"] = o.nargs
        if annotation is bool:
            # the switch flips the config's default: --force sets True, --no-restrict sets False
            parser.add_argument(o.flag, action="store_false" if value else "store_true", dest=_dest(base, o),
                                **kwargs)
            continue
        choices = _literal_choices(annotation)
        if choices is not None:
            kwargs["choices"] = choices
            if isinstance(choices[0], int) and not isinstance(choices[0], bool):  # through the number check
                kwargs["type"] = opt.integer(min(choices), max(choices))
            elif not isinstance(choices[0], str):
                kwargs["type"] = type(choices[0])
        parse = o.type or (None if choices is not None else _checked_type(annotation))
        if parse is not None:
            kwargs["type"] = parse
        parser.add_argument(o.flag, **kwargs)


def config_from_args(base: Any, options: Iterable[Option], args: argparse.Namespace) -> Any:
    """The config ``base`` (an instance or a dataclass) with the parsed values of ``options``."""
    values: dict[str, Any] = {}
    for o in options:
        v = getattr(args, _dest(base, o))
        if v is not None:
            values.update((path, v) for path in o.paths)
    return with_fields(base, values)


def with_fields(base: Any, values: Mapping[str, Any]) -> Any:
    """A copy of the config ``base`` (an instance, or a dataclass for its defaults) with the fields at
    the dotted paths of ``values`` replaced; nested configs are copied, never changed in place."""
    direct: dict[str, Any] = {}
    nested: dict[str, dict[str, Any]] = {}
    for path, v in values.items():
        head, _, rest = path.partition(".")
        if rest:
            nested.setdefault(head, {})[rest] = v
        else:
            direct[head] = v
    for head, sub in nested.items():
        direct[head] = with_fields(_value(base, head), sub)
    return base(**direct) if isinstance(base, type) else dataclasses.replace(base, **direct)


def _dest(base: Any, o: Option) -> str:
    """The attribute of the parsed args: a switch's field name (``restrict`` for ``--no-restrict``), else
    argparse's own name for a long option (``--max-angle``: ``max_angle``; it is also the metavar)."""
    if _annotation(base, o.paths[0]) is bool:
        return o.paths[0].rpartition(".")[2]
    return o.flag.lstrip("-").replace("-", "_")


def _value(base: Any, path: str) -> Any:
    """The value at ``path`` of an instance, or the default of a dataclass's field (None if it has none)."""
    head, _, rest = path.partition(".")
    if isinstance(base, type):
        f = {f.name: f for f in dataclasses.fields(base)}[head]
        if f.default is not dataclasses.MISSING:
            v = f.default
        elif f.default_factory is not dataclasses.MISSING:
            v = f.default_factory()
        else:
            v = None
    else:
        v = getattr(base, head)
    return _value(v, rest) if rest else v


def _annotation(base: Any, path: str) -> Any:
    """The resolved type annotation of the field at ``path``."""
    parent, _, leaf = path.rpartition(".")
    owner = _value(base, parent) if parent else base
    cls = owner if isinstance(owner, type) else type(owner)
    return typing.get_type_hints(cls)[leaf]


def _literal_choices(annotation: Any) -> tuple | None:
    """The values of a ``Literal[...]`` (also inside ``X | None``), else None."""
    if typing.get_origin(annotation) is Literal:
        return typing.get_args(annotation)
    for arg in typing.get_args(annotation):
        if typing.get_origin(arg) is Literal:
            return typing.get_args(arg)
    return None


def _checked_type(annotation: Any) -> Callable[[str], Any] | None:
    """A finite number for ``float``, an integer for ``int`` (also inside ``X | None``); None for text."""
    kinds = set(typing.get_args(annotation)) | {annotation}
    if float in kinds:
        return opt.number()
    if int in kinds:
        return opt.integer()
    return None
