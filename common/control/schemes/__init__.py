"""Bilateral control schemes, one module each, registered as entry points.

The registry is the entry-point group ``bipedtele.schemes``: a new scheme is one module (its
class holds its damping and its port laws) and one entry in its distribution's entry points;
nothing else names it (docs/schemes.md, "Where a scheme acts, and how one is written").

``paper`` (the default), ``paper-constant``, ``pd-worst-case``, ``pd-measured``, ``wave``,
``tdpa``; the contract is :class:`~bipedtele.control.schemes.base.Scheme`, checked by
:func:`~bipedtele.control.schemes.check.check_scheme`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from bipedtele.control.schemenames import ENTRY_POINT_GROUP, registered, scheme_names
from bipedtele.control.schemes.base import Scheme

if TYPE_CHECKING:
    from bipedtele.control.config import ControlConfig

__all__ = ["ENTRY_POINT_GROUP", "Scheme", "make_scheme", "scheme_class", "scheme_names"]


def scheme_class(name: str) -> type[Scheme]:
    """Return the scheme registered as ``name``.

    Raises
    ------
    ValueError
        No such scheme, or its entry point is not a :class:`Scheme`; the message names
        the allowed ones.
    """
    ep = registered().get(name)
    if ep is None:
        raise ValueError(f"scheme {name!r}: allowed: {', '.join(scheme_names())}")
    cls = ep.load()
    if not (isinstance(cls, type) and issubclass(cls, Scheme)) or getattr(cls, "name", None) != name:
        raise ValueError(f"scheme {name!r}: its entry point {ep.value} is not a Scheme named {name!r}")
    return cls


def make_scheme(cfg: ControlConfig) -> Scheme:
    """Return the scheme ``cfg.scheme`` built for ``cfg`` (worst delays ``cfg.worst_delays_s``)."""
    w1, w2 = cfg.worst_delays_s
    return scheme_class(cfg.scheme)(cfg, (w1, w2))
