"""Strict mapping → dataclass conversion: what every YAML config of slimseg is read through.

Unknown and missing fields, and values of the wrong type, raise one error that names the
file and the dotted field (``recipe.yaml.lr0: expected a number, got 'x'``). Nested
dataclasses, ``tuple[...]``, optional (``X | None``) and the scalar types are converted.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from typing import Any, TypeVar

from slimseg.errors import ConfigError, SlimsegError

T = TypeVar("T")


def dataclass_from_mapping(
    cls: type[T], data: Any, where: str, error: type[SlimsegError] = ConfigError
) -> T:
    """Build dataclass ``cls`` from the mapping ``data`` (``where`` names its file/field).

    Unknown, missing or mistyped fields raise ``error``; an error raised by ``cls`` itself
    (its ``__post_init__`` checks) keeps its type and gains the ``where`` prefix.
    """
    if not isinstance(data, dict):
        raise error(f"{where}: expected a mapping for {cls.__name__}, got {data!r}")
    hints = typing.get_type_hints(cls)
    names = [f.name for f in dataclasses.fields(cls)]  # type: ignore[arg-type]
    unknown = sorted(set(data) - set(names))
    if unknown:
        raise error(f"{where}: unknown field(s) {unknown}; valid fields: {names}")
    kwargs = {k: _convert(v, hints[k], f"{where}.{k}", error) for k, v in data.items()}
    try:
        return cls(**kwargs)
    except TypeError as exc:
        raise error(f"{where}: {exc}") from None
    except SlimsegError as exc:
        raise type(exc)(f"{where}: {exc}") from None


def _convert(value: Any, hint: Any, where: str, error: type[SlimsegError]) -> Any:
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        inner = [a for a in args if a is not type(None)]
        return _convert(value, inner[0], where, error)
    if dataclasses.is_dataclass(hint):
        return dataclass_from_mapping(hint, value, where, error)  # type: ignore[arg-type]
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise error(f"{where}: expected a list, got {value!r}")
        item = args[0]
        return tuple(_convert(v, item, f"{where}[{i}]", error) for i, v in enumerate(value))
    if hint is float:
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            raise error(f"{where}: expected a number, got {value!r}")
        return float(value)
    if hint in (int, str, bool) and type(value) is not hint:
        raise error(f"{where}: expected {hint.__name__}, got {value!r}")
    return value
