"""How a profile section declares its fields: :func:`param` (default, range, unit, doc) and :class:`ConfigError`.

A section is a frozen dataclass whose fields are made with :func:`param`; the range and
unit travel in the field's metadata, which :mod:`bipedtele.config.parse` turns into a
validator and the docs into a table. Nothing here imports a section, so every module that
declares one (the core's, a role's, a part's) imports only this (or
:mod:`bipedtele.config.profile`, which re-exports it).
"""

from __future__ import annotations

import dataclasses
from dataclasses import field
from typing import Any

__all__ = ["ConfigError", "param"]


class ConfigError(ValueError):
    """A configuration file or override is invalid. The message is one line."""


def param(
    default: Any = dataclasses.MISSING,
    *,
    lo: float | None = None,
    hi: float | None = None,
    lo_open: bool = False,
    unit: str = "",
    doc: str = "",
    default_factory: Any = dataclasses.MISSING,
    path: bool = False,
    secret: bool = False,
) -> Any:
    """Declare a config field with its allowed range.

    Parameters
    ----------
    default : object
        Default value.
    lo, hi : float, optional
        Inclusive bounds for numbers (and for every element of a list of numbers).
    lo_open : bool
        If true the lower bound is exclusive (``value > lo``).
    unit : str
        Physical unit, shown in error messages and in docs.
    doc : str
        One-line description.
    path : bool
        The value is a file or folder path (a relative one in a profile file is read
        relative to that file's folder).
    secret : bool
        The value is a secret (a password): never printed or recorded.
    """
    meta = {"lo": lo, "hi": hi, "lo_open": lo_open, "unit": unit, "doc": doc, "path": path, "secret": secret}
    if default_factory is not dataclasses.MISSING:
        return field(default_factory=default_factory, metadata=meta)
    return field(default=default, metadata=meta)
