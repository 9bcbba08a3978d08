"""Training configs from flat TOML files: one reader for every trainer, errors that name the key.

A trainer's config is a frozen dataclass whose fields all have defaults (ints, floats, bools, strings and tuples of
ints). A TOML file sets any of them; unknown keys, wrong types and values the dataclass rejects are one-line
:class:`~edge_explorer.errors.EdgeExplorerError` messages that name the file and the key.
"""

from __future__ import annotations

import dataclasses
import tomllib
from pathlib import Path
from typing import Any, TypeVar

from edge_explorer.errors import EdgeExplorerError

Config = TypeVar("Config")


def config_from_dict(cls: type[Config], data: dict[str, Any], source: str = "<config>") -> Config:
    """``cls(**data)`` after checking every key and value against ``cls``'s fields and defaults."""
    fields = {f.name for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(set(data) - fields)
    if unknown:
        raise EdgeExplorerError(f"{source}: unknown key(s) {unknown}; allowed: {sorted(fields)}")
    defaults = cls()
    values = {}
    for key, value in data.items():
        default = getattr(defaults, key)
        if isinstance(default, tuple):
            if not (isinstance(value, list) and all(type(v) is int for v in value)):
                raise EdgeExplorerError(f"{source}: {key} must be a list of integers, got {value!r}")
            value = tuple(value)
        elif isinstance(default, float) and type(value) is int:
            value = float(value)
        elif type(value) is not type(default):
            raise EdgeExplorerError(f"{source}: {key} must be {type(default).__name__}, got {value!r}")
        values[key] = value
    try:
        return cls(**values)
    except ValueError as exc:
        raise EdgeExplorerError(f"{source}: {exc}") from None


def load_toml_config(cls: type[Config], path: str | Path) -> Config:
    """The config of the TOML file at ``path`` (see :func:`config_from_dict`)."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise EdgeExplorerError(f"{path}: no such config file") from None
    except tomllib.TOMLDecodeError as exc:
        raise EdgeExplorerError(f"{path}: not valid TOML: {exc}") from None
    return config_from_dict(cls, data, str(path))
